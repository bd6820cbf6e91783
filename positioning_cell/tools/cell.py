"""``cell``: the operator's command-line client of the running positioning cell.

Poses are six human numbers, Tx Ty Tz in mm and Rx Ry Rz in degrees with R = Rz·Ry·Rx; on the
wire everything is SI. Text for people by default; ``--json`` prints one JSON object on stdout
instead (:mod:`positioning_cell.tools.cell_format`: ``command``, ``exit_code``, ``exit_name``,
``error`` and every field of the answer, NaN and infinities as null)::

    cell status                                  state, drives, user and machine positions
    cell move TX TY TZ RX RY RZ                  absolute, the object in the user CS
         [--relative-user | --relative-object | --frame base|machine|user]
         [--tolerance MM] [--speed-scale S]      (action /positioner/move, with progress)
    cell check TX TY TZ RX RY RZ [same options]  the checks of that move, nothing moves
    cell frames get
    cell frames set [--user 6] [--object 6]      one left out stays as it is
    cell watch [--frame user|base] [--rate HZ]   the live watch window; q or Ctrl-C quits
    cell home                                    reference if needed, then home (action)
    cell stop                                    controlled stop of whatever runs
    cell jog AXIS DELTA                          leg1_length ... (mm), leg1_theta ... (deg)
    cell speed [--linear MM_S] [--angular DEG_S] [--linear-acceleration MM_S2]
               [--angular-acceleration DEG_S2]   no option: query
    cell limits get
    cell limits set [--machine-lower 6] [--machine-upper 6] [--user-lower 6] [--user-upper 6]

Common options on every command: ``--json``, ``--timeout S`` (default 300 s for move and home,
20 s otherwise; a goal still running then is cancelled), ``--domain ID`` (default:
ROS_DOMAIN_ID of the environment). As the cell's own processes, the client keeps to the
loopback (``loopback_only``) unless the environment names its own Fast DDS profile.

Ctrl-C (or SIGTERM) during a move or a homing cancels the goal (a controlled stop) and waits
for its result, ``aborted_stop`` (exit 4); a second Ctrl-C stops waiting (exit 130). The
progress bar is one line on stderr, drawn only when stderr is a terminal.

``status`` converts the platform poses of /positioner/target (latched) and /positioner/pose
(the estimate) with the coordinate systems (GetCoordinateSystems) and the positioner's
``mechanism.*`` parameters (the machine CS: zero at the home pose).

Exit codes (``cell_format.EXIT_CODES``, the one table; ``cell --help`` prints it):

====  =================  ======================================================================
code  name               when
====  =================  ======================================================================
0     success            done: settled within the tolerance, a valid check, a query answered,
                         a setting taken
1     out_of_tolerance   settled, but not within the tolerance
2     usage              bad command line (argparse), nothing sent
3     refused            refused, nothing moved: any refused_* code, a goal rejected, an
                         invalid check, a setting or jog refused
4     aborted            aborted, the drives were stopped: any aborted_* code, a cancel by
                         Ctrl-C or by --timeout (aborted_stop), or no outcome given
5     not_there          the cell is not there: a service, action server, status or answer
                         did not come within --timeout
130   interrupted        Ctrl-C outside a goal, or a second Ctrl-C while a cancelled goal
                         winds down (its result not awaited)
====  =================  ======================================================================
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import IO, Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped
from positioning_cell_interfaces.action import Home, MoveToPose
from positioning_cell_interfaces.msg import BoxLimits, MoveCommand, MoveOutcome
from positioning_cell_interfaces.msg import CoordinateSystems as SystemsMsg
from positioning_cell_interfaces.srv import (
    CheckPose,
    GetCoordinateSystems,
    GetLimits,
    Jog,
    SetCoordinateSystems,
    SetLimits,
    SetSpeed,
)
from rcl_interfaces.srv import GetParameters

from positioning_cell import names
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import PositioningError
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.limits.speed import Speeds as LibrarySpeeds
from positioning_cell.polling import wait_until
from positioning_cell.ros import operator_messages as om
from positioning_cell.ros.client import CellClient, GoalClient
from positioning_cell.ros.messages import (
    pose_arrays,
    pose_stamped,
    status_level,
    status_values,
)
from positioning_cell.ros.parameters import parse_answer, requested_names
from positioning_cell.ros.processes import loopback_only
from positioning_cell.ros.qos import LATCHED_QOS, LATEST_QOS
from positioning_cell.tools import cell_format as cf
from positioning_cell.tools.cell_watch import watch

#: Longest wait for a service or an action server to appear (s; at most --timeout).
SERVER_WAIT = 30.0
#: After a cancel: how long the result (or the goal's acceptance) may take (s).
CANCEL_WAIT = 30.0
#: status: after the positioner's status, how long the driver's status, the target and the
#: estimate may take to come (s).
STATUS_EXTRA_WAIT = 2.0
#: Polling period of a running goal, and of the progress bar (s).
POLL = 0.05


class InterruptedCommandError(Exception):
    """SIGINT or SIGTERM outside a goal (or a second one during a cancel)."""


class Signals:
    """SIGINT and SIGTERM: counted; outside :meth:`deferred` they also raise
    InterruptedCommandError (inside, the goal loop reads the count and cancels)."""

    def __init__(self) -> None:
        self.count = 0
        self._deferring = False

    def __call__(self, signum: int, frame: Any) -> None:
        self.count += 1
        if not self._deferring:
            raise InterruptedCommandError(signal.Signals(signum).name)

    @contextlib.contextmanager
    def deferred(self) -> Iterator[None]:
        """Count signals without raising while the block runs."""
        before, self._deferring = self._deferring, True
        try:
            yield
        finally:
            self._deferring = before


@dataclass
class Report:
    """What a command found: its exit code, the fields of its JSON document, its text for
    people, and an error (why it failed) for stderr and the document."""

    code: int
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
    """One command's client, signals, output and timeout."""

    client: CellClient
    signals: Signals
    out: Output
    timeout: float

    def call(self, srv_type: Any, name: str, request: Any) -> Any:
        """A service call within the timeout (TimeoutError: the cell is not there); the
        client makes sure the server knows this new process first
        (:meth:`CellClient.handshake`)."""
        return self.client.call(srv_type, name, request, self.timeout)

    def stamp(self) -> Time:
        return self.client.node.get_clock().now().to_msg()


