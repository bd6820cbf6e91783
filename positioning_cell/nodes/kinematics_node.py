"""kinematics_node (node ``positioner``): pose commands → controller → mover → joint trajectories
and their plans; the pose from the encoders, the machine for ROS tools, /diagnostics."""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from sensor_msgs.msg import JointState, Temperature
from std_msgs.msg import Header
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory

from positioning_cell import names
from positioning_cell.motion.controller import Controller
from positioning_cell.motion.inputs import inputs_report
from positioning_cell.motion.mover import (
    Machine,
    MoveAbortedError,
    Mover,
    PositionerSettings,
    ResultCode,
    State,
)
from positioning_cell.motion.state_log import StateLog
from positioning_cell.nodes.operator_interface import OperatorInterface
from positioning_cell.ros import messages as m
from positioning_cell.ros import qos
from positioning_cell.ros.latest import SourceReader
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos_watch import QosWatchedNode
from positioning_cell.ros.registration import RegistrationReader
from positioning_cell.ros.robot_state import RobotState
from positioning_cell.ros.senders import own_publisher_ids
from positioning_cell.ros.spin import NodeStart, Spin, aside_node

_LEVELS = {State.FAULT: 'error', State.ABORTED: 'warn'}


class PositionerNode(QosWatchedNode):
    """The ``positioner`` node (docs/conventions/interfaces.md)."""

    NAME = names.NODE_POSITIONER
    SETTINGS = PositionerSettings

    def __init__(self, **kwargs: Any) -> None:
        self._state_log = StateLog()  # before the first state is reported
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS, lambda s, _: self.mover.reconfigure(s),
                                     lambda s, _: self.mover.prepare(s))
        settings = self.params.settings
        src, self._inputs_message = settings.sources, ''
        self._inputs = self._joints, self._tracker, self._answers = (  # from their source only
            SourceReader(self, JointState, names.JOINT_STATES, src.leg_driver,
                         qos.JOINT_READER_QOS),
            SourceReader(self, PoseWithCovarianceStamped, names.MEASURED_POSE, src.tracker,
                         qos.STREAM_QOS),
            SourceReader(self, DiagnosticStatus, names.TRAJECTORY_STATUS, src.leg_driver,
                         qos.STREAM_QOS))
        self._registration = RegistrationReader(self, src.tracker)
        self.pub_traj = self.create_publisher(JointTrajectory, names.JOINT_TRAJECTORY,
                                              qos.COMMAND_QOS)
        self.pub_target = self.create_publisher(PoseStamped, names.TARGET, qos.LATCHED_QOS)
        self.pub_pose = self.create_publisher(PoseStamped, names.ESTIMATED_POSE, qos.STREAM_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                              qos.DIAGNOSTICS_QOS)
        topics, services = MutuallyExclusiveCallbackGroup(), ReentrantCallbackGroup()
        self._reference = self.create_client(Trigger, names.DRIVER_REFERENCE,
                                             callback_group=topics)
        self.mover = Mover(settings, Machine(
            send_trajectory=self._send,
            stop_drives=lambda: self.pub_traj.publish(m.stop_trajectory()),
            publish_target=lambda p, q: self.pub_target.publish(m.pose_stamped(p, q,
                                                                               self._now())),
            latest_joints=lambda: m.joint_reading(self._joints.newest()),
            new_measurements=lambda: [m.measurement(x) for x in self._tracker.take()],
            trajectory_answers=lambda: [a for s in self._answers.take()
                                        if (a := m.answer(s)) is not None],
            reference_drives=self._reference_drives,
            drives_connected=lambda: (self.pub_traj.get_subscription_count() > 0
                                      and self._answers.publisher_count() > 0),
            state_changed=self._state_changed,
            refused=self._refused,
            identity=self.get_fully_qualified_name(),
            publisher_ids=lambda: own_publisher_ids(self, self.pub_traj.topic_name),
            registration=self._registration.take))
        self.controller = Controller(self.mover, settings.operator)  # ConfigError: no start
        self.robot = RobotState(self, self.mover.mech, settings.markers_every,
                                lambda: self.controller.systems)
        self.create_subscription(DiagnosticArray, names.DIAGNOSTICS, self._on_diagnostics,
                                 qos.DIAGNOSTICS_QOS, callback_group=topics)
        self.create_subscription(Temperature, names.AIR_TEMPERATURE, self._on_temperature,
                                 qos.STREAM_QOS, callback_group=topics)
        for name, kind, cb in ((names.HOME, Trigger, self._srv_home),
                               (names.STOP, Trigger, self._srv_stop)):
            self.create_service(kind, name, cb, qos_profile=qos.SERVICE_QOS,
                                callback_group=services)
        self.operator = OperatorInterface(self, self.controller, services,
                                          self._publish_diagnostics)
        aside_node(self, 'outputs', [(1.0 / settings.pose_rate_hz, self._publish_pose),
                                     (1.0, self._publish_diagnostics)])  # off this executor
        # The heartbeat on a group of its own: a slow pose estimate never delays it.
        beat = self.create_publisher(Header, names.HEARTBEAT, qos.HEARTBEAT_QOS)
        self.create_timer(settings.liveness.heartbeat_period,
                          lambda: beat.publish(Header(stamp=self._now())),
                          callback_group=MutuallyExclusiveCallbackGroup())

    def _send(self, traj: Any, start: float | None) -> None:
        self.pub_traj.publish(m.joint_trajectory(traj, start))
        self.operator.publish_plan(traj, start)

    def _reference_drives(self) -> bool:
        """Ask the drives to reference (False: the service is not there, nothing sent)."""
        if not self._reference.service_is_ready():
            return False
        self._reference.call_async(Trigger.Request())
        return True

    def _now(self) -> Any:
        return self.get_clock().now().to_msg()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == names.STATUS_DRIVER:
                self.mover.driver_status({**m.status_values(status), 'message': status.message})

    def _on_temperature(self, msg: Temperature) -> None:  # refused: on the compensation status
        self.mover.air_temperature(msg.temperature, msg.variance)

    # -- outputs --------------------------------------------------------------------------------
    def _publish_pose(self) -> None:
        estimate = self.mover.estimate_pose()
        if any(reader.unreported() for reader in self._inputs):
            self._publish_inputs()
        if estimate is None:
            return
        msg = m.pose_stamped(estimate.position, estimate.quaternion, self._now())
        self.pub_pose.publish(msg)
        self.operator.publish_setpoint(msg.header.stamp)
        self.robot.publish(estimate.position, estimate.quaternion, msg.header.stamp)

    def _status(self, level: str, message: str, code: ResultCode | None, each: bool = False
                ) -> None:
        if self._state_log.logs(level, message, each):
            self.get_logger().warning(message)
        op = getattr(self, 'controller', None)
        values = {**self.mover.status_values(code), **(op.status_values() if op else {})}
        self.pub_diag.publish(m.diagnostic(names.STATUS_POSITIONER, level, message, values,
                                           self._now()))

    def _state_changed(self, state: State, reason: str, code: ResultCode | None) -> None:
        """A new state (the result code of the move it ends, if any) on /diagnostics."""
        self._status(_LEVELS.get(state, 'ok'), f'{state.value}: {reason}', code)

    def _publish_diagnostics(self) -> None:
        self._state_changed(self.mover.state, self.mover.reason, None)
        self._publish_inputs()
        self.pub_diag.publish(m.diagnostic(names.STATUS_POSITIONER_COMPENSATION,
                                           *self.mover.compensation_report(), self._now()))

    def _publish_inputs(self) -> None:
        """Who else publishes on the inputs (ignored): ERROR while any does, logged once."""
        level, message, values = inputs_report({r.topic: r.foreign() for r in self._inputs},
                                               [r.source for r in self._inputs])
        if level != 'ok' and message != self._inputs_message:
            self.get_logger().error(message)
        self._inputs_message = message
        self.pub_diag.publish(m.diagnostic(names.STATUS_POSITIONER_INPUTS, level, message,
                                           values, self._now()))

    def _refused(self, code: ResultCode, reason: str) -> None:
        self._status('warn', f'refused ({code.value}): {reason}', code, each=True)

    # -- services -------------------------------------------------------------------------------
    def _srv_home(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        try:
            response.message = f'at home, referenced; {self.mover.home().reason}'
            response.success = True
        except MoveAbortedError as err:
            response.success, response.message = False, f'{err.code.value}: {err}'
        return response

    def _srv_stop(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        response.success, response.message = True, self.mover.stop()
        return response

    def close(self) -> None:
        """At shutdown: a running move ends aborted and the drives stop; the range worker ends."""
        self.mover.stop()
        self.operator.range_worker.close()


#: The entry point of ``kinematics_node`` (alone; ``cell_container`` hosts it with others).
main = NodeStart(PositionerNode, Spin.THREADS, threads=6, imports=())


if __name__ == '__main__':
    raise SystemExit(main())
