"""kinematics_node (node ``positioner``): pose commands by service → the move state machine
(:mod:`positioning_cell.motion.mover`) → joint trajectories for the leg driver; the pose
estimated from the encoders on /positioner/pose; the state on /diagnostics."""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from nav_msgs.srv import GetPlan
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray

from positioning_cell import names
from positioning_cell.core import kinematics
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.motion.mover import (
    JointReading,
    Machine,
    MoveAbortedError,
    Mover,
    PositionerSettings,
    State,
)
from positioning_cell.motion.trajectory import Trajectory
from positioning_cell.nodes import messages as m
from positioning_cell.nodes.latest import Reader
from positioning_cell.nodes.parameters import NodeParameters
from positioning_cell.nodes.qos import COMMAND_QOS, DIAGNOSTICS_QOS, LATCHED_QOS, STREAM_QOS
from positioning_cell.nodes.spin import Spin, run

_LEVELS = {State.FAULT: 'error', State.ABORTED: 'warn'}


class PositionerNode(Node):
    """The ``positioner`` node (README: nodes, topics, services)."""

    NAME = names.NODE_POSITIONER
    SETTINGS = PositionerSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS, self._on_change)
        settings = self.params.settings
        kinematics.warm_up()  # compiled FK ready before the first command
        self._joints = Reader(self, JointState, names.JOINT_STATES)
        self._tracker = Reader(self, PoseWithCovarianceStamped, names.MEASURED_POSE, STREAM_QOS)
        self.pub_traj = self.create_publisher(JointTrajectory, names.JOINT_TRAJECTORY,
                                              COMMAND_QOS)
        self.pub_target = self.create_publisher(PoseStamped, names.TARGET, LATCHED_QOS)
        self.pub_pose = self.create_publisher(PoseStamped, names.ESTIMATED_POSE, STREAM_QOS)
        self.pub_markers = self.create_publisher(MarkerArray, names.MARKERS, STREAM_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                              DIAGNOSTICS_QOS)
        self.mover = Mover(settings, Machine(
            send_trajectory=self._send, stop_drives=self._stop_drives,
            publish_target=lambda p, q: self.pub_target.publish(m.pose_stamped(p, q,
                                                                               self._now())),
            latest_joints=self._latest_joints, new_measurements=self._new_measurements,
            state_changed=lambda state, reason: self._publish_diagnostics()))
        self._estimates = 0
        topics, services = MutuallyExclusiveCallbackGroup(), ReentrantCallbackGroup()
        self.create_subscription(DiagnosticArray, names.DIAGNOSTICS, self._on_diagnostics,
                                 DIAGNOSTICS_QOS, callback_group=topics)
        for name, srv, cb in ((names.MOVE_TO_POSE, GetPlan, self._srv_move),
                              (names.CHECK_POSE, GetPlan, self._srv_check),
                              (names.HOME, Trigger, self._srv_home),
                              (names.STOP, Trigger, self._srv_stop)):
            self.create_service(srv, name, cb, callback_group=services)
        self.create_timer(1.0 / settings.pose_rate_hz, self._publish_pose, callback_group=topics)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=topics)

    def _now(self) -> Any:
        return self.get_clock().now().to_msg()

    def _on_change(self, settings: PositionerSettings, changed: frozenset[str]) -> None:
        self.mover.reconfigure(settings)

    # -- the mover's world ----------------------------------------------------------------------
    def _send(self, traj: Trajectory) -> None:
        self.pub_traj.publish(m.joint_trajectory(traj, self._now()))

    def _stop_drives(self) -> None:
        self.pub_traj.publish(m.stop_trajectory())

    def _latest_joints(self) -> JointReading | None:
        msg = self._joints.newest()
        if msg is None:
            return None
        position = m.joint_values(msg, JOINT_NAMES)
        velocity = m.joint_values(msg, JOINT_NAMES, 'velocity')
        if position is None or velocity is None:
            return None
        return JointReading(position, velocity)

    def _new_measurements(self) -> list[Any]:
        return [m.pose_arrays(msg.pose.pose) for msg in self._tracker.take()]

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith(names.STATUS_DRIVER):
                values = {kv.key: kv.value for kv in status.values}
                values.update(level=str(m.status_level(status)), message=status.message)
                self.mover.driver_status(values)

    # -- outputs --------------------------------------------------------------------------------
    def _publish_pose(self) -> None:
        estimate = self.mover.estimate_pose()
        if estimate is None:
            return
        msg = m.pose_stamped(estimate.position, estimate.quaternion, self._now())
        self.pub_pose.publish(msg)
        self._estimates += 1
        if self._estimates % self.params.settings.markers_every == 0:
            mech = self.mover.mech
            top = kinematics.platform_points(mech, estimate.position[None],
                                             estimate.quaternion[None])[0]
            self.pub_markers.publish(m.platform_markers(mech.base_joints, top, msg.header))

    def _publish_diagnostics(self) -> None:
        mover = self.mover
        level = _LEVELS.get(mover.state, 'ok')
        if level != 'ok':
            self.get_logger().warning(f'{mover.state.value}: {mover.reason}')
        self.pub_diag.publish(m.diagnostic(
            names.STATUS_POSITIONER, level, f'{mover.state.value}: {mover.reason}',
            {'state': mover.state.value, 'reason': mover.reason, 'mode': mover.mode.value},
            self._now()))

    # -- services -------------------------------------------------------------------------------
    def _srv_check(self, request: GetPlan.Request, response: GetPlan.Response) -> Any:
        goal = request.goal
        try:
            traj = self.mover.check(goal.header.frame_id, *m.pose_arrays(goal.pose))
        except MoveAbortedError:
            response.plan = m.path_msg([], [], self._now())
            return response
        response.plan = m.path_msg(traj.position, traj.quaternion, self._now())
        return response

    def _srv_move(self, request: GetPlan.Request, response: GetPlan.Response) -> Any:
        goal = request.goal
        try:
            result = self.mover.move(goal.header.frame_id, *m.pose_arrays(goal.pose),
                                     tolerance=request.tolerance)
        except MoveAbortedError:
            response.plan = m.path_msg([], [], self._now())
            return response
        response.plan = m.path_msg(result.positions, result.quaternions, self._now())
        return response

    def _srv_home(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        try:
            self.mover.home()
        except MoveAbortedError as err:
            response.success, response.message = False, str(err)
            return response
        response.success, response.message = True, 'at home'
        return response

    def _srv_stop(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        response.success, response.message = True, self.mover.stop()
        return response


def main(args: list[str] | None = None) -> int:
    """Entry point of `ros2 run positioning_cell kinematics_node`."""
    return run(PositionerNode, args, Spin.THREADS)


if __name__ == '__main__':
    raise SystemExit(main())
