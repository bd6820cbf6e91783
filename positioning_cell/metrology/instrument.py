"""The laser tracker as an instrument: its pose in the base frame, its datasheet accuracy, and
the conversions between its readings and base-frame points.

Frames: ``base`` (the cell); ``tracker`` (the instrument: origin at its gimbal point, z along
its standing axis; its pose in ``base`` is configured). SI units: m, rad.

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

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import Quad, Triple, as_unit_quaternions, matrix_from_quaternion
from positioning_cell.errors import InputError
from positioning_cell.parameters import ParameterError, check_fields, setting

FloatArray = NDArray[np.float64]


# -- instrument --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Tracker:
    """A laser tracker: its pose in the base frame and its datasheet accuracy.

    position (m) and orientation (unit quaternion x, y, z, w) place the tracker frame in
    ``base``; mpe_constant a (m) and mpe_proportional b (m per m of distance) give
    MPE(d) = a + b·d; coverage_factor k turns it into σ(d) = MPE(d) / k (module docstring).
    """

    position: Triple = setting((2.0, -1.0, 0.8), 'tracker origin in the base frame', 'm',
                               dynamic=True)
    orientation: Quad = setting((0.0, 0.0, 0.0, 1.0), 'tracker frame in base, unit quaternion '
                                'x, y, z, w', dynamic=True)
    mpe_constant: float = setting(15e-6, 'MPE(d) = a + b d: a', 'm', low=0.0, low_open=True,
                                  high=1e-3, dynamic=True)
    mpe_proportional: float = setting(6e-6, 'MPE(d) = a + b d: b', 'm/m', low=0.0, high=1e-3,
                                      dynamic=True)
    coverage_factor: float = setting(2.0, 'k: MPE = k sigma', low=0.5, high=6.0, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)
        try:
            as_unit_quaternions(self.orientation, 'orientation')
        except InputError as err:
            raise ParameterError('orientation', self.orientation,
                                 'must be a unit quaternion x, y, z, w') from err

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
