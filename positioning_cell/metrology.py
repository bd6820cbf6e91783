"""Simulated laser tracker: the machine's truth, the tracker's readings of the platform's
targets (SMRs), the outlier-robust rigid fit of the platform pose and its covariance.

Frames: ``base`` (the cell); ``tracker`` (the instrument: origin at its gimbal point, z along
its standing axis; its pose in ``base`` is configured); ``platform`` (the target layout is given
there). SI units throughout: m, rad. Batches: N poses, T targets.

Noise model (how the datasheet's MPE becomes standard deviations)
----------------------------------------------------------------
A tracker datasheet states one maximum permissible error for a measured point coordinate,
MPE(d) = a + b·d at distance d, e.g. ±(15 µm + 6 µm/m) (ISO 10360-10 / ASME B89.4.19 style),
and manufacturers quote "typical" values as half the MPE. So the MPE is read as a coverage
interval with factor k = 2 (≈ 95 % of readings of a normal error within it):
σ(d) = MPE(d) / k, k = ``coverage_factor``. Because the figure is for a point coordinate in
any direction, not for one instrument channel, each of the three directions of a reading gets
the same σ(d): the range (line of sight) σ_r = σ(d); the elevation angle σ_el = σ(d) / d; the
azimuth angle σ_az = σ(d) / (d·cos el), since an azimuth error moves the point by d·cos el·δaz.
The three channels are independent and normal, so to first order a measured point has the
isotropic covariance σ(d)²·I, in any frame.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance import ClearanceModel, attained_pose, model_from_params
from positioning_cell.config import flatten
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.kinematics import ForwardResult
from positioning_cell.mechanism import Mechanism
from positioning_cell.poses import (
    as_pose_batch,
    as_unit_quaternions,
    matrix_from_quaternion,
    quaternion_from_matrix,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
Triple = tuple[float, float, float]

#: Default SMR layout, platform frame (m): a 0.30 m × 0.20 m panel fixture on the platform with
#: a 1.5" SMR at each corner 30 mm above the platform plane, and one on a 100 mm tower over the
#: platform origin, so the five are not coplanar.
DEFAULT_TARGETS: tuple[Triple, ...] = (
    (0.15, 0.10, 0.03), (-0.15, 0.10, 0.03), (-0.15, -0.10, 0.03), (0.15, -0.10, 0.03),
    (0.0, 0.0, 0.10),
)
#: Fewest targets a layout must have (the issue: at least four), and a fit needs.
MIN_LAYOUT_TARGETS = 4
MIN_FIT_TARGETS = 3
#: A target whose residual exceeds this many σ(d) is rejected as an outlier (for an inlier
#: |e|²/σ² is about χ² with < 3 degrees of freedom: P(|e| > 5σ) < 2e-5).
DEFAULT_REJECT_THRESHOLD = 5.0
#: Two targets closer than this (m) are one target; an SMR is 38.1 mm across.
_MIN_TARGET_SEPARATION = 1e-3
#: Relative spread below which a set of targets counts as collinear (pose undetermined).
_COLLINEAR = 1e-6


class TooFewTargetsError(InputError):
    """A fit with fewer than three usable (visible, non-collinear) targets: no pose."""


# -- instrument --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Tracker:
    """A laser tracker: its pose in the base frame and its datasheet accuracy.

    position (m) and orientation (unit quaternion x, y, z, w) place the tracker frame in
    ``base``; mpe_constant a (m) and mpe_proportional b (m per m of distance) give
    MPE(d) = a + b·d; coverage_factor k turns it into σ(d) = MPE(d) / k (module docstring).
    """

    position: Triple = (2.0, -1.0, 0.8)
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    mpe_constant: float = 15e-6
    mpe_proportional: float = 6e-6
    coverage_factor: float = 2.0

    def __post_init__(self) -> None:
        if len(self.position) != 3 or not all(math.isfinite(v) for v in self.position):
            raise ConfigError(f'tracker.position = {self.position!r}: expected 3 finite m')
        try:
            as_unit_quaternions(self.orientation, 'tracker.orientation')
        except InputError as err:
            raise ConfigError(str(err) + ' (x, y, z, w)') from err
        checks = (('mpe_constant', 0.0, False), ('mpe_proportional', 0.0, True),
                  ('coverage_factor', 0.0, False))
        for name, low, inclusive in checks:
            value = getattr(self, name)
            ok = math.isfinite(value) and (value >= low if inclusive else value > low)
            if not ok:
                relation = '>=' if inclusive else '>'
                raise ConfigError(f'tracker.{name} = {value!r}: must be finite and {relation} 0')

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Tracker:
        """From a ``tracker.*`` block (nested or dotted keys; missing keys keep the defaults);
        unknown keys and bad values raise ConfigError naming them."""
        flat = {k.removeprefix('tracker.'): v for k, v in flatten(params).items()}
        kwargs: dict[str, Any] = {}
        for key, value in flat.items():
            if key in ('position', 'orientation'):
                kwargs[key] = _numbers(f'tracker.{key}', value, 3 if key == 'position' else 4)
            elif key in ('mpe_constant', 'mpe_proportional', 'coverage_factor'):
                kwargs[key] = _number(f'tracker.{key}', value)
            else:
                raise ConfigError(f'tracker: unknown parameter {key!r}')
        return cls(**kwargs)

    @cached_property
    def rotation(self) -> FloatArray:
        """R_base_tracker (3, 3): tracker axes as columns in the base frame."""
        matrix: FloatArray = matrix_from_quaternion(as_unit_quaternions(self.orientation))[0]
        matrix.setflags(write=False)
        return matrix

    def mpe(self, distance: ArrayLike) -> FloatArray:
        """MPE(d) = a + b·d (m) at distances d (m), any shape."""
        return self.mpe_constant + self.mpe_proportional * np.asarray(distance, dtype=float)

    def sigma(self, distance: ArrayLike) -> FloatArray:
        """σ(d) = MPE(d) / k (m): standard deviation of a point coordinate at distance d."""
        sigma: FloatArray = self.mpe(distance) / self.coverage_factor
        return sigma

    def spherical(self, points: ArrayLike) -> FloatArray:
        """Readings (..., 3) range r (m), azimuth az = atan2(y, x) and elevation el above the
        tracker's xy-plane (rad), in the tracker frame, of base-frame points (..., 3) m."""
        local = (np.asarray(points, dtype=float) - np.asarray(self.position)) @ self.rotation
        horizontal = np.hypot(local[..., 0], local[..., 1])
        return np.stack([np.linalg.norm(local, axis=-1),
                         np.arctan2(local[..., 1], local[..., 0]),
                         np.arctan2(local[..., 2], horizontal)], axis=-1)

    def points(self, spherical: ArrayLike) -> FloatArray:
        """Base-frame points (..., 3) m of readings (..., 3) r, az, el (inverse of
        :meth:`spherical`)."""
        s = np.asarray(spherical, dtype=float)
        r, az, el = s[..., 0], s[..., 1], s[..., 2]
        local = r[..., None] * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                         np.sin(el)], axis=-1)
        out: FloatArray = local @ self.rotation.T + np.asarray(self.position)
        return out

    def reading_sigma(self, spherical: ArrayLike) -> FloatArray:
        """Standard deviations (..., 3) of the readings r (m), az, el (rad) at readings
        (..., 3): σ(r), σ(r) / (r·cos el), σ(r) / r (module docstring)."""
        s = np.asarray(spherical, dtype=float)
        r, el = s[..., 0], s[..., 2]
        sigma = self.sigma(r)
        return np.stack([sigma, sigma / (r * np.maximum(np.cos(el), 1e-9)), sigma / r], axis=-1)

    def point_covariance(self, points: ArrayLike) -> FloatArray:
        """First-order covariance (..., 3, 3) m² of measured base-frame points (..., 3):
        J·diag(σ_r², σ_az², σ_el²)·Jᵀ with J = ∂point/∂(r, az, el), rotated into ``base``."""
        s = self.spherical(points)
        r, az, el = s[..., 0], s[..., 1], s[..., 2]
        ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
        zero = np.zeros_like(r)
        jac_local = np.stack([  # columns ∂/∂r, ∂/∂az, ∂/∂el in the tracker frame
            np.stack([ce * ca, -r * ce * sa, -r * se * ca], axis=-1),
            np.stack([ce * sa, r * ce * ca, -r * se * sa], axis=-1),
            np.stack([se, zero, r * ce], axis=-1)], axis=-2)
        jac = self.rotation @ jac_local
        variance = self.reading_sigma(s) ** 2
        out: FloatArray = (jac * variance[..., None, :]) @ np.swapaxes(jac, -1, -2)
        return out


