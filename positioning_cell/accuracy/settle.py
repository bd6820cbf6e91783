"""Pose accuracy of the cell: measured vs commanded pose, settle detection, ISO 9283 figures
and tolerance verdicts. Pure numpy/scipy over arrays of samples; no ROS.

Time series are float seconds (:func:`stamp_seconds` of the message header stamps), positions
(N, 3) m in the ``base`` frame, unit quaternions (N, 4) x, y, z, w.

How one attained pose per visit is found (the same rule in the batch functions and in the
streaming :class:`AccuracyAccumulator`):

* A target (commanded pose) starts a *segment* at its time; a target equal to the current one
  (within the key tolerances) changes nothing. Each segment gets a *pose key*: the index, in
  order of first appearance, of the first earlier target equal to it within the key
  tolerances, so the n visits of one commanded pose are the n cycles of ISO 9283.
* A sample belongs to the last target whose time is <= its time. The window ending at sample
  i holds the samples j <= i of its segment with t_j > t_i − window. It is *complete* when
  t_i − window >= target time + dwell and it holds at least ``min_samples`` samples.
* A complete window is *stable* when the diagonal of the bounding box of its positions is
  <= ``position_threshold`` and that of its orientation errors (rotation vectors of
  R_cmdᵀ·R, rad) is <= ``angle_threshold``.
* A visit is judged on the *final* settled window of its segment, not on a pause before a
  correction (``measured`` compensation moves, pauses, measures and corrects, then reports
  the move settled): once the positioner has reported the end of the move (a *move end* at
  time E, :func:`positioning_cell.accuracy.monitor.move_ended`), the first stable window that
  begins after it (t_i − window >= E) of a sample that came after the move end (in the order
  the monitor takes them: stamp order, :mod:`positioning_cell.accuracy.stamp_order`) settles the
  segment. Otherwise (no move end: a bag recorded before the positioner's end reports were
  read, a move that reports none; or the next target came too soon after the end for a whole
  window) the last stable window of the segment settles it when the next target arrives (or
  at the end of the stream: :meth:`AccuracyAccumulator.finish`). The attained pose of the
  visit is the window's mean position and mean rotation (chordal L2 mean). Later samples of
  that segment are not used.

Events must come in time order (samples non-decreasing; a target after the last sample), so a
live node and an offline run over a recorded bag give identical figures: whether a window
counts depends only on what arrived before its last sample, never on how the events are
grouped into batches.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.iso9283 import PoseFigures, iso9283
from positioning_cell.core.poses import (
    QUATERNION_UNIT_TOLERANCE,
    Quad,
    Triple,
    as_pose_batch,
    as_vectors,
    pose_error,
    quad,
    row_norms,
    triple,
)
from positioning_cell.errors import InputError
from positioning_cell.parameters import check_fields, parse, setting, to_params
from positioning_cell.records import plain_fields

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

def stamp_seconds(sec: int, nanosec: int) -> float:
    """A header stamp (builtin_interfaces/Time) as float seconds, the time axis of this module."""
    return float(sec) + float(nanosec) * 1e-9


@dataclass(frozen=True)
class SettleSettings:
    """Settle detection and pose grouping (SI): the ``settle:`` block of the accuracy monitor
    (module docstring of :mod:`positioning_cell.accuracy.settle`)."""

    window: float = setting(0.5, 'stability window', 's', low=0.0, low_open=True, high=60.0)
    dwell: float = setting(0.5, 'time after a target change before a window may start', 's',
                           low=0.0, high=600.0)
    position_threshold: float = setting(0.15e-3, 'largest bounding-box diagonal of the '
                                        'positions of a stable window', 'm', low=0.0,
                                        low_open=True, high=0.1)
    angle_threshold: float = setting(1e-3, 'largest bounding-box diagonal of the orientation '
                                     'errors (rotation vectors) of a stable window', 'rad',
                                     low=0.0, low_open=True, high=1.0)
    min_samples: int = setting(5, 'fewest samples in a window', low=2, high=100_000)
    key_position_tolerance: float = setting(1e-6, 'targets this close are one commanded pose',
                                            'm', low=0.0, low_open=True, high=0.01)
    key_angle_tolerance: float = setting(1e-6, 'targets this close are one commanded pose',
                                         'rad', low=0.0, low_open=True, high=0.1)

    def __post_init__(self) -> None:
        check_fields(self)

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> SettleSettings:
        """From the ``settle:`` block (keys relative to it); missing keys keep their
        defaults, unknown keys raise ConfigError."""
        return parse(cls, params)

    def to_params(self) -> dict[str, Any]:
        """The ``settle:`` block (inverse of :meth:`from_params`)."""
        return to_params(self)


# -- errors and orientation angles -----------------------------------------------------------
def measurement_error(position: ArrayLike, quaternion: ArrayLike, position_cmd: ArrayLike,
                      quaternion_cmd: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Measured minus commanded pose: Δp = p − p_cmd (N, 3) m in base, and the rotation vector
    of R_cmdᵀ·R (N, 3) rad. One commanded pose (3,), (4,) applies to all N; else N of each."""
    p, q = as_pose_batch(position, quaternion)
    pc, qc = as_pose_batch(position_cmd, quaternion_cmd)
    if pc.shape[0] not in (1, p.shape[0]):
        raise InputError(f'{p.shape[0]} poses but {pc.shape[0]} commanded poses')
    return pose_error(p, q, pc, qc)

