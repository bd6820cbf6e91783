"""A move's time base: how long its motion lasts at least and when the drives start it. The
coordinated cell (issue 27) gives every positioner the slowest one's duration and one start,
so that they move as one (docs/howto/coordinated.md); a move of one positioner alone has
neither (as fast as its speeds allow, started on receipt)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from positioning_cell.errors import InputError

#: The longest duration a move may be asked to last, s.
MAX_DURATION = 3600.0
#: A duration that asks for the coordinated time law as fast as the limits allow (what the
#: coordinator checks each positioner's goal with, to learn its least duration), s.
FASTEST_COORDINATED = 1e-6


@dataclass(frozen=True)
class Timing:
    """``duration``: the least duration of the motion, s (0: the fastest profile the speeds
    allow; > 0: the coordinated time law, one shape for every positioner,
    :func:`~positioning_cell.moves.trajectory.plan_profile`);
    ``start``: when the drives start it, ROS time (s since the epoch; None: on receipt).
    InputError naming a field that is not a finite number in range."""

    duration: float = 0.0
    start: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.duration) and 0.0 <= self.duration <= MAX_DURATION):
            raise InputError(f'duration = {self.duration!r}: must be a number of seconds in '
                             f'[0, {MAX_DURATION:g}] (0: as fast as the speeds allow)')
        if self.start is not None and not (math.isfinite(self.start) and self.start > 0.0):
            raise InputError(f'start = {self.start!r}: must be a ROS time > 0 (or none: on '
                             'receipt)')

    def delay(self, now: float) -> float:
        """Seconds from ``now`` (ROS time, s) to the start (0 without one; negative: past)."""
        return 0.0 if self.start is None else self.start - now

    def late(self, now: float) -> str | None:
        """Why the start can no longer be kept at ``now`` (ROS time, s): it is already past;
        None when it can (or there is none)."""
        delay = self.delay(now)
        if delay >= 0.0:
            return None
        return f'the start time was {-delay:.3f} s ago: the motion could not start with it'


#: A move of one positioner alone: as fast as its speeds allow, started on receipt.
AT_ONCE = Timing()
