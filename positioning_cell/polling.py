"""Bounded waits for a condition (no fixed sleeps): used by the run driver and the tests."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def wait_until(condition: Callable[[], Any], timeout: float, what: str,
               poll: float = 0.02, cutoff: Callable[[], float] | None = None) -> Any:
    """Poll ``condition`` every ``poll`` s until it returns something truthy and return that;
    TimeoutError naming ``what`` after ``timeout`` s, or once the monotonic time passes
    ``cutoff()`` (read at each poll; e.g. a short grace after a stop: inf, none)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        now = time.monotonic()
        if now > deadline:
            raise TimeoutError(f'timed out after {timeout:.1f} s waiting for {what}')
        if cutoff is not None and now > cutoff():
            raise TimeoutError(f'gave up waiting for {what}: stopping')
        time.sleep(poll)


def backoff(attempt: int, first: float, most: float, factor: float = 1.5) -> float:
    """The wait (s) after attempt number ``attempt`` (0, 1, ...) of a request that may be lost
    (an answer sent before discovery has matched its reader): ``first``, ``factor`` times
    longer after each attempt, at most ``most``."""
    return float(min(most, first * factor ** attempt))