# -- messages <-> the pure values -----------------------------------------------------------------
def move_command(request: cf.MoveRequest, stamp: Time | None = None) -> MoveCommand:
    """The MoveCommand of a request (SI, quaternion x, y, z, w; the pose's frame_id the
    request's frame)."""
    command = MoveCommand(mode=int(request.mode), tolerance=float(request.tolerance),
                          speed_scale=float(request.speed_scale))
    command.pose = pose_stamped(request.position, request.quaternion, stamp or Time(),
                                request.frame)
    return command


def outcome_of(msg: MoveOutcome) -> cf.Outcome:
    """A MoveOutcome as plain values."""
    p, q = pose_arrays(msg.attained.pose)
    up, uq = pose_arrays(msg.attained_user)
    return cf.Outcome(int(msg.code), str(msg.code_name), str(msg.reason),
                      str(msg.attained.header.frame_id), p, q, up, uq,
                      np.asarray(msg.position_error, dtype=float).reshape(3),
                      np.asarray(msg.orientation_error, dtype=float).reshape(3),
                      np.asarray(msg.uncertainty, dtype=float).reshape(6))


def check_of(response: Any) -> cf.CheckReport:
    """A CheckPose response as plain values."""
    v = response.validity
    p, q = pose_arrays(response.goal.pose)
    return cf.CheckReport(bool(response.valid), int(v.bits), [str(n) for n in v.bit_names],
                          [str(t) for t in v.violations], [str(n) for n in v.margin_names],
                          [float(m) for m in v.margins], str(response.goal.header.frame_id),
                          p, q, float(response.duration))


