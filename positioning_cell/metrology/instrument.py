"""The laser tracker as an instrument: its datasheet accuracy (:class:`TrackerAccuracy`, the
``tracker:`` parameters), the instrument placed in the base frame by a registration
(:class:`Tracker`), and the conversions between its readings and base-frame points.

Frames: ``base`` (the cell); ``tracker`` (the instrument: origin at its gimbal point, z along
its standing axis). A reading is a point in the tracker frame (Cartesian, m; the instrument
measures it as range r, azimuth az = atan2(y, x) and elevation el above its xy-plane). The
tracker's pose in ``base`` is not known to the cell: it *locates* the instrument from readings
of base reference targets (:mod:`.locate`), and that registration, with its uncertainty, turns
readings into base-frame points. SI units: m, rad.

Error model (how the datasheet's MPEs become a covariance)
----------------------------------------------------------
A tracker datasheet in ISO 10360-10:2021 Annex D style states a maximum permissible error per
*channel*: the absolute distance meter along the line of sight, e_ADM(r) = a_r + b_r·r (e.g.
±10 µm + 0.3 µm/m), and the transverse error from the angle encoders and the beam's pointing,
e_T(r) = a_t + b_t·r (e.g. ±15 µm + 6 µm/m), at distance r; "typical" values are half the MPE.
So an MPE is read as a coverage interval with factor k (``coverage_factor``, default 2, ≈ 95 %
of normal errors within it): σ_r(r) = e_ADM(r) / k along the beam and σ_t(r) = e_T(r) / k in
each of the two directions across it. In reading channels: σ(r) = σ_r, σ(el) = σ_t / r,
σ(az) = σ_t / (r·cos el) (an azimuth error moves the point by r·cos el·δaz). The channels are
independent and normal, so to first order a reading has the covariance
Σ = U·diag(σ_r², σ_t², σ_t²)·Uᵀ, U = (beam, azimuth, elevation directions): a cigar across
the line of sight (σ_t ≈ 2.7 σ_r at 2.5 m), rotated into ``base`` by the registration.

That is the random part, what averaging removes. A real tracker also has a systematic part
that averaging cannot remove: the range scale follows the refractive index of the air, about
−1 ppm per K of air-temperature error, so a whole run is scaled by a few ppm; and residual
angular errors (e.g. the vertical index) offset the angles by a few µrad. These belong to the
simulation's truth (``truth.tracker.*``, :mod:`positioning_cell.sim.tracker`); the cell's
model states the datasheet covariance above plus the registration's own uncertainty
(:meth:`Tracker.registration_covariance`), which the located residuals judge.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import as_unit_quaternions, matrix_from_quaternion
from positioning_cell.errors import InputError
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]


# -- the datasheet ------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackerAccuracy:
    """The ``tracker:`` block: datasheet MPEs of the two channels, MPE(r) = a + b·r (m, r in
    m), and the coverage factor k, σ = MPE / k (module docstring)."""

    range_mpe_constant: float = setting(10e-6, 'ADM (range) MPE = a + b r: a', 'm', low=0.0,
                                        low_open=True, high=1e-3, dynamic=True)
    range_mpe_proportional: float = setting(0.3e-6, 'ADM (range) MPE = a + b r: b', 'm/m',
                                            low=0.0, high=1e-3, dynamic=True)
    transverse_mpe_constant: float = setting(15e-6, 'transverse (angular) MPE = a + b r: a',
                                             'm', low=0.0, low_open=True, high=1e-3,
                                             dynamic=True)
    transverse_mpe_proportional: float = setting(6e-6, 'transverse (angular) MPE = a + b r: b',
                                                 'm/m', low=0.0, high=1e-3, dynamic=True)
    coverage_factor: float = setting(2.0, 'k: MPE = k sigma', low=0.5, high=6.0, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)

    def range_sigma(self, distance: ArrayLike) -> FloatArray:
        """σ_r(r) (m) along the line of sight at distances r (m), any shape."""
        r = np.asarray(distance, dtype=float)
        sigma: FloatArray = (self.range_mpe_constant + self.range_mpe_proportional * r) \
            / self.coverage_factor
        return sigma

    def transverse_sigma(self, distance: ArrayLike) -> FloatArray:
        """σ_t(r) (m) in each direction across the line of sight at distances r (m)."""
        r = np.asarray(distance, dtype=float)
        sigma: FloatArray = (self.transverse_mpe_constant
                             + self.transverse_mpe_proportional * r) / self.coverage_factor
        return sigma

    def reading_sigma(self, spherical: ArrayLike) -> FloatArray:
        """Standard deviations (..., 3) of the channels r (m), az, el (rad) at readings
        (..., 3) r, az, el: σ_r, σ_t / (r·cos el), σ_t / r."""
        s = np.asarray(spherical, dtype=float)
        r, el = s[..., 0], s[..., 2]
        transverse = self.transverse_sigma(r)
        return np.stack([self.range_sigma(r),
                         transverse / (r * np.maximum(np.cos(el), 1e-9)), transverse / r],
                        axis=-1)

    def local_covariance(self, local: ArrayLike) -> FloatArray:
        """First-order covariance (..., 3, 3) m² of readings (..., 3) m, tracker frame:
        J·diag(σ_r², σ_az², σ_el²)·Jᵀ with J = ∂point/∂(r, az, el)."""
        s = spherical_from_local(local)
        r, az, el = s[..., 0], s[..., 1], s[..., 2]
        ca, sa, ce, se = np.cos(az), np.sin(az), np.cos(el), np.sin(el)
        zero = np.zeros_like(r)
        jac = np.stack([  # columns ∂/∂r, ∂/∂az, ∂/∂el
            np.stack([ce * ca, -r * ce * sa, -r * se * ca], axis=-1),
            np.stack([ce * sa, r * ce * ca, -r * se * sa], axis=-1),
            np.stack([se, zero, r * ce], axis=-1)], axis=-2)
        variance = self.reading_sigma(s) ** 2
        out: FloatArray = (jac * variance[..., None, :]) @ np.swapaxes(jac, -1, -2)
        return out


def spherical_from_local(local: ArrayLike) -> FloatArray:
    """Readings (..., 3) r (m), az, el (rad) of tracker-frame points (..., 3) m."""
    p = np.asarray(local, dtype=float)
    horizontal = np.hypot(p[..., 0], p[..., 1])
    return np.stack([np.linalg.norm(p, axis=-1), np.arctan2(p[..., 1], p[..., 0]),
                     np.arctan2(p[..., 2], horizontal)], axis=-1)


def local_from_spherical(spherical: ArrayLike) -> FloatArray:
    """Tracker-frame points (..., 3) m of readings (..., 3) r, az, el (inverse of
    :func:`spherical_from_local`)."""
    s = np.asarray(spherical, dtype=float)
    r, az, el = s[..., 0], s[..., 1], s[..., 2]
    out: FloatArray = r[..., None] * np.stack([np.cos(el) * np.cos(az),
                                               np.cos(el) * np.sin(az), np.sin(el)], axis=-1)
    return out


# -- the instrument in the base frame -----------------------------------------------------------
@dataclass(frozen=True)
class Tracker:
    """The tracker placed in ``base``: its ``accuracy``, its pose (``position`` m of its origin,
    ``orientation`` unit quaternion x, y, z, w of its axes) and the 6 × 6 ``covariance`` of
    that pose (None: taken as exact), order δp (m), δθ (rad, small rotation about the base
    axes: R = exp([δθ]×)·R_true), the rotation about the tracker origin. For the cell this is
    a located registration (:func:`positioning_cell.metrology.locate.locate`); only a
    simulator places one at its true pose."""

    accuracy: TrackerAccuracy
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    covariance: FloatArray | None = None

    def __post_init__(self) -> None:
        position = np.asarray(self.position, dtype=float)
        if position.shape != (3,) or not np.all(np.isfinite(position)):
            raise InputError(f'tracker position: expected 3 finite numbers, got '
                             f'{self.position!r}')
        quaternion = as_unit_quaternions(self.orientation, 'tracker orientation')[0]
        object.__setattr__(self, 'position', tuple(float(v) for v in position))
        object.__setattr__(self, 'orientation', tuple(float(v) for v in quaternion))
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=float)
            if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
                raise InputError('tracker covariance: expected a finite 6 x 6 matrix')
            cov.setflags(write=False)
            object.__setattr__(self, 'covariance', cov)

    @cached_property
    def rotation(self) -> FloatArray:
        """R_base_tracker (3, 3): tracker axes as columns in the base frame."""
        matrix: FloatArray = matrix_from_quaternion(as_unit_quaternions(self.orientation))[0]
        matrix.setflags(write=False)
        return matrix

    def to_local(self, points: ArrayLike) -> FloatArray:
        """Tracker-frame points (..., 3) m of base-frame points (..., 3) m."""
        out: FloatArray = (np.asarray(points, dtype=float) - np.asarray(self.position)) \
            @ self.rotation
        return out

    def to_base(self, local: ArrayLike) -> FloatArray:
        """Base-frame points (..., 3) m of tracker-frame readings (..., 3) m."""
        out: FloatArray = np.asarray(local, dtype=float) @ self.rotation.T \
            + np.asarray(self.position)
        return out

    def spherical(self, points: ArrayLike) -> FloatArray:
        """Readings (..., 3) r (m), az, el (rad) of base-frame points (..., 3) m."""
        return spherical_from_local(self.to_local(points))

    def points(self, spherical: ArrayLike) -> FloatArray:
        """Base-frame points (..., 3) m of readings (..., 3) r, az, el."""
        return self.to_base(local_from_spherical(spherical))

    def distance(self, points: ArrayLike) -> FloatArray:
        """Range (...,) m from the tracker origin to base-frame points (..., 3) m."""
        out: FloatArray = np.linalg.norm(np.asarray(points, dtype=float)
                                         - np.asarray(self.position), axis=-1)
        return out

    def point_covariance(self, points: ArrayLike) -> FloatArray:
        """Datasheet covariance (..., 3, 3) m² of the reading of each base-frame point
        (..., 3), in ``base`` (:meth:`TrackerAccuracy.local_covariance` rotated)."""
        local = self.accuracy.local_covariance(self.to_local(points))
        out: FloatArray = self.rotation @ local @ self.rotation.T
        return out

    @property
    def registration(self) -> Registration | None:
        """This registration as the cell publishes it (None without a covariance)."""
        if self.covariance is None:
            return None
        return Registration(np.asarray(self.position, dtype=float), self.covariance)

    def registration_covariance(self, position: ArrayLike) -> FloatArray:
        """Covariance (N, 6, 6) that this registration's own uncertainty adds to rigid-body
        poses at positions (N, 3) m (:func:`registration_covariance`; zero without a
        covariance)."""
        p = np.atleast_2d(np.asarray(position, dtype=float))
        if self.covariance is None:
            return np.zeros((len(p), 6, 6))
        return registration_covariance(self.position, self.covariance, p)


def registration_jacobian(tracker_position: ArrayLike, position: ArrayLike) -> FloatArray:
    """J (N, 6, 6): how a registration's error (δp m, δθ rad about the base axes at the tracker
    origin ``tracker_position`` (3,) m, or one per pose (N, 3), base frame) moves the measured
    rigid-body poses at positions (N, 3) m (order x, y, z, rot-x, rot-y, rot-z). Every point
    moves by δp + δθ × (x − p_tracker), so J = [[I, −[p − p_tracker]×], [0, I]]."""
    p = np.atleast_2d(np.asarray(position, dtype=float))
    jac = np.broadcast_to(np.eye(6), (len(p), 6, 6)).copy()
    jac[:, :3, 3:] = -skew(p - np.asarray(tracker_position, dtype=float))
    return jac


def registration_covariance(tracker_position: ArrayLike, covariance: ArrayLike,
                            position: ArrayLike) -> FloatArray:
    """Covariance (N, 6, 6) that a registration's uncertainty ``covariance`` (6, 6: δp m, δθ
    rad about the base axes at the tracker origin ``tracker_position`` (3,) m, base frame)
    adds to rigid-body poses at positions (N, 3) m: J·Σ·Jᵀ with J of
    :func:`registration_jacobian`; fully correlated between readings: averaging does not
    reduce it."""
    jac = registration_jacobian(tracker_position, position)
    out: FloatArray = jac @ np.asarray(covariance, dtype=float) @ np.swapaxes(jac, 1, 2)
    return out


class Registration(NamedTuple):
    """A located tracker as the cell's other nodes receive it (/metrology/registration): the
    ``position`` (3,) m of its origin in ``base`` and the ``covariance`` (6, 6) of the
    registration (δp m, δθ rad about the base axes at that origin), the part of every
    reading's stated covariance that is common to all readings."""

    position: FloatArray
    covariance: FloatArray

    @classmethod
    def checked(cls, position: ArrayLike, covariance: ArrayLike) -> Registration:
        """A registration from a received position (3,) m and covariance (36,) or (6, 6);
        InputError unless the position is finite and the covariance finite, symmetric, with
        a non-negative diagonal."""
        p = np.asarray(position, dtype=float).reshape(-1)
        cov = np.asarray(covariance, dtype=float)
        if p.shape != (3,) or cov.size != 36:
            raise InputError(f'tracker registration: expected a position (3,) and a 6 x 6 '
                             f'covariance, got {p.shape} and {cov.shape}')
        cov = cov.reshape(6, 6)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(cov))
                and np.all(np.diag(cov) >= 0.0) and np.allclose(cov, cov.T, rtol=1e-9, atol=0.0)):
            raise InputError('tracker registration: expected a finite position and a finite, '
                             'symmetric covariance with a non-negative diagonal')
        return cls(p, cov)

    def covariance_at(self, position: ArrayLike) -> FloatArray:
        """:func:`registration_covariance` (N, 6, 6) at platform positions (N, 3) m."""
        return registration_covariance(self.position, self.covariance, position)


