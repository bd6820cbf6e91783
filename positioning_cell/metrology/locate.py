"""Locating the tracker in the base frame ("locate instrument", as in SpatialAnalyzer): the
best-fit registration of the tracker frame onto base reference targets of known base
coordinates, from the tracker's readings of them, with its residuals and its covariance.

Frames: readings in ``tracker`` (Cartesian, m), reference targets and the located pose in
``base``; SI: m, rad.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import Triple, quaternion_from_matrix
from positioning_cell.errors import InputError
from positioning_cell.metrology.fit import rigid_fit_covariance, weighted_kabsch
from positioning_cell.metrology.instrument import Tracker, TrackerAccuracy
from positioning_cell.metrology.targets import MIN_LAYOUT_TARGETS, check_point_set, collinear
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

#: Default base reference targets, base frame (m): SMR nests on the positioner's base plate
#: and on two posts of the cell frame, around and above the workspace, not coplanar.
DEFAULT_BASE_TARGETS: tuple[Triple, ...] = (
    (0.25, 0.25, 0.0), (-0.25, 0.25, 0.0), (-0.25, -0.25, 0.0), (0.25, -0.25, 0.0),
    (0.30, 0.0, 0.40), (-0.30, 0.05, 0.35),
)

#: Fewest base targets a location may use (three fix the pose, the fourth checks it).
MIN_LOCATE_TARGETS = MIN_LAYOUT_TARGETS


class LocateError(InputError):
    """No registration: too few base targets read, or degenerate (collinear) ones."""


@dataclass(frozen=True)
class LocateSettings:
    """The ``locate:`` block: the base reference targets (known base coordinates) the tracker
    locates itself on, how many readings of each are averaged, and the residual that is
    reported as suspect."""

    base_targets: tuple[Triple, ...] = setting(
        DEFAULT_BASE_TARGETS, 'base reference targets x, y, z per target (>= 4, distinct, not '
        'collinear), base frame', 'm')
    samples: int = setting(20, 'readings of each base target averaged per location', low=1,
                           high=10000)
    residual_limit: float = setting(4.0, 'a located target residual beyond this many sigma '
                                    'is reported (warn)', low=0.5, high=1000.0)

    def __post_init__(self) -> None:
        check_fields(self)
        check_point_set('base_targets', self.base_targets, 'in the base frame')

    @cached_property
    def array(self) -> FloatArray:
        """The base targets (T, 3), m, base frame (read-only)."""
        arr = np.asarray(self.base_targets, dtype=float)
        arr.setflags(write=False)
        return arr


class Location(NamedTuple):
    """A located tracker.

    tracker: the registration (pose of the tracker in ``base`` with its 6 × 6 covariance,
    order δp m, δθ rad about the base axes at the tracker origin); residuals (T, 3) m, base:
    known base coordinates − located averaged reading (NaN where a target was not read);
    normalised (T,): each residual's Mahalanobis distance under the covariance of its averaged
    reading; samples (T,): readings averaged per target; rms, max (m): of |residual| over the
    targets used; variance_factor: χ² / (3 T − 6) of the residuals (about 1 when the noise is
    as stated; the covariance is scaled up by it when it is larger).
    """

    tracker: Tracker
    residuals: FloatArray
    normalised: FloatArray
    samples: IntArray
    rms: float
    max: float
    variance_factor: float

    @property
    def used(self) -> BoolArray:
        """Targets that were read (T,)."""
        used: BoolArray = self.samples > 0
        return used


def locate(accuracy: TrackerAccuracy, base_targets: ArrayLike, readings: ArrayLike) -> Location:
    """The best-fit tracker pose in ``base`` from readings (T, 3) or (N, T, 3) m, tracker frame
    (NaN rows: not read), of base targets (T, 3) m with known base coordinates.

    The N readings of each target are averaged (a mean reading of n_i samples has the
    covariance Σ_i / n_i of :meth:`TrackerAccuracy.local_covariance`); the rigid transform
    taking the mean readings onto the base coordinates is the weighted Kabsch fit of
    :func:`positioning_cell.metrology.fit.weighted_kabsch` with w_i = 3 / tr(Σ_i / n_i). Its
    covariance is first order (:func:`positioning_cell.metrology.fit.rigid_fit_covariance`,
    rotation about the located tracker origin), scaled by the variance factor when the
    residuals show more error than the averaged noise explains (a systematic error of the
    instrument or a moved target: averaging does not remove it). Fewer than
    :data:`MIN_LOCATE_TARGETS` targets read, or collinear ones, raise :class:`LocateError`.
    """
    base = np.asarray(base_targets, dtype=float)
    if base.ndim != 2 or base.shape[1] != 3 or not np.all(np.isfinite(base)):
        raise LocateError(f'base_targets: expected finite rows (T, 3), got shape {base.shape}')
    arr = np.asarray(readings, dtype=float)
    arr = arr[np.newaxis] if arr.ndim == 2 else arr
    if arr.ndim != 3 or arr.shape[1:] != base.shape:
        raise LocateError(f'readings: expected shape {base.shape} or (N, {len(base)}, 3) for '
                          f'the {len(base)} base targets, got {np.shape(readings)}')
    if np.any(np.isinf(arr)):
        raise LocateError('readings: infinite coordinates (mark a target not read with NaN)')
    read = np.all(np.isfinite(arr), axis=-1)
    samples = read.sum(axis=0)
    used = samples > 0
    if used.sum() < MIN_LOCATE_TARGETS:
        raise LocateError(f'{int(used.sum())} of {len(base)} base targets read; locating the '
                          f'tracker needs at least {MIN_LOCATE_TARGETS}')
    if collinear(base[None], used[None])[0]:
        raise LocateError(f'the {int(used.sum())} base targets read lie on one line: the '
                          'rotation about it is undetermined')
    count = np.maximum(samples, 1)
    mean = np.where(used[:, None], np.where(read[..., None], arr, 0.0).sum(axis=0)
                    / count[:, None], 0.0)
    local_cov = accuracy.local_covariance(np.where(used[:, None], mean, [1.0, 0.0, 0.0]))
    local_cov /= count[:, None, None]
    weight = np.where(used, 3.0 / np.trace(local_cov, axis1=-2, axis2=-1), 0.0)
    rot, pos = weighted_kabsch(mean, base[None], weight[None])
    rot, pos = rot[0], pos[0]
    point_cov = rot @ local_cov @ rot.T  # covariance of the located readings, base frame
    residual = base - (mean @ rot.T + pos)
    chi2_each = np.einsum('ti,tij,tj->t', residual, np.linalg.inv(point_cov), residual)
    dof = 3 * int(used.sum()) - 6
    variance_factor = float(np.sum(chi2_each[used]) / dof)
    cov = rigid_fit_covariance((base - pos)[None], weight[None], point_cov[None])[0]
    cov *= max(1.0, variance_factor)
    q = quaternion_from_matrix(rot[None], orthonormal=True)[0]  # rot: an SVD's, orthonormal
    tracker = Tracker(accuracy, tuple(pos), tuple(q), cov)
    norms = np.linalg.norm(residual[used], axis=-1)
    return Location(tracker, np.where(used[:, None], residual, np.nan),
                    np.where(used, np.sqrt(chi2_each), np.nan), samples.astype(np.int64),
                    float(np.sqrt(np.mean(norms**2))), float(norms.max()), variance_factor)
