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
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.errors import ConfigError, InputError
from positioning_cell.poses import as_pose_batch, as_unit_quaternions, as_vectors, pose_error

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]
Triple = tuple[float, float, float]
Quad = tuple[float, float, float, float]

#: Default position tolerance of a settled pose, m (0.05 mm).
POSITION_TOLERANCE = 0.05e-3
#: Default orientation tolerance of a settled pose, rad (0.01°).
ORIENTATION_TOLERANCE = math.radians(0.01)
#: Orientation angles a, b, c of ISO 9283: roll, pitch, yaw about the fixed base axes x, y, z,
#: R = Rz(c)·Ry(b)·Rx(a) (scipy's extrinsic 'xyz').
EULER_SEQUENCE = 'xyz'


def stamp_seconds(sec: int, nanosec: int) -> float:
    """A header stamp (builtin_interfaces/Time) as float seconds, the time axis of this module."""
    return float(sec) + float(nanosec) * 1e-9


# -- settings --------------------------------------------------------------------------------
def _positive(owner: str, name: str, value: float, *, zero_ok: bool = False) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or value < 0.0 or (value == 0.0 and not zero_ok):
        bound = '>= 0' if zero_ok else '> 0'
        raise ConfigError(f'{owner}.{name} = {value!r}: must be a finite number {bound}')


