"""The commands of ``cell`` (:mod:`positioning_cell.tools.cell`: the command line and the
exit codes): each asks the running cell through
:class:`~positioning_cell.ros.operator_client.OperatorClient` and reports text or JSON. Imported
once the command line is parsed, so ``cell --help`` and a usage error load none of this."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from positioning_cell import names
from positioning_cell.errors import PositioningError
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.frames.transforms import Transform
from positioning_cell.limits.speed import Speeds as LibrarySpeeds
from positioning_cell.polling import wait_until
from positioning_cell.tools import cell_format as cf
from positioning_cell.tools.cell_parser import default_timeout, human_pose
from positioning_cell.tools.cell_watch import run_window, watch
from positioning_cell.tools.exits import Exit
from positioning_cell.tools.interruption import Interrupted, Signals, interruptible

if TYPE_CHECKING:
    from rich.console import Group

    from positioning_cell.ros.early import ClientNode
    from positioning_cell.ros.operator_client import Limits, OperatorClient

#: status: after the positioner's status, how long the driver's status, the target and the
#: estimate may take to come (s).
STATUS_EXTRA_WAIT = 2.0
#: Longest wait of ``cell status`` (s) for axis ranges while the positioner's range search
#: starts (the first reader of /positioner/axis_ranges starts its worker: about a second).
STATUS_RANGES_WAIT = 6.0


@dataclass
class Report:
    """What a command found: its exit code, the fields of its JSON document, its text for
    people, and an error (why it failed) for stderr and the document."""

    code: Exit
    fields: dict[str, Any] = field(default_factory=dict)
    text: str = ''
    error: str | None = None


class Output:
    """stdout for the answer (text or JSON), stderr for errors and the progress bar (only on
    a terminal)."""

    def __init__(self, as_json: bool, stdout: IO[str] | None = None,
                 stderr: IO[str] | None = None) -> None:
        self.as_json = as_json
        self.stdout = stdout or sys.stdout
        self.stderr = stderr or sys.stderr
        self._progress = 0
        try:
            self.tty = self.stderr.isatty()
        except (AttributeError, ValueError):
            self.tty = False

    def progress(self, line: str) -> None:
        """Redraw the progress line (a terminal only)."""
        if self.tty:
            self.stderr.write('\r' + line.ljust(self._progress))
            self.stderr.flush()
            self._progress = len(line)

    def end_progress(self) -> None:
        """Clear the progress line."""
        if self.tty and self._progress:
            self.stderr.write('\r' + ' ' * self._progress + '\r')
            self.stderr.flush()
            self._progress = 0

    def note(self, text: str) -> None:
        """A line on stderr (e.g. 'cancelling')."""
        self.end_progress()
        self.stderr.write(f'cell: {text}\n')
        self.stderr.flush()

    def emit(self, command: str, report: Report) -> None:
        """Print the report: one JSON document, or its text (and its error on stderr)."""
        self.end_progress()
        if self.as_json:
            doc = cf.command_document(command, report.code, report.error, report.fields)
            self.stdout.write(cf.json_text(doc) + '\n')
        elif report.text:
            self.stdout.write(report.text.rstrip('\n') + '\n')
        if report.error:
            self.stderr.write(f'cell: {report.error}\n')
        self.stdout.flush()
        self.stderr.flush()


@dataclass
class Session:
    """One command's client (:class:`~positioning_cell.ros.operator_client.OperatorClient`,
    its calls bounded by the timeout), signals and output."""

    client: OperatorClient
    signals: Signals
    out: Output

    @property
    def timeout(self) -> float:
        return self.client.timeout

    def interrupts(self) -> int:
        """SIGINT and SIGTERM counted so far."""
        return self.signals.count


def _not_there(err: TimeoutError) -> str:
    return f'the cell is not there: {err}'


# -- the commands ---------------------------------------------------------------------------------
def cmd_move(session: Session, args: Any) -> Report:
    request = cf.move_request(args)
    fields: dict[str, Any] = {'request': request.document()}
    try:
        with session.signals.deferred():
            run = session.client.move(request, session.interrupts, session.out.note,
                                      session.out.progress)
    except TimeoutError as err:
        return Report(Exit.NOT_THERE, fields | cf.GoalRun().fields(), '', _not_there(err))
    return Report(run.exit_code, fields | run.fields(), run.text(), run.error)


def cmd_home(session: Session, args: Any) -> Report:
    try:
        with session.signals.deferred():
            run = session.client.home(session.interrupts, session.out.note,
                                      session.out.progress)
    except TimeoutError as err:
        return Report(Exit.NOT_THERE, cf.GoalRun().fields(), '', _not_there(err))
    return Report(run.exit_code, run.fields(), run.text(), run.error)


def cmd_check(session: Session, args: Any) -> Report:
    request = cf.move_request(args)
    report = session.client.check(request)
    return Report(report.exit_code, {'request': request.document(), **report.document()},
                  report.text())


def cmd_status(session: Session, args: Any) -> Report:
    client = session.client
    feed = client.status_feed()
    deadline = time.monotonic() + session.timeout
    notes = []
    systems = None
    file = ''
    try:
        systems, file = client.coordinate_systems()
    except PositioningError as err:
        notes.append(f'user positions unknown: {err}')
    mechanism = None
    try:
        mechanism = client.mechanism()
    except (TimeoutError, PositioningError) as err:
        notes.append(f'machine positions unknown (the positioner\'s mechanism): {err}')
    status = wait_until(feed.positioner, max(deadline - time.monotonic(), 0.0),
                        f'the status "{names.STATUS_POSITIONER}" on {names.DIAGNOSTICS}')
    with contextlib.suppress(TimeoutError):
        wait_until(lambda: feed.driver() and feed.target() and feed.estimate()
                   and feed.measured() and feed.axis_ranges(), STATUS_EXTRA_WAIT, 'the rest')
    with contextlib.suppress(TimeoutError):  # the first reader starts the range search
        wait_until(lambda: (r := feed.axis_ranges()) is not None and not r.pending,
                   STATUS_RANGES_WAIT, 'the axis ranges')
    driver, target, estimate = feed.driver(), feed.target(), feed.estimate()
    measured = feed.measured()
    if measured is None:
        notes.append(f'no tracker reading on {names.MEASURED_POSE}')
    if driver is None:
        notes.append(f'no status "{names.STATUS_DRIVER}" on {names.DIAGNOSTICS}')
    if target is None:
        notes.append(f'no target on {names.TARGET} (nothing commanded yet)')
    if estimate is None:
        notes.append(f'no estimate on {names.ESTIMATED_POSE}')
    ranges = feed.axis_ranges()
    if ranges is None:
        notes.append(f'no axis ranges on {names.AXIS_RANGES}')
    report = cf.StatusReport(
        positioner=status.values, positioner_message=status.message,
        positioner_level=status.level, driver=None if driver is None else driver.values,
        target=target, estimate=estimate, systems=systems, systems_file=file,
        mechanism=mechanism, notes=notes, measured=measured, now=time.time(),
        axis_ranges=ranges)
    return Report(Exit.OK, report.document(), report.text())


def cmd_frames_get(session: Session, args: Any) -> Report:
    systems, file = session.client.coordinate_systems()
    named = session.client.system_names()
    return Report(Exit.OK, {'coordinate_systems': cf.systems_document(systems, file, named)},
                  cf.systems_text(systems, file, named))


def cmd_frames_define(session: Session, args: Any) -> Report:
    value = Transform.from_human(human_pose(args))
    success, reason = session.client.define_coordinate_system(args.kind, args.name, value,
                                                              args.use)
    return _systems_report(session, success, reason, {
        'defined': {'kind': args.kind, 'name': args.name, 'active': args.use,
                    'pose': cf.transform_document(value)}})


def cmd_frames_use(session: Session, args: Any) -> Report:
    success, reason = session.client.select_coordinate_systems(args.user or '',
                                                               args.object or '')
    return _systems_report(session, success, reason,
                           {'selected': {'user': args.user, 'object': args.object}})


def _systems_report(session: Session, success: bool, reason: str,
                    fields: dict[str, Any]) -> Report:
    """A change of the named systems answered: refused with why, else the systems now."""
    fields |= {'success': success, 'reason': reason}
    if not success:
        return Report(Exit.REFUSED, fields, '', f'refused: {reason}')
    report = cmd_frames_get(session, None)
    return Report(Exit.OK, fields | report.fields, report.text)


def cmd_frames_set(session: Session, args: Any) -> Report:
    user, obj = cf.frames_request(args)
    previous = None
    if user is None or obj is None:
        previous, _ = session.client.coordinate_systems()
        user = previous.user if user is None else user
        obj = previous.object if obj is None else obj
    systems = CoordinateSystems(user=user, object=obj)
    success, reason = session.client.set_coordinate_systems(systems)
    fields = {'success': success, 'reason': reason,
              'coordinate_systems': cf.systems_document(systems),
              'previous': None if previous is None else cf.systems_document(previous)}
    if not success:
        return Report(Exit.REFUSED, fields, '', f'refused: {reason}')
    return Report(Exit.OK, fields, cf.systems_text(systems) + (f'\n{reason}' if reason
                                                                else ''))


def _limits_fields(limits: Limits) -> tuple[dict[str, Any], str]:
    boxes = (limits.factory, limits.machine, limits.user, limits.constraints)
    return cf.limits_document(*boxes), cf.limits_text(*boxes)


def cmd_limits_get(session: Session, args: Any) -> Report:
    doc, text = _limits_fields(session.client.limits())
    return Report(Exit.OK, {'limits': doc}, text)


def cmd_limits_set(session: Session, args: Any) -> Report:
    current = session.client.limits()
    machine, user = cf.limits_request(args).merged(current.machine, current.user)
    return _set_limits(session, current, machine, user)


def cmd_limits_reset(session: Session, args: Any) -> Report:
    """The factory's limits back: the machine box the factory's, no user box."""
    current = session.client.limits()
    unlimited = (np.full(6, -math.inf), np.full(6, math.inf))
    return _set_limits(session, current, current.factory, unlimited)


def _set_limits(session: Session, current: Limits, machine: cf.Box, user: cf.Box) -> Report:
    """SetLimits with ``machine`` and ``user`` (SI), reported with the boxes in force after
    it (``current`` before it, when refused)."""
    success, reason = session.client.set_limits(machine, user)
    fields: dict[str, Any] = {'success': success, 'reason': reason,
                              'requested': {'machine': cf.box_document(machine),
                                            'user': cf.box_document(user)}}
    if not success:
        return Report(Exit.REFUSED, fields | {'limits': _limits_fields(current)[0]}, '',
                      f'refused: {reason}')
    doc, text = _limits_fields(session.client.limits())
    return Report(Exit.OK, fields | {'limits': doc}, text)


def cmd_speed(session: Session, args: Any) -> Report:
    request = cf.speed_request(args)
    answer = session.client.set_speed(request)
    fields = {'query': request == LibrarySpeeds.keep(), 'success': answer.success,
              'reason': answer.reason, 'requested': cf.speeds_document(request),
              'current': cf.speeds_document(answer.current),
              'maximum': cf.speeds_document(answer.maximum)}
    text = cf.speeds_text(answer.current, answer.maximum)
    if not answer.success:
        return Report(Exit.REFUSED, fields, text, f'refused: {answer.reason}')
    return Report(Exit.OK, fields, text)


def cmd_jog(session: Session, args: Any) -> Report:
    axis, delta = cf.jog_request(args)
    answer = session.client.jog(axis, delta)
    success, code_name, reason, position = answer
    unit = cf.jog_unit(axis)
    fields = {'axis': axis, 'delta': delta, 'delta_human': args.delta, 'unit': unit,
              'success': success, 'code_name': code_name, 'reason': reason,
              'position': position, 'position_human': cf.jog_human(axis, position)}
    code = cf.jog_exit_code(success, code_name)
    if not success:  # the answer's position is no reading then: neither echoed nor given
        fields |= {'position': None, 'position_human': None}
        return Report(code, fields, '', f'{code_name or "refused"}: {reason}')
    text = f'{axis}: {cf.jog_human(axis, position):.4f} {unit}'
    return Report(code, fields, text + (f' ({reason})' if reason else ''))


def cmd_stop(session: Session, args: Any) -> Report:
    success, message = session.client.stop()
    fields = {'success': success, 'message': message}
    if not success:
        return Report(Exit.REFUSED, fields, '', f'refused: {message}')
    return Report(Exit.OK, fields, message or 'stopped')


def cmd_watch(session: Session, args: Any) -> Report:
    """The live watch window (:mod:`positioning_cell.tools.cell_watch`) until q or Ctrl-C."""
    def stop() -> bool:
        return session.signals.count > 0

    with session.signals.deferred():
        if args.panel:  # the coordinated cell's window (imported here, as it is used)
            from positioning_cell.tools.cell_watch_panel import render_panel
            source = session.client.panel_watch_inputs()

            def draw(now: float) -> tuple[Group, bool]:
                state = source.snapshot()
                return render_panel(state, now), state.coordinator is not None

            run_window(draw, args.rate, stop)
        else:
            watch(session.client.watch_inputs().snapshot, args.frame, args.rate, stop)
    return Report(Exit.OK)


COMMANDS: dict[str, Callable[[Session, Any], Report]] = {
    'status': cmd_status, 'move': cmd_move, 'check': cmd_check,
    'frames get': cmd_frames_get, 'frames set': cmd_frames_set,
    'frames define': cmd_frames_define, 'frames use': cmd_frames_use, 'home': cmd_home,
    'stop': cmd_stop, 'jog': cmd_jog, 'speed': cmd_speed, 'limits get': cmd_limits_get,
    'limits set': cmd_limits_set, 'limits reset': cmd_limits_reset, 'watch': cmd_watch,
}


# -- main -----------------------------------------------------------------------------------------
def run(args: argparse.Namespace, node: ClientNode | None = None) -> int:
    """Run the command of parsed command-line ``args`` (:mod:`positioning_cell.tools.cell`);
    its exit code. ``node``: the client's node, started before this module was imported
    (:func:`positioning_cell.ros.early.start_node`; None: made here)."""
    out = Output(args.json)
    timeout = args.timeout or default_timeout(args.command)
    client: OperatorClient | None = None
    with interruptible() as signals:
        try:
            from positioning_cell.ros.early import start_node
            from positioning_cell.ros.operator_client import OperatorClient

            client = OperatorClient(node or start_node(args.domain), timeout)
            report = COMMANDS[args.command](Session(client, signals, out), args)
        except Interrupted:
            report = Report(Exit.INTERRUPTED, error='interrupted')
        except TimeoutError as err:
            report = Report(Exit.NOT_THERE, error=_not_there(err))
        finally:
            if client is not None:
                with signals.ignored():
                    client.close()
    out.emit(args.command, report)
    return int(report.code)
