"""The outlier-robust rigid fit of the platform pose to the tracker's readings of its targets,
and its first-order covariance; the weighted rigid fit (Kabsch) and its covariance are shared
with locating the tracker (:mod:`.locate`). Frames: readings and poses in ``base`` (converted
with the tracker's located registration), targets in ``platform``; SI: m, rad."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import as_pose_batch, quaternion_from_matrix
from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import Tracker, skew
from positioning_cell.metrology.targets import TargetLayout, collinear
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

MIN_FIT_TARGETS = 3

#: A target whose residual exceeds this many σ(d) is rejected as an outlier (for an inlier
#: |e|²/σ² is about χ² with < 3 degrees of freedom: P(|e| > 5σ) < 2e-5).
DEFAULT_REJECT_THRESHOLD = 5.0

class TooFewTargetsError(InputError):
    """A fit with fewer than three usable (visible, non-collinear) targets: no pose."""


@dataclass(frozen=True)
class FitSettings:
    """The ``fit:`` block: outlier rejection of the pose fit (dynamic)."""

    reject_threshold: float = setting(DEFAULT_REJECT_THRESHOLD, 'reject a target whose '
                                      'residual exceeds this many sigma', low=1.0, high=1000.0,
                                      dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)


# -- fit ---------------------------------------------------------------------------------------
class PoseFit(NamedTuple):
    """Fitted platform poses of N readings.

    position (N, 3) m and quaternion (N, 4) x, y, z, w in ``base``; covariance (N, 6, 6) in the
    geometry_msgs/PoseWithCovariance order x, y, z, rot-x, rot-y, rot-z (m², m·rad, rad²), the
    rotations small angles about the fixed base axes: R_fit = exp([δθ]×)·R_true;
    residuals (N, T) m: |measured − fitted target| (NaN where hidden); visible and inliers
    (N, T); rms (N,) m: root mean square residual of the inliers.
    """

    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray
    residuals: FloatArray
    visible: BoolArray
    inliers: BoolArray
    rms: FloatArray

    @property
    def rejected(self) -> NDArray[np.int64]:
        """Targets rejected as outliers per reading (N,)."""
        count: NDArray[np.int64] = np.sum(self.visible & ~self.inliers, axis=1)
        return count

def fit_pose(tracker: Tracker, layout: TargetLayout, points: ArrayLike, *,
             reject_threshold: float = DEFAULT_REJECT_THRESHOLD) -> PoseFit:
    """Least-squares rigid fit of the layout onto measured points (T, 3) or (N, T, 3) m in
    ``base`` (NaN rows: hidden targets), robust to outliers.

    Minimises Σ w_i |m_i − (p + R·b_i)|² with w_i = 1 / σ̄_i², σ̄_i² = tr Σ_i / 3 the
    reading's mean variance (Σ_i = :meth:`Tracker.point_covariance`), in closed form by SVD
    (:func:`weighted_kabsch`); for the anisotropic noise this is not quite the
    maximum-likelihood pose, and the covariance is that of this estimator
    (:func:`pose_covariance`). Outliers: while some inlier's residual |e_i| / σ̄_i exceeds
    ``reject_threshold`` (the metric of the weights: a Mahalanobis distance under Σ_i would
    count the transverse noise the fit spreads along other beams) and more than three
    inliers remain, the target whose removal leaves the smallest weighted residual sum of
    squares is dropped and the pose refitted. Fewer than three visible targets, or collinear
    ones, raise :class:`TooFewTargetsError`.
    """
    if not (math.isfinite(reject_threshold) and reject_threshold > 0.0):
        raise InputError(f'reject_threshold = {reject_threshold!r}: must be finite and > 0')
    arr = _measured_points(points, len(layout.platform))
    visible = np.all(np.isfinite(arr), axis=-1)
    _require_targets(layout.array, visible, 'visible')
    measured = np.where(visible[..., None], arr, 0.0)
    point_cov = tracker.point_covariance(np.where(visible[..., None], arr,
                                                  tracker.to_base([1.0, 0.0, 0.0])))
    mean_sigma = np.sqrt(np.trace(point_cov, axis1=-2, axis2=-1) / 3.0)
    weight = np.where(visible, 1.0 / mean_sigma**2, 0.0)
    inliers = visible.copy()
    rows = np.arange(arr.shape[0])
    for _ in range(len(layout.platform)):  # at most T − 3 rejections, then one confirming pass
        rot, pos = weighted_kabsch(layout.array, measured, weight * inliers)
        error = np.linalg.norm(measured - pos[:, None] - layout.array @ np.swapaxes(rot, 1, 2),
                               axis=-1)
        normalised = np.where(inliers, error / mean_sigma, -np.inf)
        drop = (normalised.max(axis=1) > reject_threshold) & (inliers.sum(axis=1) > 3)
        if not drop.any():
            break
        drop_rows = rows[drop]
        cost = _deletion_cost(layout.array, measured[drop_rows], weight[drop_rows],
                              inliers[drop_rows])
        best = np.argmin(cost, axis=1)
        found = np.isfinite(cost[np.arange(len(best)), best])
        if not found.any():
            break
        inliers[drop_rows[found], best[found]] = False
    _require_targets(layout.array, inliers, 'inlier')
    quaternion = quaternion_from_matrix(rot, orthonormal=True)  # Kabsch: R = V·D·Uᵀ
    rms = np.sqrt(np.sum(np.where(inliers, error**2, 0.0), axis=1) / inliers.sum(axis=1))
    covariance = pose_covariance(tracker, layout, pos, quaternion, inliers)
    return PoseFit(pos, quaternion, covariance, np.where(visible, error, np.nan), visible,
                   inliers, rms)

def pose_covariance(tracker: Tracker, layout: TargetLayout, position: ArrayLike,
                    quaternion: ArrayLike, used: ArrayLike | None = None) -> FloatArray:
    """First-order covariance (N, 6, 6) of the fitted pose from the ``used`` targets (N, T)
    (default all) at platform poses (N, 3) m, (N, 4), order x, y, z, rot-x, rot-y, rot-z:
    the reading noise of the fit (:func:`rigid_fit_covariance` with the weights of
    :func:`fit_pose` and Σ_i = :meth:`Tracker.point_covariance`) plus the uncertainty of the
    tracker's registration (:meth:`Tracker.registration_covariance`), which is common to all
    targets and readings."""
    p, q = as_pose_batch(position, quaternion)
    targets = layout.in_base(p, q)
    mask = (np.ones(targets.shape[:2], dtype=bool) if used is None
            else np.broadcast_to(np.asarray(used, dtype=bool), targets.shape[:2]))
    point_cov = tracker.point_covariance(targets)
    weight = np.where(mask, 3.0 / np.trace(point_cov, axis1=-2, axis2=-1), 0.0)
    return (rigid_fit_covariance(targets - p[:, None, :], weight, point_cov)
            + tracker.registration_covariance(p))


def rigid_fit_covariance(lever: FloatArray, weight: FloatArray,
                         point_cov: FloatArray) -> FloatArray:
    """First-order covariance (N, 6, 6) of the rigid motion (δp, δθ) fitted by
    :func:`weighted_kabsch` with weights (N, T) to points with covariances (N, T, 3, 3) m²,
    at levers c_i (N, T, 3) m from the point the rotation is taken about.

    A point moves by δm_i = J_i·(δp, δθ) with J_i = [I, −[c_i]×] (small rotation δθ about the
    base axes). The weighted least-squares estimate has δx = A⁻¹ Σ w_i J_iᵀ δm_i,
    A = Σ w_i J_iᵀ J_i, so cov = A⁻¹ (Σ w_i² J_iᵀ Σ_i J_i) A⁻¹ (the sandwich: exact for any
    weights, A⁻¹ itself only for w_i Σ_i = I).
    """
    cross = skew(lever)
    jac = np.concatenate([np.broadcast_to(np.eye(3), cross.shape), -cross], axis=-1)
    jac_t = np.swapaxes(jac, -1, -2)  # (N, T, 6, 3)
    normal = np.einsum('nt,ntij->nij', weight, jac_t @ jac)
    middle = np.einsum('nt,ntij->nij', weight**2, jac_t @ point_cov @ jac)
    normal_inv = np.linalg.inv(normal)
    cov: FloatArray = normal_inv @ middle @ normal_inv
    return 0.5 * (cov + np.swapaxes(cov, -1, -2))

def _measured_points(points: ArrayLike, count: int) -> FloatArray:
    try:
        arr = np.asarray(points, dtype=float)
    except (TypeError, ValueError) as err:
        raise InputError(f'points: expected numbers, got {points!r}') from err
    if arr.ndim == 2:
        arr = arr[np.newaxis]
    if arr.ndim != 3 or arr.shape[1:] != (count, 3):
        raise InputError(f'points: expected shape ({count}, 3) or (N, {count}, 3) for the '
                         f'{count} targets, got {np.shape(points)}')
    if np.any(np.isinf(arr)):
        raise InputError('points: infinite coordinates (mark a hidden target with NaN)')
    return arr

def _require_targets(body: FloatArray, mask: BoolArray, what: str) -> None:
    counts = mask.sum(axis=1)
    few = counts < MIN_FIT_TARGETS
    if few.any():
        i = int(np.flatnonzero(few)[0])
        raise TooFewTargetsError(f'reading {i}: {counts[i]} of {mask.shape[1]} targets {what}; '
                                 f'a pose needs at least {MIN_FIT_TARGETS}')
    line = collinear(np.broadcast_to(body, (*mask.shape, 3)), mask)
    if line.any():
        i = int(np.flatnonzero(line)[0])
        raise TooFewTargetsError(f'reading {i}: the {counts[i]} {what} targets lie on one '
                                 'line; their rotation about it is undetermined')

def _deletion_cost(body: FloatArray, measured: FloatArray, weight: FloatArray,
                   inliers: BoolArray) -> FloatArray:
    """For each inlier k of each row (n, T): the weighted residual sum of squares Σ w_i e_i²
    of the fit without target k (inf where k is no inlier or the rest is collinear). Dropping
    the target whose removal fits the rest best resists the masking a single least-squares
    residual suffers with few targets."""
    n, t = inliers.shape
    keep = inliers[:, None, :] & ~np.eye(t, dtype=bool)  # (n, candidate k, T)
    cand_weight = (weight[:, None, :] * keep).reshape(n * t, t)
    cand_measured = np.repeat(measured, t, axis=0)
    usable = inliers.ravel() & ~collinear(np.broadcast_to(body, (n * t, t, 3)),
                                           keep.reshape(n * t, t))
    cost = np.full(n * t, np.inf)
    if usable.any():
        rot, pos = weighted_kabsch(body, cand_measured[usable], cand_weight[usable])
        error = cand_measured[usable] - pos[:, None] - body @ np.swapaxes(rot, 1, 2)
        cost[usable] = np.sum(cand_weight[usable] * np.sum(error**2, axis=-1), axis=1)
    return cost.reshape(n, t)

def weighted_kabsch(body: FloatArray, measured: FloatArray,
                    weight: FloatArray) -> tuple[FloatArray, FloatArray]:
    """R (N, 3, 3) and p (N, 3) minimising Σ w_i |m_i − (p + R·b_i)|² for body points (T, 3)
    and measured points (N, T, 3) with weights (N, T): closed form by SVD of the weighted
    cross-covariance (Kabsch; Arun et al. 1987), det-corrected to a proper rotation."""
    w = weight / weight.sum(axis=1, keepdims=True)
    body_mean = w @ body
    measured_mean = np.einsum('nt,ntk->nk', w, measured)
    cross = np.einsum('nt,ntj,ntk->njk', w, body[None] - body_mean[:, None],
                      measured - measured_mean[:, None])
    u, _, vt = np.linalg.svd(cross)
    v = np.swapaxes(vt, 1, 2)
    fix = np.ones((len(w), 3))
    fix[:, 2] = np.sign(np.linalg.det(v @ np.swapaxes(u, 1, 2)))
    rot: FloatArray = (v * fix[:, None, :]) @ np.swapaxes(u, 1, 2)
    pos: FloatArray = measured_mean - np.einsum('nij,nj->ni', rot, body_mean)
    return rot, pos