@dataclass(frozen=True)
class TargetLayout:
    """Targets (SMRs) fixed to the platform: centres in the platform frame, rows (T, 3), m.
    At least four, distinct, not all on one line (default :data:`DEFAULT_TARGETS`)."""

    points: tuple[Triple, ...] = DEFAULT_TARGETS

    def __post_init__(self) -> None:
        arr = np.asarray(self.points, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != 3 or not np.all(np.isfinite(arr)):
            raise ConfigError(f'targets = {self.points!r}: expected rows of 3 finite m')
        if arr.shape[0] < MIN_LAYOUT_TARGETS:
            raise ConfigError(f'targets: {arr.shape[0]} given, the tracker needs at least '
                              f'{MIN_LAYOUT_TARGETS} targets on the platform')
        gaps = np.linalg.norm(arr[:, None] - arr[None], axis=-1) + np.eye(len(arr))
        if gaps.min() < _MIN_TARGET_SEPARATION:
            i, j = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
            raise ConfigError(f'targets {i} and {j} are {gaps[i, j]:.3g} m apart: '
                              f'targets must be >= {_MIN_TARGET_SEPARATION} m apart')
        if _collinear(arr[None], np.ones((1, len(arr)), dtype=bool))[0]:
            raise ConfigError('targets all lie on one line: they cannot fix a rotation')

    @classmethod
    def from_flat(cls, values: ArrayLike) -> TargetLayout:
        """From 3·T numbers x1, y1, z1, x2, ... (m, platform frame): the parameter form."""
        arr = np.asarray(_numbers('targets.platform', values, None), dtype=float)
        if arr.size % 3:
            raise ConfigError(f'targets.platform: {arr.size} numbers, expected 3 per target')
        return cls(tuple((float(x), float(y), float(z)) for x, y, z in arr.reshape(-1, 3)))

    @cached_property
    def array(self) -> FloatArray:
        """The targets (T, 3), m, platform frame (read-only)."""
        arr = np.asarray(self.points, dtype=float)
        arr.setflags(write=False)
        return arr

    def in_base(self, position: FloatArray, quaternion: FloatArray) -> FloatArray:
        """Target centres (N, T, 3) m in ``base`` for validated platform poses (N, 3), (N, 4)."""
        rot = matrix_from_quaternion(quaternion)
        out: FloatArray = position[:, None, :] + self.array @ np.swapaxes(rot, -1, -2)
        return out


@dataclass(frozen=True)
class Faults:
    """Simulated measurement faults, independent per target and reading: a target is hidden
    (line of sight blocked) with occlusion_probability; a visible reading is an outlier with
    outlier_probability: its point is displaced by outlier_magnitude (m) in a random direction
    (a mis-seated SMR, a beam re-acquired on a wrong reflector)."""

    occlusion_probability: float = 0.0
    outlier_probability: float = 0.0
    outlier_magnitude: float = 1e-3

    def __post_init__(self) -> None:
        for name in ('occlusion_probability', 'outlier_probability'):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f'fault.{name} = {value!r}: must be a probability in [0, 1]')
        if not (math.isfinite(self.outlier_magnitude) and self.outlier_magnitude >= 0.0):
            raise ConfigError(f'fault.outlier_magnitude = {self.outlier_magnitude!r}: '
                              'must be a finite length >= 0 m')


