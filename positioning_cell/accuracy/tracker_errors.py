"""The tracker against the simulation truth: measured minus true pose over pairs of equal
stamps, batch and message by message. SI: m, rad, s."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.settle import as_times
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
from positioning_cell.records import plain_fields

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
        return plain_fields(self)

def error_statistics(position_error: ArrayLike, orientation_error: ArrayLike) -> ErrorStatistics:
    """Statistics of errors Δp (N, 3) m and rotation vectors (N, 3) rad, N >= 1 (through
    :class:`ErrorSums`, as the streaming accumulator computes them)."""
    dp = as_vectors(position_error, 3, 'position_error')
    rv = as_vectors(orientation_error, 3, 'orientation_error')
    if dp.shape[0] != rv.shape[0] or dp.shape[0] == 0:
        raise InputError(f'need equal, non-zero counts: {dp.shape[0]} position and '
                         f'{rv.shape[0]} orientation errors')
    sums = ErrorSums()
    sums.add(dp, rv)
    stats = sums.statistics()
    assert stats is not None
    return stats


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

#: True poses kept while no measurement waits for them (a truth-only stream, e.g. a tracker
#: that has not measured yet): beyond this many the oldest are dropped.
MAX_UNPAIRED_TRUTHS = 10_000


def _two_sum(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """a + b and the rounding error of that sum, elementwise (Neumaier)."""
    total = a + b
    return total, np.where(np.abs(a) >= np.abs(b), (a - total) + b, (b - total) + a)


class ErrorSums:
    """Running sums of paired pose errors, for :class:`ErrorStatistics` in bounded memory:
    count, Σ Δp (3,) m, Σ |Δp|², max |Δp|, Σ angle², max angle (rad). The sums are
    compensated (Neumaier), so adding the same errors in other groupings changes a figure
    only in its last bits."""

    def __init__(self) -> None:
        self.count = 0
        self._sum = np.zeros(5)          # Σ Δx, Σ Δy, Σ Δz, Σ |Δp|², Σ angle²
        self._carry = np.zeros(5)
        self.max_position = 0.0
        self.max_angle = 0.0

    def add(self, position_error: FloatArray, orientation_error: FloatArray) -> None:
        """Add errors Δp (N, 3) m and rotation vectors (N, 3) rad."""
        if position_error.shape[0] == 0:
            return
        d, a = row_norms(position_error), row_norms(orientation_error)
        part = np.concatenate([position_error.sum(axis=0), [(d * d).sum(), (a * a).sum()]])
        self._sum, error = _two_sum(self._sum, part)
        self._carry = self._carry + error
        self.count += int(position_error.shape[0])
        self.max_position = max(self.max_position, float(d.max()))
        self.max_angle = max(self.max_angle, float(a.max()))

    @staticmethod
    def grouped(label_m: IntArray, label_t: IntArray, position_error: FloatArray,
                orientation_error: FloatArray) -> dict[tuple[int, int], ErrorSums]:
        """The sums of errors Δp (N, 3) m and rotation vectors (N, 3) rad per pair of labels
        (N,), (N,): one sort and one reduction for all groups (:func:`grouped_rows`)."""
        return sums_by_labels(*grouped_rows(label_m, label_t, position_error,
                                            orientation_error))

    def merged(self, other: ErrorSums) -> ErrorSums:
        """These sums and ``other``'s together (a new object)."""
        return ErrorSums.total([self, other])

    @staticmethod
    def total(parts: Iterable[ErrorSums]) -> ErrorSums:
        """The sums of all ``parts`` together (a new object): each component the correctly
        rounded sum of the parts' sums and carries (``math.fsum``), whatever their order."""
        parts = list(parts)
        out = ErrorSums()
        out.count = sum(p.count for p in parts)
        out._sum = np.array([math.fsum([v for p in parts for v in (p._sum[i], p._carry[i])])
                             for i in range(5)])
        out.max_position = max((p.max_position for p in parts), default=0.0)
        out.max_angle = max((p.max_angle for p in parts), default=0.0)
        return out

    def statistics(self) -> ErrorStatistics | None:
        """The statistics of everything added; None when nothing was."""
        if self.count == 0:
            return None
        s = (self._sum + self._carry) / self.count
        return ErrorStatistics(samples=self.count, mean_position_error=triple(s[:3]),
                               rms_position_error=float(np.sqrt(s[3])),
                               max_position_error=self.max_position,
                               rms_orientation_error=float(np.sqrt(s[4])),
                               max_orientation_error=self.max_angle)


