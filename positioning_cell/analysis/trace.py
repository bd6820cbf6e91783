"""The error of a run over time in bounded memory: per time bin the smallest and largest |Δp|
(m) and rotation angle (rad) of the samples that fell in it, and how many there were.

The bins start at the first sample, 1 ms wide; whenever a sample would fall beyond the last of
``capacity`` bins, the width doubles and neighbouring bins merge, so a run of any length keeps at
most ``capacity`` bins (a 1 h run at 2000 bins: 2.048 s each) and a short one keeps every sample
apart. A plot of the envelope (min to max per bin) shows what a plot of every sample shows at
the resolution of a figure (a 12-inch figure at 110 dpi is 1320 pixels wide).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Bins kept at most.
TRACE_BINS = 2048
#: The narrowest bin, s.
TRACE_FIRST_WIDTH = 1e-3


@dataclass(frozen=True)
class Envelope:
    """The trace as arrays over its non-empty bins: ``time`` (K,) s (bin centres, or the
    sample's own time where a bin holds one sample), ``count`` (K,), and the min and max of
    |Δp| (m) and of the angle (rad) per bin."""

    time: FloatArray
    count: IntArray
    position_min: FloatArray
    position_max: FloatArray
    angle_min: FloatArray
    angle_max: FloatArray


class ErrorTrace:
    """Samples' errors binned over time (module docstring); :meth:`add` takes them in
    non-decreasing time, vectorised."""

    def __init__(self, capacity: int = TRACE_BINS, first_width: float = TRACE_FIRST_WIDTH
                 ) -> None:
        self.capacity = capacity
        self.width = first_width
        self.start = math.nan
        self.samples = 0
        self.first = math.nan
        self.last = math.nan
        self._count = np.zeros(capacity, dtype=np.intp)
        self._time = np.zeros(capacity)              # sum of times (for a lone sample's time)
        self._lo = np.full((capacity, 2), math.inf)
        self._hi = np.full((capacity, 2), -math.inf)

    def _coarsen(self) -> None:
        """Double the bin width: bins 2k and 2k + 1 become bin k."""
        half = self.capacity // 2
        self._count = np.concatenate([self._count.reshape(half, 2).sum(axis=1),
                                      np.zeros(self.capacity - half, dtype=np.intp)])
        self._time = np.concatenate([self._time.reshape(half, 2).sum(axis=1),
                                     np.zeros(self.capacity - half)])
        self._lo = np.concatenate([self._lo.reshape(half, 2, 2).min(axis=1),
                                   np.full((self.capacity - half, 2), math.inf)])
        self._hi = np.concatenate([self._hi.reshape(half, 2, 2).max(axis=1),
                                   np.full((self.capacity - half, 2), -math.inf)])
        self.width *= 2.0

    def add(self, time: FloatArray, position_error: FloatArray,
            orientation_error: FloatArray) -> None:
        """Samples at ``time`` (N,) s (non-decreasing, after every earlier one) with errors
        Δp (N, 3) m and rotation vectors (N, 3) rad; rows with NaN errors (no target yet) are
        left out."""
        keep = ~np.isnan(position_error[:, 0])
        if not keep.any():
            return
        t = time[keep]
        values = np.column_stack([np.sqrt((position_error[keep] ** 2).sum(axis=1)),
                                  np.sqrt((orientation_error[keep] ** 2).sum(axis=1))])
        if math.isnan(self.start):
            self.start = self.first = float(t[0])
        self.last = float(t[-1])
        self.samples += int(t.size)
        index = np.floor((t - self.start) / self.width).astype(np.intp)
        while index[-1] >= self.capacity:
            self._coarsen()
            index = np.floor((t - self.start) / self.width).astype(np.intp)
        bins, first = np.unique(index, return_index=True)
        self._count[bins] += np.diff(np.append(first, t.size))
        self._time[bins] += np.add.reduceat(t, first)
        self._lo[bins] = np.minimum(self._lo[bins], np.minimum.reduceat(values, first, axis=0))
        self._hi[bins] = np.maximum(self._hi[bins], np.maximum.reduceat(values, first, axis=0))

    def envelope(self) -> Envelope:
        """The non-empty bins (see :class:`Envelope`)."""
        used = np.flatnonzero(self._count)
        count = self._count[used]
        centre = self.start + (used + 0.5) * self.width
        time = np.where(count == 1, self._time[used] / np.maximum(count, 1), centre)
        return Envelope(time, count, self._lo[used, 0], self._hi[used, 0], self._lo[used, 1],
                        self._hi[used, 1])
