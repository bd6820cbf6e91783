"""The mover's outside world simulated offline, without ROS and without waiting: drives that
take every trajectory and stand at its end at once, encoders that read the axes exactly, and
the laser tracker (the simulator's: true pose of the machine, readings with the instrument's
noise and systematic errors, fitted through the cell's located registration). For judging the
positioner's own move logic (:class:`positioning_cell.motion.mover.Mover`, unchanged) on a
simulated machine in a benchmark; the truth stays here (:meth:`InstantCell.true_pose`).

The machine's effects follow its history
(:class:`~positioning_cell.sim.effects.history.MachineHistory`): each trajectory's start and
end, on a clock advanced by the trajectory's duration (no settling time: the air hardly drifts
in an instant cell)."""

from __future__ import annotations

import threading

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.kinematics import inverse
from positioning_cell.metrology.instrument import Registration, Tracker
from positioning_cell.metrology.targets import TargetLayout
from positioning_cell.moves.fingerprint import fingerprint
from positioning_cell.moves.machine import Answer, JointReading, Machine, Measurement
from positioning_cell.moves.trajectory import Trajectory
from positioning_cell.sim.effects.thermal import REFERENCE_TEMPERATURE
from positioning_cell.sim.tracker import SimulatedTracker, observe
from positioning_cell.sim.truth import Truth

FloatArray = NDArray[np.float64]

#: The drives' report to the mover: enabled, at rest, referenced.
DRIVES_READY = {'enabled': 'true', 'state': 'holding', 'referenced': 'true'}


class InstantCell:
    """The drives, encoders and tracker of the machine ``truth`` (module docstring); each look
    of the mover at the tracker gets ``samples`` new readings."""

    def __init__(self, truth: Truth, instrument: SimulatedTracker, located: Tracker,
                 targets: TargetLayout, rng: np.random.Generator, samples: int = 10,
                 sensor_seed: int = 1) -> None:
        self.truth, self.instrument, self.located, self.targets = truth, instrument, located, \
            targets
        self.rng, self.samples = rng, samples
        self._sensor_rng = np.random.default_rng(sensor_seed)
        mech = truth.mechanism
        home = inverse(mech, mech.home_position, mech.home_quaternion)
        self.position: FloatArray = np.concatenate([home.lengths[0], home.thetas[0]])
        self.history = truth.history()
        self.time = 0.0  # s since the start
        self.history.update(self.position, self.time)
        self._answers: list[Answer] = []
        self._shift: FloatArray | None = None
        self._lock = threading.Lock()

    def machine(self) -> Machine:
        """The :class:`Machine` a mover drives."""
        return Machine(send_trajectory=self._send, stop_drives=lambda: None,
                       publish_target=lambda p, q: None, latest_joints=self._joints,
                       new_measurements=self._measure, trajectory_answers=self._take,
                       registration=self._registration)

    def true_pose(self) -> tuple[FloatArray, FloatArray]:
        """Judging only: where the platform really is, position (3,) m, quaternion (4,)."""
        pose, shift = self.truth.settle(self.position[None, :3], self.position[None, 3:],
                                        conditions=self.history.conditions(self.time),
                                        shift0=self._shift)
        self._shift = shift[0]  # the next pose's start (Truth.settle)
        return pose.position[0], pose.quaternion[0]

    def air_readings(self, count: int) -> FloatArray:
        """``count`` readings (count,) °C of the cell's air-temperature sensor now (its offset
        and noise: :meth:`~positioning_cell.sim.effects.thermal.Thermal.sensor`); without
        thermal effects the air is at 20 °C and the sensor exact, as the live simulator's."""
        thermal = self.truth.effects.thermal
        if thermal is None:
            return np.full(count, REFERENCE_TEMPERATURE)
        return thermal.sensor(np.full(count, self.time), self._sensor_rng)

    def _send(self, traj: Trajectory, start: float | None = None) -> None:
        del start  # an instant machine: every motion is over when sent
        joints = np.hstack([traj.lengths, traj.thetas])
        with self._lock:
            self.position = joints[-1].copy()
            self.history.update(joints[0], self.time)
            self.time += float(traj.times[-1] - traj.times[0])
            self.history.update(joints[-1], self.time)
            self._answers.append(Answer(fingerprint(traj.times, joints), True, 'ok'))

    def _take(self) -> list[Answer]:
        with self._lock:
            out, self._answers = self._answers, []
        return out

    def _joints(self) -> JointReading:
        with self._lock:
            return JointReading(self.position.copy(), np.zeros(6))

    def _registration(self) -> Registration | None:
        """The located registration, as the tracker node publishes it."""
        return self.located.registration

    def _measure(self) -> list[Measurement]:
        p, q = self.true_pose()
        n = self.samples
        _, fit = observe(self.instrument, self.located, self.targets, np.repeat(p[None], n, 0),
                         np.repeat(q[None], n, 0), self.rng)
        return [Measurement(fit.position[k], fit.quaternion[k], fit.covariance[k])
                for k in range(n)]