#: The columns of a row of :func:`grouped_rows`: count, Σ Δx, Σ Δy, Σ Δz, Σ |Δp|², Σ angle²,
#: max |Δp|, max angle.
ROW_COLUMNS = 8


def grouped_rows(label_m: IntArray, label_t: IntArray, position_error: FloatArray,
                 orientation_error: FloatArray) -> tuple[IntArray, FloatArray]:
    """The sums of errors Δp (N, 3) m and rotation vectors (N, 3) rad per pair of labels
    (N,), (N,) as columns: the pairs (G, 2) and per pair the :data:`ROW_COLUMNS` figures
    (G, 8), one sort and one reduction for all groups."""
    if position_error.shape[0] == 0:
        return np.empty((0, 2), dtype=np.intp), np.empty((0, ROW_COLUMNS))
    order = np.lexsort((label_t, label_m))
    lm, lt = label_m[order], label_t[order]
    starts = np.flatnonzero(np.r_[True, (lm[1:] != lm[:-1]) | (lt[1:] != lt[:-1])])
    dp, rv = position_error[order], orientation_error[order]
    d, a = row_norms(dp), row_norms(rv)
    rows = np.column_stack([np.diff(np.r_[starts, order.size]).astype(float),
                            np.add.reduceat(dp, starts, axis=0),
                            np.add.reduceat(d * d, starts), np.add.reduceat(a * a, starts),
                            np.maximum.reduceat(d, starts), np.maximum.reduceat(a, starts)])
    return np.column_stack([lm[starts], lt[starts]]).astype(np.intp), rows


def combined_rows(labels: IntArray, rows: FloatArray) -> tuple[IntArray, FloatArray]:
    """Rows of :func:`grouped_rows` (several may share a pair of labels) as one row per pair,
    in label order: counts and maxima combined, each sum the correctly rounded sum of its
    rows' (``math.fsum``), whatever their order."""
    if labels.shape[0] == 0:
        return labels, rows
    order = np.lexsort((labels[:, 1], labels[:, 0]))
    labels, rows = labels[order], rows[order]
    starts = np.flatnonzero(np.r_[True, (labels[1:] != labels[:-1]).any(axis=1)])
    out = rows[starts].copy()
    out[:, 0] = np.add.reduceat(rows[:, 0], starts)  # counts: whole numbers, exact
    out[:, 6:] = np.maximum.reduceat(rows[:, 6:], starts, axis=0)
    ends = np.r_[starts[1:], labels.shape[0]]
    for g in np.flatnonzero(ends - starts > 1).tolist():  # over groups, not samples
        block = rows[starts[g]:ends[g]]
        out[g, 1:6] = [math.fsum(block[:, c]) for c in range(1, 6)]
    return labels[starts], out


def sums_by_labels(labels: IntArray, rows: FloatArray) -> dict[tuple[int, int], ErrorSums]:
    """Rows of :func:`grouped_rows` as one :class:`ErrorSums` per pair of labels, in label
    order (:func:`combined_rows`)."""
    labels, rows = combined_rows(labels, rows)
    out: dict[tuple[int, int], ErrorSums] = {}
    for (m, t), row in zip(labels.tolist(), rows, strict=True):  # over groups, not samples
        sums = ErrorSums()
        sums.count, sums._sum = int(row[0]), row[1:6].copy()
        sums.max_position, sums.max_angle = float(row[6]), float(row[7])
        out[m, t] = sums
    return out


