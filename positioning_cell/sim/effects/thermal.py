"""Temperature of the cell and the machine: the air drifting over a shift, the legs warming
above it while their drives work, the expansion of the legs, base and platform from the
20 °C reference (ISO 1), the cell's air-temperature sensor with its own error, and the laser
tracker's range scale following the air (refraction).

Air (°C) at time t (s since start): T_air(t) = T_0 + r·t/3600 + n(t), with n a seeded sum of
four sinusoids of periods drawn log-uniformly within ``noise_periods``, RMS ``air_noise``.
Legs: each leg's excess over the air obeys dΔ/dt = −Δ/τ plus a step h·|δl| per travel δl of
its screw (first order: friction heat of the nut and bearings per metre travelled), so after
travels d_j at times t_j, Δ(t) = Δ(t_0) e^{−(t−t_0)/τ} + h Σ d_j e^{−(t−t_j)/τ}.
Expansion: a leg's length between its joint centres scales by 1 + α_l (T_leg − 20), the base
and platform joint circles by 1 + α (T_air − 20) (joint-centre offsets α ΔT·A_i, α ΔT·b_i).
Tracker: a range r is read as r·(1 + k (T_air − T_used)·1e-6), k ≈ −0.95 ppm/K (Edlén 1966
dispersion of air, 1 K ↔ ≈ 1 ppm), T_used what the tracker's weather correction assumes.
Sensor: T_read = T_air + o + noise, o drawn once (a calibrated Pt100 class AA: ±0.1 K)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.parameters import check_fields, setting
from positioning_cell.sim.effects import check_ordered

FloatArray = NDArray[np.float64]

#: Reference temperature of dimensional metrology (ISO 1), °C.
REFERENCE_TEMPERATURE = 20.0
_NOISE_COMPONENTS = 4


@dataclass(frozen=True)
class ThermalParameters:
    """The ``truth.thermal`` block: the cell's air, the legs' heating, the expansion of the
    machine and the air-temperature sensor's error (module docstring)."""

    enabled: bool = setting(False, 'simulate temperature (drift, heating, expansion, '
                            'refraction, sensor)')
    seed: int = setting(0, 'seed of the air noise and the sensor offset', low=0,
                        high=2**31 - 1)
    air_start: float = setting(20.5, 'air temperature at the start', 'degC', low=0.0,
                               high=40.0)
    air_drift: float = setting(0.75, 'air temperature drift', 'K/h', low=-10.0, high=10.0)
    air_noise: float = setting(0.1, 'RMS of the slow air-temperature noise', 'K', low=0.0,
                               high=5.0)
    noise_periods: tuple[float, float] = setting((600.0, 7200.0), 'range of the noise '
                                                 'periods', 's', low=1.0, high=1e6)
    leg_heating: float = setting(0.15, 'leg warming per metre its screw travels', 'K/m',
                                 low=0.0, high=100.0)
    time_constant: float = setting(1200.0, 'leg cooling time constant', 's', low=1.0,
                                   high=1e6)
    leg_expansion: float = setting(11.5e-6, 'linear expansion of a leg (steel)', '1/K',
                                   low=0.0, high=1e-4)
    base_expansion: float = setting(23e-6, 'linear expansion of the base (aluminium)', '1/K',
                                    low=0.0, high=1e-4)
    platform_expansion: float = setting(23e-6, 'linear expansion of the platform '
                                        '(aluminium)', '1/K', low=0.0, high=1e-4)
    refraction: float = setting(-0.95, 'tracker range scale per K of air-temperature error',
                                'ppm/K', low=-10.0, high=10.0)
    sensor_offset_sigma: float = setting(0.1, 'sigma of the drawn offset of the air-'
                                         'temperature sensor', 'K', low=0.0, high=5.0)
    sensor_noise: float = setting(0.02, 'noise of one air-temperature reading', 'K', low=0.0,
                                  high=5.0)

    def __post_init__(self) -> None:
        check_fields(self)
        check_ordered('noise_periods', self.noise_periods)

    def draw(self) -> Thermal:
        """The thermal behaviour of one cell (seeded)."""
        rng = np.random.default_rng(self.seed)
        low, high = np.log(self.noise_periods)
        periods = np.exp(rng.uniform(low, high, _NOISE_COMPONENTS))
        phases = rng.uniform(0.0, 2.0 * np.pi, _NOISE_COMPONENTS)
        offset = float(rng.normal(0.0, self.sensor_offset_sigma))
        return Thermal(self, periods, phases, offset)


