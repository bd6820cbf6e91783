"""The pose_measurement node's work without ROS: the machine's truth turned into the true
platform pose from the true joints, and the simulated laser tracker measuring it.

The latest true joint state is kept (older ones are of no use); at most ``truth_rate_hz`` the
true pose is computed from it (unchanged joints: the previous pose, newly stamped), and at
``rate_hz`` the tracker reads the targets at the current true pose and fits the pose, stamped
with the time of the truth it measured. Stamps are opaque here: whatever the caller gives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import ConvergenceError, InputError
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.metrology.fit import FitSettings, PoseFit, TooFewTargetsError
from positioning_cell.metrology.instrument import Tracker
from positioning_cell.metrology.targets import TargetLayout
from positioning_cell.parameters import check_fields, group, setting
from positioning_cell.sim.tracker import TrackerFaults, observe
from positioning_cell.sim.truth import Truth, TruthParameters

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PoseMeasurementSettings:
    """Every parameter of the ``pose_measurement`` node (config/cell.yaml)."""

    mechanism: Mechanism = group(Mechanism, 'the nominal machine')
    payload: Payload = group(Payload, 'what the platform carries (load-driven clearance)')
    structure: Structure = group(Structure, 'stiffness and masses of the machine')
    truth: TruthParameters = group(TruthParameters, 'simulation truth (read-only)')
    tracker: Tracker = group(Tracker, 'the laser tracker')
    targets: TargetLayout = group(TargetLayout, 'the SMRs on the platform')
    fault: TrackerFaults = group(TrackerFaults, 'injected measurement faults')
    fit: FitSettings = group(FitSettings, 'the pose fit')
    rate_hz: float = setting(20.0, 'tracker measurement rate', 'Hz', low=0.1, high=200.0)
    truth_rate_hz: float = setting(50.0, 'largest true-pose update rate', 'Hz', low=1.0,
                                   high=500.0)
    seed: int = setting(0, 'seed of the measurement noise and faults', low=0, high=2**31 - 1)

    def __post_init__(self) -> None:
        check_fields(self)

    def true_machine(self) -> Truth:
        """The truth these settings describe (ConfigError naming a bad ``truth.*`` key)."""
        return Truth.from_parameters(self.truth, self.mechanism, self.payload, self.structure)


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


class PoseMeasurementSimulator:
    """Truth and tracker (module docstring). :attr:`status` is (level, message) for
    /diagnostics: 'ok', 'warn' or 'error'; :attr:`stats` the figures it reports."""

    def __init__(self, settings: PoseMeasurementSettings) -> None:
        self.settings = settings
        self.truth = settings.true_machine()
        self._rng = np.random.default_rng(settings.seed)
        self._latest: tuple[FloatArray, Any] | None = None
        self._joints = np.full(6, np.nan)  # joints of the current true pose (NaN: none)
        self._phis: FloatArray | None = None
        self.true_pose: TruePose | None = None
        self.status = ('warn', 'waiting for the true joint states')
        self.stats: dict[str, Any] = {
            'targets_visible': 0, 'targets_used': 0, 'outliers_rejected': 0,
            'outliers_rejected_total': 0, 'fit_residual_rms_um': float('nan'),
            'measurements': 0, 'failed_measurements': 0, 'truth_updates': 0}

    def reconfigure(self, settings: PoseMeasurementSettings) -> None:
        """New dynamic settings (tracker, targets, faults, fit); the truth is read-only."""
        self.settings = settings

    def joints(self, values: ArrayLike | None, stamp: Any) -> None:
        """The latest true joint state (6,) m / rad in JOINT_NAMES order (None: the message
        lacked a joint), kept until the next truth update."""
        arr = None if values is None else np.asarray(values, dtype=float)
        if arr is None or arr.shape != (6,) or not np.all(np.isfinite(arr)):
            self.status = ('warn', 'ignored a true joint state without finite positions of '
                                   'all six joints')
            return
        self._latest = (arr, stamp)

    def update_truth(self) -> TruePose | None:
        """The true pose of the latest joint state (None: no new joint state, or no pose for
        it, :attr:`status` says why)."""
        if self._latest is None:
            return None
        joints, stamp = self._latest
        self._latest = None
        if self.true_pose is not None and np.array_equal(joints, self._joints):
            self.true_pose = self.true_pose._replace(stamp=stamp)  # the machine has not moved
        else:
            try:
                result = self.truth.attained_pose(joints[:3], joints[3:], self._phis)
                if not result.converged[0]:
                    raise ConvergenceError('forward kinematics did not converge')
            except (InputError, ConvergenceError) as err:
                self.true_pose = None
                self.status = ('error', f'no true pose for joints {joints.tolist()}: {err}')
                return None
            self._joints, self._phis = joints, result.phis[0]
            self.true_pose = TruePose(result.position[0], result.quaternion[0], stamp)
        self.stats['truth_updates'] += 1
        return self.true_pose

    def measure(self) -> Reading | None:
        """One tracker reading of the current true pose (None: no pose yet, or too few
        targets visible; :attr:`status` says so)."""
        if self.true_pose is None:
            return None
        s = self.settings
        try:
            _, fit = observe(s.tracker, s.targets, self.true_pose.position,
                             self.true_pose.quaternion, self._rng, s.fault,
                             reject_threshold=s.fit.reject_threshold)
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

    def diagnostics(self) -> tuple[str, str, dict[str, Any]]:
        """(level, message, values) of the /diagnostics status."""
        level, message = self.status
        if level == 'ok':
            message = (f'{self.stats["targets_used"]}/{len(self.settings.targets.platform)} '
                       f'targets, residual RMS {self.stats["fit_residual_rms_um"]} um')
        return level, message, dict(self.stats)
