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
* The first stable window of a segment settles it: the attained pose of the visit is the
  window's mean position and mean rotation (chordal L2 mean). Later samples of that segment
  are not used.

Events must come in time order (samples non-decreasing; a target after the last sample), so a
live node and an offline run over a recorded bag give identical figures.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.accuracy.iso9283 import PoseFigures, iso9283
from positioning_cell.core.poses import (
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
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

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
        if self._positions:
            same = self.same(np.array(self._positions), np.array(self._quaternions),
                             position, quaternion)
            hits = np.flatnonzero(same)
            if hits.size:
                return int(hits[0])
        self._positions.append(np.array(position, dtype=float))
        self._quaternions.append(np.array(quaternion, dtype=float))
        return len(self._positions) - 1

    def same(self, positions: FloatArray, quaternions: FloatArray, position: FloatArray,
             quaternion: FloatArray) -> NDArray[np.bool_]:
        """Which of the poses (K, 3), (K, 4) equal the pose (3,), (4,) within the tolerances."""
        dp, rv = pose_error(positions, quaternions, position[np.newaxis],
                            quaternion[np.newaxis])
        return np.asarray((np.sqrt((dp ** 2).sum(axis=1)) <= self.position_tolerance)
                          & (np.sqrt((rv ** 2).sum(axis=1)) <= self.angle_tolerance))

def _window_spreads(values: FloatArray, starts: IntArray, ends: IntArray) -> FloatArray:
    """Bounding-box diagonals (M,) of the windows values[starts[m]:ends[m] + 1] of (N, 3)."""
    padded = np.vstack([values, values[-1:]])
    index = np.empty(2 * starts.size, dtype=np.intp)
    index[0::2] = starts
    index[1::2] = ends + 1
    high = np.maximum.reduceat(padded, index, axis=0)[0::2]
    low = np.minimum.reduceat(padded, index, axis=0)[0::2]
    return row_norms(high - low)

def _window_pose(position: FloatArray, quaternion: FloatArray) -> tuple[Triple, Quad]:
    """Attained pose of a settle window: mean position and chordal L2 mean rotation."""
    p = np.ascontiguousarray(position).mean(axis=0)
    q = Rotation.from_quat(np.ascontiguousarray(quaternion)).mean().as_quat(canonical=True)
    return triple(p), quad(q)

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
                   settings: SettleSettings | None = None) -> list[Visit]:
    """The settled visits (in time order) of a measured series against a target series.

    ``times`` (N,) s non-decreasing, ``position`` (N, 3) m, ``quaternion`` (N, 4): the
    measured poses; ``target_times`` (M,) s non-decreasing with their commanded poses (M, 3),
    (M, 4). The rule is in the module docstring; vectorised over samples.
    """
    settings = settings or SettleSettings()
    t = as_times(times, 'times')
    p, q = as_pose_batch(position, quaternion)
    tt = as_times(target_times, 'target_times')
    tp, tq = as_pose_batch(target_position, target_quaternion)
    if t.size != p.shape[0] or tt.size != tp.shape[0]:
        raise InputError(f'{t.size} times for {p.shape[0]} poses, {tt.size} target times '
                         f'for {tp.shape[0]} targets')
    keys = PoseKeys(settings.key_position_tolerance, settings.key_angle_tolerance)
    segments: list[tuple[float, FloatArray, FloatArray, int]] = []
    for k in range(tt.size):  # over targets, not samples
        if segments and keys.same(segments[-1][1][np.newaxis], segments[-1][2][np.newaxis],
                                  tp[k], tq[k])[0]:
            continue
        segments.append((float(tt[k]), tp[k], tq[k], keys.key_for(tp[k], tq[k])))
    if not segments or t.size == 0:
        return []
    seg_time = np.array([s[0] for s in segments])
    seg = np.searchsorted(seg_time, t, side='right') - 1
    first = int(np.searchsorted(seg, 0, side='left'))
    t, p, q, seg = t[first:], p[first:], q[first:], seg[first:]
    if t.size == 0:
        return []
    seg_p = np.array([s[1] for s in segments])
    seg_q = np.array([s[2] for s in segments])
    _, rv = pose_error(p, q, seg_p[seg], seg_q[seg])
    index = np.arange(t.size)
    start = np.searchsorted(t, t - settings.window, side='right')
    complete = ((t - settings.window >= seg_time[seg] + settings.dwell)
                & (index - start + 1 >= settings.min_samples))
    cand = np.flatnonzero(complete)
    if cand.size == 0:
        return []
    stable = ((_window_spreads(p, start[cand], cand) <= settings.position_threshold)
              & (_window_spreads(rv, start[cand], cand) <= settings.angle_threshold))
    settled = cand[stable]
    _, first_of_segment = np.unique(seg[settled], return_index=True)
    visits: list[Visit] = []
    cycles: dict[int, int] = {}
    for i in settled[first_of_segment]:  # one per settled segment
        s, (seg_t, seg_pos, seg_quat, key) = int(start[i]), segments[int(seg[i])]
        cycles[key] = cycles.get(key, 0) + 1
        visits.append(_visit(key, cycles[key], seg_t, seg_pos, seg_quat, t[s:i + 1],
                             p[s:i + 1], q[s:i + 1]))
    return visits

