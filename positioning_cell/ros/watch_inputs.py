"""What a watch window reads of the running cell, into a
:class:`~positioning_cell.watch.state.WatchState`: the command, the estimate, the tracker's
measurements, the coordinate systems, the positioner's state, the monitor's verdicts and the
recorder's status, and
two other nodes' parameters (the accuracy monitor's tolerances, the tracker's target layout),
asked for until they answer and followed on /parameter_events. Read-only: nothing here
publishes to the cell or sets anything. Used by ``live_view_node`` and ``cell watch``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from positioning_cell_interfaces.action import Home, MoveToPose
from positioning_cell_interfaces.msg import AxisRanges as AxisRangesMsg
from positioning_cell_interfaces.msg import CoordinateSystems as CoordinateSystemsMsg
from rcl_interfaces.msg import ParameterEvent, ParameterValue
from rcl_interfaces.srv import GetParameters
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from positioning_cell import names
from positioning_cell.accuracy.monitor import TOLERANCES_PREFIX
from positioning_cell.accuracy.verdicts import Tolerances
from positioning_cell.errors import PositioningError
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.metrology.targets import TargetLayout
from positioning_cell.polling import backoff
from positioning_cell.recording.status import RecorderReport
from positioning_cell.ros import messages as m
from positioning_cell.ros import operator_messages as om
from positioning_cell.ros.parameters import parse_answer, requested_names
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, LATCHED_QOS, SERVICE_QOS
from positioning_cell.sim.pose_measurement import TARGETS_PREFIX
from positioning_cell.watch.state import Snapshot, Status, WatchState

#: A viewer takes the newest samples and never holds a writer back: best effort, shallow.
WATCH_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                       reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)
#: How often another node's parameters are asked for until it answers, s (a graph query
#: while its service is not there): first every ASK_PERIOD, 1.5 times longer after each
#: attempt that finds no service, at most every ASK_PERIOD_MAX (an absent node costs next to
#: nothing, one that comes is asked within ASK_PERIOD_MAX).
ASK_PERIOD, ASK_PERIOD_MAX = 0.05, 0.5
#: A request unanswered (or answered with values that do not parse) is asked again after
#: ANSWER_WAIT s, 1.5 times longer after each request, at most every ANSWER_WAIT_MAX s:
#: discovery is not symmetric, and an answer the server sends before it has matched this
#: client's reader is lost (the match takes tens to hundreds of ms after the service shows;
#: a first wait of 2 s put 2 s on ``cell watch``'s first table one start in two).
ANSWER_WAIT, ANSWER_WAIT_MAX = 0.25, 2.0


class RemoteParameters:
    """The parameters under ``prefix`` of settings type ``cls`` on node ``remote``, parsed and
    passed to ``apply`` when first answered and after each change on /parameter_events (a
    value that does not parse is logged and ignored)."""

    def __init__(self, node: Node, remote: str, cls: type, prefix: str,
                 apply: Callable[[Any], None]) -> None:
        self.node, self.remote, self.cls, self.prefix, self.apply = \
            node, remote, cls, prefix, apply
        self.names = requested_names(cls, prefix)
        self.values: dict[str, ParameterValue] | None = None
        # One GetParameters client, not rclpy's AsyncParameterClient: that one also makes
        # set_parameters clients, and a viewer must have no means to change another node
        # (test_live_view_node.test_the_live_view_commands_nothing).
        self._client = node.create_client(GetParameters, f'/{remote}/get_parameters',
                                          qos_profile=SERVICE_QOS)
        self._pending: Any = None
        self._requests = 0
        self._period = ASK_PERIOD
        self._timer = node.create_timer(ASK_PERIOD, self._ask)
        self._events = node.create_subscription(ParameterEvent, names.PARAMETER_EVENTS,
                                                self._on_event, 100)
        self._ask()

    def _ask(self) -> None:
        if self.values is not None:
            self._timer.cancel()
            return
        if self._pending is not None:  # unanswered for a period (ANSWER_WAIT): asked again
            self._client.remove_pending_request(self._pending)
            self._pending = None
        if self._client.service_is_ready():
            self._pending = self._client.call_async(GetParameters.Request(names=self.names))
            self._pending.add_done_callback(self._on_answer)
            period = backoff(self._requests, ANSWER_WAIT, ANSWER_WAIT_MAX)
            self._requests += 1
        else:
            period = min(ASK_PERIOD_MAX, 1.5 * self._period)
        if period != self._period:
            self._period = period
            self._timer.timer_period_ns = int(period * 1e9)
            self._timer.reset()  # the new period from now (rcl would apply it after a tick)

    def close(self) -> None:
        """Stop asking and following: its timer, client and subscription leave the node
        (which may go on without them)."""
        self._timer.cancel()
        if self._pending is not None:
            self._client.remove_pending_request(self._pending)
            self._pending = None
        self.node.destroy_subscription(self._events)
        self.node.destroy_client(self._client)
        self.node.destroy_timer(self._timer)

    def _on_answer(self, future: Any) -> None:
        if future is self._pending:
            self._pending = None
        if future.cancelled():
            return
        response = future.result()
        if response is None or len(response.values) != len(self.names):
            return
        self._set(dict(zip(self.names, response.values, strict=True)))

    def _on_event(self, event: ParameterEvent) -> None:
        if event.node != f'/{self.remote}' or self.values is None:
            return
        changed = {p.name: p.value for p in [*event.new_parameters, *event.changed_parameters]
                   if p.name in self.names}
        if changed:
            self._set({**self.values, **changed})

    def _set(self, values: dict[str, ParameterValue]) -> None:
        try:
            parsed: Any = parse_answer(self.cls, self.prefix, [values[n] for n in self.names])
        except PositioningError as err:
            self.node.get_logger().warning(f'/{self.remote} {self.prefix}*: {err}')
            return
        self.values = values
        self.apply(parsed)


class WatchInputs:
    """Subscriptions of ``node`` feeding ``state``; ``on_measurement()`` runs after each
    tracker measurement is stored (the live view sends from there)."""

    def __init__(self, node: Node, state: WatchState,
                 on_measurement: Callable[[], None] | None = None) -> None:
        self.node, self.state = node, state
        self._on_measurement = on_measurement
        self.rejected = 0
        node.create_subscription(PoseStamped, names.TARGET, self._target, LATCHED_QOS)
        node.create_subscription(PoseStamped, names.SETPOINT, self._setpoint, WATCH_QOS)
        # The goals' own feedback (any client's move or homing): phase and progress at the
        # action's period, finer than the positioner's 1 Hz status.
        for action, name in ((MoveToPose, names.MOVE_ACTION), (Home, names.HOME_ACTION)):
            node.create_subscription(action.Impl.FeedbackMessage, f'{name}/_action/feedback',
                                     self._feedback, WATCH_QOS)
        # The estimate comes at the encoders' rate (100 Hz) and only the newest is drawn: taken
        # serialised, deserialised once per send (:meth:`snapshot`).
        self._estimate_raw: bytes | None = None
        node.create_subscription(PoseStamped, names.ESTIMATED_POSE, self._estimate, WATCH_QOS,
                                 raw=True)
        node.create_subscription(PoseWithCovarianceStamped, names.MEASURED_POSE,
                                 self._measured, WATCH_QOS)
        node.create_subscription(CoordinateSystemsMsg, names.COORDINATE_SYSTEMS, self._systems,
                                 LATCHED_QOS)
        node.create_subscription(AxisRangesMsg, names.AXIS_RANGES, self._ranges, LATCHED_QOS)
        node.create_subscription(DiagnosticArray, names.DIAGNOSTICS, self._diagnostics,
                                 DIAGNOSTICS_QOS)
        self.parameters = [
            RemoteParameters(node, names.NODE_MONITOR, Tolerances, TOLERANCES_PREFIX,
                             state.tolerances),
            RemoteParameters(node, names.NODE_MEASUREMENT, TargetLayout, TARGETS_PREFIX,
                             lambda layout: state.targets(layout.array))]

    def close(self) -> None:
        """Stop asking other nodes for their parameters."""
        for remote in self.parameters:
            remote.close()

    def _guard(self, what: str, update: Callable[[], None]) -> bool:
        """Run ``update``; a message the state refuses is counted and logged, never fatal."""
        try:
            update()
            return True
        except PositioningError as err:
            self.rejected += 1
            self.node.get_logger().warning(f'{what} ignored: {err}',
                                           throttle_duration_sec=5.0)
            return False

    def _target(self, msg: PoseStamped) -> None:
        self._guard(names.TARGET, lambda: self.state.command(
            *m.pose_arrays(msg.pose), m.seconds(msg.header.stamp)))

    def _feedback(self, msg: Any) -> None:
        now = self.node.get_clock().now().nanoseconds * 1e-9
        self.state.goal_progress(str(msg.feedback.phase_name), float(msg.feedback.progress), now)

    def _setpoint(self, msg: PoseStamped) -> None:
        self._guard(names.SETPOINT, lambda: self.state.setpoint(
            *m.pose_arrays(msg.pose), m.seconds(msg.header.stamp)))

    def _estimate(self, raw: bytes) -> None:
        self._estimate_raw = raw

    def snapshot(self) -> Snapshot:
        """The state now, with the newest estimate taken in."""
        raw, self._estimate_raw = self._estimate_raw, None
        if raw is not None:
            msg = deserialize_message(raw, PoseStamped)
            self._guard(names.ESTIMATED_POSE,
                        lambda: self.state.estimate(*m.pose_arrays(msg.pose)))
        return self.state.snapshot()

    def _measured(self, msg: PoseWithCovarianceStamped) -> None:
        reading = m.measurement(msg)
        if self._guard(names.MEASURED_POSE, lambda: self.state.measurement(
                reading.position, reading.quaternion, reading.covariance,
                m.seconds(msg.header.stamp))) and self._on_measurement is not None:
            self._on_measurement()

    def _systems(self, msg: CoordinateSystemsMsg) -> None:
        self._guard(names.COORDINATE_SYSTEMS, lambda: self.state.coordinate_systems(
            CoordinateSystems(om.transform(msg.user), om.transform(msg.object))))

    def _ranges(self, msg: AxisRangesMsg) -> None:
        self._guard(names.AXIS_RANGES, lambda: self.state.axis_ranges(om.axis_ranges(msg)[0]))

    def _diagnostics(self, msg: DiagnosticArray) -> None:
        now = self.node.get_clock().now().nanoseconds * 1e-9
        for status in msg.status:
            if status.name == names.STATUS_POSITIONER:
                self.state.positioner(Status(m.status_level(status), status.message, now,
                                             m.status_values(status)))
            elif status.name == names.STATUS_DRIVER:
                self.state.driver(Status(m.status_level(status), status.message, now,
                                         m.status_values(status)))
            elif status.name == names.STATUS_MONITOR_VERDICT:
                self.state.verdict(Status(m.status_level(status), status.message, now))
            elif status.name == names.STATUS_RECORDER:
                self.state.recorder(RecorderReport(m.status_level(status), status.message,
                                                   m.status_values(status), now))


__all__ = ['WATCH_QOS', 'RemoteParameters', 'WatchInputs']
