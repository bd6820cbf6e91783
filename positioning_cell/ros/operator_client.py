"""The ROS half of the operator's client ``cell`` (:mod:`positioning_cell.tools.cell`): the
positioner's operator services and actions as calls that take and give the plain values of
:mod:`positioning_cell.tools.cell_format` (SI), the messages built and read here only; the
goal loop (progress, a cancel on an interrupt or the timeout); and the watch window's inputs.
The command line itself never sees rclpy or a message type."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from positioning_cell_interfaces.action import Home, MoveToPose
from positioning_cell_interfaces.msg import AxisRanges as AxisRangesMsg
from positioning_cell_interfaces.srv import (
    CheckPose,
    DefineCoordinateSystem,
    GetCoordinateSystems,
    GetLimits,
    Jog,
    SelectCoordinateSystems,
    SetCoordinateSystems,
    SetLimits,
    SetSpeed,
)
from rcl_interfaces.srv import GetParameters
from rclpy.node import Node

from positioning_cell import names
from positioning_cell.core.mechanism import MECHANISM_PREFIX, Mechanism
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.frames.transforms import Transform
from positioning_cell.limits.axis_ranges import AxisRanges
from positioning_cell.limits.speed import Speeds
from positioning_cell.ros import cell_messages as cm
from positioning_cell.ros import operator_messages as om
from positioning_cell.ros.client import CellClient, GoalClient
from positioning_cell.ros.messages import (
    measurement,
    pose_arrays,
    pose_msg,
    status_level,
    status_values,
)
from positioning_cell.ros.parameters import parse_answer, requested_names
from positioning_cell.ros.qos import LATCHED_QOS, LATEST_QOS, STREAM_QOS
from positioning_cell.ros.watch_inputs import RemoteParameters, WatchInputs
from positioning_cell.tools import cell_format as cf
from positioning_cell.watch.state import Snapshot, WatchState

if TYPE_CHECKING:
    from positioning_cell.ros.panel_watch_inputs import PanelWatchSource

#: Longest wait for a service or an action server to appear (s; at most the timeout).
SERVER_WAIT = 30.0


# -- the answers of the services ------------------------------------------------------------------
class Limits(NamedTuple):
    """GetLimits: the factory, machine and user boxes, and the factory's constraints."""

    factory: cf.Box
    machine: cf.Box
    user: cf.Box
    constraints: list[str]


class SpeedAnswer(NamedTuple):
    """SetSpeed: taken or not, why, the speeds now and their maxima."""

    success: bool
    reason: str
    current: Speeds
    maximum: Speeds


class JogAnswer(NamedTuple):
    """Jog: taken or not, the outcome's code name, why, the axis position after (m or rad)."""

    success: bool
    code_name: str
    reason: str
    position: float


@dataclass(frozen=True)
class StatusValues:
    """The newest status of one node on /diagnostics: its values, message and level."""

    values: dict[str, str]
    message: str
    level: int


