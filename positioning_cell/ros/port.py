"""The ROS port: :class:`~positioning_cell.procedures.port.CellPort` on the running cell,
through a :class:`~positioning_cell.ros.client.CellClient` (its services, its parameters, its
own subscriptions to the encoders, the tracker, the air-temperature sensor, the simulator's
true axis positions, the load rig's load cell and the monitor's verdicts, and the marker and
load-rig publishers)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped, WrenchStamped
from numpy.typing import ArrayLike
from positioning_cell_interfaces.msg import MoveCommand
from positioning_cell_interfaces.srv import Jog, MoveToPose
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.calibration.collect import encoder_window
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import Registration
from positioning_cell.motion.settings import CALIBRATION_FILE, COMPENSATION_MODE
from positioning_cell.polling import wait_until
from positioning_cell.procedures.port import FloatArray, Moved, ProcedureError, Readings, Seen
from positioning_cell.ros.client import CellClient, verdict_text
from positioning_cell.ros.messages import (
    force_of,
    force_stamped,
    joint_values,
    measurement,
    pose_stamped,
    registration,
    seconds,
)
from positioning_cell.ros.qos import LATCHED_QOS, MARKER_QOS, SERVICE_QOS, STREAM_QOS

#: Messages kept per stream (the encoders' 100 Hz: 30 s): a procedure's window is far
#: shorter, and so is the time between two calibration poses.
HISTORY = 3000
#: Air-temperature readings kept (the sensor's 1 Hz: 10 min).
AIR_HISTORY = 600
#: After the monitor's verdict, how long (s) the true pose may take to settle as well, so the
#: simulation-truth figures have every visit.
TRUTH_WAIT = 1.5
#: How long a call to the positioner may take (s): a move, a homing or a jog.
MOVE_TIMEOUT = 120.0
#: After a window of tracker readings, the longest wait (s) for the encoder reading that shows
#: every encoder reading of the window has come.
ENCODER_WAIT = 1.0


class RosCellPort:
    """:class:`~positioning_cell.procedures.port.CellPort` on the cell of ``client``
    (``timeout`` s for a reading, a parameter, a service to appear); ``namespace``: one
    positioner's node set of a coordinated cell (every name through :func:`names.in_set`;
    '': the single positioner's cell)."""

    def __init__(self, client: CellClient, timeout: float = 30.0, namespace: str = '') -> None:
        self.client, self.timeout, self.namespace = client, timeout, namespace
        self._positioner = f'{namespace}/{names.NODE_POSITIONER}' if namespace \
            else names.NODE_POSITIONER
        wire = self._wire
        self._lock = threading.Lock()
        self._joints: deque[tuple[float, FloatArray]] = deque(maxlen=HISTORY)
        self._true: deque[tuple[float, FloatArray]] = deque(maxlen=HISTORY)
        self._poses: deque[tuple[float, Any]] = deque(maxlen=HISTORY)
        self._air: deque[tuple[float, float]] = deque(maxlen=AIR_HISTORY)
        node = client.node
        node.create_subscription(JointState, wire(names.JOINT_STATES),
                                 lambda m: self._on_joints(self._joints, m), STREAM_QOS)
        node.create_subscription(JointState, wire(names.TRUE_JOINT_STATES),
                                 lambda m: self._on_joints(self._true, m), STREAM_QOS)
        node.create_subscription(PoseWithCovarianceStamped, wire(names.MEASURED_POSE),
                                 self._on_pose, STREAM_QOS)
        node.create_subscription(Temperature, wire(names.AIR_TEMPERATURE), self._on_air,
                                 STREAM_QOS)
        self._registration: Registration | None = None
        node.create_subscription(PoseWithCovarianceStamped, wire(names.TRACKER_REGISTRATION),
                                 self._on_registration, LATCHED_QOS)
        self._markers: dict[str, Any] = {}
        self._load_cell: FloatArray | None = None  # the rig's latest reading
        node.create_subscription(WrenchStamped, wire(names.LOAD_FORCE), self._on_load_cell,
                                 LATCHED_QOS)
        self._load_command = node.create_publisher(WrenchStamped, wire(names.LOAD_COMMAND),
                                                   LATCHED_QOS)
        self._verdicts = client.statuses(names.STATUS_MONITOR_VERDICT)
        # its own client of /positioner/stop: stop() may be called from any thread, while the
        # procedure's thread waits for a move on the shared client
        self._stop = node.create_client(Trigger, wire(names.STOP), qos_profile=SERVICE_QOS)

    def _wire(self, name: str) -> str:
        """The wire name ``name`` (names.py) has in this port's set."""
        return names.in_set(name, self.namespace)

    # -- what comes in --------------------------------------------------------------------------
    def _on_joints(self, into: deque[tuple[float, FloatArray]], msg: Any) -> None:
        values = joint_values(msg, JOINT_NAMES)
        if values is not None:
            with self._lock:
                into.append((seconds(msg.header.stamp), values))

    def _on_pose(self, msg: Any) -> None:
        reading = measurement(msg)
        with self._lock:
            self._poses.append((seconds(msg.header.stamp), reading))

    def _on_registration(self, msg: Any) -> None:
        try:
            found = registration(msg)
        except InputError:  # not usable: the readings are then taken as independent
            return
        with self._lock:
            self._registration = found

    def _on_load_cell(self, msg: Any) -> None:
        try:
            force = force_of(msg)
        except InputError:
            return  # not the rig's reading in base: none
        with self._lock:
            self._load_cell = force

    def _on_air(self, msg: Any) -> None:
        with self._lock:
            self._air.append((seconds(msg.header.stamp), float(msg.temperature)))

    def now(self) -> float:
        return float(self.client.node.get_clock().now().nanoseconds * 1e-9)

    # -- moves ----------------------------------------------------------------------------------
    def home(self) -> Moved:
        try:
            done, message = self.client.home(max(self.timeout, 60.0), self.namespace)
        except TimeoutError as err:
            return Moved(False, '', f'homing: {err}')
        return Moved(done, 'success' if done else message.split(':')[0], message)

    def move(self, position: ArrayLike, quaternion: ArrayLike, tolerance: float = 0.0) -> Moved:
        command = MoveCommand(pose=pose_stamped(position, quaternion,
                                                self.client.node.get_clock().now().to_msg()),
                              mode=MoveCommand.ABSOLUTE, tolerance=float(tolerance))
        try:
            response = self.client.call(MoveToPose, self._wire(names.MOVE_TO_POSE),
                                        MoveToPose.Request(command=command), MOVE_TIMEOUT)
        except TimeoutError as err:
            return Moved(False, '', str(err))
        outcome = response.outcome
        return Moved(outcome.code == 0, str(outcome.code_name), str(outcome.reason))

    def jog(self, axis: str, delta: float) -> Moved:
        try:
            answer = self.client.call(Jog, self._wire(names.JOG),
                                      Jog.Request(axis=axis, delta=float(delta)),
                                      max(self.timeout, 60.0))
        except TimeoutError as err:
            return Moved(False, '', f'jog {axis}: {err}')
        return Moved(bool(answer.success), str(answer.code_name), str(answer.reason))

    def stop(self) -> None:
        if self._stop.service_is_ready():
            self._stop.call_async(Trigger.Request())

    def rest(self, seconds: float) -> None:
        time.sleep(seconds)

    # -- the positioner's parameters ------------------------------------------------------------
    def _parameter(self, name: str) -> str:
        try:
            return str(self.client.get_parameter(self._positioner, name) or '')
        except TimeoutError as err:
            raise ProcedureError(f'the positioner\'s {name}: {err}') from err

    def _set(self, name: str, value: str) -> tuple[bool, str]:
        try:
            result = self.client.set_parameter(self._positioner, name, value)
        except TimeoutError as err:
            return False, str(err)
        return bool(result.successful), str(result.reason)

    def mode(self) -> str:
        return self._parameter(COMPENSATION_MODE)

    def set_mode(self, mode: str) -> None:
        taken, reason = self._set(COMPENSATION_MODE, mode)
        if not taken:
            raise ProcedureError(f'the positioner refused {COMPENSATION_MODE} = {mode}: '
                                 f'{reason}')

    def calibration_file(self) -> str:
        return self._parameter(CALIBRATION_FILE)

    def load_calibration(self, path: str) -> tuple[bool, str]:
        return self._set(CALIBRATION_FILE, path)

    # -- readings -------------------------------------------------------------------------------
    def joints(self) -> FloatArray:
        # The first reading stamped from now on, not the newest one here: under load this
        # process took the stream 0.3 s late, and an axis test's next jog, planned from a
        # reading that a jog had left behind, ended its axis 177 um off the target (Dec 8).
        since = self.now()
        try:
            wait_until(lambda: self._joints and self._joints[-1][0] >= since, self.timeout,
                       f'an encoder reading on {self._wire(names.JOINT_STATES)}')
        except TimeoutError as err:
            raise ProcedureError(str(err)) from err
        with self._lock:
            return self._joints[-1][1].copy()

    def _since(self, start: float) -> list[tuple[float, Any]]:
        with self._lock:
            return [entry for entry in self._poses if entry[0] >= start]

    def readings(self, samples: int, timeout: float) -> Readings:
        start = self.now()
        try:
            wait_until(lambda: len(self._since(start)) >= samples, timeout,
                       f'{samples} tracker readings on {self._wire(names.MEASURED_POSE)}')
        except TimeoutError as err:
            raise ProcedureError(str(err)) from err
        taken = sorted(self._since(start), key=lambda e: e[0])[:samples]
        end = taken[-1][0]
        # the window's encoder readings complete: one stamped after it has come (the encoders
        # and the tracker publish apart; a bag of the run holds every reading of the window)
        with contextlib.suppress(TimeoutError):
            wait_until(lambda: self._joints and self._joints[-1][0] > end,
                       min(timeout, ENCODER_WAIT), 'an encoder reading after the window')
        with self._lock:
            encoder = [v for t, v in self._joints if start <= t <= end]
            latest = self._joints[-1][1] if self._joints else None
            true = [v for t, v in self._true if start <= t <= end]
            located = self._registration
        if not encoder:
            if latest is None:
                raise ProcedureError(f'no encoder reading on {self._wire(names.JOINT_STATES)}')
            encoder = [latest]
        mean, sem = encoder_window(encoder)
        position = np.array([m.position for _, m in taken])
        return Readings(np.array([t for t, _ in taken]), position,
                        np.array([m.quaternion for _, m in taken]),
                        np.array([m.covariance for _, m in taken]),
                        mean, np.mean(true, axis=0) if true else None, start, end, sem,
                        located)

    def encoder_stream(self, since: float) -> tuple[FloatArray, FloatArray]:
        with self._lock:
            kept = [(t, v) for t, v in self._joints if t >= since]
        kept.sort(key=lambda e: e[0])
        return (np.array([t for t, _ in kept], dtype=float),
                np.array([v for _, v in kept], dtype=float).reshape(-1, 6))

    def air_temperature(self, since: float) -> tuple[FloatArray, FloatArray]:
        with self._lock:
            kept = sorted((e for e in self._air if e[0] >= since), key=lambda e: e[0])
        return (np.array([t for t, _ in kept], dtype=float),
                np.array([v for _, v in kept], dtype=float))

    def apply_load(self, force: ArrayLike) -> None:
        wanted = np.asarray(force, dtype=float).reshape(3)
        self._load_command.publish(force_stamped(wanted, self.client.node.get_clock().now()
                                                 .to_msg()))

        def reads_it() -> bool:
            with self._lock:
                return self._load_cell is not None and bool(np.allclose(
                    self._load_cell, wanted, rtol=1e-9, atol=1e-9))
        try:
            wait_until(reads_it, self.timeout, f'the load rig\'s reading of {wanted.tolist()} N '
                       f'on {self._wire(names.LOAD_FORCE)} (a command it refuses is in the '
                       f'{names.NODE_MEASUREMENT} log)')
        except TimeoutError as err:
            raise ProcedureError(str(err)) from err

    # -- markers and the monitor ----------------------------------------------------------------
    def mark(self, topic: str, text: str) -> None:
        if topic not in names.MARKER_TOPICS:
            raise ValueError(f'{topic} is not a marker topic ({", ".join(names.MARKER_TOPICS)})')
        if topic == names.PROGRAM:  # latched: the recorder takes the step before the move
            self.client.publish_program(text, self._wire(topic))
            return
        publisher = self._markers.get(topic)
        if publisher is None:
            # transient-local: a recorder that subscribes once it sees this publisher still
            # gets every marker sent before
            publisher = self._markers[topic] = self.client.node.create_publisher(
                String, self._wire(topic), MARKER_QOS)
        publisher.publish(String(data=text))

    def recorded(self, topic: str) -> bool:
        return self.client.subscribed(self._wire(topic), names.NODE_RECORDER)

    def _truth_visits(self) -> int | None:
        """Settled visits of the true pose so far (None: the monitor has no truth)."""
        try:
            truth = self.client.monitor_report()['truth']
        except TimeoutError as err:
            raise ProcedureError(f'the accuracy monitor: {err}') from err
        return None if truth is None else len(truth['visits'])

    def seen(self) -> Seen:
        return Seen(len(self._verdicts), self._truth_visits())

    def verdict(self, before: Seen, timeout: float) -> str | None:
        try:
            wait_until(lambda: len(self._verdicts) > before.verdicts, timeout, 'the verdict')
        except TimeoutError:
            return None
        visits = before.true_visits
        if visits is not None:  # the true pose settles too before the next target
            with contextlib.suppress(TimeoutError):
                wait_until(lambda: (self._truth_visits() or 0) > visits,
                           TRUTH_WAIT, 'the true pose to settle')
        return verdict_text(self._verdicts[before.verdicts])
