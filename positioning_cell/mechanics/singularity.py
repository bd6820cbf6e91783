"""Singularity by screw theory (seed 001): rank and conditioning of the actuation and
constraint wrench system, sample by sample along a path, and a refusal that says where.

With its actuators locked a parallel mechanism is rigid exactly when the wrenches its limbs can
carry (constraint wrenches plus one actuation wrench per actuator) span all six dimensions. The
measure is the reciprocal condition number of that system, each wrench normalised to a unit
force (or unit couple), moments taken about the platform centre and divided by the
characteristic length R_B: 1 for an isotropic system, 0 at a singularity. For the 3-UPS
positioner the system is the three leg-line forces (actuated l_i) and the three forces through
B_i along ∂u_i/∂θ_i (actuated θ_i); a UPS limb has no constraint wrench.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.kinematics import inverse as inverse_kinematics
from positioning_cell.core.kinematics import leg_directions, platform_points
from positioning_cell.core.limits import MAX_LISTED, LimitReport, Violation
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch
from positioning_cell.mechanics.screw import RANK_TOLERANCE, moved, positioner_actuation_wrenches

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Default refusal margin on the wrench-system conditioning. On this machine the measure runs
#: about 3.5 times the Jacobian conditioning of
#: :func:`positioning_cell.core.kinematics.conditioning`
#: (0.63 vs 0.21 at home, 0.026 vs 0.0073 near the singularity at a π/2 turn about z), so 0.07
#: matches the kinematic limit ``Mechanism.min_conditioning`` = 0.02.
DEFAULT_MARGIN = 0.07


class WrenchConditioning(NamedTuple):
    """rank (N,) of the wrench systems and their conditioning (N,) in [0, 1]."""

    rank: IntArray
    conditioning: FloatArray


def wrench_conditioning(wrenches: ArrayLike, length: float) -> WrenchConditioning:
    """Rank and reciprocal condition number of wrench systems (N, k, 6) (or one (k, 6)),
    normalised wrenches (f; m) with m about the platform centre; m is divided by ``length``
    (m) so that forces and moments weigh alike. Fewer than six wrenches: conditioning 0."""
    w = np.asarray(wrenches, dtype=float)
    if w.ndim == 2:
        w = w[None]
    scaled = w * np.array([1.0, 1.0, 1.0] + [1.0 / length] * 3)
    sv = np.linalg.svd(scaled, compute_uv=False)
    top = np.maximum(sv[:, 0], 1e-300)
    ranks = np.sum(sv > RANK_TOLERANCE * top[:, None], axis=1).astype(np.int64)
    cond = sv[:, 5] / top if sv.shape[1] >= 6 else np.zeros(w.shape[0])
    return WrenchConditioning(ranks, cond)


def positioner_wrenches(mech: Mechanism, position: ArrayLike,
                        quaternion: ArrayLike) -> FloatArray:
    """Actuation wrench systems (N, 6, 6) of the 3-UPS positioner at poses (N, 3) m, (N, 4),
    unit forces, moments about the platform centre (base frame axes)."""
    p, q = as_pose_batch(position, quaternion)
    joints = inverse_kinematics(mech, p, q)
    u = leg_directions(mech, joints.phis, joints.thetas)
    about_origin = positioner_actuation_wrenches(mech, platform_points(mech, p, q), u)
    return moved(about_origin, p[:, None, :])


def positioner_conditioning(mech: Mechanism, position: ArrayLike,
                            quaternion: ArrayLike) -> WrenchConditioning:
    """Rank and conditioning (N,) of the positioner's actuation wrench system at poses."""
    return wrench_conditioning(positioner_wrenches(mech, position, quaternion),
                               mech.characteristic_length)


@dataclass(frozen=True)
class SingularityReport:
    """Singularity check of ``n_samples`` poses of a path: ``measure`` (N,) is the wrench-system
    conditioning, ``rank`` (N,) its rank; samples with measure < ``margin`` are listed in
    ``bad_samples`` (all of them, in order). ``worst_sample`` has the smallest measure."""

    n_samples: int
    margin: float
    measure: FloatArray
    rank: IntArray
    bad_samples: tuple[int, ...]

    @property
    def ok(self) -> bool:
        """True when every sample keeps the margin."""
        return not self.bad_samples

    @property
    def first_bad_sample(self) -> int | None:
        """Index of the first sample closer to a singularity than the margin, or None."""
        return self.bad_samples[0] if self.bad_samples else None

    @property
    def worst_sample(self) -> int:
        """Index of the sample nearest a singularity."""
        return int(np.argmin(self.measure))

    def message(self) -> str:
        """Words for a refusal (or for the log when ok)."""
        w = self.worst_sample
        worst = (f'sample {w}: wrench-system conditioning {self.measure[w]:.4g}, rank '
                 f'{int(self.rank[w])} of 6')
        if self.ok:
            return (f'all {self.n_samples} samples keep the singularity margin '
                    f'{self.margin:.4g} (nearest: {worst})')
        first = self.bad_samples[0]
        return (f'too close to a singularity: {len(self.bad_samples)} of {self.n_samples} '
                f'samples below the margin {self.margin:.4g}, first at sample {first} '
                f'(conditioning {self.measure[first]:.4g}, rank {int(self.rank[first])} of 6); '
                f'nearest {worst}')

    def as_limit_report(self) -> LimitReport:
        """The same refusal as a :class:`positioning_cell.core.limits.LimitReport` (constraint
        'conditioning_min'), to merge with :func:`positioning_cell.core.limits.check_poses`."""
        listed = tuple(
            Violation(s, 'conditioning_min', None, float(self.measure[s]), self.margin,
                      self.margin - float(self.measure[s]), '')
            for s in self.bad_samples[:MAX_LISTED])
        return LimitReport(self.n_samples, listed, len(self.bad_samples))

    def raise_if_violated(self) -> None:
        """Raise :class:`positioning_cell.core.limits.LimitError` when a sample is too close."""
        self.as_limit_report().raise_if_violated()


def check_path(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
               margin: float | None = None) -> SingularityReport:
    """Check every pose of a path (N, 3) m, (N, 4) x, y, z, w against a singularity margin on
    the wrench-system conditioning (default :data:`DEFAULT_MARGIN`). Never raises for a
    violation; malformed input raises InputError."""
    limit = DEFAULT_MARGIN if margin is None else float(margin)
    result = positioner_conditioning(mech, position, quaternion)
    bad = np.flatnonzero(~(result.conditioning >= limit))
    return SingularityReport(result.conditioning.shape[0], limit, result.conditioning,
                             result.rank, tuple(int(i) for i in bad))
