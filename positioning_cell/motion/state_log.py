"""Which of the positioner's state reports go into its log: each state once while it lasts.
The state is published on /diagnostics at every change and again every second, and one state
can be reported twice at once (a drive fault: by the driver's status on the executor, and by
the aborted move's end, with its code, on the move's thread; both orders happen), so the log
keeps only the first report of each, whoever makes it."""

from __future__ import annotations

import threading


class StateLog:
    """The positioner's state reports to log (module docstring). Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._logged = ''

    def logs(self, level: str, message: str, each: bool = False) -> bool:
        """Whether the report (``level`` ``ok``, ``warn`` or ``error``, its ``message``) is to
        be logged: a report not ``ok`` whose message is not the one logged last since the
        last ``ok``, or any report not ``ok`` with ``each`` (a refused request: each is an
        event of its own)."""
        with self._lock:
            new = level != 'ok' and (each or message != self._logged)
            self._logged = message if level != 'ok' else ''
            return new
