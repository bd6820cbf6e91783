"""Every joint's value at platform poses: the actuated l_i, θ_i, the U joints' passive φ_i and
the S joints' three angles, in the order of :data:`~positioning_cell.robot.urdf.MOVING_JOINT_NAMES`
(the cell's /joint_states; docs/conventions/robot-description.md).

The leg's rod frame after its U and prismatic joints is R_rod,i = Rz(γ_i)·Ry(φ_i)·Rx(−θ_i)
(its z axis the leg direction u_i of kinematics.md), at the S-joint centre B_i. The S joint
turns it into the platform's orientation R: R_rod,iᵀ·R = Rx(s_x)·Ry(s_y)·Rz(s_z), so
s_y = asin(M₀₂), s_x = atan2(−M₁₂, M₂₂), s_z = atan2(−M₀₁, M₀₀) (M = R_rod,iᵀ·R). The tilt of
the S joint t (cos t = u_i · R e_z, the limit of :mod:`positioning_cell.core.limits`) satisfies
cos t = cos s_x · cos s_y, so |s_x|, |s_y| ≤ t < 90°: the decomposition is never singular
inside the limits.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.kinematics import inverse
from positioning_cell.core.mechanism import LEG_AZIMUTHS, Mechanism
from positioning_cell.core.poses import matrix_from_quaternion

FloatArray = NDArray[np.float64]


def _rotations(axis: int, angles: FloatArray) -> FloatArray:
    """Rotation matrices (..., 3, 3) about base axis ``axis`` (0 x, 1 y, 2 z) by ``angles``."""
    c, s = np.cos(angles), np.sin(angles)
    out = np.zeros(np.shape(angles) + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i], out[..., j, j] = c, c
    out[..., i, j], out[..., j, i] = -s, s
    return out


def rod_rotations(phis: FloatArray, thetas: FloatArray) -> FloatArray:
    """R_rod,i = Rz(γ_i)·Ry(φ_i)·Rx(−θ_i) (N, 3 legs, 3, 3) from φ, θ (N, 3) rad: the leg's
    frame after its U joint, z along u_i (base frame)."""
    gamma = _rotations(2, np.asarray(LEG_AZIMUTHS))
    rotation: FloatArray = np.einsum('kab,nkbc,nkcd->nkad', gamma, _rotations(1, phis),
                                     _rotations(0, -thetas))
    return rotation


def s_joint_angles(rod: FloatArray, rotation: FloatArray) -> FloatArray:
    """The S joints' angles (N, 3 legs, 3: s_x, s_y, s_z) rad from the rod frames (N, 3, 3, 3)
    and the platform's orientation (N, 3, 3): R_rodᵀ·R = Rx(s_x)·Ry(s_y)·Rz(s_z)."""
    m = np.einsum('nkba,nbc->nkac', rod, rotation)
    return np.stack([np.arctan2(-m[..., 1, 2], m[..., 2, 2]),
                     np.arcsin(np.clip(m[..., 0, 2], -1.0, 1.0)),
                     np.arctan2(-m[..., 0, 1], m[..., 0, 0])], axis=-1)


def joint_positions(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike) -> FloatArray:
    """Every joint's value (N, 18) at platform poses (N, 3) m, (N, 4) x, y, z, w of the machine
    ``mech``: l_1..3 (m), θ_1..3, φ_1..3, s_x 1..3, s_y 1..3, s_z 1..3 (rad), the order of
    :data:`~positioning_cell.robot.urdf.MOVING_JOINT_NAMES`. Inverse kinematics in closed form
    (kinematics.md), the S angles as the module says. Raises InputError for bad poses; limits
    are not checked."""
    joints = inverse(mech, position, quaternion)
    rotation = matrix_from_quaternion(np.reshape(np.asarray(quaternion, dtype=float), (-1, 4)))
    s = s_joint_angles(rod_rotations(joints.phis, joints.thetas), rotation)
    return np.concatenate([joints.lengths, joints.thetas, joints.phis, s[..., 0], s[..., 1],
                           s[..., 2]], axis=1)
