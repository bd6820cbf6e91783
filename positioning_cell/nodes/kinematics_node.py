"""kinematics_node (node `positioner`): pose commands by service → validated, compensated joint
trajectories for the leg driver; the pose estimate from the encoders; closed-loop correction
from the laser tracker. All decisions are library calls (trajectory, limits, clearance,
positioner); this file moves messages."""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Point, PoseStamped, PoseWithCovarianceStamped
from nav_msgs.msg import Path
from nav_msgs.srv import GetPlan
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from positioning_cell import clearance, kinematics
from positioning_cell.errors import PositioningError
from positioning_cell.mechanism import JOINT_NAMES
from positioning_cell.nodes.common import (
    COMMAND_QOS,
    LATCHED_QOS,
    STREAM_QOS,
    Parameters,
    ParamSpec,
    diagnostic,
    flat_block,
    joint_values,
    mechanism_from,
    mechanism_specs,
    pose_arrays,
    pose_stamped,
    run,
)
from positioning_cell.positioner import (
    CompensationMode,
    State,
    Tolerance,
    corrected_command,
    deviation,
    joints_arrived,
    mean_pose,
    validate_goal,
)
from positioning_cell.trajectory import MotionLimits, Trajectory, plan_move

MODES = tuple(m.value for m in CompensationMode)
SPECS = [
    *mechanism_specs(),
    ParamSpec('compensation.mode', 'measured', 'none | model | measured', choices=MODES),
    ParamSpec('compensation.clearance.model', 'effective_length',
              'clearance model used for compensation: none | effective_length | vector | load',
              choices=('none', 'effective_length', 'vector', 'load'), read_only=True),
    ParamSpec('compensation.clearance.r_a', 0.16e-3, 'U-joint clearance, m', 0.0, 0.01,
              read_only=True),
    ParamSpec('compensation.clearance.r_b', 0.16e-3, 'S-joint clearance, m', 0.0, 0.01,
              read_only=True),
    ParamSpec('compensation.clearance.seed', -1, 'seed of the direction draws (-1: none)',
              read_only=True),
    *(ParamSpec(f'compensation.clearance.{k}', [0.0], f'{k} per leg, rad (empty: drawn)',
                read_only=True) for k in ('delta_a1', 'delta_a2', 'delta_b1', 'delta_b2')),
    ParamSpec('compensation.max_iterations', 5, 'closed-loop corrections per move', 0, 50),
    ParamSpec('compensation.samples', 10, 'tracker samples averaged per correction', 1, 200),
    ParamSpec('tolerance.position', 10e-6, 'settle tolerance (position), m', 0.0, 0.01),
    ParamSpec('tolerance.orientation', 1e-4, 'settle tolerance (orientation), rad', 0.0, 0.1),
    ParamSpec('motion.linear_speed', 0.01, 'm/s', 1e-5, 1.0),
    ParamSpec('motion.linear_acceleration', 0.05, 'm/s^2', 1e-5, 10.0),
    ParamSpec('motion.angular_speed', 0.1, 'rad/s', 1e-5, 10.0),
    ParamSpec('motion.angular_acceleration', 0.5, 'rad/s^2', 1e-5, 100.0),
    ParamSpec('trajectory.period', 0.01, 'spacing of trajectory points, s', 0.001, 0.5),
    ParamSpec('arrival.length_tolerance', 5e-6, 'encoder arrival tolerance, m', 0.0, 0.01),
    ParamSpec('arrival.theta_tolerance', 5e-5, 'encoder arrival tolerance, rad', 0.0, 0.1),
    ParamSpec('arrival.length_speed', 2e-4, 'at rest below this speed, m/s', 0.0, 1.0),
    ParamSpec('arrival.theta_speed', 2e-3, 'at rest below this speed, rad/s', 0.0, 1.0),
    ParamSpec('arrival.timeout', 5.0, 'extra time to arrive after the trajectory ends, s',
              0.1, 120.0),
    ParamSpec('settle_time', 0.2, 'dwell after arrival before the pose counts as settled, s',
              0.0, 10.0),
    ParamSpec('measurement_timeout', 5.0, 'wait for tracker samples, s', 0.1, 60.0),
    ParamSpec('pose_rate_hz', 50.0, 'rate of /positioner/pose and markers, Hz', 1.0, 200.0),
]


class MoveAbortedError(Exception):
    """A move ended before it settled; the message says why."""