# -- measurement -------------------------------------------------------------------------------
class Measurement(NamedTuple):
    """Readings of N poses: points (N, T, 3) m in ``base``, NaN where hidden; visible (N, T);
    outlier (N, T): the simulator's truth about which readings it corrupted."""

    points: FloatArray
    visible: BoolArray
    outlier: BoolArray


def measure(tracker: Tracker, layout: TargetLayout, position: ArrayLike, quaternion: ArrayLike,
            rng: np.random.Generator, faults: Faults | None = None) -> Measurement:
    """Simulated readings of the targets of N platform poses (N, 3) m, (N, 4) x, y, z, w.

    Each visible target's reading (r, az, el) gets independent normal noise of
    :meth:`Tracker.reading_sigma`; then occlusion and outliers per ``faults``. The same number
    of draws is taken whatever the fault settings, so a seeded stream stays aligned.
    """
    faults = faults or Faults()
    p, q = as_pose_batch(position, quaternion)
    true_points = layout.in_base(p, q)
    readings = tracker.spherical(true_points)
    if np.any(readings[..., 0] <= 0.0):
        raise InputError('a target coincides with the tracker position: no reading')
    noisy = readings + rng.standard_normal(readings.shape) * tracker.reading_sigma(readings)
    points = tracker.points(noisy)
    shape = readings.shape[:-1]
    hidden = rng.random(shape) < faults.occlusion_probability
    wild = (rng.random(shape) < faults.outlier_probability) & ~hidden
    direction = rng.standard_normal(readings.shape)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    points = np.where(wild[..., None], points + faults.outlier_magnitude * direction, points)
    points[hidden] = np.nan
    return Measurement(points, ~hidden, wild)


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

    Minimises Σ w_i |m_i − (p + R·b_i)|² with w_i = 1 / σ(d_i)²: the maximum-likelihood pose
    for the isotropic noise of this tracker model, solved in closed form by SVD (weighted
    Kabsch / Arun et al. 1987, det-corrected). Outliers: while some inlier's residual |e_i| / σ_i
    exceeds ``reject_threshold`` and more than three inliers remain, the target whose removal
    leaves the smallest weighted residual sum of squares is dropped and the pose refitted.
    Fewer than three visible targets, or collinear ones, raise :class:`TooFewTargetsError`.
    The covariance is first order (:func:`pose_covariance`).
    """
    if not (math.isfinite(reject_threshold) and reject_threshold > 0.0):
        raise InputError(f'reject_threshold = {reject_threshold!r}: must be finite and > 0')
    arr = _measured_points(points, len(layout.points))
    visible = np.all(np.isfinite(arr), axis=-1)
    _require_targets(layout.array, visible, 'visible')
    measured = np.where(visible[..., None], arr, 0.0)
    sigma = tracker.sigma(np.linalg.norm(measured - np.asarray(tracker.position), axis=-1))
    weight = np.where(visible, 1.0 / sigma**2, 0.0)
    inliers = visible.copy()
    rows = np.arange(arr.shape[0])
    for _ in range(len(layout.points)):  # at most T − 3 rejections, then one confirming pass
        rot, pos = _weighted_kabsch(layout.array, measured, weight * inliers)
        error = np.linalg.norm(measured - pos[:, None] - layout.array @ np.swapaxes(rot, 1, 2),
                               axis=-1)
        normalised = np.where(inliers, error / sigma, -np.inf)
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
    quaternion = quaternion_from_matrix(rot)
    rms = np.sqrt(np.sum(np.where(inliers, error**2, 0.0), axis=1) / inliers.sum(axis=1))
    covariance = pose_covariance(tracker, layout, pos, quaternion, inliers)
    return PoseFit(pos, quaternion, covariance, np.where(visible, error, np.nan), visible,
                   inliers, rms)


def pose_covariance(tracker: Tracker, layout: TargetLayout, position: ArrayLike,
                    quaternion: ArrayLike, used: ArrayLike | None = None) -> FloatArray:
    """First-order covariance (N, 6, 6) of the weighted fit of the ``used`` targets (N, T)
    (default all) at platform poses (N, 3) m, (N, 4), order x, y, z, rot-x, rot-y, rot-z.

    A target at c_i = R·b_i moves by δm_i = J_i·(δp, δθ) with J_i = [I, −[c_i]×] (small
    rotation δθ about the base axes). The weighted least-squares estimate then has
    δx = A⁻¹ Σ w_i J_iᵀ δm_i, A = Σ w_i J_iᵀ J_i, so cov = A⁻¹ (Σ w_i² J_iᵀ Σ_i J_i) A⁻¹
    with Σ_i = :meth:`Tracker.point_covariance` (equal to A⁻¹ for this isotropic model).
    """
    p, q = as_pose_batch(position, quaternion)
    targets = layout.in_base(p, q)
    mask = (np.ones(targets.shape[:2], dtype=bool) if used is None
            else np.broadcast_to(np.asarray(used, dtype=bool), targets.shape[:2]))
    sigma = tracker.sigma(np.linalg.norm(targets - np.asarray(tracker.position), axis=-1))
    weight = np.where(mask, 1.0 / sigma**2, 0.0)
    c = targets - p[:, None, :]
    skew = np.zeros((*c.shape, 3))
    skew[..., 0, 1], skew[..., 0, 2], skew[..., 1, 2] = -c[..., 2], c[..., 1], -c[..., 0]
    skew -= np.swapaxes(skew, -1, -2)
    jac = np.concatenate([np.broadcast_to(np.eye(3), skew.shape), -skew], axis=-1)  # (N,T,3,6)
    jac_t = np.swapaxes(jac, -1, -2)
    normal = np.einsum('nt,ntij->nij', weight, jac_t @ jac)
    middle = np.einsum('nt,ntij->nij', weight**2,
                       jac_t @ tracker.point_covariance(targets) @ jac)
    normal_inv = np.linalg.inv(normal)
    cov: FloatArray = normal_inv @ middle @ normal_inv
    return 0.5 * (cov + np.swapaxes(cov, -1, -2))


def observe(tracker: Tracker, layout: TargetLayout, position: ArrayLike, quaternion: ArrayLike,
            rng: np.random.Generator, faults: Faults | None = None, *,
            reject_threshold: float = DEFAULT_REJECT_THRESHOLD) -> tuple[Measurement, PoseFit]:
    """One tracker cycle for N true poses: :func:`measure`, then :func:`fit_pose`."""
    measurement = measure(tracker, layout, position, quaternion, rng, faults)
    return measurement, fit_pose(tracker, layout, measurement.points,
                                 reject_threshold=reject_threshold)


# -- truth -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Truth:
    """The simulated machine as it really is: ``mechanism`` with its joint-centre geometric
    errors, and its joint ``clearance`` (None: none). The positioner never sees it."""

    mechanism: Mechanism = field(default_factory=Mechanism.default)
    clearance: ClearanceModel = None

    def attained_pose(self, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """True platform poses for actual joints: lengths (N, 3) m, thetas (N, 3) rad;
        ``phi0`` the previous passive angles (branch continuity), see clearance.attained_pose."""
        return attained_pose(self.mechanism, self.clearance, lengths, thetas, phi0)


def truth_from_params(params: Mapping[str, Any], mech: Mechanism) -> Truth:
    """The truth from a ``truth.*`` block (nested or dotted keys) over the nominal ``mech``.

    ``clearance.*``: as :func:`clearance.model_from_params` (model effective_length | vector |
    none, r_a, r_b, optional directions/offsets) with directions not given drawn from
    ``numpy.random.default_rng(clearance.seed)``, so a compensation block with the same keys and
    seed reproduces the same draws. ``base_offsets`` / ``platform_offsets``: 9 numbers each (m;
    base / platform frame, default zeros), geometric errors of the U / S joint centres added to
    the nominal model's own offsets (Mechanism.with_offsets).
    """
    flat = {k.removeprefix('truth.'): v for k, v in flatten(params).items() if v is not None}
    offsets = {}
    for key in ('base_offsets', 'platform_offsets'):
        value = flat.pop(key, [0.0] * 9)
        arr = np.asarray(_numbers(f'truth.{key}', value, 9), dtype=float).reshape(3, 3)
        offsets[key] = np.asarray(getattr(mech, key)) + arr
    block = {}
    for key, value in flat.items():
        if not key.startswith('clearance.'):
            raise ConfigError(f'truth: unknown parameter {key!r}')
        block[key] = value
    seed = block.get('clearance.seed')
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise ConfigError(f'truth.clearance.seed = {seed!r}: expected an integer >= 0')
    rng = None if seed is None else np.random.default_rng(seed)
    try:
        model = model_from_params(block, mech, rng=rng)
    except ConfigError as err:
        raise ConfigError(f'truth.{err}') from err
    return Truth(mech.with_offsets(offsets['base_offsets'], offsets['platform_offsets']), model)


@dataclass(frozen=True)
class Simulation:
    """Everything the pose_measurement parameters configure: the truth, the tracker, the
    target layout, the faults and the fit's outlier threshold (validated)."""

    truth: Truth = field(default_factory=Truth)
    tracker: Tracker = field(default_factory=Tracker)
    layout: TargetLayout = field(default_factory=TargetLayout)
    faults: Faults = field(default_factory=Faults)
    reject_threshold: float = DEFAULT_REJECT_THRESHOLD

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Simulation:
        """From the node's parameters (nested or dotted; config/cell.yaml ``pose_measurement``):
        ``mechanism.*`` (the nominal machine), ``truth.*`` (:func:`truth_from_params`),
        ``tracker.*`` (:meth:`Tracker.from_params`), ``targets.platform`` (3·T numbers, m),
        ``fault.*`` (:class:`Faults`), ``fit.reject_threshold``. Unset values (None) and missing
        keys keep the defaults; other keys (the node's rates and seed) are not read here."""
        flat = {k: v for k, v in flatten(params).items() if v is not None}

        def block(prefix: str) -> dict[str, Any]:
            return {k[len(prefix) + 1:]: v for k, v in flat.items() if k.startswith(prefix + '.')}

        mech = Mechanism.from_params(block('mechanism'))
        faults = block('fault')
        unknown = set(faults) - {'occlusion_probability', 'outlier_probability',
                                 'outlier_magnitude'}
        if unknown:
            raise ConfigError(f'fault: unknown parameter(s) {sorted(unknown)}')
        layout = (TargetLayout.from_flat(flat['targets.platform'])
                  if 'targets.platform' in flat else TargetLayout())
        threshold = _number('fit.reject_threshold',
                            flat.get('fit.reject_threshold', DEFAULT_REJECT_THRESHOLD))
        if not (math.isfinite(threshold) and threshold > 0.0):
            raise ConfigError(f'fit.reject_threshold = {threshold!r}: must be finite and > 0')
        return cls(truth_from_params(block('truth'), mech), Tracker.from_params(block('tracker')),
                   layout, Faults(**{k: _number(f'fault.{k}', v) for k, v in faults.items()}),
                   threshold)


