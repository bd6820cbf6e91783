"""The conditions the positioner compensates under, as it knows them: the measured air
temperature (:mod:`positioning_cell.motion.temperature`) and the direction each axis last
moved in, applied to the calibrated machine's thermal and reversal terms
(:class:`~positioning_cell.calibration.machine.MachineModel`), and the warnings a move earns
when it leaves what the calibration was identified over (its validity envelope,
:mod:`positioning_cell.calibration.envelope`) or compensates with a stale or nominal
temperature. Warnings never refuse a move; they are said in its outcome and in the
positioner's diagnostics.

Approach: a move's joint targets are first computed with the previous approach; each axis
whose target differs from its encoder reading by more than :data:`APPROACH_DEADBAND` takes
the sign of that difference (an axis that does not move keeps the direction it last moved
in), and the targets are computed again with it. A reversing axis thus gets the reversal band
as a step at the start of its trajectory, as a backlash compensation does.
"""

from __future__ import annotations

import threading

import numpy as np
from numpy.typing import NDArray

from positioning_cell.calibration.calibrated import Calibrated
from positioning_cell.calibration.conditions import Conditions
from positioning_cell.calibration.machine import ConditionedMachine, MachineModel
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.motion.temperature import (
    TemperatureInput,
    TemperatureSettings,
    TemperatureState,
)

FloatArray = NDArray[np.float64]

#: A joint target closer than this to the encoder reading is no motion (m for legs, rad for
#: θ): the axis keeps the direction it last moved in.
APPROACH_DEADBAND = 1e-9


def _thermal(model: MachineModel) -> bool:
    return bool(model.terms.leg_expansion or model.terms.structure_expansion)


class Compensation:
    """The compensation's conditions (module docstring). Thread-safe."""

    def __init__(self, settings: TemperatureSettings) -> None:
        self.temperature = TemperatureInput(settings)
        self._lock = threading.Lock()
        self._approach = np.zeros(6)
        #: The warnings of the last move (empty: none).
        self.warnings: tuple[str, ...] = ()

    @property
    def approach(self) -> FloatArray:
        """The direction (6,) each axis last moved in (JOINT_NAMES order; 0: not yet)."""
        with self._lock:
            return self._approach.copy()

    def conditions(self, now: float, approach: FloatArray | None = None) -> Conditions:
        """The conditions at ``now`` s: the temperature the compensation uses and ``approach``
        (None: the directions the axes last moved in)."""
        return Conditions(self.temperature.current(now).value,
                          self.approach if approach is None else approach)

    def model(self, calibrated: Calibrated, now: float,
              approach: FloatArray | None = None) -> MachineModel | ConditionedMachine:
        """The calibrated machine under the conditions at ``now`` (a ClearanceLike)."""
        return calibrated.model.at(self.conditions(now, approach))

    def uncertainty(self, calibrated: Calibrated, position: FloatArray, quaternion: FloatArray,
                    now: float) -> FloatArray | None:
        """Standard uncertainty (6,) (m, rad; x, y, z, rot-x, rot-y, rot-z) of where the
        calibrated machine puts the platform when commanded to the pose (3,) m, (4,) under the
        conditions at ``now``: the calibration's own and that of the temperature in use
        (:meth:`Calibrated.pose_covariance`). None when the calibration does not say."""
        air = self.temperature.current(now)
        cov = calibrated.pose_covariance(position, quaternion,
                                         Conditions(air.value, self.approach), air.sigma)
        return None if cov is None else np.sqrt(np.clip(np.diag(cov), 0.0, None))

    def approach_to(self, calibrated: Calibrated, position: FloatArray, quaternion: FloatArray,
                    joints: FloatArray, now: float) -> FloatArray:
        """The direction (6,) each axis moves in from the encoder reading ``joints`` (6,) to
        the targets of the pose (3,) m, (4,) (module docstring)."""
        previous = self.approach
        if not calibrated.model.terms.reversal.any():
            return previous
        target = calibrated.model.commands(position[None], quaternion[None],
                                           self.conditions(now, previous))
        return self.direction(np.concatenate([target.lengths[0], target.thetas[0]]), joints)

    def direction(self, target: FloatArray, joints: FloatArray) -> FloatArray:
        """The direction (6,) each axis moves in from ``joints`` (6,) to ``target`` (6,); an
        axis that does not move keeps the one it last moved in."""
        delta = target - joints
        out: FloatArray = np.where(np.abs(delta) > APPROACH_DEADBAND, np.sign(delta),
                                   self.approach)
        return out

    def moved(self, target: FloatArray, joints: FloatArray) -> None:
        """A move from the encoder reading ``joints`` (6,) to the joint ``target`` (6,) was
        sent: the axes' directions from now on."""
        approach = self.direction(target, joints)
        with self._lock:
            self._approach = approach

    def judge(self, calibrated: Calibrated | None, mech: Mechanism, mass: float,
              position: FloatArray, quaternion: FloatArray, now: float) -> tuple[str, ...]:
        """The warnings of a move to the pose (3,) m, (4,) carrying ``mass`` kg (kept as
        :attr:`warnings`): outside the calibration's envelope, the reasons; a thermal model
        compensating with a temperature that is not a fresh reading, its reason."""
        found: list[str] = []
        if calibrated is not None:
            air = self.temperature.current(now)
            thermal = _thermal(calibrated.model)
            if calibrated.envelope is not None:
                reasons = calibrated.envelope.reasons(
                    mech, position[None], quaternion[None], mass,
                    air.value if thermal and air.state is not TemperatureState.NOMINAL
                    else None)[0]
                found += [f'outside the calibration: {r}' for r in reasons]
            if thermal and air.state is not TemperatureState.MEASURED:
                found.append(air.reason)
        self.warnings = tuple(found)
        return self.warnings

    def report(self, calibrated: Calibrated | None, now: float
               ) -> tuple[str, str, dict[str, str]]:
        """(level, message, values) for the diagnostics: WARN while the last move had
        warnings, the latest temperature reading was refused, or a thermal model in use has
        no fresh temperature; the values give the
        temperature in use, its source and uncertainty, the readings refused (and the last
        reason), the axes' approach directions and the last move's warnings."""
        air = self.temperature.current(now)
        problems = list(self.warnings)
        if self.temperature.refusing:
            problems.append(self.temperature.last_refusal)
        if (calibrated is not None and _thermal(calibrated.model)
                and air.state is not TemperatureState.MEASURED and air.reason not in problems):
            problems.append(air.reason)
        values = {'air_temperature': f'{air.value:.2f}',
                  'air_temperature_sigma': f'{air.sigma:.2f}',
                  'air_temperature_source': air.state.value,
                  'air_temperature_refused': str(self.temperature.refused),
                  'air_temperature_last_refusal': self.temperature.last_refusal,
                  'approach': ' '.join(f'{a:+.0f}' for a in self.approach),
                  'warnings': '; '.join(self.warnings)}
        if problems:
            return 'warn', '; '.join(problems), values
        return 'ok', (f'air {air.value:.2f} degC ({air.state.value}, sigma {air.sigma:.2f} K)'
                      + ('' if calibrated is not None else '; no calibrated machine in use')), \
            values
