"""Limit checking for batches of poses: stroke, joint ranges, S-joint tilt, leg clearance
distance and singularity margin. A refusal says which constraint, which leg, at which sample and
by how much."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.kinematics import (
    PAIRS_I,
    PAIRS_J,
    _inverse_jacobian,
    _inverse_validated,
    conditioning,
    platform_points,
)
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, matrix_from_quaternion
from positioning_cell.errors import PositioningError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: How many violations a report keeps in full (the count is always exact).
MAX_LISTED = 50

_RAD = 'rad'


@dataclass(frozen=True)
class Violation:
    """One violated constraint at one sample: value and limit in SI (m, rad or dimensionless);
    ``excess`` > 0 is how far beyond the limit. ``leg`` is 1-based, or a pair 'i-j', or None."""

    sample: int
    constraint: str
    leg: str | None
    value: float
    limit: float
    excess: float
    unit: str

    def describe(self) -> str:
        """One line for people, with mm and degrees."""
        where = f'leg {self.leg} ' if self.leg else ''
        kind = 'above the maximum' if self.constraint.endswith('max') else 'below the minimum'
        if self.constraint == 'spherical_tilt':
            kind = 'above the maximum'
        what = f'{where}{_LABELS[self.constraint]} {_fmt(self.value, self.unit)}'
        bound = f'{kind} {_fmt(self.limit, self.unit)} by {_fmt(self.excess, self.unit)}'
        return f'sample {self.sample}: {what} {bound}'


_LABELS = {
    'length_min': 'length', 'length_max': 'length',
    'phi_min': 'phi', 'phi_max': 'phi', 'theta_min': 'theta', 'theta_max': 'theta',
    'spherical_tilt': 'spherical-joint tilt', 'leg_distance_min': 'distance between legs',
    'conditioning_min': 'conditioning (singularity margin)',
}


def _fmt(value: float, unit: str) -> str:
    if unit == 'm':
        return f'{value * 1e3:.4f} mm'
    if unit == _RAD:
        return f'{np.degrees(value):.4f} deg'
    return f'{value:.4g}'


@dataclass(frozen=True)
class LimitReport:
    """Result of a limit check over ``n_samples`` poses; ``violations`` lists up to 50 of
    ``n_violations``, ordered by sample."""

    n_samples: int
    violations: tuple[Violation, ...]
    n_violations: int

    @property
    def ok(self) -> bool:
        """True when no constraint is violated."""
        return self.n_violations == 0

    @property
    def first_bad_sample(self) -> int | None:
        """Index of the first violating sample, or None."""
        return self.violations[0].sample if self.violations else None

    def message(self, most: int = 3) -> str:
        """Words for a refusal: the first ``most`` violations and the total count."""
        if self.ok:
            return f'all {self.n_samples} samples within limits'
        lines = [v.describe() for v in self.violations[:most]]
        more = self.n_violations - len(lines)
        tail = f' (+{more} more)' if more > 0 else ''
        return 'outside limits: ' + '; '.join(lines) + tail

    def merged(self, other: LimitReport) -> LimitReport:
        """One report of two checks of the same samples, violations ordered by sample."""
        if other.n_samples != self.n_samples:
            raise ValueError(f'cannot merge reports of {self.n_samples} and '
                             f'{other.n_samples} samples')
        found = sorted(self.violations + other.violations, key=lambda v: v.sample)
        return LimitReport(self.n_samples, tuple(found[:MAX_LISTED]),
                           self.n_violations + other.n_violations)

    def raise_if_violated(self) -> None:
        """Raise :class:`LimitError` carrying this report when anything is violated."""
        if not self.ok:
            raise LimitError(self)


class LimitError(PositioningError):
    """A pose or path violates a joint, stroke, collision or singularity limit (the report
    says which)."""

    def __init__(self, report: LimitReport) -> None:
        super().__init__(report.message())
        self.report = report


def segment_distance(p1: FloatArray, q1: FloatArray, p2: FloatArray,
                     q2: FloatArray) -> FloatArray:
    """Shortest distance between segments p1–q1 and p2–q2 (..., 3), clamped closest points."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.sum(d1 * d1, axis=-1)
    e = np.sum(d2 * d2, axis=-1)
    b = np.sum(d1 * d2, axis=-1)
    c = np.sum(d1 * r, axis=-1)
    f = np.sum(d2 * r, axis=-1)
    denom = a * e - b * b
    with np.errstate(divide='ignore', invalid='ignore'):
        s = np.where(denom > 1e-18, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = (b * s + f) / e
        s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0),
                     np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip((b * s + f) / e, 0.0, 1.0)
    gap = p1 + d1 * s[..., None] - (p2 + d2 * t[..., None])
    return np.linalg.norm(gap, axis=-1)  # type: ignore[no-any-return]