def systems_of(msg: SystemsMsg) -> CoordinateSystems:
    """The library's coordinate systems of a CoordinateSystems message."""
    return CoordinateSystems(user=om.transform(msg.user), object=om.transform(msg.object))


def systems_msg(systems: CoordinateSystems) -> SystemsMsg:
    """The CoordinateSystems message of the library's."""
    return om.systems_msg(systems.user, systems.object)


def box_of(msg: BoxLimits) -> cf.Box:
    return cf.box_of(msg.lower, msg.upper)


def box_msg(box: cf.Box) -> BoxLimits:
    return BoxLimits(lower=[float(v) for v in box[0]], upper=[float(v) for v in box[1]])


def positioner_mechanism(session: Session) -> Mechanism:
    """The positioner's mechanism, from its ``mechanism.*`` parameters (TimeoutError if it
    does not answer; PositioningError if they are not a mechanism)."""
    response = session.call(GetParameters, f'/{names.NODE_POSITIONER}/get_parameters',
                            GetParameters.Request(names=requested_names(Mechanism,
                                                                        'mechanism.')))
    return parse_answer(Mechanism, 'mechanism.', response.values)


# -- goals (actions) ------------------------------------------------------------------------------
@dataclass
class GoalRun:
    """How a goal went: accepted (None: no answer), the outcome (None: none came, ``error``
    says why and ``code`` is the exit code), the goal status of the result, whether it was
    cancelled and why ('interrupt' or 'timeout')."""

    accepted: bool | None = None
    outcome: cf.Outcome | None = None
    goal_status: int | None = None
    cancelled: bool = False
    cancel_cause: str | None = None
    error: str | None = None
    code: int = cf.EXIT_ABORTED

    @property
    def exit_code(self) -> int:
        return self.code if self.outcome is None else self.outcome.exit_code

    def fields(self) -> dict[str, Any]:
        return {'accepted': self.accepted, 'cancelled': self.cancelled,
                'cancel_cause': self.cancel_cause, 'goal_status': self.goal_status,
                'outcome': None if self.outcome is None else self.outcome.document()}

    def text(self) -> str:
        lines = []
        if self.cancelled:
            cause = 'Ctrl-C' if self.cancel_cause == 'interrupt' else '--timeout'
            lines.append(f'cancelled ({cause})')
        if self.outcome is not None:
            lines.append(self.outcome.text())
        return '\n'.join(lines)


def run_goal(session: Session, action_type: Any, name: str, goal: Any,
             progress: Callable[[Any], str]) -> GoalRun:
    """Send ``goal`` to action server ``name`` and wait for its result, drawing
    ``progress(feedback)``; Ctrl-C or the timeout cancels it (then the result is awaited
    CANCEL_WAIT s more; a second Ctrl-C gives up). TimeoutError if the server is not there."""
    with GoalClient(session.client, action_type, name) as goals:
        goals.ready(min(session.timeout, SERVER_WAIT))
        with session.signals.deferred():
            return _drive(session, goals, goal, progress)


def _drive(session: Session, goals: GoalClient, goal: Any,
           progress: Callable[[Any], str]) -> GoalRun:
    run = GoalRun()
    latest: list[Any] = [None]
    start = session.signals.count
    send = goals.action.send_goal_async(goal, feedback_callback=lambda m: latest.__setitem__(
        0, m.feedback))
    deadline = time.monotonic() + session.timeout
    handle: Any = None
    result: Any = None
    cancel_at: float | None = None
    while True:
        now = time.monotonic()
        if handle is None and send.done():
            handle = send.result()
            run.accepted = bool(handle.accepted)
            if not handle.accepted:
                run.error, run.code = 'the positioner rejected the goal', cf.EXIT_REFUSED
                return run
            result = handle.get_result_async()
        if result is not None and result.done():
            _take_result(run, result.result())
            return run
        interrupts = session.signals.count - start
        if interrupts >= 2:
            run.error, run.code = ('interrupted again: the result of the cancelled goal was '
                                   'not awaited'), cf.EXIT_INTERRUPTED
            return run
        if run.cancel_cause is None and (interrupts or now > deadline):
            run.cancel_cause = 'interrupt' if interrupts else 'timeout'
            cancel_at = now
            session.out.note('cancelling the goal (a controlled stop); Ctrl-C again: do not '
                             'wait' if interrupts else f'no result within {session.timeout:g} '
                             's: cancelling the goal (a controlled stop)')
        if run.cancel_cause is not None and handle is not None and not run.cancelled:
            handle.cancel_goal_async()
            run.cancelled = True
        if cancel_at is not None and now > cancel_at + CANCEL_WAIT:
            what = 'the goal\'s acceptance' if handle is None else 'the result'
            run.error = f'{what} did not come within {CANCEL_WAIT:g} s of the cancel'
            run.code = cf.EXIT_NOT_THERE
            return run
        if latest[0] is not None:
            session.out.progress(progress(latest[0]))
        goals.spin_once(POLL)  # the answers and feedback, taken by this thread only