class _PairRows:
    """The rows of :func:`grouped_rows` committed so far, in blocks of columns (two arrays a
    block): every :data:`BLOCKS` blocks are joined into one row per pair of labels
    (:func:`combined_rows`), so that memory is ~80 bytes a pair of labels (issue 24: an
    :class:`ErrorSums` object per pair took ~330), however many pairings fed it (the live
    monitor pairs at every reading)."""

    BLOCKS = 64

    def __init__(self) -> None:
        self._labels: list[IntArray] = []
        self._rows: list[FloatArray] = []

    def add(self, labels: IntArray, rows: FloatArray) -> None:
        if not labels.shape[0]:
            return
        self._labels.append(labels)
        self._rows.append(rows)
        if len(self._labels) >= self.BLOCKS:
            joined = combined_rows(np.concatenate(self._labels), np.concatenate(self._rows))
            self._labels, self._rows = [joined[0]], [joined[1]]

    def with_rows(self, labels: IntArray, rows: FloatArray) -> tuple[IntArray, FloatArray]:
        """Every committed row and ``labels``, ``rows`` after them."""
        return (np.concatenate([*self._labels, labels]), np.concatenate([*self._rows, rows]))

    def __len__(self) -> int:
        """The rows kept."""
        return sum(labels.shape[0] for labels in self._labels)


class _Series:
    """Poses of one source in stamp order, the oldest dropped once no pairing needs them:
    times (N,) s, positions (N, 3), quaternions (N, 4), labels (N,), and the index in the
    whole series of the first one kept."""

    def __init__(self) -> None:
        self.time = np.empty(0)
        self.position = np.empty((0, 3))
        self.quaternion = np.empty((0, 4))
        self.label = np.empty(0, dtype=np.intp)
        self.base = 0
        self.last = -math.inf

    def add(self, t: FloatArray, p: FloatArray, q: FloatArray, label: IntArray) -> None:
        self.time = np.concatenate([self.time, t])
        self.position = np.concatenate([self.position, p])
        self.quaternion = np.concatenate([self.quaternion, q])
        self.label = np.concatenate([self.label, label])
        if t.size:
            self.last = float(t[-1])

    def drop(self, count: int) -> None:
        """Forget the first ``count`` kept."""
        if count > 0:
            self.time, self.position = self.time[count:], self.position[count:]
            self.quaternion, self.label = self.quaternion[count:], self.label[count:]
            self.base += count


