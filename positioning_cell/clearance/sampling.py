"""The clearance effect of an uncompensated machine, sampled: pose errors over random clearance
directions (seed 000 Table 1), the basis of the clearance-effect benchmark."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance.effective_length import EffectiveLengthClearance
from positioning_cell.clearance.model import ClearanceLike
from positioning_cell.clearance.vector import VectorClearance
from positioning_cell.core.kinematics import inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, pose_error
from positioning_cell.errors import ConfigError

FloatArray = NDArray[np.float64]


def monte_carlo_pose_errors(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                            r_a: float, r_b: float, samples: int, rng: np.random.Generator,
                            kind: str = 'effective_length') -> FloatArray:
    """Pose errors (samples, N, 6) of an uncompensated machine whose clearance directions are
    drawn uniformly (seed 000 Table 1: δ in [0, 2π); vector model: directions on the sphere).

    Each sample commands the nominal inverse kinematics of the N poses and records attained
    − commanded: Δp (m, base frame) and the rotation vector of R_cmdᵀ·R_att (rad).
    """
    p, q = as_pose_batch(position, quaternion)
    cmd = inverse(mech, p, q)
    makers: dict[str, Callable[[float, float, np.random.Generator], ClearanceLike]] = {
        'effective_length': EffectiveLengthClearance.random, 'vector': VectorClearance.random}
    make = makers.get(kind)
    if make is None:
        raise ConfigError(f'kind = {kind!r}: expected effective_length or vector')
    out = np.empty((samples, p.shape[0], 6))
    for s in range(samples):  # one clearance draw per sample; each is a batched FK over poses
        att = make(r_a, r_b, rng).attained_pose(mech, cmd.lengths, cmd.thetas, cmd.phis)
        dp, dr = pose_error(att.position, att.quaternion, p, q)
        out[s, :, :3], out[s, :, 3:] = dp, dr
    return out