def check_poses(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike) -> LimitReport:
    """Check poses (N, 3) m / (N, 4) x, y, z, w against every limit of ``mech``.

    Raises InputError for malformed input; never raises for a violated limit (see
    :meth:`LimitReport.raise_if_violated`).
    """
    p, q = as_pose_batch(position, quaternion)
    checks = _checks(mech, p, q)
    found: list[Violation] = []
    total = 0
    for name, value, limit, sign, unit in checks:
        excess = sign * (value - limit)
        samples, cols = np.nonzero(excess > 0.0)
        total += samples.size
        for s, k in zip(samples[:MAX_LISTED], cols[:MAX_LISTED], strict=True):
            found.append(Violation(int(s), name, _leg_label(name, int(k)), float(value[s, k]),
                                   float(limit), float(excess[s, k]), unit))
    found.sort(key=lambda v: (v.sample, v.constraint))
    return LimitReport(p.shape[0], tuple(found[:MAX_LISTED]), total)


def within_limits(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike) -> BoolArray:
    """Per pose (N,), whether poses (N, 3) m / (N, 4) violate no limit of ``mech`` (the checks
    of :func:`check_poses`)."""
    p, q = as_pose_batch(position, quaternion)
    ok = np.ones(p.shape[0], dtype=bool)
    for _, value, limit, sign, _ in _checks(mech, p, q):
        ok &= np.all(sign * (value - limit) <= 0.0, axis=1)
    return ok


#: One limit of :func:`limit_values`: (name, value (N, k), limit, sign, unit).
LimitValue = tuple[str, FloatArray, float, float, str]


def limit_values(mech: Mechanism, p: FloatArray, q: FloatArray) -> list[LimitValue]:
    """Every limit as (name, value (N, k), limit, sign (+1: value must stay below), unit),
    in the order of :func:`check_poses`, for poses already validated (N, 3) m / (N, 4) unit
    quaternions (:func:`positioning_cell.core.poses.as_pose_batch`). The signed margin of a
    value is ``sign * (limit - value)``: positive inside by that much (SI), negative violated.
    """
    joints = _inverse_validated(mech, p, q)
    points = platform_points(mech, p, q)
    u = (points - mech.base_joints) / joints.lengths[..., None]
    normal = matrix_from_quaternion(q)[:, :, 2]
    tilt = np.arccos(np.clip(np.einsum('nkj,nj->nk', u, normal), -1.0, 1.0))
    base = np.broadcast_to(mech.base_joints, points.shape)
    gap = segment_distance(base[:, PAIRS_I], points[:, PAIRS_I], base[:, PAIRS_J],
                           points[:, PAIRS_J])
    cond = conditioning(mech, _inverse_jacobian(mech, p, q))[:, None]
    return [
        ('length_min', joints.lengths, mech.length_min, -1.0, 'm'),
        ('length_max', joints.lengths, mech.length_max, 1.0, 'm'),
        ('phi_min', joints.phis, mech.phi_min, -1.0, _RAD),
        ('phi_max', joints.phis, mech.phi_max, 1.0, _RAD),
        ('theta_min', joints.thetas, mech.theta_min, -1.0, _RAD),
        ('theta_max', joints.thetas, mech.theta_max, 1.0, _RAD),
        ('spherical_tilt', tilt, mech.tilt_max, 1.0, _RAD),
        ('leg_distance_min', gap, mech.min_leg_distance, -1.0, 'm'),
        ('conditioning_min', cond, mech.min_conditioning, -1.0, ''),
    ]


_checks = limit_values  # the former private name


def _leg_label(name: str, k: int) -> str | None:
    if name == 'conditioning_min':
        return None
    if name == 'leg_distance_min':
        return f'{PAIRS_I[k] + 1}-{PAIRS_J[k] + 1}'
    return str(k + 1)


def require_within_limits(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike) -> None:
    """Raise :class:`LimitError` naming the constraint, leg, sample and excess if any pose
    violates a limit."""
    check_poses(mech, position, quaternion).raise_if_violated()
