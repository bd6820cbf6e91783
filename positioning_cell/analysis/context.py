"""What a recorded run says about the cell besides its poses, for trends over many runs: when
it ran, the calibration the positioner had loaded (its ``positioner: state`` diagnostics,
value ``calibration``), the calibration runs recorded in it (``/cell/calibration`` markers)
and the tracker's registrations (its ``pose_measurement`` diagnostics: where it located itself
on the base targets, with what residuals, and the air-temperature sensor's reading it was
given). Collected message by message in recorded order; memory is one entry per change, not
per message."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

from positioning_cell.calibration.collect import Marker
from positioning_cell.errors import InputError
from positioning_cell.names import NO_CALIBRATION, STATUS_MEASUREMENT, STATUS_POSITIONER


@dataclass(frozen=True)
class CalibrationInForce:
    """From ``time`` (s, the diagnostic's stamp) on, the positioner used calibration ``file``
    (None: none, the nominal machine)."""

    time: float
    file: str | None


@dataclass(frozen=True)
class CalibrationRun:
    """A calibration run recorded in the bag: its ``run`` name (its start, UTC ISO 8601),
    the log time (s) of its first marker and how many poses it measured."""

    run: str
    time: float
    poses: int


@dataclass(frozen=True)
class Registration:
    """A location of the tracker on the base targets (the ``locations``-th since it started),
    first reported at ``time`` (s): residual RMS and max over the targets (µm), each target's
    residual (µm), the variance factor, and the registration's standard uncertainty (µm,
    µrad per axis)."""

    time: float
    locations: int
    residual_rms_um: float
    residual_max_um: float
    residuals_um: tuple[float, ...]
    variance_factor: float
    sigma_position_um: tuple[float, ...]
    sigma_rotation_urad: tuple[float, ...]


@dataclass(frozen=True)
class AirTemperature:
    """The cell's air-temperature sensor over a run (°C): its ``low``est, ``mean`` and
    ``high``est reading as the tracker's diagnostics gave them (about once a second), and
    how many (``readings``)."""

    low: float
    mean: float
    high: float
    readings: int


@dataclass(frozen=True)
class RunContext:
    """The context of one run: ``start``/``end`` (s, log times of the bag's first and last
    message), the calibration in force over time, the calibration runs and the tracker's
    registrations, each in time order, and the air temperature over the run (None: not
    recorded)."""

    start: float
    end: float
    calibrations: tuple[CalibrationInForce, ...] = ()
    calibration_runs: tuple[CalibrationRun, ...] = ()
    registrations: tuple[Registration, ...] = ()
    air_temperature: AirTemperature | None = None

    def calibration_at(self, time: float) -> str | None:
        """The calibration file in force at ``time`` s (None: none known or none loaded)."""
        now: str | None = None
        for change in self.calibrations:
            if change.time > time:
                break
            now = change.file
        return now

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (s, µm, µrad)."""
        return asdict(self)


def _numbers(text: str) -> tuple[float, ...]:
    """A JSON list of numbers (as the diagnostics print them), NaN for 'nan'."""
    values = json.loads(text.replace('nan', 'NaN'))
    return tuple(float(v) for v in values)


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


class ContextCollector:
    """Feed :meth:`diagnostics` and :meth:`calibration_marker` in recorded order, then
    :meth:`result`. Statuses that do not parse are counted in ``problems``, never fatal."""

    def __init__(self) -> None:
        self._calibrations: list[CalibrationInForce] = []
        self._runs: dict[str, CalibrationRun] = {}
        self._registrations: list[Registration] = []
        self._air = [math.inf, 0.0, -math.inf, 0]  # lowest, sum, highest, count
        self.problems: list[str] = []

    def diagnostics(self, stamp: float, statuses: Sequence[Any]) -> None:
        """The statuses (diagnostic_msgs/DiagnosticStatus: ``name``, ``values`` of ``key``,
        ``value``) of one /diagnostics message stamped ``stamp`` s."""
        for status in statuses:
            if status.name == STATUS_POSITIONER:
                self._positioner(stamp, {kv.key: kv.value for kv in status.values})
            elif status.name == STATUS_MEASUREMENT:
                self._tracker(stamp, {kv.key: kv.value for kv in status.values})

    def _positioner(self, stamp: float, values: Mapping[str, str]) -> None:
        if 'calibration' not in values:
            return
        file = None if values['calibration'] == NO_CALIBRATION else values['calibration']
        if not self._calibrations or self._calibrations[-1].file != file:
            self._calibrations.append(CalibrationInForce(stamp, file))

    def _tracker(self, stamp: float, values: Mapping[str, str]) -> None:
        air = _number(values.get('air_temperature_c', 'nan'))
        if math.isfinite(air):
            low, total, high, count = self._air
            self._air = [min(low, air), total + air, max(high, air), int(count) + 1]
        if 'locations' not in values or 'locate_residuals_um' not in values:
            return
        try:
            locations = int(values['locations'])
            if self._registrations and self._registrations[-1].locations == locations:
                return
            self._registrations.append(Registration(
                stamp, locations, _number(values.get('locate_residual_rms_um', 'nan')),
                _number(values.get('locate_residual_max_um', 'nan')),
                _numbers(values['locate_residuals_um']),
                _number(values.get('locate_variance_factor', 'nan')),
                _numbers(values.get('registration_sigma_position_um', '[]')),
                _numbers(values.get('registration_sigma_rotation_urad', '[]'))))
        except (ValueError, TypeError) as err:
            self.problems.append(f'pose_measurement diagnostics at {stamp:.3f} s: {err}')

    def calibration_marker(self, log_time: float, text: str) -> None:
        """One /cell/calibration message (its JSON) logged at ``log_time`` s."""
        try:
            marker = Marker.from_json(text)
        except InputError as err:
            self.problems.append(str(err))
            return
        run = self._runs.get(marker.run)
        self._runs[marker.run] = (CalibrationRun(marker.run, log_time, 1) if run is None
                                  else CalibrationRun(run.run, run.time, run.poses + 1))

    def result(self, start: float, end: float) -> RunContext:
        """The context of the run between log times ``start`` and ``end`` (s)."""
        low, total, high, count = self._air
        return RunContext(start, end, tuple(self._calibrations),
                          tuple(sorted(self._runs.values(), key=lambda r: r.time)),
                          tuple(self._registrations),
                          AirTemperature(low, total / count, high, int(count)) if count
                          else None)
