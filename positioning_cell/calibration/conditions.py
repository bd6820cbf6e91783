"""The conditions a pose is reached under, as the cell knows them: the measured air temperature
(°C) and the direction each axis last moved in (+1 increasing, −1 decreasing, 0 not known,
JOINT_NAMES order). A machine model's thermal and reversal terms depend on them
(:mod:`positioning_cell.calibration.machine`); calibration data carry them per pose
(:class:`~positioning_cell.calibration.identify.CalibrationData`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: Air temperatures the cell accepts, °C (a cell outside them is not a workshop).
TEMPERATURE_RANGE = (-20.0, 60.0)
#: The reference temperature of a model that was not identified over measured temperatures
#: (the ISO 1 reference temperature of dimensional metrology), °C.
STANDARD_TEMPERATURE = 20.0


def checked_temperature(value: ArrayLike | None, n: int, what: str = 'calibration data',
                        one_for_all: bool = False) -> FloatArray | None:
    """Temperatures (n,) °C as floats, or None (InputError naming ``what`` when of another
    shape, not finite or outside :data:`TEMPERATURE_RANGE`); ``one_for_all``: one value may
    stand for every pose."""
    if value is None:
        return None
    arr = np.asarray(value, dtype=float)
    if one_for_all and arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise InputError(f'{what} temperature has shape {arr.shape}, expected ({n},)')
    low, high = TEMPERATURE_RANGE
    if not np.all(np.isfinite(arr)) or np.any((arr < low) | (arr > high)):
        raise InputError(f'{what} temperature must be finite and within {low:g} to '
                         f'{high:g} degC')
    return arr


def checked_approach(value: ArrayLike | None, n: int, what: str = 'calibration data',
                     one_for_all: bool = False) -> FloatArray | None:
    """Approach signs (n, 6) as floats, or None (InputError naming ``what`` when of another
    shape or holding values other than −1, 0, +1); ``one_for_all``: one row (6,) may stand
    for every pose."""
    if value is None:
        return None
    arr = np.asarray(value, dtype=float)
    if one_for_all and arr.shape == (6,):
        arr = np.broadcast_to(arr, (n, 6)).copy()
    if arr.shape != (n, 6):
        raise InputError(f'{what} approach has shape {arr.shape}, expected ({n}, 6)')
    if not np.all(np.isin(arr, (-1.0, 0.0, 1.0))):
        raise InputError(f'{what} approach holds values other than -1, 0, +1')
    return arr


@dataclass(frozen=True)
class Conditions:
    """Conditions of N poses (module docstring): ``temperature`` (N,) or one value, °C (None:
    not known, taken as the model's reference temperature), ``approach`` (N, 6) or one row
    (6,) of −1/0/+1 (None: not known, taken as 0, the middle of a reversal band)."""

    temperature: ArrayLike | None = None
    approach: ArrayLike | None = None

    def temperature_change(self, n: int, reference: float) -> FloatArray:
        """Temperature minus ``reference`` (n,) K (zeros when not known)."""
        t = checked_temperature(self.temperature, n, 'conditions', one_for_all=True)
        return np.zeros(n) if t is None else t - reference

    def approach_signs(self, n: int) -> FloatArray:
        """Approach signs (n, 6) (zeros when not known)."""
        a = checked_approach(self.approach, n, 'conditions', one_for_all=True)
        return np.zeros((n, 6)) if a is None else a
