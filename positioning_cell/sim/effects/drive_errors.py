"""Errors of the drives between the motor (whose encoder the cell reads) and the real axis:
the ball screw's cumulative lead error (a scale of the travel) and its periodic error over one
pitch, the θ axes' scale error, and each axis's reversal error (lost motion): the real axis
lags the motor by half the band in the direction it last moved in (hysteresis).

Per leg: l_real = l + s·(l − l_ref) + a·sin(2π (l − l_ref)/p + φ) − d·b/2, with s the lead
scale, a and p the periodic amplitude and pitch, φ its phase, d = ±1 the approach direction
(0: unknown, the middle of the band) and b the reversal band; per θ axis:
θ_real = θ + s_θ·θ − d·b_θ/2. Lengths in m, angles in rad; l_ref is the home length (a
constant part of the lead error is an encoder zero, absorbed by calibration). Sizes: ISO
3408-3 lead accuracy classes (class 5: e_300 = 23 µm per 300 mm, ±30 ppm drawn), the
periodic (wobble) error over one revolution v_2π of a class 3-5 screw (≈ 1-2 µm), the lost
motion of a preloaded nut and its bearings (3-8 µm) and of a strain-wave gear with motor
(≈ 10-30 µrad, Harmonic Drive CSF lost-motion data)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from positioning_cell.parameters import check_fields, setting
from positioning_cell.sim.effects import check_ordered

FloatArray = NDArray[np.float64]
Pair = tuple[float, float]


@dataclass(frozen=True)
class DriveErrorParameters:
    """The ``truth.drives`` block: drive errors, drawn per axis from ``seed`` (module
    docstring)."""

    enabled: bool = setting(False, 'simulate the drive errors')
    seed: int = setting(0, 'seed of the drawn drive errors', low=0, high=2**31 - 1)
    lead_error_sigma: float = setting(15.0, 'sigma of the drawn lead (travel scale) error of '
                                      'each ball screw', 'ppm', low=0.0, high=1000.0)
    screw_pitch: float = setting(0.005, 'ball-screw lead (periodic error period)', 'm',
                                 low=0.0, low_open=True, high=0.1)
    periodic_amplitude: float = setting(1.5e-6, 'amplitude of the periodic lead error', 'm',
                                        low=0.0, high=1e-4)
    length_reversal: Pair = setting((3e-6, 8e-6), 'range of the drawn reversal band of a leg '
                                    '(lost motion), uniform', 'm', low=0.0, high=1e-3)
    theta_scale_sigma: float = setting(20.0, 'sigma of the drawn scale error of a theta '
                                       'axis', 'ppm', low=0.0, high=1000.0)
    theta_reversal: Pair = setting((1e-5, 3e-5), 'range of the drawn reversal band of a '
                                   'theta axis, uniform', 'rad', low=0.0, high=0.01)

    def __post_init__(self) -> None:
        check_fields(self)
        check_ordered('length_reversal', self.length_reversal)
        check_ordered('theta_reversal', self.theta_reversal)

    def draw(self, reference_length: float) -> DriveErrors:
        """The drive errors of one machine (seeded)."""
        rng = np.random.default_rng(self.seed)
        lead = rng.normal(0.0, self.lead_error_sigma * 1e-6, 3)
        phase = rng.uniform(0.0, 2.0 * np.pi, 3)
        band = rng.uniform(*self.length_reversal, 3)
        theta_scale = rng.normal(0.0, self.theta_scale_sigma * 1e-6, 3)
        theta_band = rng.uniform(*self.theta_reversal, 3)
        return DriveErrors(lead, self.screw_pitch, self.periodic_amplitude, phase, band,
                           theta_scale, theta_band, reference_length)


@dataclass(frozen=True)
class DriveErrors:
    """One machine's drive errors: lead scale (3,), screw pitch m, periodic amplitude m and
    phase (3,) rad, leg reversal band (3,) m, θ scale (3,), θ reversal band (3,) rad, and the
    reference length l_ref m of the lead error (module docstring)."""

    lead_scale: FloatArray
    pitch: float
    amplitude: float
    phase: FloatArray
    length_band: FloatArray
    theta_scale: FloatArray
    theta_band: FloatArray
    reference_length: float

    @property
    def bands(self) -> FloatArray:
        """The reversal bands (6,): legs m, then θ rad (full widths)."""
        return np.concatenate([self.length_band, self.theta_band])

    def actual(self, lengths: FloatArray, thetas: FloatArray,
               approach: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Real leg lengths (N, 3) m and θ (N, 3) rad of axes whose motors stand at
        ``lengths``, ``thetas`` (encoder zero offsets applied), approached from ``approach``
        (N, 6) ±1, 0 unknown (module docstring)."""
        travel = lengths - self.reference_length
        real_l = (lengths + self.lead_scale * travel
                  + self.amplitude * np.sin(2.0 * np.pi * travel / self.pitch + self.phase)
                  - 0.5 * approach[:, :3] * self.length_band)
        real_t = thetas + self.theta_scale * thetas - 0.5 * approach[:, 3:] * self.theta_band
        return real_l, real_t
