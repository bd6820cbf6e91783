"""An independent forward kinematics: scipy least squares over the pose (p, rotation vector) on
the full closure l_i = |p + R b_i − A_i|, θ_i = asin(u_i · e_t,i); no passive angles, no
platform triangle. Slow, one pose per call: the reference that tests check
:func:`positioning_cell.core.kinematics.forward` against and the baseline benchmarks compare to."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from positioning_cell.core.mechanism import Mechanism

FloatArray = NDArray[np.float64]


def reference_forward(mech: Mechanism, lengths: ArrayLike,
                      thetas: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Position (3,) m and quaternion (4,) x, y, z, w of one pose from lengths (3,) m and
    thetas (3,) rad, started from home (Levenberg-Marquardt to machine precision)."""
    l_cmd = np.asarray(lengths, dtype=float).reshape(3)
    t_cmd = np.asarray(thetas, dtype=float).reshape(3)

    def residual(x: FloatArray) -> FloatArray:
        rot = Rotation.from_rotvec(x[3:]).as_matrix()
        d = x[:3] + mech.platform_joints @ rot.T - mech.base_joints
        length = np.linalg.norm(d, axis=1)
        theta = np.arcsin(np.sum(d * mech.tangential, axis=1) / length)
        # θ residuals scaled by R_B so that both parts are lengths.
        out: FloatArray = np.concatenate([length - l_cmd,
                                          (theta - t_cmd) * mech.platform_radius])
        return out

    x0 = np.concatenate([mech.home_position, np.zeros(3)])
    x = least_squares(residual, x0, xtol=1e-15, ftol=1e-15, gtol=1e-15, method='lm').x
    return x[:3], np.asarray(Rotation.from_rotvec(x[3:]).as_quat())