@dataclass(frozen=True)
class SettleSettings:
    """Settle detection and pose grouping (SI). ``window`` (s) the stability window;
    ``dwell`` (s) the time after a target change before a window may start;
    ``position_threshold`` (m) and ``angle_threshold`` (rad) the largest bounding-box
    diagonals of a stable window; ``min_samples`` the fewest samples in a window;
    ``key_position_tolerance`` (m) and ``key_angle_tolerance`` (rad) how close two targets
    must be to count as the same commanded pose."""

    window: float = 0.5
    dwell: float = 0.5
    position_threshold: float = 0.15e-3
    angle_threshold: float = 1e-3
    min_samples: int = 5
    key_position_tolerance: float = 1e-6
    key_angle_tolerance: float = 1e-6

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == 'min_samples':
                value = self.min_samples
                if isinstance(value, bool) or not isinstance(value, int) or value < 2:
                    raise ConfigError(f'settle.min_samples = {value!r}: must be an integer >= 2')
            else:
                _positive('settle', f.name, getattr(self, f.name), zero_ok=f.name == 'dwell')

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> SettleSettings:
        """From the ``settle:`` block of config/cell.yaml (keys without the prefix); missing
        keys keep their defaults, unknown keys raise ConfigError."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(params) - names)
        if unknown:
            raise ConfigError(f'settle: unknown parameter(s) {", ".join(unknown)}')
        values = {k: (v if k == 'min_samples' or isinstance(v, bool) else _number(v))
                  for k, v in params.items()}
        return cls(**values)

    def to_params(self) -> dict[str, Any]:
        """The ``settle:`` block (inverse of :meth:`from_params`)."""
        return asdict(self)


def _number(value: Any) -> Any:
    return float(value) if isinstance(value, (int, float)) else value


@dataclass(frozen=True)
class Tolerances:
    """Tolerances of a settled pose: ``position`` (m) on |p − p_cmd| and ``orientation``
    (rad) on the rotation angle of R_cmdᵀ·R. Defaults 0.05 mm and 0.01°."""

    position: float = POSITION_TOLERANCE
    orientation: float = ORIENTATION_TOLERANCE

    def __post_init__(self) -> None:
        _positive('tolerance', 'position', self.position)
        _positive('tolerance', 'orientation', self.orientation)


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


def orientation_angles(quaternion: ArrayLike) -> FloatArray:
    """ISO 9283 orientation angles a, b, c (N, 3) rad of unit quaternions (N, 4): roll, pitch,
    yaw about the fixed base axes x, y, z (R = Rz(c)·Ry(b)·Rx(a)); a, c in [−π, π],
    b in [−π/2, π/2]. Near b = ±π/2 (gimbal lock) a and c are not separable."""
    q = as_unit_quaternions(quaternion)
    return np.asarray(Rotation.from_quat(q).as_euler(EULER_SEQUENCE))


def wrap_angle(angle: ArrayLike) -> FloatArray:
    """Angles wrapped into [−π, π) rad."""
    return np.asarray((np.asarray(angle, dtype=float) + math.pi) % (2.0 * math.pi) - math.pi)


# -- ISO 9283 --------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseFigures:
    """ISO 9283:1998 pose accuracy (§7.2.1) and repeatability (§7.2.2) of one commanded pose
    from its n attained poses. SI: m and rad; angles a, b, c per :data:`EULER_SEQUENCE`.

    ``barycentre`` (x̄, ȳ, z̄); AP_x = x̄ − x_c, AP_y, AP_z; AP_p = √(AP_x² + AP_y² + AP_z²);
    AP_a = ā − a_c, AP_b, AP_c with each a_j taken as a_c + wrap(a_j − a_c) (no jump at ±π).
    l_j = |P_j − barycentre|, l̄ their mean, S_l = √(Σ(l_j − l̄)²/(n−1)), RP_l = l̄ + 3·S_l;
    S_a = √(Σ(a_j − ā)²/(n−1)), RP_a = ±3·S_a (the half-width is stored), RP_b, RP_c.
    The S and RP terms are None when n < 2.
    """

    key: int
    n: int
    commanded_position: Triple
    commanded_quaternion: Quad
    commanded_angles: Triple
    barycentre: Triple
    ap_x: float
    ap_y: float
    ap_z: float
    ap_p: float
    ap_a: float
    ap_b: float
    ap_c: float
    l_mean: float
    s_l: float | None
    rp_l: float | None
    s_a: float | None
    s_b: float | None
    s_c: float | None
    rp_a: float | None
    rp_b: float | None
    rp_c: float | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples as lists; None for undefined terms)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    def for_people(self) -> dict[str, str]:
        """The figures formatted for people: µm and degrees ('n/a' where undefined)."""
        def um(v: float | None) -> str:
            return 'n/a' if v is None else f'{v * 1e6:.1f}'

        def deg(v: float | None) -> str:
            return 'n/a' if v is None else f'{math.degrees(v):.4f}'

        return {'n': str(self.n), 'AP_p_um': um(self.ap_p), 'RP_l_um': um(self.rp_l),
                'AP_a_deg': deg(self.ap_a), 'AP_b_deg': deg(self.ap_b),
                'AP_c_deg': deg(self.ap_c), 'RP_a_deg': deg(self.rp_a),
                'RP_b_deg': deg(self.rp_b), 'RP_c_deg': deg(self.rp_c)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PoseFigures:
        """Inverse of :meth:`to_dict`; missing or unknown keys raise InputError."""
        names = [f.name for f in fields(cls)]
        if set(data) != set(names):
            raise InputError(f'PoseFigures: expected keys {names}, got {sorted(data)}')
        values: dict[str, Any] = {
            k: (tuple(float(x) for x in v) if isinstance(v, list) else v)
            for k, v in data.items()}
        return cls(**values)


def iso9283(commanded_position: ArrayLike, commanded_quaternion: ArrayLike,
            attained_position: ArrayLike, attained_quaternion: ArrayLike,
            key: int = 0) -> PoseFigures:
    """ISO 9283:1998 §7.2.1 (AP) and §7.2.2 (RP) of one commanded pose (3,), (4,) from its n
    attained poses (n, 3) m, (n, 4), in visit order. See :class:`PoseFigures` for the formulas."""
    pc, qc = as_pose_batch(commanded_position, commanded_quaternion)
    if pc.shape[0] != 1:
        raise InputError(f'iso9283 takes one commanded pose, got {pc.shape[0]}')
    pa, qa = as_pose_batch(attained_position, attained_quaternion)
    n = pa.shape[0]
    barycentre = pa.mean(axis=0)
    ap = barycentre - pc[0]
    l_j = np.sqrt(((pa - barycentre) ** 2).sum(axis=1))
    angles_c = orientation_angles(qc)[0]
    deviation = wrap_angle(orientation_angles(qa) - angles_c)
    ap_abc = deviation.mean(axis=0)
    s_l: float | None = None
    s_abc: list[float | None] = [None, None, None]
    rp_abc: list[float | None] = [None, None, None]
    if n >= 2:
        s_l = float(l_j.std(ddof=1))
        s = deviation.std(axis=0, ddof=1)
        s_abc = [float(v) for v in s]
        rp_abc = [3.0 * float(v) for v in s]
    return PoseFigures(
        key=int(key), n=n, commanded_position=_triple(pc[0]),
        commanded_quaternion=_quad(qc[0]), commanded_angles=_triple(angles_c),
        barycentre=_triple(barycentre), ap_x=float(ap[0]), ap_y=float(ap[1]),
        ap_z=float(ap[2]), ap_p=float(np.sqrt((ap ** 2).sum())), ap_a=float(ap_abc[0]),
        ap_b=float(ap_abc[1]), ap_c=float(ap_abc[2]), l_mean=float(l_j.mean()), s_l=s_l,
        rp_l=None if s_l is None else float(l_j.mean()) + 3.0 * s_l,
        s_a=s_abc[0], s_b=s_abc[1], s_c=s_abc[2], rp_a=rp_abc[0], rp_b=rp_abc[1],
        rp_c=rp_abc[2])


def _triple(v: ArrayLike) -> Triple:
    a = np.asarray(v, dtype=float)
    return (float(a[0]), float(a[1]), float(a[2]))


def _quad(v: ArrayLike) -> Quad:
    a = np.asarray(v, dtype=float)
    return (float(a[0]), float(a[1]), float(a[2]), float(a[3]))


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


def _norms(d: FloatArray) -> FloatArray:
    """Row norms of (M, 3); one expression for the batch and the streaming paths."""
    return np.asarray(np.sqrt((d * d).sum(axis=1)))


def _window_spreads(values: FloatArray, starts: IntArray, ends: IntArray) -> FloatArray:
    """Bounding-box diagonals (M,) of the windows values[starts[m]:ends[m] + 1] of (N, 3)."""
    padded = np.vstack([values, values[-1:]])
    index = np.empty(2 * starts.size, dtype=np.intp)
    index[0::2] = starts
    index[1::2] = ends + 1
    high = np.maximum.reduceat(padded, index, axis=0)[0::2]
    low = np.minimum.reduceat(padded, index, axis=0)[0::2]
    return _norms(high - low)


def _window_pose(position: FloatArray, quaternion: FloatArray) -> tuple[Triple, Quad]:
    """Attained pose of a settle window: mean position and chordal L2 mean rotation."""
    p = np.ascontiguousarray(position).mean(axis=0)
    q = Rotation.from_quat(np.ascontiguousarray(quaternion)).mean().as_quat(canonical=True)
    return _triple(p), _quad(q)


def _times(value: ArrayLike, name: str) -> FloatArray:
    t = as_vectors(np.reshape(np.asarray(value, dtype=float), (-1, 1)), 1, name)[:, 0]
    if t.size > 1 and (np.diff(t) < 0.0).any():
        i = int(np.flatnonzero(np.diff(t) < 0.0)[0]) + 1
        raise InputError(f'{name}[{i}] = {t[i]!r} is earlier than {name}[{i - 1}] = '
                         f'{t[i - 1]!r}: times must be non-decreasing')
    return t


def _time(value: float, name: str) -> float:
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
    t = _times(times, 'times')
    p, q = as_pose_batch(position, quaternion)
    tt = _times(target_times, 'target_times')
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
                 commanded_position=_triple(target_position),
                 commanded_quaternion=_quad(target_quaternion), position=position,
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


# -- verdicts --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Verdict:
    """A settled pose against the tolerances: errors and tolerances in m and rad. A value
    equal to its tolerance passes."""

    position_error: float
    orientation_error: float
    tolerances: Tolerances

    @property
    def position_ok(self) -> bool:
        """|Δp| <= position tolerance."""
        return self.position_error <= self.tolerances.position

    @property
    def orientation_ok(self) -> bool:
        """Rotation angle <= orientation tolerance."""
        return self.orientation_error <= self.tolerances.orientation

    @property
    def ok(self) -> bool:
        """Both within tolerance."""
        return self.position_ok and self.orientation_ok

    def message(self) -> str:
        """For people: µm and degrees."""
        return (f'position error {self.position_error * 1e6:.1f} µm (tolerance '
                f'{self.tolerances.position * 1e6:.1f} µm), orientation error '
                f'{math.degrees(self.orientation_error):.4f}° (tolerance '
                f'{math.degrees(self.tolerances.orientation):.4f}°): '
                f'{"OK" if self.ok else "OUT OF TOLERANCE"}')


def judge(position_error: float, orientation_error: float,
          tolerances: Tolerances | None = None) -> Verdict:
    """Verdict of a pose error: ``position_error`` |Δp| (m), ``orientation_error`` the
    rotation angle (rad), both finite and >= 0."""
    for name, value in (('position_error', position_error),
                        ('orientation_error', orientation_error)):
        if not (math.isfinite(value) and value >= 0.0):
            raise InputError(f'{name} = {value!r}: must be a finite number >= 0')
    return Verdict(float(position_error), float(orientation_error), tolerances or Tolerances())


def judge_visit(visit: Visit, tolerances: Tolerances | None = None) -> Verdict:
    """Verdict of a settled visit: its attained pose against its commanded pose."""
    dp, rv = visit.error()
    return judge(float(np.sqrt((dp ** 2).sum())), float(np.sqrt((rv ** 2).sum())), tolerances)


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
        t = _time(time, 'target time')
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
        t = _time(time, 'sample time')
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
        spreads = _norms(np.array([wp.max(axis=0) - wp.min(axis=0),
                                   wr.max(axis=0) - wr.min(axis=0)]))
        if spreads[0] > s.position_threshold or spreads[1] > s.angle_threshold:
            return update
        self._settled = True
        self._cycles[key] = self._cycles.get(key, 0) + 1
        visit = _visit(key, self._cycles[key], seg_t, seg_p, seg_q,
                       np.array([w[0] for w in window]), wp, np.array([w[2] for w in window]))
        self._visits.append(visit)
        return SampleUpdate(dp[0], rv[0], visit)


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
    d, a = _norms(dp), _norms(rv)
    return ErrorStatistics(samples=int(dp.shape[0]), mean_position_error=_triple(dp.mean(axis=0)),
                           rms_position_error=float(np.sqrt((d * d).mean())),
                           max_position_error=float(d.max()),
                           rms_orientation_error=float(np.sqrt((a * a).mean())),
                           max_orientation_error=float(a.max()))


def pair_by_stamp(times_a: ArrayLike, times_b: ArrayLike,
                  tolerance: float) -> tuple[IntArray, IntArray]:
    """Indices (ia, ib) pairing each time of ``times_a`` with the nearest of ``times_b``
    within ``tolerance`` s (both non-decreasing); each b is used once, by the first a."""
    ta, tb = _times(times_a, 'times_a'), _times(times_b, 'times_b')
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
        _positive('truth', 'max_stamp_difference', tolerance)
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
        t = _time(time, 'time')
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
