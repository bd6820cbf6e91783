"""The tracker against the simulation truth: measured minus true pose over pairs of equal
stamps, batch and message by message. SI: m, rad, s."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.settle import as_time, as_times
from positioning_cell.core.poses import (
    Triple,
    as_pose_batch,
    as_vectors,
    pose_error,
    row_norms,
    triple,
)
from positioning_cell.errors import InputError
from positioning_cell.parameters import ParameterError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

# -- the tracker against the simulation truth ------------------------------------------------
@dataclass(frozen=True)
class ErrorStatistics:
    """Statistics of paired pose errors: ``samples``; position error mean vector (m, base),
    RMS and max of |Δp| (m); RMS and max of the rotation angle (rad)."""

    samples: int
    mean_position_error: Triple
    rms_position_error: float
    max_position_error: float
    rms_orientation_error: float
    max_orientation_error: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

def error_statistics(position_error: ArrayLike, orientation_error: ArrayLike) -> ErrorStatistics:
    """Statistics of errors Δp (N, 3) m and rotation vectors (N, 3) rad, N >= 1."""
    dp = as_vectors(position_error, 3, 'position_error')
    rv = as_vectors(orientation_error, 3, 'orientation_error')
    if dp.shape[0] != rv.shape[0] or dp.shape[0] == 0:
        raise InputError(f'need equal, non-zero counts: {dp.shape[0]} position and '
                         f'{rv.shape[0]} orientation errors')
    d, a = row_norms(dp), row_norms(rv)
    return ErrorStatistics(samples=int(dp.shape[0]), mean_position_error=triple(dp.mean(axis=0)),
                           rms_position_error=float(np.sqrt((d * d).mean())),
                           max_position_error=float(d.max()),
                           rms_orientation_error=float(np.sqrt((a * a).mean())),
                           max_orientation_error=float(a.max()))

def pair_by_stamp(times_a: ArrayLike, times_b: ArrayLike,
                  tolerance: float) -> tuple[IntArray, IntArray]:
    """Indices (ia, ib) pairing each time of ``times_a`` with the nearest of ``times_b``
    within ``tolerance`` s (both non-decreasing); each b is used once, by the first a."""
    ta, tb = as_times(times_a, 'times_a'), as_times(times_b, 'times_b')
    if tb.size == 0 or ta.size == 0:
        return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
    right = np.clip(np.searchsorted(tb, ta), 0, tb.size - 1)
    left = np.clip(right - 1, 0, tb.size - 1)
    nearest = np.where(np.abs(tb[left] - ta) <= np.abs(tb[right] - ta), left, right)
    ok = np.abs(tb[nearest] - ta) <= tolerance
    ia = np.flatnonzero(ok)
    _, first = np.unique(nearest[ia], return_index=True)
    keep = np.sort(ia[first])
    return keep.astype(np.intp), nearest[keep].astype(np.intp)

def tracker_errors(times: ArrayLike, position: ArrayLike, quaternion: ArrayLike,
                   truth_times: ArrayLike, truth_position: ArrayLike,
                   truth_quaternion: ArrayLike, tolerance: float) -> ErrorStatistics | None:
    """The tracker's own error: measured minus true pose over the pairs of
    :func:`pair_by_stamp`; None when nothing pairs."""
    ia, ib = pair_by_stamp(times, truth_times, tolerance)
    if ia.size == 0:
        return None
    p, q = as_pose_batch(position, quaternion)
    pt, qt = as_pose_batch(truth_position, truth_quaternion)
    return error_statistics(*pose_error(p[ia], q[ia], pt[ib], qt[ib]))

class TrackerErrorAccumulator:
    """Message-by-message form of :func:`tracker_errors`: pairs each measurement with the
    truth of the nearest stamp within ``tolerance`` s, whichever arrives first (up to
    ``buffer`` unpaired of each kept). Equal to the batch when the stamps of each series are
    more than 2·tolerance apart."""

    def __init__(self, tolerance: float, buffer: int = 200) -> None:
        if not (math.isfinite(tolerance) and tolerance > 0.0):
            raise ParameterError('max_stamp_difference', tolerance, 'must be finite and > 0 s')
        self.tolerance = tolerance
        self._measured: deque[tuple[float, FloatArray, FloatArray]] = deque(maxlen=buffer)
        self._truth: deque[tuple[float, FloatArray, FloatArray]] = deque(maxlen=buffer)
        self._pairs: list[tuple[float, FloatArray, FloatArray]] = []

    def reset(self) -> None:
        """Forget every pair and unpaired sample."""
        self._measured.clear()
        self._truth.clear()
        self._pairs.clear()

    def add_measured(self, time: float, position: ArrayLike, quaternion: ArrayLike) -> None:
        """A measured pose at ``time`` s."""
        self._add(time, position, quaternion, self._measured, self._truth, measured=True)

    def add_truth(self, time: float, position: ArrayLike, quaternion: ArrayLike) -> None:
        """A true pose at ``time`` s."""
        self._add(time, position, quaternion, self._truth, self._measured, measured=False)

    def _add(self, time: float, position: ArrayLike, quaternion: ArrayLike,
             mine: deque[tuple[float, FloatArray, FloatArray]],
             other: deque[tuple[float, FloatArray, FloatArray]], *, measured: bool) -> None:
        t = as_time(time, 'time')
        p, q = as_pose_batch(position, quaternion)
        gaps = np.abs(np.array([o[0] for o in other]) - t)
        if gaps.size == 0 or gaps.min() > self.tolerance:
            mine.append((t, p, q))
            return
        best = int(gaps.argmin())
        t_o, p_o, q_o = other[best]
        del other[best]
        meas, truth = ((t, p, q), (t_o, p_o, q_o)) if measured else ((t_o, p_o, q_o), (t, p, q))
        dp, rv = pose_error(meas[1], meas[2], truth[1], truth[2])
        self._pairs.append((meas[0], dp[0], rv[0]))

    def statistics(self) -> ErrorStatistics | None:
        """Statistics over the pairs so far (in measurement-time order), None without pairs."""
        if not self._pairs:
            return None
        pairs = sorted(self._pairs, key=lambda x: x[0])
        return error_statistics([x[1] for x in pairs], [x[2] for x in pairs])
