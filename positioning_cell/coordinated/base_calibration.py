"""Where each positioner's base is in the cell frame (issue 27 item 5): identified from the
tracker's measurements of its attachment point at several of its poses.

Positioner i puts its attachment point at a_k (m, its own base frame) at pose k: its platform
pose through its own (calibrated) model, and the attachment's offset
(:func:`attachment_in_base`). The tracker, located in the cell frame, measures the point at
m_k (m, cell frame). The base pose T_cell_base = (R, p) minimises Σ_k |m_k − (p + R a_k)|²:
the closed-form rigid fit of :func:`positioning_cell.metrology.fit.weighted_kabsch` (Kabsch;
Arun et al. 1987), equal weights. Its first-order covariance
(:func:`positioning_cell.metrology.fit.rigid_fit_covariance`, rotation about the base
origin) is for isotropic reading noise ``sigma`` (m), scaled by the variance factor when the
residuals show more error than ``sigma`` explains (an error the model of the points does not
hold: a positioner's own calibration, a moved target). Fewer than three poses, or attachment
points on one line (the rotation about it is undetermined), are refused.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import (
    as_pose_batch,
    matrix_from_quaternion,
    quaternion_from_matrix,
)
from positioning_cell.errors import InputError
from positioning_cell.metrology.fit import rigid_fit_covariance, weighted_kabsch
from positioning_cell.metrology.targets import collinear

FloatArray = NDArray[np.float64]

#: Fewest poses that fix a base pose (three points not on one line).
MIN_POSES = 3


class BaseFit(NamedTuple):
    """A positioner's base in the cell frame: ``position`` (3,) m, ``quaternion`` (4,) x, y, z,
    w; ``covariance`` (6, 6) of (δp m, δθ rad about the cell axes at the base origin);
    ``residuals`` (K,) m of the points; ``variance_factor`` (residual variance over
    sigma², 1 when the noise explains them)."""

    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray
    residuals: FloatArray
    variance_factor: float

    @property
    def rms(self) -> float:
        """RMS of the residuals, m."""
        return float(np.sqrt(np.mean(self.residuals**2)))

    def to_cell(self, points_in_base: ArrayLike) -> FloatArray:
        """Points (K, 3) m of the positioner's base frame in the cell frame."""
        rotation = matrix_from_quaternion(self.quaternion[None])[0]
        out: FloatArray = np.asarray(points_in_base, dtype=float) @ rotation.T + self.position
        return out


def attachment_in_base(position: ArrayLike, quaternion: ArrayLike,
                       offset: ArrayLike) -> FloatArray:
    """The attachment point (K, 3) m in the positioner's base frame at its platform poses
    (K, 3) m, (K, 4): p + R·offset (``offset`` (3,) m, platform frame)."""
    p, q = as_pose_batch(position, quaternion)
    points: FloatArray = p + matrix_from_quaternion(q) @ np.asarray(offset, dtype=float)
    return points


def fit_base(in_base: ArrayLike, measured: ArrayLike, sigma: float) -> BaseFit:
    """The base pose from the attachment points ``in_base`` (K, 3) m (its base frame) and the
    tracker's ``measured`` points (K, 3) m (cell frame), reading noise ``sigma`` m (module
    docstring). InputError for shapes, non-finite values, sigma ≤ 0, fewer than
    :data:`MIN_POSES` poses or points on one line."""
    a = np.asarray(in_base, dtype=float)
    m = np.asarray(measured, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or m.shape != a.shape:
        raise InputError(f'in_base {a.shape} and measured {m.shape}: expected two (K, 3)')
    if not (np.isfinite(a).all() and np.isfinite(m).all()):
        raise InputError('in_base and measured: every coordinate must be finite')
    if not (np.isfinite(sigma) and sigma > 0.0):
        raise InputError(f'sigma = {sigma!r}: the reading noise must be a finite value > 0 m')
    if len(a) < MIN_POSES:
        raise InputError(f'{len(a)} poses: a base pose needs at least {MIN_POSES}')
    if collinear(a[None], np.ones((1, len(a)), dtype=bool))[0]:
        raise InputError(f'the {len(a)} attachment points lie on one line: the rotation about '
                         'it is undetermined (take poses off that line)')
    weight = np.ones((1, len(a)))
    rot, pos = weighted_kabsch(a, m[None], weight)
    residuals = np.linalg.norm(m - pos[0] - a @ rot[0].T, axis=1)
    dof = 3 * len(a) - 6
    factor = float(np.sum(residuals**2) / dof / sigma**2) if dof > 0 else 1.0
    point_cov = np.broadcast_to(sigma**2 * np.eye(3), (1, len(a), 3, 3))
    covariance = rigid_fit_covariance((a @ rot[0].T)[None], weight, point_cov)[0]
    return BaseFit(pos[0], quaternion_from_matrix(rot, orthonormal=True)[0],
                   covariance * max(factor, 1.0), residuals, factor)