class TrackerErrorAccumulator:
    """Streaming form of :func:`tracker_errors`: at any moment :meth:`statistics` is that of
    :func:`pair_by_stamp` over every measurement and true pose given so far, whatever order and
    batches they came in (each series in non-decreasing stamps: InputError otherwise).

    A measurement is paired for good once a true pose stamped at or after it has arrived (its
    nearest truth can no longer change); the pairs go into running sums (:class:`ErrorSums`)
    per pair of labels (the measurement's and the truth's: e.g. the segment of a run each was
    taken in); only the measurements still waiting and the
    true poses they may pair with are kept, so memory stays bounded however long the run."""

    def __init__(self, tolerance: float) -> None:
        if not (math.isfinite(tolerance) and tolerance > 0.0):
            raise ParameterError('max_stamp_difference', tolerance, 'must be finite and > 0 s')
        self.tolerance = tolerance
        self.reset()

    def reset(self) -> None:
        """Forget every pair and unpaired sample."""
        self._measured = _Series()
        self._truth = _Series()
        self._claimed = -1                      # truth index taken by the last pair
        self._sums = _PairRows()

    @property
    def last_measured(self) -> float:
        """Stamp (s) of the latest measurement given (−inf: none)."""
        return self._measured.last

    @property
    def last_truth(self) -> float:
        """Stamp (s) of the latest true pose given (−inf: none)."""
        return self._truth.last

    def add_measured(self, time: ArrayLike, position: ArrayLike, quaternion: ArrayLike,
                     label: ArrayLike | int = 0) -> None:
        """Measured poses: stamps (N,) s, positions (N, 3) m, quaternions (N, 4); ``label``
        (N,) or one for all, the key their pairs are summed under."""
        self._add(self._measured, time, position, quaternion, label, 'measurement')

    def add_truth(self, time: ArrayLike, position: ArrayLike, quaternion: ArrayLike,
                  label: ArrayLike | int = 0) -> None:
        """True poses: stamps (N,) s, positions (N, 3) m, quaternions (N, 4); ``label`` (N,)
        or one for all."""
        self._add(self._truth, time, position, quaternion, label, 'true pose')
        excess = self._truth.time.size - MAX_UNPAIRED_TRUTHS
        if excess > 0 and self._measured.time.size == 0:
            self._truth.drop(excess)

    def _add(self, series: _Series, time: ArrayLike, position: ArrayLike,
             quaternion: ArrayLike, label: ArrayLike | int, what: str) -> None:
        t = as_times(np.reshape(np.asarray(time, dtype=float), -1), f'{what} time')
        if t.size == 0:
            return
        p, q = as_pose_batch(position, quaternion)
        if t.size != p.shape[0]:
            raise InputError(f'{t.size} {what} times for {p.shape[0]} poses')
        if t.size and t[0] < series.last:
            raise InputError(f'{what} time {float(t[0])!r} s is earlier than the previous '
                             f'one ({series.last!r} s)')
        labels = np.broadcast_to(np.asarray(label, dtype=np.intp), t.shape)
        series.add(t, p, q, np.array(labels))
        self._pair(final=True)

    def _nearest(self, a: FloatArray) -> IntArray:
        """Index (into the kept truths) of the nearest truth to each stamp of ``a`` by
        :func:`pair_by_stamp`'s rule (the earlier one on a tie)."""
        tb = self._truth.time
        right = np.clip(np.searchsorted(tb, a), 0, tb.size - 1)
        left = np.clip(right - 1, 0, tb.size - 1)
        return np.where(np.abs(tb[left] - a) <= np.abs(tb[right] - a), left, right)

    def _pair(self, *, final: bool) -> tuple[IntArray, FloatArray]:
        """Pair the waiting measurements: with ``final`` only those whose nearest truth is
        settled (committed to the sums, then forgotten); otherwise all of them, as if the
        series ended now (returned, nothing committed). The pairs' :func:`grouped_rows`."""
        m, tb = self._measured, self._truth.time
        none = np.empty((0, 2), dtype=np.intp), np.empty((0, ROW_COLUMNS))
        if m.time.size == 0 or tb.size == 0:
            return none
        n = int(np.searchsorted(m.time, tb[-1], side='right')) if final else m.time.size
        a = m.time[:n]
        near = self._nearest(a)
        ok = np.abs(tb[near] - a) <= self.tolerance
        rows = np.flatnonzero(ok)
        taken = near[rows] + self._truth.base
        first = taken != np.concatenate([[self._claimed], taken[:-1]])
        rows, near = rows[first], near[rows[first]]
        out = none
        if rows.size:
            dp, rv = pose_error(m.position[rows], m.quaternion[rows], self._truth.position[near],
                                self._truth.quaternion[near])
            out = grouped_rows(m.label[rows], self._truth.label[near], dp, rv)
        if final:
            if rows.size:
                self._claimed = int(near[-1]) + self._truth.base
            self._sums.add(*out)
            m.drop(n)
            # Keep the truths a later measurement may pair with: from the last one before the
            # earliest stamp still to come, and the last two (a measurement after every truth
            # is weighed against both until a later truth arrives).
            earliest = m.time[0] if m.time.size else m.last
            keep = min(int(np.searchsorted(tb, earliest, side='left')) - 1, tb.size - 2)
            self._truth.drop(max(keep, 0))
        return out

    def sums(self) -> dict[tuple[int, int], ErrorSums]:
        """Per (measurement's label, truth's label), the sums of every pair so far (waiting
        measurements paired as if the series ended now)."""
        return sums_by_labels(*self._sums.with_rows(*self._pair(final=False)))

    def statistics(self) -> ErrorStatistics | None:
        """Statistics over every pair so far, None without pairs."""
        return ErrorSums.total(self.sums().values()).statistics()
