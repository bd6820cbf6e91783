"""The live cell for the fault matrix (:mod:`positioning_cell.procedures.fault_trials`):
:class:`FaultCell`, a :class:`~positioning_cell.procedures.fault_port.FaultPort` on the leg
driver, tracker simulator, positioner, monitor and recorder as processes on a private ROS
domain, with a client that injects (parameters, SIGKILL and restart, the drives' enable,
foreign messages, floods of calls) and watches the positioner's statuses, the drives'
answers, the true joint states and poses, the tracker and the estimate, each with its receipt
time (time.monotonic). The truth is read here only to judge."""

from __future__ import annotations

import contextlib
import math
import os
import signal
import threading
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from numpy.typing import ArrayLike
from positioning_cell_interfaces.msg import MoveCommand
from positioning_cell_interfaces.srv import CheckPose, MoveToPose
from rclpy.duration import Duration
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from positioning_cell import names
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.parameters import parse
from positioning_cell.polling import wait_until
from positioning_cell.procedures.fault_port import (
    Flood,
    ParameterValue,
    ProcedureError,
    Report,
    TrueStates,
)
from positioning_cell.procedures.fault_trials import CLIENT_NODE, ready
from positioning_cell.procedures.port import FloatArray, Moved
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.domains import free_domain
from positioning_cell.ros.messages import (
    duration,
    pose_arrays,
    pose_stamped,
    published_monotonic,
    status_values,
)
from positioning_cell.ros.port import RosCellPort
from positioning_cell.ros.processes import Processes, cell_environment
from positioning_cell.ros.qos import COMMAND_QOS, DIAGNOSTICS_QOS, STREAM_QOS
from positioning_cell.sim.drives import DriverSettings

#: What is kept of each stream (receipt time first).
KEPT_STATUSES, KEPT_TRUTH, KEPT_POSES = 5000, 20_000, 5000
#: The characters of a node's log an unanswered parameter set shows.
LOG_TAIL = 3000


def _node(name: str) -> names.CellNode:
    found = next((n for n in names.CELL_NODES if n.name == name), None)
    if found is None:
        raise ProcedureError(f'{name} is not a node of the cell')
    return found


