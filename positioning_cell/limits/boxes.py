"""Limit boxes in pose6 and the three layers of them (Symétrie's factory, machine and user
limits).

A box bounds each pose6 component (Tx, Ty, Tz m; Rx, Ry, Rz rad, R = Rz·Ry·Rx) between a lower
and an upper bound. The layers, each inside the one before:

- the **factory box** (machine CS), a read-only configuration (:class:`FactoryBoxSettings`;
  by default derived from the mechanism, :func:`derived_factory_box`); always finite;
- the **machine box** (machine CS), set by the operator within the factory box (default: the
  factory box itself); being inside a finite box, it is finite too;
- the **user box** (user CS), set by the operator so that its 64 vertices, mapped into the
  machine CS by the caller, lie within the machine box; either finite on every bound, or
  unlimited on every bound (±inf: no user limit, the default).

The machine CS is that of :mod:`positioning_cell.frames` (not imported here): origin at the
platform's home pose, axes parallel to ``base``, the machine pose of a platform pose (p, R) in
``base`` being (p − p_home, R): zero at home. A pose inside the boxes is not therefore
reachable: the mechanism's own limits (:mod:`positioning_cell.core.limits`) apply as well. Rotation
components are compared wrapped into [-π, π]. Containment of a user box is judged at its
vertices (the controller's rule): exact for a user CS that is a translation of the machine CS,
an approximation of the rotations otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.limits import MAX_LISTED, within_limits
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_vectors, quaternion_from_euler_xyz
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.limits.validity import VALID, CheckResult, Validity
from positioning_cell.parameters import ParameterError, check_fields, setting

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: The pose6 components, in order.
AXES = ('Tx', 'Ty', 'Tz', 'Rx', 'Ry', 'Rz')
#: The first three components are translations (m), the last three rotations (rad).
LINEAR = 3

#: A mapping of pose6 batches (N, 6) from the user CS to the machine CS.
PoseMap = Callable[[FloatArray], ArrayLike]


def as_pose6(value: ArrayLike, name: str = 'pose6') -> FloatArray:
    """``value`` as finite pose6 rows (N, 6) (a single (6,) row: N = 1); InputError otherwise."""
    return as_vectors(value, 6, name)


def wrap_angles(pose6: FloatArray) -> FloatArray:
    """A copy of pose6 rows (N, 6) with the rotations wrapped into [-π, π] (±π kept)."""
    out = np.array(pose6, dtype=float)
    rot = out[:, LINEAR:]
    out[:, LINEAR:] = rot - 2.0 * math.pi * np.round(rot / (2.0 * math.pi))
    return out


def pose6_text(axis: int, value: float) -> str:
    """A pose6 component for people: mm or deg, three decimals."""
    if axis < LINEAR:
        return f'{value * 1e3:.3f} mm'
    return f'{math.degrees(value):.3f} deg'


def _pose6_row_text(row: FloatArray) -> str:
    return ', '.join(f'{AXES[k]} {pose6_text(k, float(row[k]))}' for k in range(6))


def _bounds(value: ArrayLike, name: str) -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise InputError(f'{name}: expected 6 numbers, got {value!r}') from err
    if arr.shape != (6,):
        raise InputError(f'{name}: expected 6 numbers (Tx, Ty, Tz, Rx, Ry, Rz), got shape '
                         f'{arr.shape}')
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class BoxLimits:
    """Bounds of pose6: ``lower`` and ``upper`` (6,) in Tx, Ty, Tz (m), Rx, Ry, Rz (rad) order.

    Each bound is a number, or -inf (lower) / +inf (upper) for no limit; lower <= upper;
    finite rotation bounds lie within [-π, π]. InputError names the axis otherwise.
    """

    lower: tuple[float, ...]
    upper: tuple[float, ...]

    def __post_init__(self) -> None:
        lower, upper = _bounds(self.lower, 'lower'), _bounds(self.upper, 'upper')
        for k, axis in enumerate(AXES):
            lo, hi = lower[k], upper[k]
            if math.isnan(lo) or math.isnan(hi):
                raise InputError(f'{axis}: bounds [{lo}, {hi}] must be numbers (NaN refused)')
            if lo == math.inf or hi == -math.inf:
                raise InputError(f'{axis}: lower bound {lo} / upper bound {hi}: only -inf as a '
                                 'lower and +inf as an upper bound mean "no limit"')
            if lo > hi:
                raise InputError(f'{axis}: lower bound {pose6_text(k, lo)} above the upper '
                                 f'bound {pose6_text(k, hi)}')
            if k >= LINEAR:
                for which, v in (('lower', lo), ('upper', hi)):
                    if math.isfinite(v) and abs(v) > math.pi:
                        raise InputError(f'{axis}: {which} bound {pose6_text(k, v)} outside '
                                         '[-180, 180] deg')
        object.__setattr__(self, 'lower', lower)
        object.__setattr__(self, 'upper', upper)

    @classmethod
    def unlimited(cls) -> BoxLimits:
        """No limit on any component."""
        return cls((-math.inf,) * 6, (math.inf,) * 6)

    @property
    def low(self) -> FloatArray:
        """The lower bounds as an array (6,)."""
        return np.array(self.lower)

    @property
    def high(self) -> FloatArray:
        """The upper bounds as an array (6,)."""
        return np.array(self.upper)

    @property
    def is_finite(self) -> bool:
        """True when every bound is finite."""
        return all(math.isfinite(v) for v in self.lower + self.upper)

    @property
    def is_unlimited(self) -> bool:
        """True when no bound is finite (no limit at all)."""
        return not any(math.isfinite(v) for v in self.lower + self.upper)

    def margins(self, pose6: ArrayLike) -> FloatArray:
        """Signed margin (N, 6) SI of each pose6 row (N, 6) and component, rotations wrapped:
        the distance to the nearer bound, positive inside, negative outside (+inf: no limit)."""
        p = wrap_angles(as_pose6(pose6))
        margin: FloatArray = np.minimum(p - self.low, self.high - p)
        return margin

    def check(self, pose6: ArrayLike,
              layer_name: str) -> tuple[BoolArray, list[str], dict[str, float]]:
        """Check pose6 rows (N, 6): per row whether it is inside (N,); one line per axis
        outside, at its worst sample, for people, naming ``layer_name`` (e.g. "machine limits:
        Tz 52.000 mm above the maximum 50.000 mm by 2.000 mm at sample 3 (the worst of 4 of 10
        samples outside)"); and per
        axis ('Tx' ... 'Rz') the smallest signed margin over the rows, SI (+inf: no limit or no
        rows)."""
        p = wrap_angles(as_pose6(pose6))
        margin = np.minimum(p - self.low, self.high - p)
        outside = margin < 0.0
        ok: BoolArray = np.asarray(~outside.any(axis=1))
        lines = []
        for k in np.flatnonzero(outside.any(axis=0)):  # per axis its worst sample
            s = int(np.argmin(margin[:, k]))
            count = int(outside[:, k].sum())
            tail = f' (the worst of {count} of {p.shape[0]} samples outside)' if count > 1 else ''
            lines.append(f'{layer_name}: {AXES[k]} {self.outside_text(int(k), float(p[s, k]))}'
                         f' at sample {s}{tail}')
        worst = margin.min(axis=0) if p.shape[0] else np.full(6, math.inf)
        return ok, lines, {axis: float(worst[k]) for k, axis in enumerate(AXES)}

    def outside_text(self, k: int, value: float, whose: str = '', where: str = '') -> str:
        """Words for ``value`` of axis ``k`` outside this box: the value (``where`` it is,
        e.g. ' in the machine CS,'), which bound (``whose``, e.g. 'machine '), by how much
        (mm, deg)."""
        above = value > self.upper[k]
        bound = self.upper[k] if above else self.lower[k]
        kind = f'above the {whose}maximum' if above else f'below the {whose}minimum'
        return (f'{pose6_text(k, value)}{where} {kind} {pose6_text(k, bound)} by '
                f'{pose6_text(k, abs(value - bound))}')

    def contains(self, other: BoxLimits) -> list[str]:
        """What of ``other`` lies outside this box, one line per bound (empty: contained)."""
        lines = []
        for k, axis in enumerate(AXES):
            if other.lower[k] < self.lower[k]:
                lines.append(f'{axis} lower bound {pose6_text(k, other.lower[k])} below the '
                             f'minimum {pose6_text(k, self.lower[k])} by '
                             f'{pose6_text(k, self.lower[k] - other.lower[k])}')
            if other.upper[k] > self.upper[k]:
                lines.append(f'{axis} upper bound {pose6_text(k, other.upper[k])} above the '
                             f'maximum {pose6_text(k, self.upper[k])} by '
                             f'{pose6_text(k, other.upper[k] - self.upper[k])}')
        return lines

    def vertices(self) -> FloatArray:
        """The 64 vertices (64, 6): vertex i takes the upper bound of axis k where bit k of i
        is set. InputError for a box that is not finite."""
        if not self.is_finite:
            raise InputError('a box with an infinite bound has no vertices')
        pick = (np.arange(64)[:, None] >> np.arange(6)[None, :]) & 1
        corners: FloatArray = np.where(pick == 1, self.high, self.low)
        return corners


# -- the factory box ------------------------------------------------------------------------------
#: Largest rotation about each axis of the derived factory box (rad).
DERIVED_ROTATION = math.radians(30.0)
#: Grid of the derived factory box: each reach is found on this many steps of its cap.
DERIVED_STEPS = 400


def base_pq_of_machine_pose6(mech: Mechanism,
                             pose6: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Platform poses in ``base`` of machine pose6 rows (N, 6): positions p_home + t (N, 3) m
    and quaternions (N, 4) x, y, z, w of R = Rz·Ry·Rx (the machine CS of the module
    docstring)."""
    return pose6[:, :LINEAR] + mech.home_position, quaternion_from_euler_xyz(pose6[:, LINEAR:])


def derived_factory_box(mech: Mechanism, rotation: float = DERIVED_ROTATION,
                        steps: int = DERIVED_STEPS) -> BoxLimits:
    """The factory box of a mechanism, machine CS (zero at home): along each pose6 component
    alone, in each direction from the home pose, the farthest the platform goes within every
    limit of the mechanism (:func:`positioning_cell.core.limits.within_limits`), up to a cap:
    Tx, Ty ±(length_max − length_min); Tz from −(home_length − length_min) to
    +(length_max − home_length); rotations ±``rotation``. Conservative: each reach is the last
    grid point (``steps`` per cap) before the first one out of limits. ConfigError when the
    home pose itself is out of limits."""
    stroke = mech.length_max - mech.length_min
    caps_up = np.array([stroke, stroke, mech.length_max - mech.home_length] + [rotation] * 3)
    caps_down = np.array([stroke, stroke, mech.home_length - mech.length_min] + [rotation] * 3)
    caps = np.stack([caps_up, caps_down])  # (2, 6): direction (+, -), axis
    fractions = np.arange(steps + 1) / steps
    signs = np.array([1.0, -1.0])
    # Poses (2, 6, steps + 1, 6): direction, axis moved, grid point, pose6 (zero but the axis).
    poses = np.zeros((2, 6, steps + 1, 6))
    for k in range(6):
        poses[:, k, :, k] = signs[:, None] * caps[:, k, None] * fractions[None, :]
    p, q = base_pq_of_machine_pose6(mech, poses.reshape(-1, 6))
    ok = within_limits(mech, p, q).reshape(2, 6, steps + 1)
    if not ok[:, :, 0].all():
        raise ConfigError('the home pose is outside the limits of the mechanism: no factory '
                          'box can be derived')
    # The last grid point before the first one out of limits (all in: the cap).
    first_out = np.where(ok.all(axis=2), steps + 1, np.argmin(ok, axis=2))
    reach = caps * fractions[first_out - 1]
    return BoxLimits(tuple(-reach[1]), tuple(reach[0]))


@dataclass(frozen=True)
class FactoryBoxSettings:
    """The factory box (read-only configuration): the machine-CS box the factory allows."""

    lower: tuple[float, ...] | None = setting(
        None, 'factory box, lower bounds Tx, Ty, Tz (m), Rx, Ry, Rz (rad), machine CS (zero at '
        'home); not given: derived from the mechanism', 'm, rad', length=6)
    upper: tuple[float, ...] | None = setting(
        None, 'factory box, upper bounds Tx, Ty, Tz (m), Rx, Ry, Rz (rad), machine CS (zero at '
        'home); not given: derived from the mechanism', 'm, rad', length=6)
    rotation: float = setting(DERIVED_ROTATION, 'derived factory box: largest rotation about '
                              'each axis', 'rad', low=0.0, high=math.pi, low_open=True)

    def __post_init__(self) -> None:
        check_fields(self)
        if (self.lower is None) != (self.upper is None):
            given = 'lower' if self.lower is not None else 'upper'
            raise ParameterError(given, getattr(self, given), 'give both lower and upper, or '
                                 'neither (derived from the mechanism)')
        if self.lower is not None and self.upper is not None:
            try:
                BoxLimits(self.lower, self.upper)
            except InputError as err:
                raise ParameterError('lower', self.lower, str(err)) from None

    def box(self, mech: Mechanism) -> BoxLimits:
        """The factory box: the configured bounds, else :func:`derived_factory_box`."""
        if self.lower is not None and self.upper is not None:
            return BoxLimits(self.lower, self.upper)
        return derived_factory_box(mech, self.rotation)


# -- the three layers -----------------------------------------------------------------------------
def _layer_problems(factory: BoxLimits, machine: BoxLimits, user: BoxLimits) -> list[str]:
    problems = []
    if not factory.is_finite:
        problems.append('factory box: every bound must be finite')
    problems += [f'machine limits outside the factory box: {line}'
                 for line in factory.contains(machine)]
    if not (user.is_finite or user.is_unlimited):
        axes = sorted({AXES[k] for k in range(6)
                       if not (math.isfinite(user.lower[k]) and math.isfinite(user.upper[k]))},
                      key=AXES.index)
        problems.append(f'user limits: {", ".join(axes)} unlimited but not the other axes: a '
                        'user box is finite on every bound or unlimited on every bound')
    return problems


def _user_problems(machine: BoxLimits, user: BoxLimits, to_machine: PoseMap) -> list[str]:
    vertices = user.vertices()
    try:
        mapped = as_pose6(to_machine(vertices.copy()), 'user vertices in the machine CS')
    except InputError as err:
        return [f'user limits: {err}']
    if mapped.shape != vertices.shape:
        return [f'user limits: the mapping gave {mapped.shape[0]} poses for 64 vertices']
    mapped = wrap_angles(mapped)
    margin = np.minimum(mapped - machine.low, machine.high - mapped)
    problems = []
    found = np.argwhere(margin < 0.0)
    for i, k in found[:MAX_LISTED]:
        problems.append(f'user limits: vertex {i} ({_pose6_row_text(vertices[i])}) maps to '
                        f'{AXES[k]} '
                        + machine.outside_text(int(k), float(mapped[i, k]), 'machine ',
                                               ' in the machine CS,'))
    if len(found) > MAX_LISTED:
        problems.append(f'user limits: +{len(found) - MAX_LISTED} more vertex components '
                        'outside the machine box')
    return problems


@dataclass(frozen=True)
class LimitLayers:
    """The factory, machine and user boxes (module docstring). Built directly, the factory
    box must be finite, the machine box within it and the user box finite or unlimited
    (InputError listing what is not); the user box's vertices are checked against the machine
    box by :meth:`validated`, which needs the user-to-machine mapping."""

    factory_box: BoxLimits
    machine_box: BoxLimits
    user_box: BoxLimits = field(default_factory=BoxLimits.unlimited)

    def __post_init__(self) -> None:
        problems = _layer_problems(self.factory_box, self.machine_box, self.user_box)
        if problems:
            raise InputError('limits refused: ' + '; '.join(problems))

    @classmethod
    def of(cls, factory_box: BoxLimits) -> LimitLayers:
        """The default layers: machine box = factory box, no user limit."""
        return cls(factory_box, factory_box, BoxLimits.unlimited())

    @classmethod
    def for_mechanism(cls, mech: Mechanism,
                      factory: FactoryBoxSettings | None = None) -> LimitLayers:
        """The default layers of a mechanism and its factory-box configuration."""
        return cls.of((factory or FactoryBoxSettings()).box(mech))

    def validated(self, machine: BoxLimits, user: BoxLimits,
                  user_vertices_in_machine: PoseMap) -> LimitLayers:
        """New layers with this factory box and the given machine and user boxes, or
        InputError listing everything outside: machine bounds outside the factory box, user
        vertices (64, 6, user CS) that ``user_vertices_in_machine`` maps (to pose6 (64, 6),
        machine CS) outside the machine box. An unlimited user box is always accepted."""
        problems = _layer_problems(self.factory_box, machine, user)
        if not problems and user.is_finite:
            problems = _user_problems(machine, user, user_vertices_in_machine)
        if problems:
            raise InputError('limits refused: ' + '; '.join(problems))
        return LimitLayers(self.factory_box, machine, user)

    def check(self, machine_pose6: ArrayLike,
              user_pose6: ArrayLike | None = None) -> CheckResult:
        """The machine and user layers of poses: ``machine_pose6`` (N, 6) in the machine CS
        against the machine box (MACHINE_LIMITS; being within the factory box, it is the
        tighter), ``user_pose6`` (N, 6), the same poses in the user CS, against the user box
        (USER_LIMITS; not needed, and not checked, when the user box is unlimited). Margins
        'machine.Tx' ... 'user.Rz'."""
        result = _layer_check(self.machine_box, machine_pose6, 'machine limits', 'machine',
                              Validity.MACHINE_LIMITS)
        if self.user_box.is_unlimited:
            return result
        if user_pose6 is None:
            raise InputError('the user box is limited: the poses in the user CS are needed')
        if as_pose6(user_pose6).shape[0] != as_pose6(machine_pose6).shape[0]:
            raise InputError('machine_pose6 and user_pose6 must hold the same number of poses')
        return result.merged(_layer_check(self.user_box, user_pose6, 'user limits', 'user',
                                          Validity.USER_LIMITS))


def _layer_check(box: BoxLimits, pose6: ArrayLike, layer_name: str, prefix: str,
                 bit: Validity) -> CheckResult:
    ok, lines, margins = box.check(pose6, layer_name)
    return CheckResult(VALID if ok.all() else bit, tuple(lines),
                       {f'{prefix}.{axis}': m for axis, m in margins.items()})