class StatusFeed:
    """What ``cell status`` reads off the topics, subscribed at construction: the positioner's
    and the driver's statuses, the target, the estimate and the tracker's reading; each method
    gives the newest (None while none came)."""

    def __init__(self, cell: CellClient) -> None:
        self._positioner = cell.statuses(names.STATUS_POSITIONER)
        self._driver = cell.statuses(names.STATUS_DRIVER)
        self._targets = cell.collect(PoseStamped, names.TARGET, LATCHED_QOS)
        self._estimates = cell.collect(PoseStamped, names.ESTIMATED_POSE, LATEST_QOS)
        self._measured = cell.collect(PoseWithCovarianceStamped, names.MEASURED_POSE,
                                      STREAM_QOS)
        self._ranges = cell.collect(AxisRangesMsg, names.AXIS_RANGES, LATCHED_QOS)

    @staticmethod
    def _status(statuses: list[Any]) -> StatusValues | None:
        if not statuses:
            return None
        status = statuses[-1]
        return StatusValues(status_values(status), str(status.message), status_level(status))

    @staticmethod
    def _pose(poses: list[Any]) -> tuple[np.ndarray, np.ndarray] | None:
        return pose_arrays(poses[-1].pose) if poses else None

    def positioner(self) -> StatusValues | None:
        """The positioner's newest status."""
        return self._status(self._positioner)

    def driver(self) -> StatusValues | None:
        """The leg driver's newest status."""
        return self._status(self._driver)

    def target(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The newest commanded platform pose (position m, quaternion x, y, z, w)."""
        return self._pose(self._targets)

    def estimate(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The newest estimated platform pose."""
        return self._pose(self._estimates)

    def axis_ranges(self) -> AxisRanges | None:
        """The newest axis ranges from the current user position (None while none came)."""
        return om.axis_ranges(self._ranges[-1])[0] if self._ranges else None

    def measured(self) -> cf.MeasuredValues | None:
        """The tracker's newest reading of the platform pose: the pose, its standard
        uncertainty (6,) and the time it measured (s, the cell's clock; NaN: not stamped)."""
        if not self._measured:
            return None
        reading = measurement(self._measured[-1])
        return cf.MeasuredValues((reading.position, reading.quaternion),
                                 np.sqrt(np.diag(reading.covariance)), reading.stamp)


# -- the client -----------------------------------------------------------------------------------
class OperatorClient:
    """The operator's calls on a :class:`CellClient` of its own on ``node`` (from
    :func:`positioning_cell.ros.early.start_node`: its own context, rclpy's signal handlers
    left out, the command line handles SIGINT and SIGTERM,
    :mod:`positioning_cell.tools.interruption`; shut down by :meth:`close`). Each call waits at
    most ``timeout`` s (TimeoutError: the cell is not there)."""

    def __init__(self, node: Node, timeout: float) -> None:
        self.cell = CellClient(node=node)
        self.timeout = timeout

    def close(self) -> None:
        """Shut the client down."""
        self.cell.close()

    def _call(self, srv_type: Any, name: str, request: Any) -> Any:
        return self.cell.call(srv_type, name, request, self.timeout)

    def _stamp(self) -> Time:
        return self.cell.node.get_clock().now().to_msg()

    def check(self, request: cf.MoveRequest) -> cf.CheckReport:
        """CheckPose: the checks of that move; nothing moves."""
        return cm.check_of(self._call(CheckPose, names.CHECK_POSE, CheckPose.Request(
            command=cm.move_command(request, self._stamp()))))

    def coordinate_systems(self) -> tuple[CoordinateSystems, str]:
        """GetCoordinateSystems: the systems and the file they are kept in."""
        response = self._call(GetCoordinateSystems, names.GET_COORDINATE_SYSTEMS,
                              GetCoordinateSystems.Request())
        return cm.systems_of(response.systems), str(response.file)

    def system_names(self) -> cf.SystemNames:
        """GetCoordinateSystems: the named systems (active and stored names)."""
        r = self._call(GetCoordinateSystems, names.GET_COORDINATE_SYSTEMS,
                       GetCoordinateSystems.Request())
        return cf.SystemNames(str(r.active_user), str(r.active_object),
                              [str(n) for n in r.user_names], [str(n) for n in r.object_names])

    def define_coordinate_system(self, kind: str, name: str, value: Transform,
                                 activate: bool) -> tuple[bool, str]:
        """DefineCoordinateSystem: (taken, why)."""
        response = self._call(DefineCoordinateSystem, names.DEFINE_COORDINATE_SYSTEM,
                              DefineCoordinateSystem.Request(
                                  kind=kind, name=name, pose=pose_msg(*value.to_pq()),
                                  activate=activate))
        return bool(response.success), str(response.reason)

    def select_coordinate_systems(self, user: str, obj: str) -> tuple[bool, str]:
        """SelectCoordinateSystems ('' keeps a kind): (taken, why)."""
        response = self._call(SelectCoordinateSystems, names.SELECT_COORDINATE_SYSTEMS,
                              SelectCoordinateSystems.Request(user=user, object=obj))
        return bool(response.success), str(response.reason)

    def set_coordinate_systems(self, systems: CoordinateSystems) -> tuple[bool, str]:
        """SetCoordinateSystems: (taken, why)."""
        response = self._call(SetCoordinateSystems, names.SET_COORDINATE_SYSTEMS,
                              SetCoordinateSystems.Request(
                                  systems=om.systems_msg(systems.user, systems.object)))
        return bool(response.success), str(response.reason)

    def limits(self) -> Limits:
        """GetLimits."""
        response = self._call(GetLimits, names.GET_LIMITS, GetLimits.Request())
        return Limits(cm.box_of(response.factory), cm.box_of(response.machine),
                      cm.box_of(response.user),
                      [str(c) for c in response.factory_constraints])

    def set_limits(self, machine: cf.Box, user: cf.Box) -> tuple[bool, str]:
        """SetLimits: (taken, why)."""
        response = self._call(SetLimits, names.SET_LIMITS,
                              SetLimits.Request(machine=cm.box_msg(machine),
                                                user=cm.box_msg(user)))
        return bool(response.success), str(response.reason)

    def set_speed(self, request: Speeds) -> SpeedAnswer:
        """SetSpeed (a request that keeps everything is a query)."""
        response = self._call(SetSpeed, names.SET_SPEED,
                              SetSpeed.Request(request=om.speeds_msg(request)))
        return SpeedAnswer(bool(response.success), str(response.reason),
                           om.speeds(response.current), om.speeds(response.maximum))

    def jog(self, axis: str, delta: float) -> JogAnswer:
        """Jog one axis by ``delta`` (m or rad)."""
        response = self._call(Jog, names.JOG, Jog.Request(axis=axis, delta=delta))
        return JogAnswer(bool(response.success), str(response.code_name), str(response.reason),
                         float(response.position))

    def stop(self) -> tuple[bool, str]:
        """The controlled stop: (success, message)."""
        return self.cell.trigger(names.STOP, self.timeout)

    def mechanism(self) -> Mechanism:
        """The positioner's mechanism, from its ``mechanism.*`` parameters (TimeoutError if it
        does not answer; PositioningError if they are not a mechanism)."""
        request = GetParameters.Request(names=requested_names(Mechanism, MECHANISM_PREFIX))
        response = self._call(GetParameters, f'/{names.NODE_POSITIONER}/get_parameters',
                              request)
        return parse_answer(Mechanism, MECHANISM_PREFIX, response.values)

    def status_feed(self) -> StatusFeed:
        """Subscribe to what ``cell status`` shows (:class:`StatusFeed`)."""
        return StatusFeed(self.cell)

    def move(self, request: cf.MoveRequest, interrupts: Callable[[], int],
             note: Callable[[str], None], progress: Callable[[str], None]) -> cf.GoalRun:
        """The move action: the goal sent, its progress drawn, cancelled on an interrupt or
        the timeout (:func:`drive`). TimeoutError if the server is not there."""
        goal = MoveToPose.Goal(command=cm.move_command(request, self._stamp()))
        return self._goal(MoveToPose, names.MOVE_ACTION, goal, cm.move_progress, interrupts,
                          note, progress)

    def home(self, interrupts: Callable[[], int], note: Callable[[str], None],
             progress: Callable[[str], None]) -> cf.GoalRun:
        """The home action (reference if needed, then home), as :meth:`move`."""
        return self._goal(Home, names.HOME_ACTION, Home.Goal(), cm.home_progress, interrupts,
                          note, progress)

    def _goal(self, action_type: Any, name: str, goal: Any, line: Callable[[Any], str],
              interrupts: Callable[[], int], note: Callable[[str], None],
              progress: Callable[[str], None]) -> cf.GoalRun:
        with GoalClient(self.cell, action_type, name) as goals:
            goals.ready(min(self.timeout, SERVER_WAIT))
            return cm.drive(goals, goal, self.timeout, interrupts, note,
                         lambda feedback: progress(line(feedback)))

    def watch_inputs(self) -> WatchSource:
        """The watch window's inputs on this client's node (:class:`WatchSource`)."""
        return WatchSource(self.cell)

    def panel_watch_inputs(self) -> PanelWatchSource:
        """The coordinated cell's watch window's inputs on this client's node
        (:class:`~positioning_cell.ros.panel_watch_inputs.PanelWatchSource`; imported here:
        the coordinated cell's statics are not for every ``cell`` command to load)."""
        from positioning_cell.ros.panel_watch_inputs import PanelWatchSource
        return PanelWatchSource(self.cell.node)


class WatchSource:
    """The watch's inputs on ``client``'s node: the cell's topics and the monitor's and
    tracker's parameters (:class:`~positioning_cell.ros.watch_inputs.WatchInputs`), the
    machine from the positioner's ``mechanism.*``."""

    def __init__(self, client: CellClient) -> None:
        self.state = WatchState(None)
        self.inputs = WatchInputs(client.node, self.state)
        self.machine = RemoteParameters(client.node, names.NODE_POSITIONER, Mechanism,
                                        MECHANISM_PREFIX, self.state.mechanism)

    def snapshot(self) -> Snapshot:
        """The state now."""
        return self.inputs.snapshot()
