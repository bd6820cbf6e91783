"""The end of a move's settle dwell: the axes stand still at their target.

After the drives arrived (every encoder within the coarse arrival tolerance, slower than the
at-rest speed) the servos are still closing the last microns: the platform is not yet where a
measurement of the settled pose may be taken. The dwell ends once every encoder has stayed
within a fine tolerance of its target (a count or two) over a window of time, or, at the
latest, after the configured ``settle_time``. The window must be at least the tracker's
latency (a reading arriving after the window ends was taken inside it, with the axes at
rest), so readings counted from the end of the dwell are measurements of the settled pose.
When the readings carry the time they were taken (their stamps, on the drives' clock, which
the tracker's readings share), the platform stood still from the stamp of the window's first
reading on (:attr:`RestWatch.still_from`): tracker readings stamped from then on measure the
settled pose too, even those that came in during the window. Positions in m and rad
(JOINT_NAMES order), times in s on one monotonic clock.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import as_vectors
from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]


class RestWatch:
    """Whether the encoders stand still at ``target`` (6,): every reading since ``window`` s
    ago within ``tolerance`` (6,) of it (m, rad). ``window`` 0: never (the dwell runs its
    whole time)."""

    def __init__(self, target: ArrayLike, tolerance: ArrayLike, window: float) -> None:
        if not window >= 0.0:
            raise InputError(f'window = {window!r}: must be >= 0 s')
        self.target = as_vectors(target, 6, 'target')[0]
        self.tolerance = as_vectors(tolerance, 6, 'tolerance')[0]
        self.window = float(window)
        self._since: float | None = None
        self._since_stamp = math.nan
        self._last = -np.inf

    def reading(self, position: ArrayLike, at: float, stamp: float = math.nan) -> bool:
        """An encoder reading (6,) seen at ``at`` s (a reading not newer than the last one
        changes nothing), ``stamp``: when the drives took it (s on their clock; NaN: not
        known); True once the axes have stood still for the window."""
        if at > self._last:
            self._last = at
            within = bool(np.all(np.abs(np.asarray(position, dtype=float) - self.target)
                                 <= self.tolerance))
            if not within:
                self._since, self._since_stamp = None, math.nan
            elif self._since is None:
                self._since, self._since_stamp = at, float(stamp)
        return self.at_rest

    @property
    def still_from(self) -> float:
        """At rest: the stamp of the window's first reading (from then on the axes stood
        still); else, or with readings not stamped, NaN."""
        return self._since_stamp if self.at_rest else math.nan

    @property
    def at_rest(self) -> bool:
        """The readings have stayed within the tolerance for the whole window."""
        return (self.window > 0.0 and self._since is not None
                and self._last - self._since >= self.window)
