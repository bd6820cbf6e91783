"""Live axis ranges: for each of the six pose6 components of the user position (Tx, Ty, Tz m;
Rx, Ry, Rz rad, R = Rz·Ry·Rx, the user CS of :mod:`positioning_cell.frames.systems`), the
interval reachable from a pose with the other five held, and the constraint that binds at each
end (issue 26, item 6). Pure library, no ROS.

The interval is the connected one containing the pose's own value on which every margin of a
check stays valid (>= 0): the factory layer (:func:`positioning_cell.core.limits.limit_values`:
stroke, phi, theta, spherical tilt, leg distance, conditioning), the machine box (machine
pose6) and the user box (user pose6, the canonical angles of the rotation, as the positioner
checks them). The search goes at most ``spans[k]`` from the pose along axis k: where nothing
binds before, the end is there and its binding is :data:`SPAN_LIMIT`.

Method: along each of the 12 directions (axis, sign) the margins are evaluated at
:data:`COARSE_STEPS` equal steps of the span until the first invalid one, then the crossing is
bracketed to :data:`TOLERANCE` (m or rad; 0.1 µm, 0.1 µrad) by false position on the worst
margin (Illinois), a bisection every third step. Each end is the last valid value found: valid
itself, the true boundary at most :data:`TOLERANCE` beyond it. An invalid sliver narrower than
one coarse step (span / 64) between two valid steps is not seen: the margins are smooth on
that scale for this mechanism (the tests compare with a scan 60 times finer). All twelve
bounds run in one compiled kernel (:mod:`positioning_cell.core.compiled`; ~1 ms on one core,
benchmarks/axis_ranges.py): a node that calls it warms it while it is built
(:func:`warm_up`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.compiled import kernel, kernel_array
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.limits.boxes import AXES, LINEAR, LimitLayers, as_pose6, pose6_text
from positioning_cell.limits.validity import CONSTRAINT_BITS
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Coarse steps of each direction's span before the first crossing is bracketed.
COARSE_STEPS = 64
#: Width (m for Tx..Tz, rad for Rx..Rz) of the bracket of a crossing at the end.
TOLERANCE = 1e-7
#: The binding of an end where no limit binds within the span.
SPAN_LIMIT = 'span limit'
#: The constraint names, in the kernel's order: the factory layer's
#: (:data:`positioning_cell.limits.validity.CONSTRAINT_BITS`), then the machine box's and the
#: user box's lower and upper bound of each pose6 component ('machine.Tx_min', ...).
CONSTRAINTS: tuple[str, ...] = (
    tuple(f'factory.{name}' for name in CONSTRAINT_BITS)
    + tuple(f'{layer}.{axis}_{end}' for layer in ('machine', 'user') for axis in AXES
            for end in ('min', 'max')))
_N_CONSTRAINTS = len(CONSTRAINTS)
#: The kernel's binding index of :data:`SPAN_LIMIT`.
_SPAN = _N_CONSTRAINTS
#: Default spans: 0.1 m along Tx, Ty, Tz, 1 rad about Rx, Ry, Rz (beyond the factory box).
DEFAULT_SPANS = (0.1,) * LINEAR + (1.0,) * LINEAR


@dataclass(frozen=True)
class AxisRangeSettings:
    """The live axis ranges of the positioner (``operator.axis_ranges``): how far the search
    goes along each axis, and how often they are published."""

    spans: tuple[float, ...] = setting(
        DEFAULT_SPANS, 'farthest an axis range reaches from the pose on each side, Tx, Ty, Tz '
        '(m), Rx, Ry, Rz (rad): the end is "span limit" there', 'm, rad', low=0.0,
        low_open=True, high=math.pi, length=6)
    rate_hz: float = setting(4.0, 'rate of /positioner/axis_ranges', 'Hz', low=0.1, high=20.0)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class AxisRange:
    """The range of one pose6 component ``axis`` ('Tx' ... 'Rz'): ``low`` .. ``high`` (m or
    rad, user CS) reachable from the pose with the other five held, and the constraint that
    binds at each end (a name of :data:`CONSTRAINTS`, or :data:`SPAN_LIMIT`)."""

    axis: str
    low: float
    high: float
    low_binding: str
    high_binding: str


@dataclass(frozen=True)
class AxisRanges:
    """The axis ranges of one user pose6 ``pose`` (6,) m, rad: six :class:`AxisRange`, Tx
    first; none, with the ``reason``, when the pose itself is not valid (or not known);
    ``pending`` when there are none yet because the search is still starting (ask again)."""

    pose: tuple[float, ...]
    ranges: tuple[AxisRange, ...] = ()
    reason: str = ''
    pending: bool = False

    @property
    def valid(self) -> bool:
        """True when the ranges are given."""
        return bool(self.ranges)

    @classmethod
    def unknown(cls, reason: str, pending: bool = False) -> AxisRanges:
        """No ranges, and why (no pose to start from...); ``pending``: not yet."""
        return cls((math.nan,) * 6, (), reason, pending)

    def document(self) -> dict[str, object]:
        """For JSON, SI (m, rad): valid, reason, the pose and per axis its range and
        bindings."""
        return {'valid': self.valid, 'pending': self.pending, 'reason': self.reason,
                'pose': list(self.pose),
                'ranges': [dataclasses.asdict(r) for r in self.ranges]}

    def lines(self) -> list[str]:
        """For people, mm and deg: one line per axis (its range and what binds at each end),
        or why there are none."""
        if not self.valid:
            return [f'none: {self.reason or "not given"}']
        return [f'{r.axis}  {pose6_text(k, r.low):>12} .. {pose6_text(k, r.high):>12}  '
                f'(low: {r.low_binding}; high: {r.high_binding})'
                for k, r in enumerate(self.ranges)]


@dataclass(frozen=True)
class RangeModel:
    """What the search needs, as contiguous arrays: the mechanism's geometry and limits, the
    limit boxes and the user and object CS (:meth:`of`)."""

    geometry: FloatArray  # (6, 3, 3): A_i, b_i, e_r,i, e_t,i, R_user, R_object
    vectors: FloatArray  # (3, 3): p_home, p_user, p_object (m)
    limits: FloatArray  # (10,): the factory limits and R_B (m)
    boxes: FloatArray  # (4, 6): machine lower, upper, user lower, upper
    spans: FloatArray  # (6,)

    @classmethod
    def of(cls, mech: Mechanism, layers: LimitLayers, systems: CoordinateSystems,
           spans: ArrayLike = DEFAULT_SPANS) -> RangeModel:
        """The model of ``mech`` within ``layers`` in the user and object CS of ``systems``,
        searching ``spans`` (6,) m, rad from a pose (InputError: not 6 numbers > 0)."""
        span = as_pose6(spans, 'spans')[0]
        if not np.all(span > 0.0):
            raise InputError(f'spans = {span.tolist()}: every span must be > 0 (m, rad)')
        user, obj = systems.user, systems.object
        geometry = np.stack([mech.base_joints, mech.platform_joints, mech.radial,
                             mech.tangential, user.R, obj.R])
        vectors = np.stack([mech.home_position, user.p, obj.p])
        limits = np.array([mech.length_min, mech.length_max, mech.phi_min, mech.phi_max,
                           mech.theta_min, mech.theta_max, mech.tilt_max,
                           mech.min_leg_distance, mech.min_conditioning,
                           mech.characteristic_length])
        boxes = np.stack([layers.machine_box.low, layers.machine_box.high,
                          layers.user_box.low, layers.user_box.high])
        return cls(*(kernel_array(a) for a in (geometry, vectors, limits, boxes, span)))

    @staticmethod
    def cached(mech: Mechanism, layers: LimitLayers, systems: CoordinateSystems,
               spans: tuple[float, ...] = DEFAULT_SPANS) -> RangeModel:
        """:meth:`of`, kept for the same arguments (the positioner's limits and coordinate
        systems change seldom; building the model is ~0.1 ms, a tenth of a search)."""
        return _cached_model(mech, layers, systems, tuple(float(v) for v in spans))

    def margins(self, user_pose6: ArrayLike) -> FloatArray:
        """The signed margins (N, :data:`CONSTRAINTS`) SI of user pose6 rows (N, 6): positive
        inside by that much, negative (-inf: no pose) violated. The kernel's own evaluation,
        for tests and diagnosis."""
        poses = kernel_array(as_pose6(user_pose6, 'user pose6'))
        out = np.empty((poses.shape[0], _N_CONSTRAINTS))
        _margins_kernel(poses, *self._arrays(), out)
        return out

    def _arrays(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        return self.geometry, self.vectors, self.limits, self.boxes

    def ranges(self, user_pose6: ArrayLike) -> AxisRanges:
        """The axis ranges of one user pose6 (6,) m, rad (module docstring), searched in this
        process. A pose that is not valid gives no ranges and the constraints it violates;
        InputError only for a pose that is not 6 finite numbers."""
        start = start_pose(user_pose6)
        return assemble(start, *search(self.fields(), start))

    def fields(self) -> tuple[FloatArray, ...]:
        """The model as its arrays, in field order (what a range worker is sent)."""
        return (self.geometry, self.vectors, self.limits, self.boxes, self.spans)


def start_pose(user_pose6: ArrayLike) -> FloatArray:
    """One user pose6 (6,) m, rad as the search takes it (InputError: not one pose of 6 finite
    numbers)."""
    pose = as_pose6(user_pose6, 'user pose6')
    if pose.shape[0] != 1:
        raise InputError(f'user pose6: one pose expected, got {pose.shape[0]}')
    start: FloatArray = kernel_array(pose[0])
    return start


def search(fields: tuple[FloatArray, ...], start: FloatArray
           ) -> tuple[FloatArray, IntArray, FloatArray]:
    """The compiled search of the model ``fields`` (:meth:`RangeModel.fields`) from ``start``
    (:func:`start_pose`): the bounds (6, 2), their bindings' indices (6, 2) and ``start``'s
    own margins (constraints,)."""
    geometry, vectors, limits, boxes, spans = (kernel_array(a) for a in fields)
    bounds = np.empty((6, 2))
    binding = np.empty((6, 2), dtype=np.int64)
    margins = np.empty(_N_CONSTRAINTS)
    _ranges_kernel(start, spans, float(COARSE_STEPS), TOLERANCE, geometry, vectors, limits,
                   boxes, bounds, binding, margins)
    return bounds, binding, margins


def assemble(start: FloatArray, bounds: FloatArray, binding: IntArray,
             margins: FloatArray) -> AxisRanges:
    """The AxisRanges of a :func:`search` from ``start``: none, naming the constraints it
    violates, when ``start`` itself is not valid."""
    values = tuple(float(v) for v in start)
    if not np.all(margins >= 0.0):
        bad = [f'{CONSTRAINTS[i]} {margins[i]:.6g}' for i in np.flatnonzero(~(margins >= 0.0))]
        return AxisRanges(values, (), 'the pose itself is not valid: ' + ', '.join(bad))
    names = (*CONSTRAINTS, SPAN_LIMIT)
    return AxisRanges(values, tuple(
        AxisRange(AXES[k], float(bounds[k, 0]), float(bounds[k, 1]),
                  names[binding[k, 0]], names[binding[k, 1]]) for k in range(6)))


def warm_up() -> None:
    """Load numba and these kernels (and forward kinematics', which then runs compiled in this
    process) from the disk cache, or compile them: a node that publishes axis ranges calls
    this while it is built (:mod:`positioning_cell.core.compiled`)."""
    from positioning_cell.core import kinematics

    kinematics.warm_up()
    mech = Mechanism.default()
    model = RangeModel.of(mech, LimitLayers.for_mechanism(mech), CoordinateSystems())
    model.ranges(np.zeros(6))
    model.margins(np.zeros((1, 6)))


@functools.lru_cache(maxsize=8)
def _cached_model(mech: Mechanism, layers: LimitLayers, systems: CoordinateSystems,
                  spans: tuple[float, ...]) -> RangeModel:
    return RangeModel.of(mech, layers, systems, spans)


# -- kernels --------------------------------------------------------------------------------------
@kernel
def _euler_into(rot: FloatArray, out: FloatArray, at: int) -> None:
    """Rx, Ry, Rz (R = Rz·Ry·Rx, Ry in [-π/2, π/2]) of ``rot`` (3, 3) into ``out[at:at + 3]``."""
    out[at] = np.arctan2(rot[2, 1], rot[2, 2])
    out[at + 1] = np.arcsin(min(1.0, max(-1.0, -rot[2, 0])))
    out[at + 2] = np.arctan2(rot[1, 0], rot[0, 0])


@kernel
def _pose_margins(pose: FloatArray, geometry: FloatArray, vectors: FloatArray,
                  limits: FloatArray, boxes: FloatArray, out: FloatArray,
                  work: FloatArray) -> None:
    """The signed margins of :data:`CONSTRAINTS` (SI; non-finite: -inf) of one user pose6
    ``pose`` (6,) into ``out``: the same values as
    :func:`positioning_cell.core.limits.limit_values` (min over legs and pairs) and
    :meth:`positioning_cell.limits.boxes.BoxLimits.margins`. ``work`` (10, 6, 6): scratch."""
    base, body, radial, tangential = geometry[0], geometry[1], geometry[2], geometry[3]
    r_user, r_object = geometry[4], geometry[5]
    rg, rgo, rot = work[0, :3, :3], work[1, :3, :3], work[2, :3, :3]
    points, d, u = work[3, :3, :3], work[4, :3, :3], work[5, :3, :3]
    legs = work[6, :4, :3]  # lengths, thetas, phis, tilts (3 legs each)
    machine, user, p = work[7, 0], work[7, 1], work[7, 2, :3]
    # G = (t, Rz·Ry·Rx) in the user CS; the platform in the machine CS is
    # T_user · G · T_object⁻¹ (positioning_cell.frames.systems).
    cx, sx = np.cos(pose[3]), np.sin(pose[3])
    cy, sy = np.cos(pose[4]), np.sin(pose[4])
    cz, sz = np.cos(pose[5]), np.sin(pose[5])
    rg[0, 0], rg[0, 1], rg[0, 2] = cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx
    rg[1, 0], rg[1, 1], rg[1, 2] = sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx
    rg[2, 0], rg[2, 1], rg[2, 2] = -sy, cy * sx, cy * cx
    for i in range(3):  # Rg · R_objectᵀ
        for j in range(3):
            rgo[i, j] = (rg[i, 0] * r_object[j, 0] + rg[i, 1] * r_object[j, 1]
                         + rg[i, 2] * r_object[j, 2])
    for i in range(3):  # R_user · Rg · R_objectᵀ
        for j in range(3):
            rot[i, j] = (r_user[i, 0] * rgo[0, j] + r_user[i, 1] * rgo[1, j]
                         + r_user[i, 2] * rgo[2, j])
    for i in range(3):  # t − Rg · R_objectᵀ · p_object, then R_user · that + p_user
        d[0, i] = pose[i] - (rgo[i, 0] * vectors[2, 0] + rgo[i, 1] * vectors[2, 1]
                             + rgo[i, 2] * vectors[2, 2])
    for i in range(3):
        machine[i] = (r_user[i, 0] * d[0, 0] + r_user[i, 1] * d[0, 1]
                      + r_user[i, 2] * d[0, 2] + vectors[1, i])
        p[i] = machine[i] + vectors[0, i]
        user[i] = pose[i]
    _euler_into(rot, machine, 3)
    _euler_into(rg, user, 3)
    # the factory layer (core.limits.limit_values)
    for k in range(3):
        for i in range(3):
            points[k, i] = (p[i] + rot[i, 0] * body[k, 0] + rot[i, 1] * body[k, 1]
                            + rot[i, 2] * body[k, 2])
            d[k, i] = points[k, i] - base[k, i]
        length = np.sqrt(d[k, 0] * d[k, 0] + d[k, 1] * d[k, 1] + d[k, 2] * d[k, 2])
        for i in range(3):
            u[k, i] = d[k, i] / length
        ut = u[k, 0] * tangential[k, 0] + u[k, 1] * tangential[k, 1] + u[k, 2] * tangential[k, 2]
        ur = u[k, 0] * radial[k, 0] + u[k, 1] * radial[k, 1] + u[k, 2] * radial[k, 2]
        un = u[k, 0] * rot[0, 2] + u[k, 1] * rot[1, 2] + u[k, 2] * rot[2, 2]
        legs[0, k] = length
        legs[1, k] = np.arcsin(min(1.0, max(-1.0, ut)))
        legs[2, k] = np.arctan2(ur, u[k, 2])
        legs[3, k] = np.arccos(min(1.0, max(-1.0, un)))
    gap = np.inf
    for i in range(3):  # the pairs (i, i + 1) of core.kinematics.PAIRS_I, PAIRS_J
        gap = min(gap, _segment_distance(base, points, i, (i + 1) % 3))
    out[0] = legs[0].min() - limits[0]
    out[1] = limits[1] - legs[0].max()
    out[2] = legs[2].min() - limits[2]
    out[3] = limits[3] - legs[2].max()
    out[4] = legs[1].min() - limits[4]
    out[5] = limits[5] - legs[1].max()
    out[6] = limits[6] - legs[3].max()
    out[7] = gap - limits[7]
    out[8] = _conditioning(p, points, u, legs[0], tangential, limits[9], work[8],
                           work[9]) - limits[8]
    for k in range(6):
        out[9 + 2 * k] = machine[k] - boxes[0, k]
        out[10 + 2 * k] = boxes[1, k] - machine[k]
        out[21 + 2 * k] = user[k] - boxes[2, k]
        out[22 + 2 * k] = boxes[3, k] - user[k]
    for c in range(out.shape[0]):
        if not np.isfinite(out[c]) and not (c >= 9 and out[c] == np.inf):
            out[c] = -np.inf  # no pose (a box without a bound stays +inf)


@kernel
def _segment_distance(base: FloatArray, points: FloatArray, i: int, j: int) -> float:
    """Shortest distance (m) between the legs A_i–B_i and A_j–B_j (``base``, ``points`` (3, 3)
    m) as segments (:func:`positioning_cell.core.limits.segment_distance`, one pair)."""
    a = b = c = e = f = 0.0
    for x in range(3):
        d1 = points[i, x] - base[i, x]
        d2 = points[j, x] - base[j, x]
        r = base[i, x] - base[j, x]
        a += d1 * d1
        e += d2 * d2
        b += d1 * d2
        c += d1 * r
        f += d2 * r
    denom = a * e - b * b
    s = min(1.0, max(0.0, (b * f - c * e) / denom)) if denom > 1e-18 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        s = min(1.0, max(0.0, -c / a))
    elif t > 1.0:
        s = min(1.0, max(0.0, (b - c) / a))
    t = min(1.0, max(0.0, (b * s + f) / e))
    total = 0.0
    for x in range(3):
        g = (base[i, x] + (points[i, x] - base[i, x]) * s
             - (base[j, x] + (points[j, x] - base[j, x]) * t))
        total += g * g
    return float(np.sqrt(total))


@kernel
def _conditioning(p: FloatArray, points: FloatArray, u: FloatArray, lengths: FloatArray,
                  tangential: FloatArray, scale: float, jac: FloatArray,
                  gram: FloatArray) -> float:
    """Reciprocal condition number of the inverse Jacobian of one pose, rotations scaled by
    ``scale`` = R_B (:func:`positioning_cell.core.kinematics.conditioning`): √(λmin/λmax) of
    JᵀJ; -inf where it is not finite. ``jac``, ``gram`` (6, 6): scratch."""
    for k in range(3):
        r0, r1, r2 = points[k, 0] - p[0], points[k, 1] - p[1], points[k, 2] - p[2]
        u0, u1, u2 = u[k, 0], u[k, 1], u[k, 2]
        ut = u0 * tangential[k, 0] + u1 * tangential[k, 1] + u2 * tangential[k, 2]
        den = lengths[k] * np.sqrt(max(1.0 - ut * ut, 0.0))
        w0 = (tangential[k, 0] - ut * u0) / den
        w1 = (tangential[k, 1] - ut * u1) / den
        w2 = (tangential[k, 2] - ut * u2) / den
        jac[k, 0], jac[k, 1], jac[k, 2] = u0, u1, u2
        jac[k, 3] = (r1 * u2 - r2 * u1) / scale
        jac[k, 4] = (r2 * u0 - r0 * u2) / scale
        jac[k, 5] = (r0 * u1 - r1 * u0) / scale
        jac[3 + k, 0], jac[3 + k, 1], jac[3 + k, 2] = w0 * scale, w1 * scale, w2 * scale
        jac[3 + k, 3] = r1 * w2 - r2 * w1
        jac[3 + k, 4] = r2 * w0 - r0 * w2
        jac[3 + k, 5] = r0 * w1 - r1 * w0
    for i in range(6):
        for j in range(i, 6):
            total = 0.0
            for k in range(6):
                total += jac[k, i] * jac[k, j]
            if not np.isfinite(total):
                return -np.inf
            gram[i, j] = total
            gram[j, i] = total
    eig = np.linalg.eigvalsh(gram)
    if not eig[-1] > 0.0:
        return -np.inf
    return float(np.sqrt(max(eig[0], 0.0) / eig[-1]))


@kernel
def _worst(margins: FloatArray) -> int:
    """The index of the smallest margin (the first on a tie)."""
    worst = 0
    for c in range(margins.shape[0]):
        if margins[c] < margins[worst]:
            worst = c
    return worst


@kernel
def _margins_kernel(poses: FloatArray, geometry: FloatArray, vectors: FloatArray,
                    limits: FloatArray, boxes: FloatArray, out: FloatArray) -> None:
    """:func:`_pose_margins` of N user pose6 rows (N, 6) into ``out`` (N, constraints)."""
    work = np.empty((10, 6, 6))
    for s in range(poses.shape[0]):
        _pose_margins(poses[s], geometry, vectors, limits, boxes, out[s], work)


@kernel
def _ranges_kernel(start: FloatArray, spans: FloatArray, steps: float, tolerance: float,
                   geometry: FloatArray, vectors: FloatArray, limits: FloatArray,
                   boxes: FloatArray, bounds: FloatArray, binding: IntArray,
                   start_margins: FloatArray) -> None:
    """The twelve bounds of the user pose6 ``start`` (6,) (module docstring) into ``bounds``
    (6, 2) (low, high) and the index of their binding constraint into ``binding`` (6, 2)
    (:data:`_SPAN` where none binds within ``spans``); ``start``'s own margins into
    ``start_margins``. Nothing is searched when ``start`` is not valid."""
    m = np.empty(start_margins.shape[0])
    work = np.empty((10, 6, 6))
    _pose_margins(start, geometry, vectors, limits, boxes, start_margins, work)
    for c in range(m.shape[0]):
        if not start_margins[c] >= 0.0:
            return
    pose = start.copy()
    n_steps = int(steps)
    for k in range(6):
        step = spans[k] / steps
        for side in range(2):
            sign = -1.0 if side == 0 else 1.0
            good, bad, bound_by = 0.0, -1.0, _SPAN
            m_good = start_margins[_worst(start_margins)]
            for i in range(1, n_steps + 1):
                off = i * step if i < n_steps else spans[k]
                pose[k] = start[k] + sign * off
                _pose_margins(pose, geometry, vectors, limits, boxes, m, work)
                c = _worst(m)
                if not m[c] >= 0.0:
                    bad, bound_by = off, c
                    break
                good, m_good = off, m[c]
            if bad >= 0.0:
                # Bracketed false position on the worst margin (Illinois: the end kept twice
                # has its margin halved), every third step a bisection: the bracket at least
                # halves every three evaluations, and shrinks superlinearly near a smooth
                # crossing.
                f_good, f_bad = m_good, m[bound_by]
                kept = 0
                for it in range(200):
                    width = bad - good
                    if width <= tolerance:
                        break
                    if it % 3 == 2 or not (np.isfinite(f_good) and np.isfinite(f_bad)):
                        mid = good + 0.5 * width
                    else:
                        mid = good + width * f_good / (f_good - f_bad)
                        mid = min(max(mid, good + 0.25 * tolerance), bad - 0.25 * tolerance)
                    pose[k] = start[k] + sign * mid
                    _pose_margins(pose, geometry, vectors, limits, boxes, m, work)
                    c = _worst(m)
                    if m[c] >= 0.0:
                        good, f_good = mid, m[c]
                        kept = kept + 1 if kept > 0 else 1
                        if kept >= 2:
                            f_bad *= 0.5
                    else:
                        bad, f_bad, bound_by = mid, m[c], c
                        kept = kept - 1 if kept < 0 else -1
                        if kept <= -2:
                            f_good *= 0.5
            bounds[k, side] = start[k] + sign * good
            binding[k, side] = bound_by
            pose[k] = start[k]

