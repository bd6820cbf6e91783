"""The six encoders of the drives: Gaussian noise on the true position, quantisation to the
resolution, and dropouts (frozen or missing readings). Randomness only from the injected
generator. Units: m, rad."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.parameters import check_fields, setting
from positioning_cell.sim.axes import AXES, per_axis
from positioning_cell.sim.servo import AxisState

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class EncoderSettings:
    """The ``encoder:`` block: linear resolution, rotary counts per revolution, the standard
    deviations of the Gaussian noise (linear, rotary) and the seed of its generator."""

    linear_resolution: float = setting(1e-6, 'linear encoder resolution', 'm per count',
                                       low=1e-9, high=1e-3)
    rotary_counts_per_rev: int = setting(2**20, 'rotary encoder counts per revolution',
                                         low=16, high=2**31 - 1)
    linear_noise: float = setting(2e-7, 'linear noise sigma', 'm', low=0.0, high=1e-3)
    rotary_noise: float = setting(2e-6, 'rotary noise sigma', 'rad', low=0.0, high=0.1)
    seed: int = setting(0, 'seed of the noise generator', low=0, high=2**31 - 1)

    def __post_init__(self) -> None:
        check_fields(self)

    @cached_property
    def resolution(self) -> FloatArray:
        """One count (6,): m on the length axes, 2π / counts rad on the θ axes."""
        return per_axis(self.linear_resolution, 2.0 * math.pi / self.rotary_counts_per_rev)

    @cached_property
    def noise(self) -> FloatArray:
        """Noise standard deviation (6,), m and rad."""
        return per_axis(self.linear_noise, self.rotary_noise)


# -- encoders --------------------------------------------------------------------------------
def quantise(values: ArrayLike, resolution: ArrayLike) -> FloatArray:
    """``values`` rounded to whole counts of ``resolution`` (broadcast), same units."""
    res = np.asarray(resolution, dtype=float)
    counts = np.round(np.asarray(values, dtype=float) / res)
    result: FloatArray = counts * res
    return result

class EncoderReading(NamedTuple):
    """What the drives report: position (6,) quantised, velocity (6,) from the drives'
    velocity observer; frozen values on axes whose encoder dropped out, NaN if missing."""

    position: FloatArray
    velocity: FloatArray

class Encoders:
    """The six encoders: Gaussian noise (σ per axis, times a burst scale) added to the true
    position, then quantisation to the resolution. A dropped-out encoder repeats its last
    reading with zero velocity ('freeze', as a stalled count would) or reads NaN ('missing').
    Randomness only from the injected ``rng``."""

    def __init__(self, settings: EncoderSettings, rng: np.random.Generator) -> None:
        self.settings = settings
        self._rng = rng
        self._last: FloatArray | None = None

    def read(self, state: AxisState, *, dropout: BoolArray | None = None,
             missing: bool = False, noise_scale: float = 1.0) -> EncoderReading:
        """One reading of the true ``state``; ``dropout`` (6,) marks failed encoders."""
        noise = self._rng.standard_normal(AXES) * (self.settings.noise * noise_scale)
        position = quantise(state.position + noise, self.settings.resolution)
        velocity = state.velocity.copy()
        if dropout is not None and dropout.any():
            last = self._last if self._last is not None else position
            position = np.where(dropout, last, position)
            velocity[dropout] = 0.0
        self._last = position
        if missing and dropout is not None:
            position = np.where(dropout, np.nan, position)
            velocity[dropout] = np.nan
        return EncoderReading(position, velocity)
