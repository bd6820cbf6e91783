"""Load-aware joint clearance: each clearance closes in the direction of the force its joint
carries (seed 004 §2, the gap connector oriented by the load), so with a payload the clearance
error is deterministic and can be compensated.

Model (the exact vector model of docs/conventions/kinematics.md with load-driven directions): with
F_A,i the force leg i exerts on the base at its U joint and F_B,i the force it exerts on the
platform at its ball (:func:`positioning_cell.mechanics.statics.joint_forces`),

- the leg's U centre sits at A_i + r_a · F_A,i / sqrt(|F_A,i|² + F_0²) (base frame),
- the ball centre sits at b_i + r_b · Rᵀ F_B,i / sqrt(|F_B,i|² + F_0²) (platform frame),

F_0 (``seating_force``, N) a small force below which the joint is not yet seated (keeps the
model smooth where a force vanishes). A leg in compression is so shortened by up to r_a + r_b.
The forces are those at the pose the platform actually takes (a fixed point, solved exactly).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance.model import ModelInputs
from positioning_cell.core.kinematics import ForwardResult, InverseResult, forward, inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, as_vectors, matrix_from_quaternion
from positioning_cell.errors import ConfigError, ConvergenceError
from positioning_cell.mechanics.statics import JointForces, Payload, Structure, joint_forces
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]

#: Fixed-point tolerance on the joint offsets' effect on the joints (m, rad).
_TOLERANCE = 1e-14
_MAX_ITERATIONS = 30


@dataclass(frozen=True)
class LoadAwareClearance:
    """Clearance r_a (U joint) and r_b (S joint), m, closed by the joint forces of ``payload``
    carried by a machine with ``structure``; ``seating_force`` F_0 in N. Implements
    :class:`positioning_cell.clearance.ClearanceLike`."""

    r_a: float
    r_b: float
    payload: Payload = field(default_factory=Payload)
    structure: Structure = field(default_factory=Structure)
    seating_force: float = 1.0

    def __post_init__(self) -> None:
        for name in ('r_a', 'r_b'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f'clearance.{name} = {value!r}: must be a finite length >= 0 m')
        if not (math.isfinite(self.seating_force) and self.seating_force > 0.0):
            raise ConfigError(
                f'clearance.seating_force = {self.seating_force!r}: must be a finite force > 0 N')

    def offsets(self, mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                forces: JointForces | None = None) -> tuple[FloatArray, FloatArray]:
        """Joint-centre offsets at poses (N, 3) m, (N, 4): U centres (N, 3, 3) in the base frame
        and ball centres (N, 3, 3) in the platform frame, m. ``forces``: the
        :func:`~positioning_cell.mechanics.statics.joint_forces` of this clearance's payload
        and structure at these poses when the caller has them (None: computed here)."""
        p, q = as_pose_batch(position, quaternion)
        if forces is None:
            forces = joint_forces(mech, p, q, self.payload, self.structure)
        rot = matrix_from_quaternion(q)
        u_off = self.r_a * _seated(forces.at_base, self.seating_force)
        s_base = self.r_b * _seated(forces.at_platform, self.seating_force)
        s_off = np.einsum('nji,nkj->nki', rot, s_base)
        return u_off, s_off

    def _joint_shift(self, mech: Mechanism, p: FloatArray, q: FloatArray) -> InverseResult:
        """Joints of the machine with clearance at poses, minus the nominal joints."""
        actual = inverse_with_offsets(mech, p, q, *self.offsets(mech, p, q))
        nominal = inverse(mech, p, q)
        return InverseResult(actual.lengths - nominal.lengths, actual.thetas - nominal.thetas,
                             actual.phis - nominal.phis)

    def attained_pose(self, mech: Mechanism, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """Where the loaded machine puts the platform for commanded lengths (N, 3) m and thetas
        (N, 3) rad: nominal FK on the commands minus the clearance's joint shift at the
        attained pose, iterated to a fixed point (each pass one warm-started batched FK)."""
        l_cmd = as_vectors(lengths, 3, 'lengths')
        t_cmd = as_vectors(thetas, 3, 'thetas')
        result = forward(mech, l_cmd, t_cmd, phi0)
        ok = result.converged.copy()
        shift_l = np.zeros_like(l_cmd)
        shift_t = np.zeros_like(t_cmd)
        for _ in range(_MAX_ITERATIONS):
            shift = self._joint_shift(mech, result.position[ok], result.quaternion[ok])
            change = max(np.max(np.abs(shift.lengths - shift_l[ok]), initial=0.0),
                         np.max(np.abs(shift.thetas - shift_t[ok]), initial=0.0))
            shift_l[ok], shift_t[ok] = shift.lengths, shift.thetas
            phis = np.where(np.isfinite(result.phis), result.phis, 0.0)
            result = forward(mech, l_cmd - shift_l, t_cmd - shift_t, phis)
            ok &= result.converged
            if change <= _TOLERANCE:
                position = np.where(ok[:, None], result.position, np.nan)
                quaternion = np.where(ok[:, None], result.quaternion, np.nan)
                return ForwardResult(position, quaternion, result.phis, ok)
        raise ConvergenceError('load-aware clearance fixed point did not converge')

    def compensate(self, mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                   forces: JointForces | None = None) -> InverseResult:
        """Joint commands putting the loaded machine on poses (N, 3) m, (N, 4): IK of the machine
        with the joint centres displaced by the load at those poses (closed form, exact);
        ``forces`` as :meth:`offsets`."""
        p, q = as_pose_batch(position, quaternion)
        return inverse_with_offsets(mech, p, q, *self.offsets(mech, p, q, forces))


def _seated(force: FloatArray, seating_force: float) -> FloatArray:
    """F / sqrt(|F|² + F_0²) (…, 3): the unit force direction once the joint is seated."""
    norm = np.sqrt(np.sum(force * force, axis=-1, keepdims=True) + seating_force**2)
    out: FloatArray = force / norm
    return out


def inverse_with_offsets(mech: Mechanism, position: FloatArray, quaternion: FloatArray,
                         u_offsets: FloatArray, s_offsets: FloatArray) -> InverseResult:
    """Closed-form IK of poses (N, 3), (N, 4) for a machine whose U centres are displaced by
    ``u_offsets`` (N, 3, 3) (base frame) and ball centres by ``s_offsets`` (N, 3, 3) (platform
    frame), different per pose. Leg i only sees its own joints, so it is the nominal IK of the
    pose shifted by R·e_b,i − e_a,i (:func:`positioning_cell.core.kinematics.inverse`: one
    batched call over the 3N shifted poses, of which leg i of the i-th shift of each pose is
    kept)."""
    n = position.shape[0]
    rot = matrix_from_quaternion(quaternion)
    shifted = (position[:, None, :] + np.einsum('nij,nkj->nki', rot, s_offsets)
               - u_offsets)  # (N, leg, 3): the pose as leg i sees it
    legs = inverse(mech, shifted.reshape(3 * n, 3), np.repeat(quaternion, 3, axis=0))
    own = np.arange(3)

    def kept(values: FloatArray) -> FloatArray:
        out: FloatArray = values.reshape(n, 3, 3)[:, own, own]
        return out

    return InverseResult(kept(legs.lengths), kept(legs.thetas), kept(legs.phis))


@dataclass(frozen=True)
class LoadParameters:
    """The ``clearance.load`` block; the payload and structure are the node's own ``payload``
    and ``structure`` blocks (shared by every node in config/cell.yaml)."""

    seating_force: float = setting(1.0, 'F_0: joint force below which a joint is not yet '
                                   'seated', 'N', low=0.0, low_open=True)

    def __post_init__(self) -> None:
        check_fields(self)

    def model(self, inputs: ModelInputs) -> LoadAwareClearance:
        """The model these parameters give with clearances r_a, r_b and the node's payload."""
        return LoadAwareClearance(inputs.r_a, inputs.r_b, inputs.payload, inputs.structure,
                                  self.seating_force)
