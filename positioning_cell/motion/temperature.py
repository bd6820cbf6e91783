"""The positioner's view of the cell's air temperature: the latest good reading of the
temperature sensor, what the compensation uses when it is missing or stale, and how uncertain
that value is.

A reading is refused (and the previous one kept) when it is not finite or lies outside
:data:`~positioning_cell.calibration.conditions.TEMPERATURE_RANGE`. The value the compensation
uses at time t:

- **measured**: the latest reading, at most ``max_age`` old; its standard uncertainty the
  sensor's stated one (the message's variance), at least ``sensor_sigma``;
- **stale**: the latest reading, older than ``max_age``; its uncertainty widened by the drift
  the air may have had since, σ = √(σ_sensor² + (drift_rate · age)²), at most
  ``nominal_sigma`` (a long-unmeasured cell is no better known than the nominal);
- **nominal**: no reading yet: ``nominal`` with ``nominal_sigma``.

A stale or nominal value carries a reason naming it, for the diagnostics and the move's
outcome; the cell keeps working on it. Times are the caller's (monotonic seconds).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

from positioning_cell.calibration.conditions import TEMPERATURE_RANGE
from positioning_cell.names import AIR_TEMPERATURE
from positioning_cell.parameters import check_fields, setting


@dataclass(frozen=True)
class TemperatureSettings:
    """The ``compensation.temperature:`` block."""

    max_age: float = setting(10.0, 'a temperature reading older than this is stale', 's',
                             low=0.1, high=3600.0, dynamic=True)
    nominal: float = setting(20.0, 'air temperature assumed before any reading', 'degC',
                             low=TEMPERATURE_RANGE[0], high=TEMPERATURE_RANGE[1],
                             dynamic=True)
    nominal_sigma: float = setting(3.0, 'standard uncertainty of the nominal temperature (and '
                                   'the most a stale one is widened to)', 'K', low=0.0,
                                   low_open=True, high=50.0, dynamic=True)
    sensor_sigma: float = setting(0.1, 'standard uncertainty of a reading whose message states '
                                  'none (variance 0)', 'K', low=0.0, low_open=True, high=10.0,
                                  dynamic=True)
    drift_rate: float = setting(1.0 / 3600.0, 'how fast the air may drift while unmeasured '
                                '(widens a stale reading)', 'K/s', low=0.0, high=1.0,
                                dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)


class TemperatureState(Enum):
    """Where the temperature the compensation uses comes from (module docstring)."""

    MEASURED = 'measured'
    STALE = 'stale'
    NOMINAL = 'nominal'


class CellTemperature(NamedTuple):
    """The air temperature the compensation uses: ``value`` °C, its standard uncertainty
    ``sigma`` K, where it comes from, and a reason when it is not a fresh reading."""

    value: float
    sigma: float
    state: TemperatureState
    reason: str


class TemperatureInput:
    """The latest good temperature reading and the rules of the module docstring
    (thread-safe: readings and queries may come from different callbacks)."""

    def __init__(self, settings: TemperatureSettings) -> None:
        self.settings = settings
        self._lock = threading.Lock()
        self._reading: tuple[float, float, float] | None = None  # value, sigma, time
        self.refused = 0
        self.last_refusal = ''

    def update(self, value: float, variance: float, now: float) -> str:
        """Take a reading (°C, K², at ``now`` s); '' when taken, else the reason it was refused
        (the previous reading is kept)."""
        low, high = TEMPERATURE_RANGE
        if not (math.isfinite(value) and math.isfinite(variance)) or variance < 0.0:
            reason = f'air temperature {value!r} degC (variance {variance!r}) is not a number'
        elif not low <= value <= high:
            reason = f'air temperature {value:.2f} degC is outside {low:g} to {high:g} degC'
        else:
            sigma = max(math.sqrt(variance), self.settings.sensor_sigma)
            with self._lock:
                self._reading = (float(value), sigma, float(now))
            return ''
        with self._lock:
            self.refused += 1
            self.last_refusal = f'{reason}: refused, the previous reading kept'
        return self.last_refusal

    def current(self, now: float) -> CellTemperature:
        """The temperature to compensate with at ``now`` s (module docstring)."""
        s = self.settings
        with self._lock:
            reading = self._reading
        if reading is None:
            return CellTemperature(s.nominal, s.nominal_sigma, TemperatureState.NOMINAL,
                                   f'no air temperature received on {AIR_TEMPERATURE}: the '
                                   f'nominal {s.nominal:g} degC used (sigma '
                                   f'{s.nominal_sigma:g} K)')
        value, sigma, stamp = reading
        age = max(now - stamp, 0.0)
        if age <= s.max_age:
            return CellTemperature(value, sigma, TemperatureState.MEASURED, '')
        widened = min(math.hypot(sigma, s.drift_rate * age), max(s.nominal_sigma, sigma))
        return CellTemperature(value, widened, TemperatureState.STALE,
                               f'air temperature {age:.0f} s old (stale after {s.max_age:g} s):'
                               f' the last reading {value:.2f} degC used, sigma widened to '
                               f'{widened:.2f} K')
