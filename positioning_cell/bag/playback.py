"""Replay timing: when each recorded message is due, and the loop that waits for it.

Bag log time t maps to wall time ``t0 + (t − origin) / rate`` after playback starts at ``t0``
(monotonic clock). The loop waits until each message's due time with an injected ``wait``
(an Event's wait in the node, so a stop request interrupts it) instead of fixed sleeps, so the
timing does not drift with the publishing cost.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from positioning_cell.bag.reader import RawMessage
from positioning_cell.errors import InputError


@dataclass(frozen=True)
class PlaybackTiming:
    """``rate``: replay speed factor (> 0; 2 = twice as fast); ``origin_ns``: the bag log time
    (ns since the epoch) played at the start of playback."""

    rate: float
    origin_ns: int

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate) and self.rate > 0.0):
            raise InputError(f'rate = {self.rate!r}: must be a finite factor > 0')

    @classmethod
    def starting(cls, bag_start_ns: int, rate: float, start_offset_s: float) -> PlaybackTiming:
        """Playback from ``start_offset_s`` (≥ 0, s of bag time) after the bag's first message."""
        if not (math.isfinite(start_offset_s) and start_offset_s >= 0.0):
            raise InputError(f'start_offset_s = {start_offset_s!r}: must be finite and >= 0')
        return cls(rate, bag_start_ns + round(start_offset_s * 1e9))

    def due_s(self, log_time_ns: int) -> float:
        """Wall seconds after playback start at which the message logged at ``log_time_ns`` is
        due (negative before the origin)."""
        return (log_time_ns - self.origin_ns) * 1e-9 / self.rate


def play(messages: Iterable[RawMessage], timing: PlaybackTiming,
         publish: Callable[[RawMessage], None], wait: Callable[[float], bool],
         clock: Callable[[], float] = time.monotonic) -> int:
    """Publish each of ``messages`` (log-time order) when due; returns how many were published.

    ``wait(seconds)`` blocks up to that long and returns True to stop playback (e.g.
    ``threading.Event.wait``); ``clock`` is a monotonic clock in s. Messages before the
    origin are skipped; late messages are published at once, without waiting.
    """
    start = clock()
    published = 0
    for message in messages:
        due = timing.due_s(message.log_time_ns)
        if due < 0.0:
            continue
        delay = start + due - clock()
        if delay > 0.0 and wait(delay):
            break
        publish(message)
        published += 1
    return published