def _take_result(run: GoalRun, response: Any) -> None:
    run.goal_status = int(response.status)
    outcome = response.result.outcome
    if not outcome.code_name:
        run.error = f'the positioner gave no outcome (goal status {run.goal_status})'
        run.code = cf.EXIT_ABORTED
        return
    run.outcome = outcome_of(outcome)


def _move_progress(feedback: Any) -> str:
    return cf.progress_line(str(feedback.phase_name), float(feedback.progress),
                            np.asarray(feedback.position_error, dtype=float))


def _home_progress(feedback: Any) -> str:
    return cf.progress_line(str(feedback.phase_name), float(feedback.progress))


def _not_there(err: TimeoutError) -> str:
    return f'the cell is not there: {err}'


# -- the commands ---------------------------------------------------------------------------------
def cmd_move(session: Session, args: Any) -> Report:
    request = cf.move_request(args)
    fields: dict[str, Any] = {'request': request.document()}
    try:
        goal = MoveToPose.Goal(command=move_command(request, session.stamp()))
        run = run_goal(session, MoveToPose, names.MOVE_ACTION, goal, _move_progress)
    except TimeoutError as err:
        return Report(cf.EXIT_NOT_THERE, fields | GoalRun().fields(), '', _not_there(err))
    return Report(run.exit_code, fields | run.fields(), run.text(), run.error)


def cmd_home(session: Session, args: Any) -> Report:
    try:
        run = run_goal(session, Home, names.HOME_ACTION, Home.Goal(), _home_progress)
    except TimeoutError as err:
        return Report(cf.EXIT_NOT_THERE, GoalRun().fields(), '', _not_there(err))
    return Report(run.exit_code, run.fields(), run.text(), run.error)


def cmd_check(session: Session, args: Any) -> Report:
    request = cf.move_request(args)
    response = session.call(CheckPose, names.CHECK_POSE,
                            CheckPose.Request(command=move_command(request, session.stamp())))
    report = check_of(response)
    return Report(report.exit_code, {'request': request.document(), **report.document()},
                  report.text())


def cmd_status(session: Session, args: Any) -> Report:
    client = session.client
    positioner = client.statuses(names.STATUS_POSITIONER)
    driver = client.statuses(names.STATUS_DRIVER)
    targets = client.collect(PoseStamped, names.TARGET, LATCHED_QOS)
    estimates = client.collect(PoseStamped, names.ESTIMATED_POSE, LATEST_QOS)
    deadline = time.monotonic() + session.timeout
    notes = []
    systems = None
    file = ''
    try:
        response = session.call(GetCoordinateSystems, names.GET_COORDINATE_SYSTEMS,
                                GetCoordinateSystems.Request())
        systems, file = systems_of(response.systems), str(response.file)
    except PositioningError as err:
        notes.append(f'user positions unknown: {err}')
    mechanism = None
    try:
        mechanism = positioner_mechanism(session)
    except (TimeoutError, PositioningError) as err:
        notes.append(f'machine positions unknown (the positioner\'s mechanism): {err}')
    wait_until(lambda: positioner, max(deadline - time.monotonic(), 0.0),
               f'the status "{names.STATUS_POSITIONER}" on {names.DIAGNOSTICS}')
    with contextlib.suppress(TimeoutError):
        wait_until(lambda: driver and targets and estimates, STATUS_EXTRA_WAIT, 'the rest')
    if not driver:
        notes.append(f'no status "{names.STATUS_DRIVER}" on {names.DIAGNOSTICS}')
    if not targets:
        notes.append(f'no target on {names.TARGET} (nothing commanded yet)')
    if not estimates:
        notes.append(f'no estimate on {names.ESTIMATED_POSE}')
    status = positioner[-1]
    report = cf.StatusReport(
        positioner=status_values(status), positioner_message=str(status.message),
        positioner_level=status_level(status),
        driver=status_values(driver[-1]) if driver else None,
        target=pose_arrays(targets[-1].pose) if targets else None,
        estimate=pose_arrays(estimates[-1].pose) if estimates else None,
        systems=systems, systems_file=file, mechanism=mechanism, notes=notes)
    return Report(cf.EXIT_OK, report.document(), report.text())