def _visit(key: int, cycle: int, target_time: float, target_position: FloatArray,
           target_quaternion: FloatArray, t: FloatArray, p: FloatArray,
           q: FloatArray) -> Visit:
    position, quaternion = _window_pose(p, q)
    return Visit(key=key, cycle=cycle, target_time=target_time, window_start=float(t[0]),
                 settle_time=float(t[-1]), samples=int(t.size),
                 commanded_position=triple(target_position),
                 commanded_quaternion=quad(target_quaternion), position=position,
                 quaternion=quaternion)

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
            settings: SettleSettings | None = None) -> AccuracyResult:
    """Batch analysis of a recorded series: :func:`settled_visits` then the ISO figures."""
    return AccuracyResult.from_visits(settled_visits(
        times, position, quaternion, target_times, target_position, target_quaternion,
        settings))

# -- streaming -------------------------------------------------------------------------------
@dataclass(frozen=True)
class SampleUpdate:
    """What one measured sample gave: its error against the current target (None without a
    target): Δp (3,) m and rotation vector (3,) rad; and the visit it settled, if any."""

    position_error: FloatArray | None = None
    orientation_error: FloatArray | None = None
    visit: Visit | None = None

class AccuracyAccumulator:
    """Message-by-message form of :func:`analyse`: on the same time-ordered events it gives
    exactly the same visits and figures. Targets go to :meth:`add_target`, measurements to
    :meth:`add_sample`; memory is one window plus the visits."""

    def __init__(self, settings: SettleSettings | None = None) -> None:
        self.settings = settings or SettleSettings()
        self._target: tuple[float, FloatArray, FloatArray, int] | None = None
        self._last_sample = -math.inf
        self._keys = PoseKeys(self.settings.key_position_tolerance,
                              self.settings.key_angle_tolerance)
        self._visits: list[Visit] = []
        self._cycles: dict[int, int] = {}
        self._settled = False
        self._window: deque[tuple[float, FloatArray, FloatArray, FloatArray]] = deque()

    def reset(self, *, keep_target: bool = False) -> None:
        """Forget every sample, visit and pose key; with ``keep_target`` the current target
        stays, as if it had just been given (key 0, its time, no samples yet)."""
        target = self._target if keep_target else None
        self._keys = PoseKeys(self.settings.key_position_tolerance,
                              self.settings.key_angle_tolerance)
        self._visits = []
        self._cycles = {}
        self._target = None
        self._settled = False
        self._window.clear()
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
    def visits(self) -> tuple[Visit, ...]:
        """Settled visits so far, in time order."""
        return tuple(self._visits)

    def result(self) -> AccuracyResult:
        """Visits and ISO 9283 figures so far."""
        return AccuracyResult.from_visits(self._visits)

    def add_target(self, time: float, position: ArrayLike, quaternion: ArrayLike, *,
                   clamp: bool = False) -> float:
        """A new commanded pose at ``time`` s; returns the time it takes effect. A target must
        be later than the last sample and not earlier than the current target; with
        ``clamp`` an earlier one takes effect just after them instead of raising InputError.
        A target equal to the current one (key tolerances) changes nothing."""
        t = as_time(time, 'target time')
        p, q = as_pose_batch(position, quaternion)
        if self._target is not None and self._keys.same(
                self._target[1][np.newaxis], self._target[2][np.newaxis], p[0], q[0])[0]:
            return self._target[0]
        earliest = max(float(np.nextafter(self._last_sample, math.inf)),
                       self._target[0] if self._target is not None else -math.inf)
        if t < earliest:
            if not clamp:
                raise InputError(f'target time {t!r} s is not after the last sample '
                                 f'({self._last_sample!r} s) and the current target')
            t = earliest
        self._target = (float(t), p[0], q[0], self._keys.key_for(p[0], q[0]))
        self._settled = False
        self._window.clear()
        return float(t)

    def add_sample(self, time: float, position: ArrayLike,
                   quaternion: ArrayLike) -> SampleUpdate:
        """One measured pose at ``time`` s (non-decreasing): its error against the current
        target, and the visit it settled, if it completed a stable window."""
        t = as_time(time, 'sample time')
        p, q = as_pose_batch(position, quaternion)
        if p.shape[0] != 1:
            raise InputError(f'add_sample takes one pose, got {p.shape[0]}')
        if self._target is None:
            return SampleUpdate()
        if t < self._last_sample:
            raise InputError(f'sample time {t!r} s is earlier than the previous sample '
                             f'({self._last_sample!r} s)')
        self._last_sample = float(t)
        seg_t, seg_p, seg_q, key = self._target
        dp, rv = pose_error(p, q, seg_p[np.newaxis], seg_q[np.newaxis])
        update = SampleUpdate(dp[0], rv[0])
        if self._settled or t < seg_t:
            return update
        s = self.settings
        window = self._window
        window.append((float(t), p[0], q[0], rv[0]))
        while window and window[0][0] <= t - s.window:
            window.popleft()
        if not (t - s.window >= seg_t + s.dwell and len(window) >= s.min_samples):
            return update
        wp = np.array([w[1] for w in window])
        wr = np.array([w[3] for w in window])
        spreads = row_norms(np.array([wp.max(axis=0) - wp.min(axis=0),
                                   wr.max(axis=0) - wr.min(axis=0)]))
        if spreads[0] > s.position_threshold or spreads[1] > s.angle_threshold:
            return update
        self._settled = True
        self._cycles[key] = self._cycles.get(key, 0) + 1
        visit = _visit(key, self._cycles[key], seg_t, seg_p, seg_q,
                       np.array([w[0] for w in window]), wp, np.array([w[2] for w in window]))
        self._visits.append(visit)
        return SampleUpdate(dp[0], rv[0], visit)
