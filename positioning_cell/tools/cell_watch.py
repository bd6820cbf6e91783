"""``cell watch``: the terminal watch window (rich): per axis the commanded and measured value,
the deviation, the tolerance with an in/out marker in colour, and the tracker's standard
uncertainty, in the ``user`` or ``base`` frame (:mod:`positioning_cell.watch`); above it the
positioner's state, the accuracy monitor's last verdict and the recording (``recording
stopped: <reason>`` when the recorder failed, stopped or went silent); below it the live
axis ranges of the user position. Redrawn ``--rate``
times a second (5 by default) in the terminal's alternate screen; works over SSH and in tmux
(plain ANSI colours, ASCII markers). ``q`` or Ctrl-C quits (exit 0). Read-only: it
subscribes and reads parameters, it never commands the cell."""

from __future__ import annotations

import contextlib
import os
import select
import sys
import termios
import time
import tty
from collections.abc import Callable
from typing import IO, Any

from rich.console import Console, Group
from rich.live import Live
from rich.table import Table
from rich.text import Text

from positioning_cell import names
from positioning_cell.accuracy.verdicts import DECISION_LEVELS, RULE_NAMES
from positioning_cell.tools.cell_format import AXIS_RANGES_TITLE
from positioning_cell.watch.state import Snapshot, Status, is_stale
from positioning_cell.watch.table import DECISION_MARKERS, HEADERS, rows

#: Keys that quit.
QUIT_KEYS = frozenset('qQ')
#: Redraw period until the deviation first shows (then 1 / --rate), s.
FIRST_PERIOD = 0.05
_LEVEL_STYLES = {0: 'green', 1: 'yellow', 2: 'bold red', 3: 'magenta'}
#: The colour of a table marker by its level (watch.table.Row.level).
LEVEL_STYLES = {'ok': 'bold green', 'warn': 'bold yellow', 'error': 'bold red'}
_LEVEL_NAMES = {0: 'OK', 1: 'WARN', 2: 'ERROR', 3: 'STALE'}


class Keys:
    """Single key presses from a terminal's stdin (cbreak mode while open, restored after);
    on a stdin that is not a terminal, none come and :meth:`wait` only waits."""

    def __init__(self, stdin: IO[str] | None = None) -> None:
        self.stdin = stdin or sys.stdin
        try:
            self.fd: int | None = self.stdin.fileno() if self.stdin.isatty() else None
        except (AttributeError, ValueError, OSError):
            self.fd = None
        self._saved: Any = None

    def __enter__(self) -> Keys:
        if self.fd is not None:
            self._saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.fd is not None and self._saved is not None:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)

    def wait(self, timeout: float) -> str | None:
        """A key pressed within ``timeout`` s, or None."""
        if self.fd is None:
            time.sleep(timeout)
            return None
        ready, _, _ = select.select([self.fd], [], [], timeout)
        return os.read(self.fd, 1).decode(errors='replace') if ready else None


def status_text(label: str, status: Status | None, missing: str) -> Text:
    line = Text(f'{label}: ', style='bold')
    if status is None:
        return line.append(missing, style='dim')
    return line.append(f'{_LEVEL_NAMES.get(status.level, "?")} ', style=_LEVEL_STYLES.get(
        status.level, '')).append(status.message)


def drives_text(driver: Status | None) -> str:
    """The drives' state for people, from the leg driver's status: ``on (holding)``,
    ``OFF (fault)``; ``?`` while none came."""
    if driver is None:
        return '?'
    on = driver.values.get('enabled', '').lower() == 'true'
    return f'{"on" if on else "OFF"} ({driver.values.get("state", "?")})'


def motion_line(snapshot: Snapshot, now: float) -> Text:
    """Phase and progress, mode, the drives' state, and what the deviation is against: the
    moving setpoint while a trajectory runs, else the goal."""
    v = {} if snapshot.positioner is None else snapshot.positioner.values
    phase = snapshot.phase(now)
    drives = drives_text(snapshot.driver)
    against = snapshot.reference[0]
    return Text.assemble(('motion: ', 'bold'), f'{phase}  mode {v.get("mode", "?")}  '
                         f'drives {drives}  ', ('vs the moving setpoint' if against ==
                                                'setpoint' else 'vs the goal', 'dim'))


