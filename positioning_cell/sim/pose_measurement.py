"""The pose_measurement node's work without ROS: the machine's truth turned into the true
platform pose from the true joints, and the simulated laser tracker measuring it.

The tracker first locates itself (:meth:`PoseMeasurementSimulator.locate`): it reads the base
reference targets ``locate.samples`` times, and the best fit of the averaged readings onto
their known base coordinates is the registration through which every later reading becomes a
base-frame point; the true tracker pose (``truth.tracker.*``) only produces the readings.

The latest true joint state is kept (older ones are of no use); at most ``truth_rate_hz`` the
true pose is computed from it (unchanged joints: the previous pose, newly stamped, recomputed
at least every :data:`RECOMPUTE_PERIOD` s while the temperature drifts), and at ``rate_hz``
the tracker reads the targets at the current true pose and fits the pose, stamped with the
time of the truth it measured. Stamps are opaque here: whatever the caller gives; times are
seconds on any clock (the first one seen is the start).

The machine's effects outside the identified model (:mod:`positioning_cell.sim.effects`)
follow the joint stream: a :class:`~positioning_cell.sim.effects.history.MachineHistory`
keeps each axis's approach direction and the legs' heating, the air drifts with time. The
cell's air-temperature sensor (``air_sensor.*``) reads the air with its own error; the
tracker's weather correction uses that reading (``air_sensor.feeds_tracker``) or 20 °C, and
its ranges scale with the difference from the true air (refraction).

The compliance test's load rig (:mod:`positioning_cell.sim.load_rig`) pushes on the platform
with the force it is commanded (:meth:`PoseMeasurementSimulator.apply_load`): the machine is
rebuilt with that load among its payload's, and the next true pose is computed anew.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConvergenceError, InputError
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.metrology.fit import FitSettings, PoseFit, TooFewTargetsError
from positioning_cell.metrology.instrument import TrackerAccuracy
from positioning_cell.metrology.locate import LocateSettings, Location, locate
from positioning_cell.metrology.targets import TargetLayout
from positioning_cell.parameters import check_fields, group, setting
from positioning_cell.sim.effects.thermal import REFERENCE_TEMPERATURE
from positioning_cell.sim.load_rig import LoadRig, LoadRigTruth, checked_force, loaded_payload
from positioning_cell.sim.tracker import SimulatedTracker, TrackerFaults, TrackerTruth, observe
from positioning_cell.sim.truth import Truth, TruthParameters

FloatArray = NDArray[np.float64]

_LEVELS = ('ok', 'warn', 'error')
#: Longest time, s, the true pose of unchanged joints is kept while temperature drifts.
RECOMPUTE_PERIOD = 1.0


@dataclass(frozen=True)
class SimulationTruth(TruthParameters):
    """The pose_measurement node's ``truth:`` block (read-only): the machine
    (:class:`TruthParameters`) and the tracker as it really is (``truth.tracker.*``)."""

    tracker: TrackerTruth = group(TrackerTruth, 'the tracker\'s true pose and systematic errors')
    load_rig: LoadRigTruth = group(LoadRigTruth, 'the load rig\'s real force')


@dataclass(frozen=True)
class AirSensor:
    """The cell's air-temperature sensor (``air_sensor.*``): its publication rate and whether
    the tracker's weather correction is fed its reading (else the tracker assumes 20 °C).
    Its error is the truth's (``truth.thermal.sensor_*``)."""

    rate_hz: float = setting(1.0, 'air-temperature publication rate', 'Hz', low=0.01,
                             high=100.0)
    feeds_tracker: bool = setting(True, 'the tracker corrects its ranges with this reading')

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class PoseMeasurementSettings:
    """Every parameter of the ``pose_measurement`` node (config/cell.yaml)."""

    mechanism: Mechanism = group(Mechanism, 'the nominal machine')
    payload: Payload = group(Payload, 'what the platform carries (load-driven clearance)')
    structure: Structure = group(Structure, 'stiffness and masses of the machine')
    truth: SimulationTruth = group(SimulationTruth, 'simulation truth (read-only)')
    tracker: TrackerAccuracy = group(TrackerAccuracy, 'the laser tracker\'s datasheet accuracy')
    locate: LocateSettings = group(LocateSettings, 'locating the tracker on base targets')
    targets: TargetLayout = group(TargetLayout, 'the SMRs on the platform')
    fault: TrackerFaults = group(TrackerFaults, 'injected measurement faults')
    fit: FitSettings = group(FitSettings, 'the pose fit')
    air_sensor: AirSensor = group(AirSensor, 'the cell\'s air-temperature sensor')
    load_rig: LoadRig = group(LoadRig, 'the compliance test\'s load rig')
    rate_hz: float = setting(20.0, 'tracker measurement rate', 'Hz', low=0.1, high=200.0)
    truth_rate_hz: float = setting(50.0, 'largest true-pose update rate', 'Hz', low=1.0,
                                   high=500.0)
    seed: int = setting(0, 'seed of the measurement noise and faults', low=0, high=2**31 - 1)

    def __post_init__(self) -> None:
        check_fields(self)

    def true_machine(self, load: FloatArray | None = None) -> Truth:
        """The truth these settings describe (ConfigError naming a bad ``truth.*`` key), with
        the load rig's load cell reading ``load`` (3,) N, base frame (None: no load)."""
        payload = (self.payload if load is None
                   else loaded_payload(self.payload, self.truth.load_rig, load))
        return Truth.from_parameters(self.truth, self.mechanism, payload, self.structure)