def _get_systems(session: Session) -> tuple[CoordinateSystems, str]:
    response = session.call(GetCoordinateSystems, names.GET_COORDINATE_SYSTEMS,
                            GetCoordinateSystems.Request())
    return systems_of(response.systems), str(response.file)


def cmd_frames_get(session: Session, args: Any) -> Report:
    systems, file = _get_systems(session)
    return Report(cf.EXIT_OK, {'coordinate_systems': cf.systems_document(systems, file)},
                  cf.systems_text(systems, file))


def cmd_frames_set(session: Session, args: Any) -> Report:
    user, obj = cf.frames_request(args)
    previous = None
    if user is None or obj is None:
        previous, _ = _get_systems(session)
        user = previous.user if user is None else user
        obj = previous.object if obj is None else obj
    systems = CoordinateSystems(user=user, object=obj)
    response = session.call(SetCoordinateSystems, names.SET_COORDINATE_SYSTEMS,
                            SetCoordinateSystems.Request(systems=systems_msg(systems)))
    success, reason = bool(response.success), str(response.reason)
    fields = {'success': success, 'reason': reason,
              'coordinate_systems': cf.systems_document(systems),
              'previous': None if previous is None else cf.systems_document(previous)}
    if not success:
        return Report(cf.EXIT_REFUSED, fields, '', f'refused: {reason}')
    return Report(cf.EXIT_OK, fields, cf.systems_text(systems) + (f'\n{reason}' if reason
                                                                   else ''))


def _get_limits(session: Session) -> Any:
    return session.call(GetLimits, names.GET_LIMITS, GetLimits.Request())


def _limits_fields(response: Any) -> tuple[dict[str, Any], str]:
    boxes = (box_of(response.factory), box_of(response.machine), box_of(response.user),
             [str(c) for c in response.factory_constraints])
    return cf.limits_document(*boxes), cf.limits_text(*boxes)


def cmd_limits_get(session: Session, args: Any) -> Report:
    doc, text = _limits_fields(_get_limits(session))
    return Report(cf.EXIT_OK, {'limits': doc}, text)


def cmd_limits_set(session: Session, args: Any) -> Report:
    current = _get_limits(session)
    machine, user = cf.limits_request(args).merged(box_of(current.machine), box_of(current.user))
    response = session.call(SetLimits, names.SET_LIMITS,
                            SetLimits.Request(machine=box_msg(machine), user=box_msg(user)))
    success, reason = bool(response.success), str(response.reason)
    fields: dict[str, Any] = {'success': success, 'reason': reason,
                              'requested': {'machine': cf.box_document(machine),
                                            'user': cf.box_document(user)}}
    if not success:
        return Report(cf.EXIT_REFUSED, fields | {'limits': _limits_fields(current)[0]}, '',
                      f'refused: {reason}')
    doc, text = _limits_fields(_get_limits(session))
    return Report(cf.EXIT_OK, fields | {'limits': doc}, text)


