"""What the positioner watches while it commands the drives: joint states that stop coming,
encoders that stop counting while their axis is commanded to move, readings that are not
numbers, a tracker that goes silent. Pure functions over the readings; the mover raises what
they find."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.mechanism import JOINT_NAMES

FloatArray = NDArray[np.float64]


def unreadable_axes(position: FloatArray) -> list[str]:
    """The axes (names) whose reading (6,) is NaN or infinite."""
    return [JOINT_NAMES[i] for i in np.flatnonzero(~np.isfinite(position))]


class FreezeWatch:
    """Encoders that freeze: for each axis the time its reading last changed; an axis is
    frozen when its reading has not changed for ``window`` s while the commanded motion over
    the last ``window`` s exceeds ``counts`` encoder counts (``count`` (6,): m or rad). Only
    time from ``start`` on counts (when the motion is due to start; a trajectory sent ahead of
    its start stands still until then)."""

    def __init__(self, window: float, counts: float, count: FloatArray,
                 start: float = -np.inf) -> None:
        self.window, self.threshold = window, counts * np.asarray(count, dtype=float)
        self.start = start
        self._last: FloatArray | None = None
        self._changed = np.zeros(6)

    def reading(self, position: FloatArray, now: float) -> None:
        """A new reading (6,) at time ``now`` (s)."""
        if self._last is None:
            self._changed[:] = now
        else:
            self._changed = np.where(position != self._last, now, self._changed)
        self._last = position.copy()

    def frozen(self, commanded_motion: FloatArray, now: float) -> list[tuple[str, float]]:
        """(axis name, commanded motion m or rad) of the frozen axes, given the commanded
        motion (6,) over the last ``window`` s."""
        if self._last is None:
            return []
        idle = now - np.maximum(self._changed, self.start) >= self.window
        moving = np.abs(commanded_motion) > self.threshold
        return [(JOINT_NAMES[i], float(commanded_motion[i]))
                for i in np.flatnonzero(idle & moving)]
