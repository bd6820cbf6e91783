"""The recorder's status on /diagnostics (status ``recorder``, every :data:`STATUS_PERIOD_S`)
and how the rest of the cell reads it.

The recorder says what it is doing in the value ``state`` (:class:`RecorderState`):
``recording`` (OK, or WARN when its disk is short of a margin), ``paused`` (WARN), ``failed``
(ERROR: writing failed, the bag was closed and the recorder stops; the message names the errno
and the file) or ``stopped`` (OK: closed on request, its last status). Whoever watches it (the
accuracy monitor, ``cell watch``, the live view) applies one rule, :func:`recording`: a
recorder that failed, stopped, reports an ERROR or has been silent for :data:`SILENT_AFTER_S`
means **recording stopped**.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from positioning_cell.recording.disk import DiskReport

#: The recorder publishes its status this often, s.
STATUS_PERIOD_S = 1.0
#: A recorder not heard from for this long has stopped recording, s (three periods and a half:
#: one late message is not a stop).
SILENT_AFTER_S = 3.5 * STATUS_PERIOD_S
#: Levels of a diagnostic status.
OK, WARN, ERROR = 0, 1, 2
_STOPPED = 'recording stopped'


class RecorderState(str, Enum):
    """The recorder's ``state`` value."""

    RECORDING = 'recording'
    PAUSED = 'paused'
    FAILED = 'failed'
    STOPPED = 'stopped'


@dataclass(frozen=True)
class RecorderStatus:
    """What the recorder publishes: ``level`` (0 OK, 1 WARN, 2 ERROR), ``message`` and the
    ``state`` value."""

    level: int
    message: str
    state: RecorderState


def recorder_status(*, paused: bool = False, failure: str = '', stopped: str = '',
                    disk: DiskReport | None = None) -> RecorderStatus:
    """The recorder's level and message: ``failure`` (the writer's one-line failure) → ERROR
    ``recording stopped: <failure>``; ``stopped`` (why it closed the bag) → OK ``recording
    stopped: <stopped>``; else ``recording`` or ``paused``, WARN when paused or when ``disk``
    has a warning (appended)."""
    if failure:
        return RecorderStatus(ERROR, f'{_STOPPED}: {failure}', RecorderState.FAILED)
    if stopped:
        return RecorderStatus(OK, f'{_STOPPED}: {stopped}', RecorderState.STOPPED)
    state = RecorderState.PAUSED if paused else RecorderState.RECORDING
    warning = disk.warning if disk is not None else ''
    message = state.value + (f'; disk space low: {warning}' if warning else '')
    return RecorderStatus(WARN if paused or warning else OK, message, state)


@dataclass(frozen=True)
class RecorderReport:
    """One recorder status as a watcher received it: level, message, key-values, and the time
    it came (s, the watcher's clock)."""

    level: int
    message: str
    values: Mapping[str, str] = field(default_factory=dict)
    received: float = 0.0


@dataclass(frozen=True)
class Recording:
    """What a watcher shows of the recording: ``level`` (0 OK, 1 WARN, 2 ERROR), ``message``
    and whether recording has ``stopped``."""

    level: int
    message: str
    stopped: bool

    def to_dict(self) -> dict[str, Any]:
        """For JSON documents (the monitor's report, the live view's status)."""
        return {'level': self.level, 'message': self.message, 'stopped': self.stopped}


def _clock(seconds: float) -> str:
    return time.strftime('%H:%M:%S', time.localtime(seconds))


def recording(report: RecorderReport | None, now: float) -> Recording | None:
    """The rule: the recorder's latest ``report`` at time ``now`` (s, the clock ``received``
    is on) → the recording's state; None while no recorder was heard of. Failed (ERROR),
    reporting an ERROR, or silent for more than :data:`SILENT_AFTER_S` (ERROR): recording
    stopped; stopped on request: recording stopped (WARN: nothing is recorded any more);
    otherwise the recorder's own level and message."""
    if report is None:
        return None
    state = report.values.get('state', '')
    if state == RecorderState.STOPPED:
        return Recording(WARN, report.message, True)
    if state == RecorderState.FAILED or report.level >= ERROR:
        message = report.message if report.message.startswith(_STOPPED) else \
            f'{_STOPPED}: {report.message}'
        return Recording(ERROR, message, True)
    if now - report.received > SILENT_AFTER_S:
        return Recording(ERROR, f'{_STOPPED}: recorder silent since '
                                f'{_clock(report.received)} (last: {report.message})', True)
    return Recording(report.level, report.message, False)