class Positioner(Node):
    """The `positioner` node (design/interfaces.md)."""

    def __init__(self) -> None:
        super().__init__('positioner')
        self.params = Parameters(self, SPECS, validate=self._model_from)
        self.mech = mechanism_from(self.params.values)
        kinematics.warm_up()  # compiled FK ready before the first command
        self.model = self._model_from(self.params.values)
        self.cond = threading.Condition()
        self.busy = threading.Lock()
        self.joints: tuple[np.ndarray, np.ndarray] | None = None
        self.metrology: list[tuple[np.ndarray, np.ndarray]] = []
        self.metrology_count = 0
        self.driver: dict[str, str] = {}
        self.command: tuple[np.ndarray, np.ndarray] | None = None
        self.estimate: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.path_log: list[Any] | None = None
        self.stop_requested = False
        self.state, self.reason = State.IDLE, 'waiting for encoder readings'
        topics, services = MutuallyExclusiveCallbackGroup(), ReentrantCallbackGroup()
        self.pub_traj = self.create_publisher(JointTrajectory, '/legs/joint_trajectory',
                                              COMMAND_QOS)
        self.pub_target = self.create_publisher(PoseStamped, '/positioner/target', LATCHED_QOS)
        self.pub_pose = self.create_publisher(PoseStamped, '/positioner/pose', STREAM_QOS)
        self.pub_markers = self.create_publisher(MarkerArray, '/positioner/markers', 10)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(JointState, '/legs/joint_states', self._on_joints, STREAM_QOS,
                                 callback_group=topics)
        self.create_subscription(PoseWithCovarianceStamped, '/metrology/pose',
                                 self._on_metrology, STREAM_QOS, callback_group=topics)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 50,
                                 callback_group=topics)
        for name, srv, cb in (('move_to_pose', GetPlan, self._srv_move),
                              ('check_pose', GetPlan, self._srv_check),
                              ('home', Trigger, self._srv_home),
                              ('stop', Trigger, self._srv_stop)):
            self.create_service(srv, f'/positioner/{name}', cb, callback_group=services)
        self.create_timer(1.0 / self.params['pose_rate_hz'], self._publish_pose,
                          callback_group=topics)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=topics)

    # -- parameters --------------------------------------------------------------------------
    def _model_from(self, values: dict[str, Any]) -> clearance.ClearanceModel:
        block = flat_block(values, 'compensation.clearance')
        seed = int(block.pop('seed'))
        for k in ('delta_a1', 'delta_a2', 'delta_b1', 'delta_b2'):
            if len(block[k]) != 3:
                block.pop(k)
        rng = np.random.default_rng(seed) if seed >= 0 else None
        return clearance.model_from_params(block, mechanism_from(values), rng)

    @property
    def mode(self) -> CompensationMode:
        return CompensationMode(self.params['compensation.mode'])

    def _now(self) -> Any:
        return self.get_clock().now().to_msg()

    # -- subscriptions -----------------------------------------------------------------------
    def _on_joints(self, msg: JointState) -> None:
        pos, vel = joint_values(msg, JOINT_NAMES), joint_values(msg, JOINT_NAMES, 'velocity')
        if pos is None:
            return
        with self.cond:
            self.joints = (pos, vel if vel is not None else np.zeros(6))
            self.cond.notify_all()

    def _on_metrology(self, msg: PoseWithCovarianceStamped) -> None:
        with self.cond:
            self.metrology.append(pose_arrays(msg.pose.pose))
            self.metrology_count += 1
            del self.metrology[:-200]
            self.cond.notify_all()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith('leg_driver'):
                with self.cond:
                    self.driver = {kv.key: kv.value for kv in status.values}
                    self.driver['level'] = str(int.from_bytes(status.level, 'little')
                                               if isinstance(status.level, bytes)
                                               else status.level)
                    self.driver['message'] = status.message
                    self.cond.notify_all()

    # -- pose estimate -----------------------------------------------------------------------
    def _publish_pose(self) -> None:
        with self.cond:
            joints = self.joints
        if joints is None:
            return
        model = None if self.mode is CompensationMode.NONE else self.model
        phi0 = self.estimate[2] if self.estimate is not None else None
        try:
            fk = clearance.attained_pose(self.mech, model, joints[0][:3], joints[0][3:], phi0)
        except PositioningError as err:
            self._set_state(State.FAULT, f'pose estimate failed: {err}')
            return
        if not fk.converged[0]:
            self._set_state(State.FAULT, 'forward kinematics did not converge for the '
                                         f'encoder readings {joints[0].tolist()}')
            return
        self.estimate = (fk.position[0], fk.quaternion[0], fk.phis[0])
        msg = pose_stamped(fk.position[0], fk.quaternion[0], self._now())
        self.pub_pose.publish(msg)
        if self.path_log is not None:
            self.path_log.append(msg)
        self.pub_markers.publish(self._markers(fk.position[0], fk.quaternion[0], msg.header))
        if self.state is State.IDLE and self.reason == 'waiting for encoder readings':
            self._set_state(State.IDLE, 'ready')

    def _markers(self, p: np.ndarray, q: np.ndarray, header: Any) -> MarkerArray:
        top = kinematics.platform_points(self.mech, p[None], q[None])[0]
        legs = Marker(header=header, ns='legs', id=0, type=Marker.LINE_LIST, action=Marker.ADD)
        legs.scale.x, legs.color.r, legs.color.g, legs.color.a = 0.004, 0.2, 0.6, 1.0
        legs.points = [Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))
                       for pair in zip(self.mech.base_joints, top, strict=True) for v in pair]
        plate = Marker(header=header, ns='platform', id=1, type=Marker.LINE_STRIP,
                       action=Marker.ADD)
        plate.scale.x, plate.color.b, plate.color.a = 0.003, 1.0, 1.0
        plate.points = [Point(x=float(v[0]), y=float(v[1]), z=float(v[2]))
                        for v in (*top, top[0])]
        return MarkerArray(markers=[legs, plate])

    # -- services ----------------------------------------------------------------------------
    def _srv_check(self, request: GetPlan.Request, response: GetPlan.Response) -> Any:
        try:
            goal = self._goal(request)
            traj = self._plan(*goal)
        except (PositioningError, MoveAbortedError) as err:
            return self._refuse(response, str(err))
        response.plan = self._path(traj)
        return response

    def _srv_move(self, request: GetPlan.Request, response: GetPlan.Response) -> Any:
        if not self.busy.acquire(blocking=False):
            return self._refuse(response, 'busy: a move is in progress')
        try:
            goal = self._goal(request)
            tol = Tolerance(request.tolerance or self.params['tolerance.position'],
                            self.params['tolerance.orientation'])
            response.plan = self._execute(*goal, tol)
        except (PositioningError, MoveAbortedError) as err:
            return self._refuse(response, str(err))
        finally:
            self.busy.release()
        return response

    def _srv_home(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        plan = self._srv_move(GetPlan.Request(goal=pose_stamped(
            self.mech.home_position, self.mech.home_quaternion, self._now())),
            GetPlan.Response())
        response.success = bool(plan.plan.poses)
        response.message = 'at home' if response.success else self.reason
        return response

    def _srv_stop(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        self.stop_requested = True
        self.pub_traj.publish(JointTrajectory(joint_names=list(JOINT_NAMES)))
        with self.cond:
            self.cond.notify_all()
        response.success, response.message = True, 'stopping with controlled deceleration'
        return response

    def _refuse(self, response: GetPlan.Response, reason: str) -> GetPlan.Response:
        self.get_logger().warn(f'refused: {reason}')
        self._set_state(State.ABORTED if self.state is not State.FAULT else State.FAULT,
                        reason)
        response.plan = Path()
        response.plan.header.frame_id = 'base'
        return response

    # -- moves -------------------------------------------------------------------------------
    def _goal(self, request: GetPlan.Request) -> tuple[np.ndarray, np.ndarray]:
        goal = request.goal
        p, q = pose_arrays(goal.pose)
        return validate_goal(goal.header.frame_id, p, q)

    def _plan(self, p: np.ndarray, q: np.ndarray) -> Trajectory:
        with self.cond:
            driver, command, estimate = dict(self.driver), self.command, self.estimate
        if command is None:  # at start and after an aborted move: where the encoders are
            if estimate is None:
                raise MoveAbortedError('no encoder readings yet from /legs/joint_states')
            command = (estimate[0], estimate[1])
        if driver.get('enabled', 'true').lower() == 'false':
            raise MoveAbortedError('drives disabled: enable them with /leg_driver/enable')
        if driver.get('state') == 'fault':
            raise MoveAbortedError(f'drive fault: {driver.get("message", "")}; clear it '
                                   'with /leg_driver/enable')
        limits = MotionLimits(*(self.params[f'motion.{k}'] for k in (
            'linear_speed', 'linear_acceleration', 'angular_speed', 'angular_acceleration')))
        model = None if self.mode is CompensationMode.NONE else self.model
        traj = plan_move(self.mech, *command, p, q, period=self.params['trajectory.period'],
                         limits=limits, clearance=model)
        if not traj.limits.ok:
            raise MoveAbortedError(f'path refused, {traj.limits.message()}')
        return traj

    def _execute(self, p: np.ndarray, q: np.ndarray, tol: Tolerance) -> Path:
        self.stop_requested = False
        self.path_log = []
        try:
            self.pub_target.publish(pose_stamped(p, q, self._now()))
            command = (p, q)
            self._go(*command)
            reason = 'settled'
            if self.mode is CompensationMode.MEASURED:
                reason = self._correct(command, p, q, tol)
            self._set_state(State.SETTLED, reason)
            path = Path(poses=self.path_log)
        except MoveAbortedError:
            with self.cond:
                self.command = None  # the axes stopped somewhere else: re-plan from them
            raise
        finally:
            self.path_log = None
        path.header.frame_id, path.header.stamp = 'base', self._now()
        return path

    def _correct(self, command: tuple[np.ndarray, np.ndarray], p: np.ndarray, q: np.ndarray,
                 tol: Tolerance) -> str:
        """Closed loop on /metrology/pose until within ``tol`` or out of iterations."""
        iterations = self.params['compensation.max_iterations']
        for done in range(iterations + 1):
            measured = self._measure()
            e_p, e_r = deviation(*measured, p, q)
            text = (f'measured error {np.linalg.norm(e_p) * 1e6:.1f} um, '
                    f'{np.degrees(np.linalg.norm(e_r)):.5f} deg after {done} corrections')
            if tol.holds(e_p, e_r):
                return f'settled within tolerance: {text}'
            if done == iterations:
                self.get_logger().warn(f'not within tolerance: {text}')
                return f'settled outside tolerance: {text}'
            self._set_state(State.CORRECTING, f'{text}: correcting')
            command = corrected_command(*command, p, q, *measured)
            self._go(*command)
        raise AssertionError('unreachable')

    def _go(self, p: np.ndarray, q: np.ndarray) -> None:
        traj = self._plan(p, q)
        final = np.concatenate([traj.lengths[-1], traj.thetas[-1]])
        msg = JointTrajectory(joint_names=list(JOINT_NAMES))
        msg.header.stamp = self._now()
        for i, t in enumerate(traj.times):
            msg.points.append(JointTrajectoryPoint(
                positions=[*traj.lengths[i], *traj.thetas[i]],
                velocities=[*traj.length_rates[i], *traj.theta_rates[i]],
                time_from_start=Duration(sec=int(t), nanosec=int((t % 1.0) * 1e9))))
        self._set_state(State.MOVING, f'moving for {traj.duration:.2f} s')
        with self.cond:
            self.command = (p, q)
        self.pub_traj.publish(msg)
        tol_p = [self.params['arrival.length_tolerance']] * 3 + [
            self.params['arrival.theta_tolerance']] * 3
        tol_v = [self.params['arrival.length_speed']] * 3 + [
            self.params['arrival.theta_speed']] * 3
        self._wait(lambda: self.joints is not None and joints_arrived(
            self.joints[0], self.joints[1], final, tol_p, tol_v),
            traj.duration + self.params['arrival.timeout'], 'the drives to arrive')
        self._set_state(State.SETTLING, 'settling')
        deadline = time.monotonic() + self.params['settle_time']
        self._wait(lambda: time.monotonic() >= deadline, self.params['settle_time'] + 1.0,
                   'settling')

    def _measure(self) -> tuple[np.ndarray, np.ndarray]:
        n = self.params['compensation.samples']
        with self.cond:
            start = self.metrology_count
        self._wait(lambda: self.metrology_count - start >= n,
                   self.params['measurement_timeout'], f'{n} new samples on /metrology/pose')
        with self.cond:
            samples = self.metrology[-n:]
        return mean_pose([s[0] for s in samples], [s[1] for s in samples])

    def _wait(self, condition: Any, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        with self.cond:
            while not condition():
                if self.stop_requested:
                    raise MoveAbortedError('stopped by /positioner/stop')
                if self.driver.get('state') == 'fault':
                    raise MoveAbortedError(f'drive fault: {self.driver.get("message", "")}')
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise MoveAbortedError(f'timed out after {timeout:.1f} s waiting for {what}')
                self.cond.wait(min(remaining, 0.05))

    # -- diagnostics -------------------------------------------------------------------------
    def _set_state(self, state: State, reason: str) -> None:
        changed = (state, reason) != (self.state, self.reason)
        self.state, self.reason = state, reason
        if changed:
            self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        level = {State.FAULT: 'error', State.ABORTED: 'warn'}.get(self.state, 'ok')
        self.pub_diag.publish(diagnostic(
            'positioner: state', level, f'{self.state.value}: {self.reason}',
            {'state': self.state.value, 'reason': self.reason, 'mode': self.mode.value},
            self._now()))

    def _path(self, traj: Trajectory) -> Path:
        path = Path()
        path.header.frame_id, path.header.stamp = 'base', self._now()
        path.poses = [pose_stamped(traj.position[i], traj.quaternion[i], path.header.stamp)
                      for i in range(len(traj.times))]
        return path


def main(args: list[str] | None = None) -> int:
    """Entry point of `ros2 run positioning_cell kinematics_node`."""
    return run(Positioner, args)


if __name__ == '__main__':
    raise SystemExit(main())