def cmd_speed(session: Session, args: Any) -> Report:
    request = cf.speed_request(args)
    response = session.call(SetSpeed, names.SET_SPEED,
                            SetSpeed.Request(request=om.speeds_msg(request)))
    success, reason = bool(response.success), str(response.reason)
    current, maximum = om.speeds(response.current), om.speeds(response.maximum)
    fields = {'query': request == LibrarySpeeds.keep(), 'success': success, 'reason': reason,
              'requested': cf.speeds_document(request), 'current': cf.speeds_document(current),
              'maximum': cf.speeds_document(maximum)}
    text = cf.speeds_text(current, maximum)
    if not success:
        return Report(cf.EXIT_REFUSED, fields, text, f'refused: {reason}')
    return Report(cf.EXIT_OK, fields, text)


def cmd_jog(session: Session, args: Any) -> Report:
    axis, delta = cf.jog_request(args)
    response = session.call(Jog, names.JOG, Jog.Request(axis=axis, delta=delta))
    success, code_name = bool(response.success), str(response.code_name)
    reason, position = str(response.reason), float(response.position)
    unit = cf.jog_unit(axis)
    fields = {'axis': axis, 'delta': delta, 'delta_human': args.delta, 'unit': unit,
              'success': success, 'code_name': code_name, 'reason': reason,
              'position': position, 'position_human': cf.jog_human(axis, position)}
    code = cf.jog_exit_code(success, code_name)
    text = f'{axis}: {cf.jog_human(axis, position):.4f} {unit}'
    if not success:
        return Report(code, fields, text, f'{code_name or "refused"}: {reason}')
    return Report(code, fields, text + (f' ({reason})' if reason else ''))


def cmd_stop(session: Session, args: Any) -> Report:
    success, message = session.client.trigger(names.STOP, session.timeout)
    fields = {'success': success, 'message': message}
    if not success:
        return Report(cf.EXIT_REFUSED, fields, '', f'refused: {message}')
    return Report(cf.EXIT_OK, fields, message or 'stopped')


def cmd_watch(session: Session, args: Any) -> Report:
    """The live watch window (:mod:`positioning_cell.tools.cell_watch`) until q or Ctrl-C."""
    with session.signals.deferred():
        watch(session.client, args.frame, args.rate, lambda: session.signals.count > 0)
    return Report(cf.EXIT_OK)


COMMANDS: dict[str, Callable[[Session, Any], Report]] = {
    'status': cmd_status, 'move': cmd_move, 'check': cmd_check,
    'frames get': cmd_frames_get, 'frames set': cmd_frames_set, 'home': cmd_home,
    'stop': cmd_stop, 'jog': cmd_jog, 'speed': cmd_speed, 'limits get': cmd_limits_get,
    'limits set': cmd_limits_set, 'watch': cmd_watch,
}


# -- main -----------------------------------------------------------------------------------------
def use_loopback() -> None:
    """This process's environment as the cell's processes get it (``loopback_only``)."""
    env = dict(os.environ)
    loopback_only(env)
    for key in set(os.environ) - set(env):
        del os.environ[key]
    os.environ.update(env)


def main(argv: Sequence[str] | None = None) -> int:
    """Command line (module docstring)."""
    parser = cf.build_parser((__doc__ or '').split('\n\n')[0].replace('``', ''))
    args = parser.parse_args(argv)
    out = Output(args.json)
    timeout = args.timeout or cf.default_timeout(args.command)
    signals = Signals()
    previous = {sig: signal.signal(sig, signals) for sig in (signal.SIGINT, signal.SIGTERM)}
    client: CellClient | None = None
    try:
        use_loopback()
        client = CellClient(args.domain, f'cell_{os.getpid()}', signals=False)
        report = COMMANDS[args.command](Session(client, signals, out, timeout), args)
    except InterruptedCommandError:
        report = Report(cf.EXIT_INTERRUPTED, error='interrupted')
    except TimeoutError as err:
        report = Report(cf.EXIT_NOT_THERE, error=_not_there(err))
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if client is not None:
            client.close()
    out.emit(args.command, report)
    return report.code


if __name__ == '__main__':
    sys.exit(main())
