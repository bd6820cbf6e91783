"""A stop asked of a running procedure from another thread (an action's cancel, a node's
shutdown) or by a signal: the procedure checks it between steps, and the drives are stopped
at once, so that the move running then ends without waiting for the next check."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from positioning_cell.polling import wait_until


class Stopped(Exception):  # noqa: N818 - what happened, not an error of the procedure
    """The procedure was asked to stop: the drives were stopped, nothing more is done."""


class StopSignal:
    """``event`` (None: nothing but a signal stops the procedure) watched for the procedure:
    :meth:`check` raises :class:`Stopped` once it is set, :meth:`wait` is a
    :func:`~positioning_cell.polling.wait_until` that also ends on it, and a watcher thread
    calls ``stop_drives`` as soon as it is set. A context manager: the watcher ends with it."""

    def __init__(self, event: threading.Event | None, stop_drives: Callable[[], None],
                 period: float = 0.05) -> None:
        self.event = event
        self._stop_drives = stop_drives
        self._period = period
        self._done = threading.Event()
        self._watcher: threading.Thread | None = None
        if event is not None:
            self._watcher = threading.Thread(target=self._watch, daemon=True,
                                             name='procedure-stop')
            self._watcher.start()

    def _watch(self) -> None:
        assert self.event is not None
        while not self._done.is_set():
            if self.event.wait(self._period):
                self._stop_drives()
                return

    @property
    def asked(self) -> bool:
        """Has a stop been asked?"""
        return self.event is not None and self.event.is_set()

    def check(self) -> None:
        """Raise :class:`Stopped` if a stop has been asked."""
        if self.asked:
            raise Stopped('stop requested')

    def wait(self, condition: Callable[[], Any], timeout: float, what: str) -> Any:
        """``condition()``'s first truthy value within ``timeout`` s (TimeoutError naming
        ``what``), or :class:`Stopped` as soon as a stop is asked."""
        value = wait_until(lambda: self.asked or condition(), timeout, what)
        self.check()
        return value

    def close(self) -> None:
        """End the watcher."""
        self._done.set()
        if self._watcher is not None:
            self._watcher.join(timeout=1.0)

    def __enter__(self) -> StopSignal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