class FaultCell(RosCellPort):
    """The cell under test (module docstring; ``log_dir``: the processes' logs and the bag,
    ``config``: the parameter file, default the shipped cell.yaml). :meth:`start` starts and
    homes it; a context manager that stops every process."""

    def __init__(self, log_dir: Path, config: Path | None = None) -> None:
        self.log_dir = log_dir
        self.config = config or config_path('cell.yaml')
        params = load_parameter_file(self.config)
        self._settings = parse(PositionerSettings,
                               node_parameters(params, names.NODE_POSITIONER))
        self._heartbeat_timeout = parse(DriverSettings, node_parameters(
            params, names.NODE_DRIVER)).command.heartbeat_timeout
        self._stack = contextlib.ExitStack()
        self.domain = self._stack.enter_context(free_domain())
        self.procs = self._stack.enter_context(
            Processes(cell_environment(self.domain), log_dir))
        client = self._stack.enter_context(CellClient(self.domain, CLIENT_NODE))
        super().__init__(client)
        node = client.node
        self._guard = threading.Lock()
        self._statuses: dict[str, list[tuple[float, DiagnosticStatus]]] = {
            names.STATUS_POSITIONER: [], names.STATUS_POSITIONER_INPUTS: [],
            names.STATUS_DRIVER: []}
        self._answers: list[tuple[float, DiagnosticStatus]] = []
        self._truth: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._true_pose: list[tuple[float, np.ndarray]] = []
        self._estimates: list[tuple[float, np.ndarray]] = []
        self._sigma = math.nan
        # rclpy hands a two-argument callback the MessageInfo too (its stubs do not say so)
        node.create_subscription(DiagnosticArray, names.DIAGNOSTICS,
                                 self._on_diagnostics,  # type: ignore[arg-type]
                                 DIAGNOSTICS_QOS)
        node.create_subscription(DiagnosticStatus, names.TRAJECTORY_STATUS, self._on_answer,
                                 STREAM_QOS)
        node.create_subscription(JointState, names.TRUE_JOINT_STATES, self._on_truth,
                                 STREAM_QOS)
        node.create_subscription(PoseStamped, names.TRUE_POSE, self._on_true_pose, STREAM_QOS)
        node.create_subscription(PoseWithCovarianceStamped, names.MEASURED_POSE,
                                 self._on_measured, STREAM_QOS)
        node.create_subscription(PoseStamped, names.ESTIMATED_POSE, self._on_estimate,
                                 STREAM_QOS)
        overrides = log_dir / 'fault_matrix.yaml'
        overrides.write_text(f'{names.NODE_RECORDER}:\n  ros__parameters:\n'
                             f'    output: {log_dir / "bag"}\n')
        self._params = [self.config, overrides]

    # -- what the client sees -------------------------------------------------------------------
    def _on_diagnostics(self, msg: DiagnosticArray, info: dict[str, int]) -> None:
        now = published_monotonic(info)
        with self._guard:
            for status in msg.status:
                into = self._statuses.get(status.name)
                if into is not None:
                    into.append((now, status))
                    del into[:-KEPT_STATUSES]

    def _on_answer(self, msg: DiagnosticStatus) -> None:
        with self._guard:
            self._answers.append((time.monotonic(), msg))
            del self._answers[:-KEPT_STATUSES]

    def _on_truth(self, msg: JointState) -> None:
        with self._guard:
            self._truth.append((time.monotonic(), np.array(msg.position),
                                np.array(msg.velocity)))
            del self._truth[:-KEPT_TRUTH]

    def _on_true_pose(self, msg: PoseStamped) -> None:
        with self._guard:
            self._true_pose.append((time.monotonic(), pose_arrays(msg.pose)[0]))
            del self._true_pose[:-KEPT_POSES]

    def _on_estimate(self, msg: PoseStamped) -> None:
        with self._guard:
            self._estimates.append((time.monotonic(), pose_arrays(msg.pose)[0]))
            del self._estimates[:-KEPT_POSES]

    def _on_measured(self, msg: PoseWithCovarianceStamped) -> None:
        self._sigma = float(np.sqrt(np.max(np.diag(
            np.reshape(msg.pose.covariance, (6, 6)))[:3])))

    @property
    def positioner_settings(self) -> PositionerSettings:
        return self._settings

    @property
    def heartbeat_timeout(self) -> float:
        return self._heartbeat_timeout

    def monotonic(self) -> float:
        return time.monotonic()

    def result_after(self, since: float) -> Report | None:
        with self._guard:
            statuses = list(self._statuses[names.STATUS_POSITIONER])
        for t, status in statuses:
            code = status_values(status).get('code', '')
            if t > since and code:
                return Report(t, code, status.message)
        return None

    def status_after(self, status: str, since: float, words: str) -> Report | None:
        with self._guard:
            found = next(((t, s) for t, s in self._statuses[status]
                          if t > since and words in s.message), None)
        if found is None:
            return None
        return Report(found[0], status_values(found[1]).get('code', ''), found[1].message)

    def true_states(self, since: float) -> TrueStates:
        with self._guard:
            taken = [x for x in self._truth if x[0] > since]
        if not taken:
            return TrueStates.empty()
        return TrueStates(np.array([t for t, _, _ in taken]),
                          np.array([p for _, p, _ in taken]),
                          np.array([v for _, _, v in taken]))

    def true_position_after(self, since: float) -> FloatArray | None:
        with self._guard:
            return next((p for t, p in self._true_pose if t > since), None)

    def estimates(self, since: float) -> FloatArray:
        with self._guard:
            taken = [p for t, p in self._estimates if t > since]
        return np.array(taken).reshape(-1, 3)

    def tracker_sigma(self) -> float:
        return self._sigma

    def check(self, position: ArrayLike, quaternion: ArrayLike) -> Moved:
        asked = self.monotonic()
        if self.client.plan(names.CHECK_POSE, position, quaternion, timeout=10.0):
            return Moved(True, 'success', 'the goal can be reached')
        refusal = wait_until(lambda: self.result_after(asked), 10.0, 'the refusal')
        return Moved(False, refusal.code, refusal.message)

    # -- processes ------------------------------------------------------------------------------
    def start(self) -> None:
        """Start every process, wait until each answers, home (the trials' ready state)."""
        for node in (*names.CELL_NODES, names.RECORDER):
            self.procs.start(node.executable, params=self._params, label=node.executable)
        for node in (*names.CELL_NODES, names.RECORDER):
            wait_until(partial(self.client.spinning, node.name), 90.0, f'{node.name} to answer')
        ready(self, 'none')

    def kill(self, node: str) -> None:
        os.killpg(self.procs.procs[_node(node).executable].pid, signal.SIGKILL)

    def restart(self, node: str) -> None:
        cell_node = _node(node)
        self.procs.stop(cell_node.executable, signal.SIGKILL, grace=5.0)
        self.procs.start(cell_node.executable, params=self._params, label=cell_node.executable)
        self.client.forget(cell_node.name)
        wait_until(lambda: self.client.spinning(cell_node.name), 90.0,
                   f'{cell_node.name} to answer')

    def running(self, node: str) -> bool:
        return _node(node).executable not in self.procs.dead()

    def forgotten(self, node: str) -> bool:
        return _node(node).name not in self.client.node.get_node_names()

    def close(self) -> dict[str, int]:
        """Stop every process (SIGINT); their exit codes."""
        try:
            return self.procs.stop()
        finally:
            self._stack.close()

    def __enter__(self) -> FaultCell:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- injections -----------------------------------------------------------------------------
    def set_parameter(self, node: str, name: str, value: ParameterValue) -> None:
        try:
            result = self.client.set_parameter(node, name, value)
        except TimeoutError as err:  # a node gone, hung, or this client: what its log says
            label = _node(node).executable
            raise TimeoutError(f'{err}; exited: {self.procs.dead() or "none"}; the end of '
                               f'{label}\'s log:\n{self.procs.log(label)[-LOG_TAIL:]}') from None
        if not result.successful:
            raise ProcedureError(f'{node} refused {name} = {value!r}: {result.reason}')

    def enable_drives(self, on: bool) -> None:
        response = self.client.call(SetBool, names.DRIVER_ENABLE, SetBool.Request(data=on))
        if not response.success:
            raise ProcedureError(f'{names.DRIVER_ENABLE} {on}: {response.message}')

    def _answer_after(self, since: float) -> tuple[float, DiagnosticStatus] | None:
        with self._guard:
            return next(((t, s) for t, s in self._answers if t > since), None)

    def foreign_trajectory(self, joints: FloatArray, ahead: float,
                           timeout: float) -> tuple[float, Report]:
        here = self.true_states(-math.inf).positions[-1]
        node = self.client.node
        msg = JointTrajectory(joint_names=list(JOINT_NAMES))
        msg.header.stamp = (node.get_clock().now() + Duration(seconds=ahead)).to_msg()
        msg.points = [JointTrajectoryPoint(positions=here.tolist(), velocities=[0.0] * 6,
                                           time_from_start=duration(0.0)),
                      JointTrajectoryPoint(positions=np.asarray(joints).tolist(),
                                           velocities=[0.0] * 6,
                                           time_from_start=duration(20.0))]
        created = time.monotonic()
        publisher = node.create_publisher(JointTrajectory, names.JOINT_TRAJECTORY, COMMAND_QOS)
        try:
            # The driver reports the new publisher from the graph before it has sent anything
            # (and once it has, both sides have matched: the reaction is the driver's).
            words = f'foreign publisher on {names.JOINT_TRAJECTORY}: /{CLIENT_NODE}'
            wait_until(lambda: self.status_after(names.STATUS_DRIVER, created, words), timeout,
                       f'the driver to report {words!r}')
            sent = time.monotonic()
            publisher.publish(msg)
            received, answer = wait_until(lambda: self._answer_after(sent), timeout,
                                          'the answer')
        finally:
            node.destroy_publisher(publisher)
        values = status_values(answer)
        code = values.get('code', '') if values.get('accepted') == 'false' else 'accepted'
        return sent, Report(received, code, answer.message)

    def spoof(self, topic: str, offset: float, messages: int, period: float) -> float:
        node = self.client.node
        kind = JointState if topic == names.JOINT_STATES else PoseWithCovarianceStamped
        publisher = node.create_publisher(kind, topic, STREAM_QOS)
        try:
            wait_until(lambda: publisher.get_subscription_count() > 0, 10.0,
                       'the cell to match')
            msg = self._spoof_message(kind, offset)
            injected = time.monotonic()
            for _ in range(messages):  # paced like a sensor
                publisher.publish(msg)
                time.sleep(period)
        finally:
            node.destroy_publisher(publisher)
        return injected

    def _spoof_message(self, kind: Any, offset: float) -> Any:
        """A reading ``offset`` off the truth: encoders (leg 1 longer) or tracker (z)."""
        stamp = self.client.node.get_clock().now().to_msg()
        if kind is JointState:
            position = self.true_states(-math.inf).positions[-1].copy()
            position[0] += offset
            return JointState(header=Header(stamp=stamp), name=list(JOINT_NAMES),
                              position=position.tolist(), velocity=[0.0] * 6)
        with self._guard:
            true_position = self._true_pose[-1][1]
        msg = PoseWithCovarianceStamped(header=Header(stamp=stamp, frame_id=names.BASE_FRAME))
        msg.pose.pose = pose_stamped(true_position + [0.0, 0.0, offset],
                                     self._settings.mechanism.home_quaternion, stamp).pose
        msg.pose.covariance = (np.eye(6) * 1e-12).ravel().tolist()
        return msg

    def flood(self, calls: int, bound: float) -> Flood:
        mech = self._settings.mechanism
        goal = MoveCommand(pose=pose_stamped(mech.home_position, mech.home_quaternion,
                                             self.client.node.get_clock().now().to_msg()))
        services: list[tuple[Any, str, Any]] = [
            (MoveToPose, names.MOVE_TO_POSE, MoveToPose.Request(command=goal)),
            (CheckPose, names.CHECK_POSE, CheckPose.Request(command=goal)),
            (Trigger, names.HOME, Trigger.Request()), (Trigger, names.STOP, Trigger.Request()),
            (SetBool, names.DRIVER_ENABLE, SetBool.Request(data=True)),
            (Trigger, names.DRIVER_REFERENCE, Trigger.Request()),
            (Trigger, names.MONITOR_REPORT, Trigger.Request()),
            (Trigger, names.MONITOR_RESET, Trigger.Request()),
            (Trigger, names.RECORDER_PAUSE, Trigger.Request()),
            (Trigger, names.RECORDER_RESUME, Trigger.Request())]
        for srv, name, _ in services:
            self.client.service(srv, name, wait=10.0)
        started = time.monotonic()
        futures = {name: self.client.call_many(srv, name, [request] * calls)
                   for srv, name, request in services}
        every = [f for mine in futures.values() for f in mine]
        with contextlib.suppress(TimeoutError):
            wait_until(lambda: all(f.done() for f in every), bound, 'every answer')
        elapsed = time.monotonic() - started
        answered = {name: sum(f.done() and f.result() is not None for f in mine)
                    for name, mine in futures.items()}
        self.client.trigger(names.RECORDER_RESUME)  # the flood paused it last, perhaps
        return Flood({name: len(mine) for name, mine in futures.items()}, answered, elapsed)