def ranges_text(snapshot: Snapshot) -> Text:
    """The positioner's live axis ranges (user CS, from the current user position), one line
    an axis, or what they wait for."""
    title = Text(f'{AXIS_RANGES_TITLE}, user CS:', style='bold')
    ranges = snapshot.axis_ranges
    if ranges is None:
        return title.append(f' waiting for {names.AXIS_RANGES}', style='dim')
    return Text('\n').join([title, *(Text(f'  {line}') for line in ranges.lines())])


def render(snapshot: Snapshot, frame: str, now: float) -> Group:
    """The watch window of ``snapshot`` in ``frame`` at wall time ``now`` (s)."""
    dev = snapshot.deviation(frame)
    title = Text.assemble(('cell watch', 'bold'), f'  frame {frame}  ',
                          time.strftime('%H:%M:%S', time.localtime(now)))
    record = snapshot.recording(now)
    parts: list[Any] = [
        title, status_text('positioner', snapshot.positioner, 'no status yet'),
        motion_line(snapshot, now),
        status_text('last verdict', snapshot.verdict, 'none since the watch started'),
        status_text('recording', None if record is None else
                     Status(record.level, record.message, now), 'no recorder seen')]
    waiting = snapshot.waiting_for()
    if frame != names.BASE_FRAME and not snapshot.systems_known:
        waiting.append(f'{names.COORDINATE_SYSTEMS} (identity user and object CS meanwhile)')
    if snapshot.tolerances is None:
        waiting.append(f'/{names.NODE_MONITOR} tolerances (the defaults meanwhile)')
    if waiting:
        parts.append(Text('waiting for: ' + ', '.join(waiting), style='yellow'))
    if dev is None:
        parts.append(Text('no deviation yet: a command and a measurement are needed',
                          style='dim'))
    else:
        age = now - snapshot.measured_stamp
        stale = is_stale(age)
        table = Table(*HEADERS, title_justify='left', expand=False,
                      caption=f'measurement {age:.2f} s old' + (' (STALE)' if stale else ''),
                      caption_style='yellow' if stale else 'dim')
        for row in rows(dev):
            cells = list(row.cells())
            table.add_row(*cells[:5], Text(cells[5], style=LEVEL_STYLES[row.level]), cells[6])
        decision = dev.verdict.decision
        parts += [table, Text.assemble(
            ('pose: ', 'bold'), (DECISION_MARKERS[decision],
                                 LEVEL_STYLES[DECISION_LEVELS[decision]]),
            (f' ({RULE_NAMES[dev.tolerances.rule]}; as measured: '
             f'{"in" if dev.ok else "out of"} tolerance)', 'dim'))]
    parts.append(ranges_text(snapshot))
    parts.append(Text('q or Ctrl-C quits', style='dim'))
    return Group(*parts)


def watch(snapshot: Callable[[], Snapshot], frame: str, rate: float, stop: Callable[[], bool],
          console: Console | None = None, keys: Keys | None = None) -> None:
    """Draw the watch window of ``snapshot()`` (the cell's state now: in ``cell``,
    :class:`positioning_cell.ros.operator_client.WatchSource`) ``rate`` times a second until
    ``q`` is pressed or ``stop()`` (Ctrl-C / SIGTERM counted by the caller) is true; every
    :data:`FIRST_PERIOD` s until the deviation can first be drawn."""
    def draw(now: float) -> tuple[Group, bool]:
        state = snapshot()
        return render(state, frame, now), state.deviation(frame) is not None

    run_window(draw, rate, stop, console, keys)


def run_window(draw: Callable[[float], tuple[Group, bool]], rate: float,
               stop: Callable[[], bool], console: Console | None = None,
               keys: Keys | None = None) -> None:
    """A live terminal window: ``draw(now)`` (wall time s) gives what to show and whether
    its main content is there yet; redrawn ``rate`` times a second once it is (every
    :data:`FIRST_PERIOD` s until then) until ``q`` is pressed or ``stop()`` is true."""
    console = console or Console()
    period, shown = 1.0 / rate, False
    with contextlib.ExitStack() as stack:
        pressed = stack.enter_context(keys or Keys())
        live = stack.enter_context(Live(draw(time.time())[0], console=console,
                                        auto_refresh=False, screen=console.is_terminal))
        while not stop():
            view, ready = draw(time.time())
            live.update(view, refresh=True)
            shown = shown or ready
            if pressed.wait(period if shown else min(period, FIRST_PERIOD)) in QUIT_KEYS:
                return


__all__ = ['Keys', 'drives_text', 'render', 'run_window', 'status_text', 'watch']