# -- helpers -----------------------------------------------------------------------------------
def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f'{name} = {value!r}: expected a number')
    return float(value)


def _numbers(name: str, value: Any, count: int | None) -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError) as err:
        raise ConfigError(f'{name} = {value!r}: expected numbers') from err
    if isinstance(value, (str, bytes)) or (count is not None and arr.size != count):
        raise ConfigError(f'{name} = {value!r}: expected {count} numbers')
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f'{name} = {value!r}: numbers must be finite')
    return tuple(float(v) for v in arr)


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
    line = _collinear(np.broadcast_to(body, (*mask.shape, 3)), mask)
    if line.any():
        i = int(np.flatnonzero(line)[0])
        raise TooFewTargetsError(f'reading {i}: the {counts[i]} {what} targets lie on one '
                                 'line; their rotation about it is undetermined')


def _collinear(points: FloatArray, mask: BoolArray) -> BoolArray:
    """True per row where the masked points (N, T, 3) span less than a plane."""
    w = mask / mask.sum(axis=1, keepdims=True)
    centred = (points - np.einsum('nt,ntk->nk', w, points)[:, None]) * np.sqrt(w)[..., None]
    s = np.linalg.svd(centred, compute_uv=False)
    result: BoolArray = s[:, 1] <= _COLLINEAR * s[:, 0]
    return result


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
    usable = inliers.ravel() & ~_collinear(np.broadcast_to(body, (n * t, t, 3)),
                                           keep.reshape(n * t, t))
    cost = np.full(n * t, np.inf)
    if usable.any():
        rot, pos = _weighted_kabsch(body, cand_measured[usable], cand_weight[usable])
        error = cand_measured[usable] - pos[:, None] - body @ np.swapaxes(rot, 1, 2)
        cost[usable] = np.sum(cand_weight[usable] * np.sum(error**2, axis=-1), axis=1)
    return cost.reshape(n, t)


def _weighted_kabsch(body: FloatArray, measured: FloatArray,
                     weight: FloatArray) -> tuple[FloatArray, FloatArray]:
    """R (N, 3, 3) and p (N, 3) minimising Σ w_i |m_i − (p + R·b_i)|² for body points (T, 3)
    and measured points (N, T, 3) with weights (N, T)."""
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

