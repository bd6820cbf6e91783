"""SIGINT, SIGTERM and SIGHUP in a command line: one way for every tool. While
:func:`interruptible` runs, each signal raises :class:`Interrupted` in the main thread (so the
tool stops the drives, puts back what it changed and exits ``Exit.INTERRUPTED``,
:mod:`positioning_cell.tools.exits`), or, inside :meth:`Signals.deferred`, is only counted (a
goal loop reads the count and cancels); the previous handlers are put back afterwards."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from types import FrameType

from positioning_cell.ros.entry import STOP_SIGNALS  # "stop now", as for a node


class Interrupted(Exception):  # noqa: N818 - what happened, not an error of the tool
    """A stop signal arrived (its name is the message)."""


class Signals:
    """The handler: counts each signal; outside :meth:`deferred` it raises Interrupted."""

    def __init__(self) -> None:
        self.count = 0
        self._deferring = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        self.count += 1
        if not self._deferring:
            raise Interrupted(signal.Signals(signum).name)

    @contextlib.contextmanager
    def deferred(self) -> Iterator[None]:
        """Count signals without raising while the block runs."""
        before, self._deferring = self._deferring, True
        try:
            yield
        finally:
            self._deferring = before

    @contextlib.contextmanager
    def ignored(self) -> Iterator[None]:
        """Neither raise nor count while the block runs (stopping is not interrupted)."""
        previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in STOP_SIGNALS}
        try:
            yield
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


@contextlib.contextmanager
def interruptible() -> Iterator[Signals]:
    """Install :class:`Signals` for SIGINT and SIGTERM for the block; the previous handlers
    afterwards, whatever happens."""
    handler = Signals()
    previous = {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}
    try:
        yield handler
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