@dataclass(frozen=True)
class Thermal:
    """One cell's temperatures (module docstring): its ``parameters``, the drawn noise
    ``periods`` (s) and ``phases`` (rad), and the sensor's ``sensor_offset`` (K)."""

    parameters: ThermalParameters
    periods: FloatArray
    phases: FloatArray
    sensor_offset: float

    def air(self, time: ArrayLike) -> FloatArray:
        """True air temperature (N,) °C at times (N,) s since the start."""
        t = np.asarray(time, dtype=float)
        p = self.parameters
        waves = np.sin(2.0 * np.pi * t[..., None] / self.periods + self.phases)
        noise = p.air_noise * np.sqrt(2.0 / _NOISE_COMPONENTS) * waves.sum(axis=-1)
        out: FloatArray = p.air_start + p.air_drift * t / 3600.0 + noise
        return out

    def sensor(self, time: ArrayLike, rng: np.random.Generator) -> FloatArray:
        """Readings (N,) °C of the air-temperature sensor at times (N,) s (its offset and
        noise)."""
        t = np.asarray(time, dtype=float)
        out: FloatArray = (self.air(t) + self.sensor_offset
                           + rng.standard_normal(t.shape) * self.parameters.sensor_noise)
        return out

    def heating(self, excess: FloatArray, start: float, time: FloatArray,
                travel: FloatArray) -> FloatArray:
        """Leg excess temperatures (N, 3) K over the air at times (N,) s (ascending, from
        ``start``): ``excess`` (3,) K at ``start``, then the travels (N, 3) m done just
        before each time (module docstring; vectorised, spans up to ~500 time constants)."""
        tau = self.parameters.time_constant
        t = np.asarray(time, dtype=float)
        last = t[-1] if t.size else start
        weights = np.exp((t - last) / tau)[:, None]
        summed = np.cumsum(self.parameters.leg_heating * np.abs(travel) * weights, axis=0)
        out: FloatArray = (summed / weights
                           + np.asarray(excess)[None, :] * np.exp(-(t - start) / tau)[:, None])
        return out

    def expanded_lengths(self, lengths: FloatArray, leg_temperature: FloatArray) -> FloatArray:
        """Leg lengths (N, 3) m between the joint centres at leg temperatures (N, 3) °C."""
        delta = leg_temperature - REFERENCE_TEMPERATURE
        out: FloatArray = lengths * (1.0 + self.parameters.leg_expansion * delta)
        return out

    def joint_offsets(self, base_joints: FloatArray, platform_joints: FloatArray,
                      air: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Offsets of the U centres (N, 3, 3) m, base frame, and of the S centres (N, 3, 3)
        m, platform frame, of joint circles expanded at air temperatures (N,) °C."""
        delta = (np.asarray(air, dtype=float) - REFERENCE_TEMPERATURE)[:, None, None]
        p = self.parameters
        return (p.base_expansion * delta * base_joints[None],
                p.platform_expansion * delta * platform_joints[None])

    def range_scale_ppm(self, air: ArrayLike, used: ArrayLike) -> FloatArray:
        """Tracker range scale error (N,) ppm of air temperatures (N,) °C against those the
        tracker's correction uses."""
        out: FloatArray = self.parameters.refraction * (np.asarray(air, dtype=float)
                                                        - np.asarray(used, dtype=float))
        return out
