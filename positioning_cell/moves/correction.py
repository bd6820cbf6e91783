"""The closed loop on the laser tracker: averaged measured poses, their deviation from the
desired pose, and the next command that moves the measured pose onto it (the way digital
assembly cells close the loop through a tracker). Poses in the base frame: m, unit quaternions
x, y, z, w."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.core.poses import as_pose_batch, pose_error

FloatArray = NDArray[np.float64]


def corrected_command(command_p: ArrayLike, command_q: ArrayLike, desired_p: ArrayLike,
                      desired_q: ArrayLike, measured_p: ArrayLike,
                      measured_q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Next pose to command so that the measured pose moves onto the desired one.

    The machine's error is nearly constant over a correction step, so the command moves by the
    measured deviation: p' = p_cmd + (p_des − p_meas); R' = R_des·R_measᵀ·R_cmd (base frame).
    """
    cp, cq = as_pose_batch(command_p, command_q)
    dp, dq = as_pose_batch(desired_p, desired_q)
    mp, mq = as_pose_batch(measured_p, measured_q)
    rot = Rotation.from_quat(dq) * Rotation.from_quat(mq).inv() * Rotation.from_quat(cq)
    return (cp + dp - mp)[0], np.asarray(rot.as_quat(canonical=True))[0]

def deviation(measured_p: ArrayLike, measured_q: ArrayLike, desired_p: ArrayLike,
              desired_q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Measured − desired: Δp (3,) m and the rotation vector of R_desᵀ·R_meas (3,) rad."""
    mp, mq = as_pose_batch(measured_p, measured_q)
    dp, dq = as_pose_batch(desired_p, desired_q)
    e_p, e_r = pose_error(mp, mq, dp, dq)
    return e_p[0], e_r[0]

def mean_pose(positions: ArrayLike, quaternions: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Mean of k poses: arithmetic mean position (3,) m, chordal L2 mean rotation (4,)."""
    p, q = as_pose_batch(positions, quaternions)
    return p.mean(axis=0), np.asarray(Rotation.from_quat(q).mean().as_quat(canonical=True))