# -- visits ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Visit:
    """One settled visit of a commanded pose. ``key`` the pose key, ``cycle`` the 1-based
    number of this visit to that key; times in s: ``target_time`` (the target took effect),
    ``window_start`` and ``settle_time`` (first and last sample of the settle window);
    ``samples`` in the window; commanded and attained (window mean) pose, m and x, y, z, w."""

    key: int
    cycle: int
    target_time: float
    window_start: float
    settle_time: float
    samples: int
    commanded_position: Triple
    commanded_quaternion: Quad
    position: Triple
    quaternion: Quad

    def error(self) -> tuple[FloatArray, FloatArray]:
        """Attained minus commanded: Δp (3,) m, rotation vector of R_cmdᵀ·R (3,) rad."""
        dp, rv = pose_error(np.array([self.position]), np.array([self.quaternion]),
                            np.array([self.commanded_position]),
                            np.array([self.commanded_quaternion]))
        return dp[0], rv[0]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples as lists)."""
        return plain_fields(self)

class PoseKeys:
    """Registry of commanded poses: the key of a target is the index of the first registered
    pose within ``position_tolerance`` (m) and ``angle_tolerance`` (rad) of it, else a new one."""

    def __init__(self, position_tolerance: float, angle_tolerance: float) -> None:
        self.position_tolerance = position_tolerance
        self.angle_tolerance = angle_tolerance
        self._positions: list[FloatArray] = []
        self._quaternions: list[FloatArray] = []

    def key_for(self, position: FloatArray, quaternion: FloatArray) -> int:
        """Key of the pose (3,), (4,), registering it when new."""
        return self.match(position, quaternion)[1]

    def match(self, position: FloatArray, quaternion: FloatArray,
              current: tuple[FloatArray, FloatArray] | None = None) -> tuple[bool, int]:
        """Whether the pose (3,), (4,) equals ``current`` (position, quaternion; None: no
        current pose), and if not its key (registered when new; −1 when it equals ``current``):
        one comparison against both."""
        known = len(self._positions)
        poses_p = ([current[0]] if current is not None else []) + self._positions
        poses_q = ([current[1]] if current is not None else []) + self._quaternions
        same = (self.same(np.array(poses_p), np.array(poses_q), position, quaternion)
                if poses_p else np.zeros(0, dtype=bool))
        if current is not None and same[0]:
            return True, -1
        hits = np.flatnonzero(same[1:] if current is not None else same)
        if hits.size:
            return False, int(hits[0])
        self._positions.append(np.array(position, dtype=float))
        self._quaternions.append(np.array(quaternion, dtype=float))
        return False, known

    def same(self, positions: FloatArray, quaternions: FloatArray, position: FloatArray,
             quaternion: FloatArray) -> NDArray[np.bool_]:
        """Which of the poses (K, 3), (K, 4) equal the pose (3,), (4,) within the tolerances."""
        arrays = [np.ascontiguousarray(a, dtype=float) for a in (positions, quaternions,
                                                                  position, quaternion)]
        found = _same_poses(*(a.tobytes() for a in arrays), self.position_tolerance,
                            self.angle_tolerance)
        return np.frombuffer(found, dtype=bool)


@functools.lru_cache(maxsize=16)
def _same_poses(positions: bytes, quaternions: bytes, position: bytes, quaternion: bytes,
                position_tolerance: float, angle_tolerance: float) -> bytes:
    """:meth:`PoseKeys.same` on the poses' bytes (float64), the answer as bytes of bools:
    cached, because the monitor's two accumulators compare the same targets against the same
    registered poses."""
    dp, rv = pose_error(np.frombuffer(positions).reshape(-1, 3),
                        np.frombuffer(quaternions).reshape(-1, 4),
                        np.frombuffer(position).reshape(1, 3),
                        np.frombuffer(quaternion).reshape(1, 4))
    same: NDArray[np.bool_] = ((np.sqrt((dp ** 2).sum(axis=1)) <= position_tolerance)
                               & (np.sqrt((rv ** 2).sum(axis=1)) <= angle_tolerance))
    return same.tobytes()

def _window_spreads(values: FloatArray, starts: IntArray, ends: IntArray) -> FloatArray:
    """Bounding-box diagonals (M,) of the windows values[starts[m]:ends[m] + 1] of (N, 3)."""
    padded = np.vstack([values, values[-1:]])
    index = np.empty(2 * starts.size, dtype=np.intp)
    index[0::2] = starts
    index[1::2] = ends + 1
    high = np.maximum.reduceat(padded, index, axis=0)[0::2]
    low = np.minimum.reduceat(padded, index, axis=0)[0::2]
    return row_norms(high - low)

def window_poses(position: FloatArray, quaternion: FloatArray, starts: IntArray,
                 stops: IntArray) -> tuple[FloatArray, FloatArray]:
    """Attained poses of V settle windows, rows ``starts[v]:stops[v]`` (ascending, disjoint) of
    positions (N, 3) m and unit quaternions (N, 4): mean positions (V, 3) and chordal L2 mean
    rotations (V, 4), w >= 0: the unit quaternion maximising Σ (q·q_i)², the eigenvector of the
    largest eigenvalue of Σ q_i q_iᵀ (Markley et al. 2007, as scipy's ``Rotation.mean``). One
    batched computation; a window's result does not depend on the others."""
    if starts.size == 0:
        return np.empty((0, 3)), np.empty((0, 4))
    rows = np.concatenate([np.arange(a, b) for a, b in zip(starts.tolist(), stops.tolist(),
                                                          strict=True)])
    offsets = np.concatenate([[0], np.cumsum(stops - starts)[:-1]]).astype(np.intp)
    count = (stops - starts).astype(float)
    p = np.add.reduceat(position[rows], offsets, axis=0) / count[:, np.newaxis]
    q = quaternion[rows]
    outer = np.add.reduceat(q[:, :, np.newaxis] * q[:, np.newaxis, :], offsets, axis=0)
    mean = np.linalg.eigh(outer)[1][:, :, -1]
    flip = (mean[:, 3] < 0.0) | ((mean[:, 3] == 0.0) & (
        np.take_along_axis(mean[:, :3], np.argmax(mean[:, :3] != 0.0, axis=1)[:, np.newaxis],
                           axis=1)[:, 0] < 0.0))
    return p, np.where(flip[:, np.newaxis], -mean, mean)


def as_times(value: ArrayLike, name: str) -> FloatArray:
    t = as_vectors(np.reshape(np.asarray(value, dtype=float), (-1, 1)), 1, name)[:, 0]
    if t.size > 1 and (np.diff(t) < 0.0).any():
        i = int(np.flatnonzero(np.diff(t) < 0.0)[0]) + 1
        raise InputError(f'{name}[{i}] = {t[i]!r} is earlier than {name}[{i - 1}] = '
                         f'{t[i - 1]!r}: times must be non-decreasing')
    return t

def as_time(value: float, name: str) -> float:
    """One time in s, finite."""
    try:
        t = float(value)
    except (TypeError, ValueError) as err:
        raise InputError(f'{name}: expected a number of seconds, got {value!r}') from err
    if not math.isfinite(t):
        raise InputError(f'{name} = {value!r} is not finite (NaN or infinite)')
    return t

def settled_visits(times: ArrayLike, position: ArrayLike, quaternion: ArrayLike,
                   target_times: ArrayLike, target_position: ArrayLike,
                   target_quaternion: ArrayLike,
                   settings: SettleSettings | None = None,
                   end_times: ArrayLike = ()) -> list[Visit]:
    """The settled visits (in time order) of a measured series against a target series.

    ``times`` (N,) s non-decreasing, ``position`` (N, 3) m, ``quaternion`` (N, 4): the
    measured poses; ``target_times`` (M,) s non-decreasing with their commanded poses (M, 3),
    (M, 4); ``end_times`` (K,) s non-decreasing: the positioner's move ends. At equal times a
    target comes before the samples and a move end after the targets and before the samples.
    The rule is in the module docstring: the streaming accumulator fed the whole series at
    once, then :meth:`AccuracyAccumulator.finish` (the end of the series closes the last
    segment); vectorised over samples.
    """
    settings = settings or SettleSettings()
    t = as_times(times, 'times')
    p, q = as_pose_batch(position, quaternion)
    tt = as_times(target_times, 'target_times')
    tp, tq = as_pose_batch(target_position, target_quaternion)
    te = as_times(end_times, 'end_times')
    if t.size != p.shape[0] or tt.size != tp.shape[0]:
        raise InputError(f'{t.size} times for {p.shape[0]} poses, {tt.size} target times '
                         f'for {tp.shape[0]} targets')
    stream = AccuracyAccumulator(settings)
    stream.add(t, p, q, Targets(np.searchsorted(t, tt, side='left'), tt, tp, tq),
               Ends(np.searchsorted(t, te, side='left'), te,
                    np.searchsorted(tt, te, side='right')))
    stream.finish()
    return list(stream.visits)


def figures_by_pose(visits: Sequence[Visit]) -> list[PoseFigures]:
    """ISO 9283 figures per pose key (ascending) from settled visits in time order. The
    commanded pose of a key is the target of its first visit."""
    out = []
    for key in sorted({v.key for v in visits}):
        mine = [v for v in visits if v.key == key]
        out.append(iso9283(mine[0].commanded_position, mine[0].commanded_quaternion,
                           [v.position for v in mine], [v.quaternion for v in mine], key))
    return out

@dataclass(frozen=True)
class AccuracyResult:
    """Settled visits in time order and the ISO 9283 figures of each commanded pose."""

    visits: tuple[Visit, ...]
    poses: tuple[PoseFigures, ...]

    @classmethod
    def from_visits(cls, visits: Sequence[Visit]) -> AccuracyResult:
        """The result of these visits (figures by :func:`figures_by_pose`)."""
        return cls(tuple(visits), tuple(figures_by_pose(visits)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict: ``visits`` and ``poses`` lists."""
        return {'visits': [v.to_dict() for v in self.visits],
                'poses': [f.to_dict() for f in self.poses]}

def analyse(times: ArrayLike, position: ArrayLike, quaternion: ArrayLike,
            target_times: ArrayLike, target_position: ArrayLike, target_quaternion: ArrayLike,
            settings: SettleSettings | None = None,
            end_times: ArrayLike = ()) -> AccuracyResult:
    """Batch analysis of a recorded series: :func:`settled_visits` then the ISO figures."""
    return AccuracyResult.from_visits(settled_visits(
        times, position, quaternion, target_times, target_position, target_quaternion,
        settings, end_times))

# -- streaming -------------------------------------------------------------------------------
@dataclass(frozen=True)
class SampleUpdate:
    """What one measured sample gave: its error against the current target (None without a
    target): Δp (3,) m and rotation vector (3,) rad; and the visit it settled, if any."""

    position_error: FloatArray | None = None
    orientation_error: FloatArray | None = None
    visit: Visit | None = None


@dataclass(frozen=True)
class Targets:
    """K targets among a batch of samples, in arrival order: ``at`` (K,) how many of the
    batch's samples arrived before each (non-decreasing), times (K,) s, positions (K, 3) m,
    quaternions (K, 4) x, y, z, w (valid: :func:`positioning_cell.core.poses.as_pose_batch`)."""

    at: IntArray
    time: FloatArray
    position: FloatArray
    quaternion: FloatArray

    @classmethod
    def none(cls) -> Targets:
        """No target."""
        return cls(np.empty(0, dtype=np.intp), np.empty(0), np.empty((0, 3)),
                   np.empty((0, 4)))

    @property
    def count(self) -> int:
        """K."""
        return int(self.time.size)


@dataclass(frozen=True)
class Ends:
    """K move ends among a batch of samples, in arrival order: the positioner reported the end
    of the move to the target then current at ``time`` (K,) s (its stamp); ``at`` (K,) how
    many of the batch's samples and ``after`` (K,) how many of its targets arrived before each
    (both non-decreasing)."""

    at: IntArray
    time: FloatArray
    after: IntArray

    @classmethod
    def none(cls) -> Ends:
        """No move end."""
        return cls(np.empty(0, dtype=np.intp), np.empty(0), np.empty(0, dtype=np.intp))

    @property
    def count(self) -> int:
        """K."""
        return int(self.time.size)


#: A settle window reduced to what its visit needs: first and last sample time (s), sample
#: count, mean position (3,) m and mean quaternion (4,).
_Window = tuple[float, float, int, FloatArray, FloatArray]


@dataclass(frozen=True)
class SegmentStart:
    """A target of a batch that started a segment (one equal to the current target does not):
    its index among the batch's targets, the time it took effect (s) and its pose key."""

    target: int
    time: float
    key: int


@dataclass(frozen=True)
class SampleBatch:
    """What a batch of N samples and the targets among them gave.

    ``accepted`` (N,): taken; a refused sample (not finite, a quaternion off unit length, or
    earlier than the previous sample) is named in ``reasons`` {row: why} and changes nothing.
    ``segment`` (N,): the segment each sample fell in, −1 without a target, 0 the segment
    current when the batch began, s >= 1 the one ``started[s − 1]`` began.
    ``position_error`` (N, 3) m and ``orientation_error`` (N, 3) rad against that segment's
    target, NaN where refused or without a target. ``visits``: (row that completed the stable
    window after a move end, visit), in time order; ``closed``: (index among the batch's
    targets of the target that closed it, visit) of the visits settled on their last stable
    window when the next target arrived (module docstring)."""

    accepted: NDArray[np.bool_]
    reasons: Mapping[int, str]
    segment: IntArray
    position_error: FloatArray
    orientation_error: FloatArray
    started: tuple[SegmentStart, ...] = ()
    visits: tuple[tuple[int, Visit], ...] = ()
    closed: tuple[tuple[int, Visit], ...] = ()

    def update(self, row: int) -> SampleUpdate:
        """The :class:`SampleUpdate` of one accepted row."""
        if self.segment[row] < 0:
            return SampleUpdate()
        visit = next((v for r, v in self.visits if r == row), None)
        return SampleUpdate(self.position_error[row], self.orientation_error[row], visit)


@dataclass(frozen=True)
class CheckedSamples:
    """Samples as :func:`check_samples` found them: times (N,) s, positions (N, 3) m, unit
    quaternions (N, 4) (rows of refused samples as given), ``accepted`` (N,) and the
    ``reasons`` of the refused rows."""

    time: FloatArray
    position: FloatArray
    quaternion: FloatArray
    accepted: NDArray[np.bool_]
    reasons: dict[int, str]


def check_samples(time: ArrayLike, position: ArrayLike, quaternion: ArrayLike,
                  previous: float, *, ordered_from: int = 0) -> CheckedSamples:
    """The samples that can be taken, vectorised: finite time, position and quaternion, a
    quaternion within 1e-6 of unit length (normalised), and, from row ``ordered_from`` on, a
    time not earlier than ``previous`` (s) nor than any sample taken before it from that row
    on. A refused row's reason is the message the one-sample checks give (:func:`as_time`,
    :func:`positioning_cell.core.poses.as_pose_batch`). A batch of the wrong shape raises
    InputError."""
    try:
        t = np.asarray(time, dtype=float).reshape(-1)
    except (TypeError, ValueError) as err:
        raise InputError(f'sample time: expected numbers of seconds, got {time!r}') from err
    p = as_vectors(position, 3, 'position', finite=False) if t.size else np.empty((0, 3))
    q = (as_vectors(quaternion, 4, 'quaternion', finite=False) if t.size
         else np.empty((0, 4)))
    if not t.size == p.shape[0] == q.shape[0]:
        raise InputError(f'{t.size} sample times, {p.shape[0]} positions and {q.shape[0]} '
                         'quaternions')
    norm = np.sqrt((q * q).sum(axis=1))
    valid = (np.isfinite(t) & np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
             & (np.abs(norm - 1.0) <= QUATERNION_UNIT_TOLERANCE))
    accepted = valid.copy()
    latest = np.full(t.size, previous)
    ordered = valid & (np.arange(t.size) >= ordered_from)
    if ordered.any():
        tv = t[ordered]
        before = np.maximum.accumulate(np.concatenate([[previous], tv[:-1]]))
        latest[ordered] = before
        accepted[ordered] = tv >= before
    reasons: dict[int, str] = {}
    for i in np.flatnonzero(~accepted):  # refused rows only: rare
        row = int(i)
        try:
            as_time(float(t[row]), 'sample time')
            as_pose_batch(p[row], q[row])
            reasons[row] = (f'sample time {float(t[row])!r} s is earlier than the previous '
                            f'sample ({float(latest[row])!r} s)')
        except InputError as err:
            reasons[row] = str(err)
    unit = np.where(valid, norm, 1.0)
    return CheckedSamples(t, p, q / unit[:, np.newaxis], accepted, reasons)


class AccuracyAccumulator:
    """Streaming form of :func:`settled_visits`: on the same time-ordered events it gives
    exactly the same visits and figures, however the events are split into batches (one code
    path: :meth:`add_sample` is a batch of one sample, :meth:`add_target` of one target,
    :meth:`end_move` of one move end). :meth:`add` takes N samples and the targets and move
    ends among them, vectorised over the samples and across segments; memory is one window,
    the open segment's best window so far, plus the visits."""

    def __init__(self, settings: SettleSettings | None = None) -> None:
        self.settings = settings or SettleSettings()
        self._target: tuple[float, FloatArray, FloatArray, int] | None = None
        self._last_sample = -math.inf
        self._keys = PoseKeys(self.settings.key_position_tolerance,
                              self.settings.key_angle_tolerance)
        self._visits: list[Visit] = []
        self._cycles: dict[int, int] = {}
        #: Each commanded pose once, however many visits command it (the visits of a repeated
        #: program share their commanded tuples: issue 24, an analysis's memory).
        self._commanded_p: dict[Triple, Triple] = {}
        self._commanded_q: dict[Quad, Quad] = {}
        self._open_segment()

    def _open_segment(self) -> None:
        """The current segment as just begun: not settled, no move end (−inf), no stable
        window yet, no sample in the stability window."""
        self._settled = False
        self._end = -math.inf
        self._pending: _Window | None = None
        self._clear_window()

    def _clear_window(self) -> None:
        """No sample in the stability window (times, positions, quaternions, rotation
        vectors against the target)."""
        self._window = (np.empty(0), np.empty((0, 3)), np.empty((0, 4)), np.empty((0, 3)))

    def kept_since(self) -> float:
        """The time (s) of the earliest sample a visit still to come may be settled on: the
        start of the open segment's best stable window so far, else the first sample in the
        stability window; inf when it holds neither (what came before is no longer needed,
        e.g. by the monitor's record of each reading's covariance)."""
        times = [self._pending[0]] if self._pending is not None else []
        if self._window[0].size:
            times.append(float(self._window[0][0]))
        return min(times, default=math.inf)

    def open_since(self) -> float:
        """The time (s) from which the open segment's readings are still needed: its start
        while no visit settled it (its stabilisation is taken over all of them:
        :mod:`positioning_cell.accuracy.stabilisation`), else :meth:`kept_since`."""
        if self._target is not None and not self._settled:
            return min(self._target[0], self.kept_since())
        return self.kept_since()

    def reset(self, *, keep_target: bool = False) -> None:
        """Forget every sample, visit and pose key; with ``keep_target`` the current target
        stays, as if it had just been given (key 0, its time, no samples yet)."""
        target = self._target if keep_target else None
        self._keys = PoseKeys(self.settings.key_position_tolerance,
                              self.settings.key_angle_tolerance)
        self._visits = []
        self._cycles = {}
        self._commanded_p, self._commanded_q = {}, {}
        self._target = None
        self._open_segment()
        if target is not None:
            self._target = (target[0], target[1], target[2],
                            self._keys.key_for(target[1], target[2]))
        else:
            self._last_sample = -math.inf

    @property
    def target(self) -> tuple[float, FloatArray, FloatArray, int] | None:
        """Current target: (time s, position (3,), quaternion (4,), key), or None."""
        return self._target

    @property
    def move_end(self) -> float | None:
        """The latest move end (s) reported for the current target, None: none yet."""
        return self._end if math.isfinite(self._end) else None

    @property
    def last_sample(self) -> float:
        """Time (s) of the latest sample taken against a target (−inf: none since the last
        reset without target)."""
        return self._last_sample

    @property
    def visits(self) -> tuple[Visit, ...]:
        """Settled visits so far, in time order."""
        return tuple(self._visits)

    @property
    def visit_count(self) -> int:
        """How many visits settled so far."""
        return len(self._visits)

    def result(self) -> AccuracyResult:
        """Visits and ISO 9283 figures so far."""
        return AccuracyResult.from_visits(self._visits)

    def _take_target(self, time: float, position: FloatArray, quaternion: FloatArray,
                     last_sample: float, clamp: bool) -> float | None:
        """A valid target (3,), (4,) after samples up to ``last_sample`` s: the time it takes
        effect when it starts a segment, None when it equals the current target."""
        current = self._target
        earliest = max(float(np.nextafter(last_sample, math.inf)),
                       current[0] if current is not None else -math.inf)
        if not clamp and time < earliest and not (current is not None and self._keys.same(
                current[1][np.newaxis], current[2][np.newaxis], position, quaternion)[0]):
            raise InputError(f'target time {time!r} s is not after the last sample '
                             f'({last_sample!r} s) and the current target')
        is_current, key = self._keys.match(position, quaternion, None if current is None
                                           else (current[1], current[2]))
        if is_current:
            return None
        self._target = (max(time, earliest), position, quaternion, key)
        self._open_segment()
        return self._target[0]

    def add_target(self, time: float, position: ArrayLike, quaternion: ArrayLike, *,
                   clamp: bool = False) -> float:
        """A new commanded pose at ``time`` s; returns the time it takes effect. A target must
        be later than the last sample and not earlier than the current target; with
        ``clamp`` an earlier one takes effect just after them instead of raising InputError.
        A target equal to the current one (key tolerances) changes nothing. A new target closes
        the segment before it on its last stable window, if no move end settled it."""
        t = as_time(time, 'target time')
        p, q = as_pose_batch(position, quaternion)
        batch = self.add_checked(_NO_SAMPLES, Targets(np.zeros(1, dtype=np.intp),
                                                      np.array([t]), p, q), clamp=clamp)
        assert self._target is not None
        return batch.started[0].time if batch.started else self._target[0]

    def end_move(self, time: float) -> None:
        """The positioner reported the end of the move to the current target at ``time`` s:
        from the next sample on, a window settles the segment only if it begins at or after
        ``time`` (module docstring). Nothing without a target or once the segment settled."""
        self.add_checked(_NO_SAMPLES, ends=Ends(np.zeros(1, dtype=np.intp),
                                                np.array([as_time(time, 'move end time')]),
                                                np.zeros(1, dtype=np.intp)))

    def finish(self) -> Visit | None:
        """The end of the stream closes the open segment as a next target would: on its last
        stable window (None: no target, settled already, or no stable window)."""
        if self._target is None or self._settled or self._pending is None:
            return None
        visit = self._visit(self._target, self._pending)
        self._visits.append(visit)
        self._settled = True
        self._pending = None
        self._clear_window()
        return visit

    def _visit(self, target: tuple[float, FloatArray, FloatArray, int],
               window: _Window) -> Visit:
        """The next visit of ``target`` (time, position, quaternion, key) settled on
        ``window``; the cycles of its key are counted on."""
        key = target[3]
        self._cycles[key] = self._cycles.get(key, 0) + 1
        start, end, count, position, quaternion = window
        p_cmd, q_cmd = triple(target[1]), quad(target[2])
        return Visit(key=key, cycle=self._cycles[key], target_time=target[0],
                     window_start=start, settle_time=end, samples=count,
                     commanded_position=self._commanded_p.setdefault(p_cmd, p_cmd),
                     commanded_quaternion=self._commanded_q.setdefault(q_cmd, q_cmd),
                     position=triple(position), quaternion=quad(quaternion))

    def add_sample(self, time: float, position: ArrayLike,
                   quaternion: ArrayLike) -> SampleUpdate:
        """One measured pose at ``time`` s (non-decreasing): its error against the current
        target, and the visit it settled, if it completed a stable window after a move end. A
        sample that cannot be taken raises InputError and changes nothing."""
        if np.size(time) != 1:
            raise InputError(f'add_sample takes one pose, got {np.size(time)}')
        batch = self.add(np.reshape(np.asarray(time, dtype=float), 1), position, quaternion)
        if not batch.accepted[0]:
            raise InputError(batch.reasons[0])
        return batch.update(0)

    def add(self, time: ArrayLike, position: ArrayLike, quaternion: ArrayLike,
            targets: Targets | None = None, ends: Ends | None = None) -> SampleBatch:
        """N measured poses at ``time`` (N,) s, positions (N, 3) m, quaternions (N, 4), and the
        ``targets`` among them (each takes effect clamped, as ``add_target(clamp=True)``) and
        the move ``ends``, all in arrival order: the rule of the module docstring, vectorised
        over the samples and across the segments. Samples before any target are taken and
        give nothing."""
        targets = targets or Targets.none()
        first_ordered = 0 if self._target is not None else (
            int(targets.at[0]) if targets.count else np.size(time))
        return self.add_checked(check_samples(time, position, quaternion, self._last_sample,
                                              ordered_from=first_ordered), targets, ends)

    def add_checked(self, checked: CheckedSamples, targets: Targets | None = None,
                    ends: Ends | None = None, *, clamp: bool = True) -> SampleBatch:
        """:meth:`add` of samples already checked by :func:`check_samples` with rules at least
        as strict as this accumulator's (the monitor's: every accepted sample is not older than
        any taken before): the checks are not made twice. Without ``clamp`` a target earlier
        than the last sample raises InputError (:meth:`add_target`)."""
        targets = targets or Targets.none()
        ends = ends or Ends.none()
        k_count = targets.count
        first_ordered = 0 if self._target is not None else (
            int(targets.at[0]) if k_count else checked.time.size)
        n, ok = checked.time.size, checked.accepted
        # The latest sample taken against a target after each number of rows.
        counted = np.where(ok & (np.arange(n) >= first_ordered), checked.time, -math.inf)
        latest = np.maximum.accumulate(np.concatenate([[self._last_sample], counted]))
        # Segments: 0 the current one (None if no target yet), then those targets start.
        segs: list[tuple[float, FloatArray, FloatArray, int] | None] = [self._target]
        settled = [self._settled]
        window, end0, pending0 = self._window, self._end, self._pending
        started: list[SegmentStart] = []
        starts_at: list[int] = []
        started_after = [0]  # segments started after each number of targets
        for k in range(k_count):  # over targets, not samples
            taken = self._take_target(float(targets.time[k]), targets.position[k],
                                      targets.quaternion[k], float(latest[targets.at[k]]),
                                      clamp)
            if taken is not None:
                assert self._target is not None
                segs.append(self._target)
                settled.append(False)
                started.append(SegmentStart(k, taken, self._target[3]))
                starts_at.append(int(targets.at[k]))
            started_after.append(len(started))
        self._last_sample = float(latest[-1])
        segment = np.searchsorted(np.array(starts_at, dtype=np.intp), np.arange(n),
                                  side='right')
        if segs[0] is None:
            segment = np.where(segment == 0, -1, segment)
        bound = self._end_bounds(segs, segment, ends, np.array(started_after)[ends.after],
                                 end0)
        dp = np.full((n, 3), math.nan)
        rv = np.full((n, 3), math.nan)
        rows = np.flatnonzero(ok & (segment >= 0))
        seg_t = np.array([g[0] if g is not None else math.nan for g in segs])
        eligible = np.empty(0, dtype=np.intp)
        if rows.size:
            seg_p = np.array([g[1] if g is not None else np.zeros(3) for g in segs])
            seg_q = np.array([g[2] if g is not None else (0.0, 0.0, 0.0, 1.0) for g in segs])
            sr = segment[rows]
            dp[rows], rv[rows] = pose_error(checked.position[rows], checked.quaternion[rows],
                                            seg_p[sr], seg_q[sr])
            eligible = rows[(checked.time[rows] >= seg_t[sr]) & ~np.array(settled)[sr]]
        visits, closed = self._settle(segs, settled, segment, eligible, checked, rv, window,
                                      seg_t, bound, pending0, started)
        return SampleBatch(ok, checked.reasons, segment, dp, rv, tuple(started), tuple(visits),
                           tuple(closed))

    def _end_bounds(self, segs: list[tuple[float, FloatArray, FloatArray, int] | None],
                    segment: IntArray, ends: Ends, end_segment: IntArray,
                    end0: float) -> FloatArray:
        """Per row (N,): the latest move end (s) of its segment that arrived before it (−inf:
        none); the open segment's latest move end is kept for the next batch."""
        bound = np.full(segment.size, -math.inf)
        first = np.searchsorted(segment, np.arange(len(segs)), side='left')
        stop = np.searchsorted(segment, np.arange(len(segs)), side='right')
        bound[first[0]:stop[0]] = end0
        last_end = [end0] + [-math.inf] * (len(segs) - 1)
        for e in range(ends.count):  # over move ends, not samples
            s = int(end_segment[e])
            if segs[s] is None:
                continue
            lo, hi = max(int(ends.at[e]), int(first[s])), int(stop[s])
            bound[lo:hi] = np.maximum(bound[lo:hi], ends.time[e])
            last_end[s] = max(last_end[s], float(ends.time[e]))
        self._end = last_end[-1]
        return bound

    def _settle(self, segs: list[tuple[float, FloatArray, FloatArray, int] | None],
                settled: list[bool], segment: IntArray, eligible: IntArray,
                checked: CheckedSamples, rv: FloatArray,
                window: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
                seg_t: FloatArray, bound: FloatArray, pending0: _Window | None,
                started: list[SegmentStart]
                ) -> tuple[list[tuple[int, Visit]], list[tuple[int, Visit]]]:
        """The visits the eligible rows (those not before their target, of a segment not
        settled yet; the window carried in, of segment 0, first) and the targets settle
        (module docstring): (row, visit) of those settled after a move end, (target, visit) of
        those closed by the next target. The last segment keeps its window and its latest
        stable window for the next batch."""
        s = self.settings
        last = len(segs) - 1
        k0 = window[0].size  # empty once segment 0 settled
        et = np.concatenate([window[0], checked.time[eligible]])
        ep = np.concatenate([window[1], checked.position[eligible]])
        eq = np.concatenate([window[2], checked.quaternion[eligible]])
        er = np.concatenate([window[3], rv[eligible]])
        es = np.concatenate([np.zeros(k0, dtype=np.intp), segment[eligible]])
        eb = np.concatenate([np.full(k0, -math.inf), bound[eligible]])
        index = np.arange(et.size)
        first = np.searchsorted(es, es, side='left')
        start = np.maximum(np.searchsorted(et, et - s.window, side='right'), first)
        complete = ((et - s.window >= seg_t[es] + s.dwell)
                    & (index - start + 1 >= s.min_samples) & (index >= k0))
        cand = np.flatnonzero(complete)
        hits = cand[(_window_spreads(ep, start[cand], cand) <= s.position_threshold)
                    & (_window_spreads(er, start[cand], cand) <= s.angle_threshold)
                    ] if cand.size else cand
        # Stable windows that begin after the move end known when their last sample came.
        ended = hits[np.isfinite(eb[hits]) & (et[hits] - s.window >= eb[hits])]
        segs_e, first_e = np.unique(es[ended], return_index=True)
        settle_at = dict(zip(segs_e.tolist(), ended[first_e].tolist(), strict=True))
        segs_h, last_h = np.unique(es[hits][::-1], return_index=True)
        latest = dict(zip(segs_h.tolist(), hits[::-1][last_h].tolist(), strict=True))
        # Per segment: the row index (into et) of its visit's window, or a carried window.
        chosen: dict[int, int | _Window] = {}
        pending: int | _Window | None = None
        for k in range(len(segs)):  # over segments, not samples
            if segs[k] is None or settled[k]:
                continue
            if k in settle_at:
                chosen[k] = settle_at[k]
                continue
            best: int | _Window | None = latest.get(k, pending0 if k == 0 else None)
            if k < last and best is not None:
                chosen[k] = best
            elif k == last:
                pending = best
        new = [i for i in (*chosen.values(), pending) if isinstance(i, int)]
        ends_ = np.array(new, dtype=np.intp)
        mean_p, mean_q = window_poses(ep, eq, start[ends_], ends_ + 1)
        reduced: dict[int, _Window] = {
            i: (float(et[start[i]]), float(et[i]), int(i + 1 - start[i]), mean_p[j], mean_q[j])
            for j, i in enumerate(new)}
        visits: list[tuple[int, Visit]] = []
        closed: list[tuple[int, Visit]] = []
        for k in sorted(chosen):
            pick = chosen[k]
            target = segs[k]
            assert target is not None
            visit = self._visit(target, reduced[pick] if isinstance(pick, int) else pick)
            self._visits.append(visit)
            if k in settle_at:
                visits.append((int(eligible[settle_at[k] - k0]), visit))
            else:
                closed.append((started[k].target, visit))
        self._pending = reduced[pending] if isinstance(pending, int) else pending
        if last in settle_at:
            self._settled = True
            self._pending = None
            self._clear_window()
            return visits, closed
        mine = np.flatnonzero(es == last)
        if mine.size:
            keep = max(int(np.searchsorted(et, et[mine[-1]] - s.window, side='right')),
                       int(mine[0]))
            self._window = (et[keep:], ep[keep:], eq[keep:], er[keep:])
        return visits, closed


#: An empty batch of samples (a target or a move end alone).
_NO_SAMPLES = CheckedSamples(np.empty(0), np.empty((0, 3)), np.empty((0, 4)),
                             np.zeros(0, dtype=bool), {})