def averaged_covariance(mean_covariance: ArrayLike, common: ArrayLike,
                        samples: int) -> FloatArray:
    """Covariance (..., 6, 6) of the mean of ``samples`` readings whose stated covariances
    average ``mean_covariance`` (..., 6, 6) and share the part ``common`` (..., 6, 6) (the
    tracker's registration): common + (C̄ − common) / samples
    (:func:`positioning_cell.moves.correction.mean_reading`, a calibration pose)."""
    mean_cov = np.asarray(mean_covariance, dtype=float)
    shared = np.asarray(common, dtype=float)
    if shared.shape[-2:] != (6, 6) or not np.all(np.isfinite(shared)):
        raise InputError(f'common covariance: expected a finite 6 x 6 matrix, got shape '
                         f'{shared.shape}')
    if samples < 1:
        raise InputError(f'samples: expected at least 1, got {samples}')
    out: FloatArray = shared + (mean_cov - shared) / samples
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def skew(v: ArrayLike) -> FloatArray:
    """[v]× (..., 3, 3) of vectors (..., 3): [v]× w = v × w."""
    a = np.asarray(v, dtype=float)
    out = np.zeros((*a.shape, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -a[..., 2], a[..., 1], -a[..., 0]
    out -= np.swapaxes(out, -1, -2)
    return out