#: The tracker's target layout as parameters (``targets.platform``, ...): the prefix the watch
#: windows read and follow it by (:mod:`positioning_cell.ros.watch_inputs`).
TARGETS_PREFIX = 'targets.'


class TruePose(NamedTuple):
    """The true platform pose: position (3,) m, quaternion (4,) x, y, z, w, the stamp of the
    joint state it was computed from."""

    position: FloatArray
    quaternion: FloatArray
    stamp: Any


class Reading(NamedTuple):
    """One tracker measurement: the fitted pose (one row of a PoseFit) and the stamp of the
    true pose it measured."""

    fit: PoseFit
    stamp: Any


class AirReading(NamedTuple):
    """One air-temperature reading: value °C, variance K² (the sensor's own error)."""

    temperature: float
    variance: float


class PoseMeasurementSimulator:
    """Truth and tracker (module docstring). :attr:`status` is (level, message) for
    /diagnostics: 'ok', 'warn' or 'error'; :attr:`stats` the figures it reports."""

    def __init__(self, settings: PoseMeasurementSettings) -> None:
        self.settings = settings
        self.truth = settings.true_machine()
        self.instrument = SimulatedTracker(settings.truth.tracker, settings.tracker)
        self._rng = np.random.default_rng(settings.seed)
        self._sensor_rng = np.random.default_rng([settings.seed, 1])
        self.history = self.truth.history()
        self._start: float | None = None
        self._time = 0.0  # s since the start of the joint state of the true pose
        self._computed_at = -np.inf
        self._air_used = REFERENCE_TEMPERATURE  # what the tracker's correction assumes
        self._air_read = math.nan  # the sensor's latest reading, °C (for /diagnostics)
        self.location: Location | None = None
        self.locate_status = ('error', 'tracker not located')
        self._latest: tuple[FloatArray, Any, float] | None = None
        self._joints = np.full(6, np.nan)  # joints of the current true pose (NaN: none)
        self._phis: FloatArray | None = None
        #: The joint shifts (6,) m, rad of the current true pose and of the one before: the
        #: next one's fixed point (Truth.settle) starts from their trend, one step on (a move's
        #: update in three rounds instead of four from the last shift alone; the trend is
        #: zero once the joints came to rest).
        self._shift: FloatArray | None = None
        self._shift_prev: FloatArray | None = None
        self.true_pose: TruePose | None = None
        #: The load rig's load cell reading (3,) N, base frame (what it was last commanded).
        self.load: FloatArray = np.zeros(3)
        self._loaded = False  # a new load: the next true pose is computed anew
        self.status = ('warn', 'waiting for the true joint states')
        self.stats: dict[str, Any] = {
            'targets_visible': 0, 'targets_used': 0, 'outliers_rejected': 0,
            'outliers_rejected_total': 0, 'fit_residual_rms_um': float('nan'),
            'measurements': 0, 'failed_measurements': 0, 'truth_updates': 0, 'locations': 0}
        self.locate()

    def reconfigure(self, settings: PoseMeasurementSettings) -> None:
        """New dynamic settings (tracker, targets, faults, fit); the truth is read-only. A new
        datasheet accuracy re-locates the tracker (its registration's weights and covariance
        come from it); if that fails the old registration is kept, with the new accuracy."""
        accuracy_changed = settings.tracker != self.settings.tracker
        self.settings = settings
        self.instrument = SimulatedTracker(settings.truth.tracker, settings.tracker)
        if accuracy_changed and not self.locate()[0] and self.location is not None:
            self.location = self.location._replace(
                tracker=replace(self.location.tracker, accuracy=settings.tracker))

    def locate(self) -> tuple[bool, str]:
        """Locate the tracker: ``locate.samples`` readings of every base target (with the
        injected faults), averaged and fitted (:func:`locate`). (success, message); on
        failure the previous registration, if any, stays in use."""
        s = self.settings
        base = s.locate.array
        try:
            readings = self.instrument.read(np.broadcast_to(base, (s.locate.samples,
                                                                   *base.shape)),
                                            self._rng, s.fault)
            location = locate(s.tracker, base, readings.local)
        except InputError as err:  # LocateError among them
            kept = '; keeping the previous registration' if self.location else ''
            self.locate_status = ('error', f'locate failed: {err}{kept}')
            return False, self.locate_status[1]
        self.location = location
        self.stats['locations'] += 1
        worst = int(np.nanargmax(location.normalised))
        summary = (f'tracker located on {int(location.used.sum())}/{len(base)} base targets: '
                   f'residual RMS {location.rms * 1e6:.1f} um, max {location.max * 1e6:.1f} um '
                   f'(target {worst}, {location.normalised[worst]:.1f} sigma)')
        if location.normalised[worst] > s.locate.residual_limit:
            self.locate_status = ('warn', f'{summary}: beyond {s.locate.residual_limit:g} '
                                          'sigma, check that target')
        else:
            self.locate_status = ('ok', summary)
        return True, summary

    def location_values(self) -> dict[str, Any]:
        """The located registration and its residuals, for /diagnostics (µm, µrad)."""
        loc = self.location
        if loc is None:
            return {}
        sigma = np.sqrt(np.diag(loc.tracker.covariance if loc.tracker.covariance is not None
                                else np.zeros((6, 6))))
        return {
            'located_position': [round(v, 7) for v in loc.tracker.position],
            'located_orientation': [round(v, 9) for v in loc.tracker.orientation],
            'registration_sigma_position_um': np.round(sigma[:3] * 1e6, 2).tolist(),
            'registration_sigma_rotation_urad': np.round(sigma[3:] * 1e6, 2).tolist(),
            'locate_residual_rms_um': round(loc.rms * 1e6, 2),
            'locate_residual_max_um': round(loc.max * 1e6, 2),
            'locate_residuals_um': np.round(np.linalg.norm(loc.residuals, axis=1) * 1e6,
                                            2).tolist(),
            'locate_residuals_sigma': np.round(loc.normalised, 2).tolist(),
            'locate_variance_factor': round(loc.variance_factor, 3),
        }

    def apply_load(self, force: ArrayLike) -> FloatArray:
        """The load rig pushes the platform origin with ``force`` (3,) N, base frame (zeros:
        unloaded): the machine is rebuilt with it (module docstring). Returns the rig's load
        cell reading, the force commanded; InputError (nothing changed) for a force that is
        not finite or beyond ``load_rig.max_force``."""
        f = checked_force(self.settings.load_rig, force)
        self.truth = self.settings.true_machine(f if np.any(f) else None)
        self.load, self._loaded = f, True  # the drives' next joint state gets the new pose
        return f.copy()

    def _since_start(self, time: float) -> float:
        if self._start is None:
            self._start = time
        return time - self._start

    def joints(self, values: ArrayLike | None, stamp: Any, time: float = 0.0) -> None:
        """The latest true joint state (6,) m / rad in JOINT_NAMES order (None: the message
        lacked a joint) at ``time`` s, kept until the next truth update."""
        arr = None if values is None else np.asarray(values, dtype=float)
        if arr is None or arr.shape != (6,) or not np.all(np.isfinite(arr)):
            self.status = ('warn', 'ignored a true joint state without finite positions of '
                                   'all six joints')
            return
        self._latest = (arr, stamp, self._since_start(time))

    def update_truth(self) -> TruePose | None:
        """The true pose of the latest joint state (None: no new joint state, or no pose for
        it, :attr:`status` says why)."""
        if self._latest is None:
            return None
        joints, stamp, time = self._latest
        self._latest = None
        self.history.update(joints, time)
        self._time = time
        drifting = self.truth.effects.thermal is not None \
            and time - self._computed_at >= RECOMPUTE_PERIOD
        if self.true_pose is not None and np.array_equal(joints, self._joints) \
                and not drifting and not self._loaded:
            self.true_pose = self.true_pose._replace(stamp=stamp)  # the machine has not moved
            self._shift_prev = self._shift  # (the next move starts from rest)
        else:
            try:
                start = self._shift
                if self._shift is not None and self._shift_prev is not None:
                    start = 2.0 * self._shift - self._shift_prev
                result, shift = self.truth.settle(joints[:3], joints[3:], self._phis,
                                                  self.history.conditions(time), start)
                if not result.converged[0]:
                    raise ConvergenceError('forward kinematics did not converge')
            except (InputError, ConvergenceError) as err:
                self.true_pose = None
                self.status = ('error', f'no true pose for joints {joints.tolist()}: {err}')
                return None
            self._joints, self._phis, self._computed_at = joints, result.phis[0], time
            self._shift_prev, self._shift = self._shift, shift[0]
            self._loaded = False
            self.true_pose = TruePose(result.position[0], result.quaternion[0], stamp)
        self.stats['truth_updates'] += 1
        return self.true_pose

    def measure(self) -> Reading | None:
        """One tracker reading of the current true pose (None: no pose yet, or too few
        targets visible; :attr:`status` says so)."""
        if self.true_pose is None:
            return None
        if self.location is None:
            self.status = ('error', 'no measurement: the tracker is not located')
            return None
        s = self.settings
        thermal = self.truth.effects.thermal
        refraction = 0.0 if thermal is None else \
            float(thermal.range_scale_ppm(thermal.air(self._time), self._air_used))
        try:
            _, fit = observe(self.instrument, self.location.tracker, s.targets,
                             self.true_pose.position, self.true_pose.quaternion, self._rng,
                             s.fault, reject_threshold=s.fit.reject_threshold,
                             refraction_ppm=refraction)
        except TooFewTargetsError as err:
            self.stats['failed_measurements'] += 1
            self.status = ('warn', f'no measurement: {err}')
            return None
        rejected = int(fit.rejected[0])
        st = self.stats
        st.update(targets_visible=int(fit.visible[0].sum()),
                  targets_used=int(fit.inliers[0].sum()), outliers_rejected=rejected,
                  fit_residual_rms_um=round(float(fit.rms[0]) * 1e6, 3),
                  outliers_rejected_total=st['outliers_rejected_total'] + rejected,
                  measurements=st['measurements'] + 1)
        self.status = ('ok', 'measuring')
        return Reading(fit, self.true_pose.stamp)

    def air_temperature(self, time: float) -> AirReading:
        """The air-temperature sensor's reading at ``time`` s (the clock of :meth:`joints`);
        the tracker's weather correction takes it when ``air_sensor.feeds_tracker``. Without
        thermal effects the air is at 20 °C and the sensor exact."""
        thermal = self.truth.effects.thermal
        params = self.settings.truth.thermal
        variance = params.sensor_offset_sigma**2 + params.sensor_noise**2
        value = REFERENCE_TEMPERATURE if thermal is None else \
            float(thermal.sensor(np.array([self._since_start(time)]), self._sensor_rng)[0])
        if self.settings.air_sensor.feeds_tracker:
            self._air_used = value
        self._air_read = value
        return AirReading(value, variance)

    def diagnostics(self) -> tuple[str, str, dict[str, Any]]:
        """(level, message, values) of the /diagnostics status."""
        level, message = self.status
        if level == 'ok':
            message = (f'{self.stats["targets_used"]}/{len(self.settings.targets.platform)} '
                       f'targets, residual RMS {self.stats["fit_residual_rms_um"]} um')
        locate_level, locate_message = self.locate_status
        if locate_level != 'ok':
            level = max(level, locate_level, key=_LEVELS.index)
            message = f'{message}; {locate_message}'
        return level, message, {**self.stats, 'load_rig_force_n': self.load.tolist(),
                                'air_temperature_c': round(self._air_read, 3),
                                **self.location_values()}
