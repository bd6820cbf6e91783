"""The positioner's typed services and actions (positioning_cell_interfaces): the move and home
actions with feedback and cancel, the move and check services, coordinate systems, limits,
speeds and jog, each one call into the operator's surface
(:class:`~positioning_cell.motion.controller.Controller`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from positioning_cell_interfaces import action as act
from positioning_cell_interfaces import srv
from positioning_cell_interfaces.msg import AxisRanges as AxisRangesMsg
from positioning_cell_interfaces.msg import CoordinateSystems as CoordinateSystemsMsg
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node

from positioning_cell import names
from positioning_cell.errors import InputError, PositioningError
from positioning_cell.limits.axis_ranges import AxisRanges
from positioning_cell.limits.jog import axis_index
from positioning_cell.limits.range_worker import RangeWorker
from positioning_cell.limits.validity import factory_constraints
from positioning_cell.motion.controller import Controller, MoveCommand
from positioning_cell.motion.mover import MoveAbortedError, MoveResult, ResultCode, State
from positioning_cell.moves.correction import deviation
from positioning_cell.moves.outcomes import Attained
from positioning_cell.moves.trajectory import Trajectory
from positioning_cell.ros import messages as m
from positioning_cell.ros import operator_messages as om
from positioning_cell.ros.goals import run_goal
from positioning_cell.ros.qos import LATCHED_QOS, SERVICE_QOS, STREAM_QOS

#: The action feedback's phase of each state.
_PHASES = {State.MOVING: act.MoveToPose.Feedback.MOVING,
           State.SETTLING: act.MoveToPose.Feedback.SETTLING,
           State.CORRECTING: act.MoveToPose.Feedback.CORRECTING}


class OperatorInterface:
    """The typed services and actions of ``node`` over ``controller`` (README: Interfaces),
    in callback group ``group``; ``status_changed()`` republishes the node's status after a
    change of the operator's settings."""

    def __init__(self, node: Node, controller: Controller, group: CallbackGroup,
                 status_changed: Callable[[], None]) -> None:
        self.node, self.controller = node, controller
        self._status_changed = status_changed
        for name, kind, cb in (
                (names.MOVE_TO_POSE, srv.MoveToPose, self._srv_move),
                (names.CHECK_POSE, srv.CheckPose, self._srv_check),
                (names.STOP_ALONG_PATH, srv.StopAlongPath, self._srv_stop_along),
                (names.SET_COORDINATE_SYSTEMS, srv.SetCoordinateSystems, self._srv_set_systems),
                (names.GET_COORDINATE_SYSTEMS, srv.GetCoordinateSystems, self._srv_get_systems),
                (names.DEFINE_COORDINATE_SYSTEM, srv.DefineCoordinateSystem,
                 self._srv_define_system),
                (names.SELECT_COORDINATE_SYSTEMS, srv.SelectCoordinateSystems,
                 self._srv_select_systems),
                (names.SET_LIMITS, srv.SetLimits, self._srv_set_limits),
                (names.GET_LIMITS, srv.GetLimits, self._srv_get_limits),
                (names.SET_SPEED, srv.SetSpeed, self._srv_set_speed),
                (names.JOG, srv.Jog, self._srv_jog)):
            node.create_service(kind, name, cb, qos_profile=SERVICE_QOS, callback_group=group)
        self.actions = [
            ActionServer(node, act.MoveToPose, names.MOVE_ACTION, self._act_move,
                         cancel_callback=lambda _: CancelResponse.ACCEPT, callback_group=group),
            ActionServer(node, act.Home, names.HOME_ACTION, self._act_home,
                         cancel_callback=lambda _: CancelResponse.ACCEPT, callback_group=group)]
        self._pub_systems = node.create_publisher(CoordinateSystemsMsg, names.COORDINATE_SYSTEMS,
                                                  LATCHED_QOS)
        self._pub_setpoint = node.create_publisher(PoseStamped, names.SETPOINT, STREAM_QOS)
        self._pub_plan = node.create_publisher(Path, names.PLANNED_PATH, LATCHED_QOS)
        self._publish_systems()
        # The axis ranges: searched by a worker process (numba never loaded here), started by
        # the first search; latched: a one-shot reader (cell status) has the last ranges at
        # once. Searched only while someone reads them.
        self.range_worker = RangeWorker()
        controller.range_search = self.range_worker.ranges
        self._pub_ranges = node.create_publisher(AxisRangesMsg, names.AXIS_RANGES, LATCHED_QOS)
        node.create_timer(1.0 / controller.settings.axis_ranges.rate_hz,
                          self.publish_axis_ranges, callback_group=group)

    def _publish_systems(self) -> None:
        """The coordinate systems in force, latched (the watch windows draw the user frame)."""
        systems = self.controller.systems
        self._pub_systems.publish(om.systems_msg(systems.user, systems.object))

    def _now(self) -> Any:
        return self.node.get_clock().now().to_msg()

    def _ranges_msg(self, ranges: AxisRanges) -> Any:
        return om.axis_ranges_msg(ranges, self.controller.named.active_user, self._now())

    def publish_axis_ranges(self) -> None:
        """The axis ranges from the current user position on /positioner/axis_ranges, while
        the topic has a reader."""
        if self._pub_ranges.get_subscription_count() > 0:
            self._pub_ranges.publish(self._ranges_msg(self.controller.current_axis_ranges()))

    def publish_plan(self, traj: Trajectory, start: float | None) -> None:
        """The plan of a trajectory sent to start at ``start`` (ROS time s; None: on receipt,
        now) on /positioner/planned_path."""
        now = self.node.get_clock().now().nanoseconds * 1e-9
        self._pub_plan.publish(m.planned_path(traj, now if start is None else start))

    def publish_setpoint(self, stamp: Any) -> None:
        """The running trajectory's setpoint on /positioner/setpoint (nothing when none runs)."""
        setpoint = self.controller.mover.setpoint()
        if setpoint is not None:
            self._pub_setpoint.publish(m.pose_stamped(*setpoint, stamp))

    # -- moves ----------------------------------------------------------------------------------
    def _resolve(self, command: MoveCommand) -> tuple[Any, Any] | Any:
        """The goal in base of a request, resolved once (the move and its feedback use it), or
        the MoveOutcome of its refusal."""
        op = self.controller
        try:
            return op.resolve(command)
        except InputError as err:
            op.mover.refusal(ResultCode.REFUSED_INVALID_GOAL, str(err))
            return self._not_settled(ResultCode.REFUSED_INVALID_GOAL, str(err), None, None)

    def _not_settled(self, code: ResultCode, reason: str, goal: tuple[Any, Any] | None,
                     where: Attained | None) -> Any:
        """The MoveOutcome of a move that did not settle: where the platform is (``where``, else
        as the positioner knows it now), and its error against ``goal`` if there is one."""
        where = where or self.controller.mover.attained_now()
        user = (None if where is None
                else self.controller.user_position(where.position, where.quaternion))
        return om.outcome(code, reason, goal=goal, user=user, stamp=self._now(), where=where)

    def _outcome(self, result: MoveResult | None, error: BaseException | None,
                 goal: tuple[Any, Any]) -> Any:
        """The MoveOutcome of a move that returned ``result`` or raised ``error``."""
        if isinstance(error, MoveAbortedError):
            return self._not_settled(error.code, str(error), goal, error.attained)
        if error is not None:
            raise error
        assert result is not None
        return om.outcome(ResultCode.SUCCESS, result.reason, result, goal,
                          self.controller.user_position(*om.attained(result, goal)),
                          self._now())

    def _goal(self, goal_handle: Any, kind: Any, run: Callable[[], MoveResult],
              goal: tuple[Any, Any]) -> Any:
        """Run a move for an action goal (:func:`run_goal`: feedback every period, a cancel
        stops the drives); its MoveOutcome."""
        begun = self.controller.mover.state_changes
        ran = run_goal(goal_handle, lambda stop, feedback: run(),
                       on_stop=self.controller.mover.stop,
                       tick=lambda: self._feedback(kind, goal, begun))
        return self._outcome(ran.value, ran.error, goal)

    def _feedback(self, kind: Any, goal: tuple[Any, Any], begun: int) -> Any:
        """The action's feedback now: the phase, the deviation from ``goal``, the progress;
        None (nothing published) while the positioner's state has not changed since the goal
        came (``begun``): the state is still the last command's, and a goal refused before
        it moved showed that one's "settled 100%"."""
        mover = self.controller.mover
        if mover.state_changes == begun:
            return None
        feedback = kind.Feedback()
        state = mover.state
        if hasattr(feedback, 'phase'):
            feedback.phase = _PHASES.get(state, kind.Feedback.PLANNING)
            estimate = mover.estimate
            if estimate is not None:
                e_p, e_r = deviation(estimate.position, estimate.quaternion, *goal)
                feedback.position_error = [float(v) for v in e_p]
                feedback.orientation_error = [float(v) for v in e_r]
        feedback.phase_name = state.value
        feedback.progress = mover.progress() if state is State.MOVING else (
            1.0 if state in (State.SETTLING, State.CORRECTING, State.SETTLED) else 0.0)
        return feedback

    @staticmethod
    def _finish(goal_handle: Any, result: Any) -> Any:
        """End an action goal by its outcome: succeeded, canceled (a requested stop) or
        aborted."""
        code = result.outcome.code_name
        if code == ResultCode.SUCCESS.value:
            goal_handle.succeed()
        elif goal_handle.is_cancel_requested and code == ResultCode.ABORTED_STOP.value:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        return result

    def _act_move(self, goal_handle: Any) -> Any:
        command = om.move_command(goal_handle.request.command)
        goal = self._resolve(command)
        outcome = goal if not isinstance(goal, tuple) else self._goal(
            goal_handle, act.MoveToPose, lambda: self.controller.move(command, resolved=goal),
            goal)
        return self._finish(goal_handle, act.MoveToPose.Result(outcome=outcome))

    def _act_home(self, goal_handle: Any) -> Any:
        mover = self.controller.mover
        outcome = self._goal(goal_handle, act.Home, mover.home,
                             (mover.mech.home_position, mover.mech.home_quaternion))
        return self._finish(goal_handle, act.Home.Result(outcome=outcome))

    # -- services -------------------------------------------------------------------------------
    def _srv_move(self, request: Any, response: Any) -> Any:
        command = om.move_command(request.command)
        goal = self._resolve(command)
        if not isinstance(goal, tuple):
            response.outcome = goal
            return response
        try:
            result = self.controller.move(command, resolved=goal)
        except MoveAbortedError as err:
            response.outcome = self._outcome(None, err, goal)
            return response
        response.outcome = self._outcome(result, None, goal)
        return response

    def _srv_stop_along(self, request: Any, response: Any) -> Any:
        try:
            response.message = self.controller.mover.stop_along(m.seconds(request.start),
                                                                request.duration)
            response.success = True
        except InputError as err:
            response.success, response.message = False, f'refused, nothing changed: {err}'
        return response

    def _srv_check(self, request: Any, response: Any) -> Any:
        check = self.controller.check(om.move_command(request.command))
        response.valid = check.result.valid
        response.validity = om.validity(check.result)
        response.duration = float(check.duration)
        response.axis_ranges = self._ranges_msg(check.ranges)
        if check.goal is not None:
            response.goal = m.pose_stamped(*check.goal, self._now())
        if not check.result.valid:
            self.controller.mover.refusal(check.result.code, f'check: {check.result.message()}')
        return response

    def _srv_set_systems(self, request: Any, response: Any) -> Any:
        return self._systems_changed(response, lambda: self.controller.set_systems(
            om.transform(request.systems.user), om.transform(request.systems.object)))

    def _srv_define_system(self, request: Any, response: Any) -> Any:
        return self._systems_changed(response, lambda: self.controller.define_system(
            str(request.kind), str(request.name), om.transform(request.pose),
            bool(request.activate)))

    def _srv_select_systems(self, request: Any, response: Any) -> Any:
        return self._systems_changed(response, lambda: self.controller.select_systems(
            str(request.user), str(request.object)))

    def _systems_changed(self, response: Any, change: Callable[[], Any]) -> Any:
        """A change of the coordinate systems (``change()`` persists it and gives the file):
        the answer, the systems in force published and on the status; refused with the
        reason, nothing changed."""
        try:
            path = change()
            response.success, response.reason = True, f'coordinate systems written to {path}'
            self._publish_systems()
        except (InputError, PositioningError) as err:
            response.success, response.reason = False, str(err)
        self._status_changed()
        return response

    def _srv_get_systems(self, request: Any, response: Any) -> Any:
        op = self.controller
        response.systems = om.systems_msg(op.systems.user, op.systems.object)
        response.file = str(op.systems_file)
        named = op.named
        response.active_user, response.active_object = named.active_user, named.active_object
        response.user_names, response.object_names = sorted(named.users), sorted(named.objects)
        return response

    def _srv_set_limits(self, request: Any, response: Any) -> Any:
        try:
            self.controller.set_limits(om.box(request.machine), om.box(request.user))
            response.success, response.reason = True, 'limits set'
        except InputError as err:
            response.success, response.reason = False, str(err)
        return response

    def _srv_get_limits(self, request: Any, response: Any) -> Any:
        layers = self.controller.layers
        response.factory = om.box_msg(layers.factory_box)
        response.machine = om.box_msg(layers.machine_box)
        response.user = om.box_msg(layers.user_box)
        response.factory_constraints = factory_constraints(self.controller.mover.mech)
        return response

    def _srv_set_speed(self, request: Any, response: Any) -> Any:
        op = self.controller
        try:
            op.set_speeds(om.speeds(request.request))
            response.success, response.reason = True, 'speeds set'
        except InputError as err:
            response.success, response.reason = False, str(err)
        response.current, response.maximum = om.speeds_msg(op.speeds), om.speeds_msg(op.maxima)
        self._status_changed()
        return response

    def _srv_jog(self, request: Any, response: Any) -> Any:
        try:
            reading = self.controller.jog(request.axis, float(request.delta))
            response.success, response.code_name = True, ResultCode.SUCCESS.value
            response.reason = f'jogged {request.axis}'
            response.position = float(reading.position[axis_index(request.axis)])
        except MoveAbortedError as err:
            response.success, response.code_name, response.reason = False, err.code.value, str(err)
        return response
