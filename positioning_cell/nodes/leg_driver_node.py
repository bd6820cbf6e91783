"""leg_driver_node (node ``leg_driver``): the simulated drives and encoders of the three legs
(:mod:`positioning_cell.sim.drives`).

Follows /legs/joint_trajectory from its commander alone (``command.commander``, the
positioner: each message is taken with the node that published it,
:mod:`positioning_cell.ros.senders`) after checking it against the command bounds and every
axis limit (an empty one stops with controlled deceleration; a zero header stamp starts on
receipt), and answers each on /legs/trajectory_status; stops a move when the commander's
heartbeat (/positioner/heartbeat) falls silent; reports any other publisher on its command
topic; publishes the encoder readings on /legs/joint_states and the truth on
/sim/legs/true_joint_states. One physics timer does it all, in this order: take the commands
that came, apply those whose checks are done (:mod:`positioning_cell.sim.commands`: decoded as
arrays and checked on a thread of their own, so a long trajectory never holds up a
publication), integrate, publish. Switched by /leg_driver/enable, referenced by
/leg_driver/reference; reports on /diagnostics. In a coordinated cell the wrench the panel
puts on the platform (/sim/platform/panel_wrench, simulation truth from the panel simulator) is
part of the load the efforts hold: what the legs' load cells read (JointState effort; with
``panel_pushes``, no effort before the first push).
"""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory

from positioning_cell import names
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.ros import messages as m
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import (
    COMMAND_QOS,
    DIAGNOSTICS_QOS,
    HEARTBEAT_QOS,
    SERVICE_QOS,
    STREAM_QOS,
)
from positioning_cell.ros.senders import IdentifiedSubscription
from positioning_cell.ros.spin import NodeStart
from positioning_cell.sim.commands import CommandQueue
from positioning_cell.sim.drives import DriverSettings, LegDriver, Outcome
from positioning_cell.sim.guard import TrajectoryRefusedError

#: How often the graph is asked who publishes on the command topic, s.
GRAPH_PERIOD_S = 0.25


class LegDriverNode(Node):
    """The ``leg_driver`` node (docs/conventions/interfaces.md)."""

    NAME = names.NODE_DRIVER
    SETTINGS = DriverSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS, self._on_change)
        settings = self.params.settings
        self._t0 = self.get_clock().now().nanoseconds
        self.driver = LegDriver(settings, self._now())
        self._states = self.create_publisher(JointState, names.JOINT_STATES, STREAM_QOS)
        self._truth = self.create_publisher(JointState, names.TRUE_JOINT_STATES, STREAM_QOS)
        self._diagnostics = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                                  DIAGNOSTICS_QOS)
        self._answers = self.create_publisher(DiagnosticStatus, names.TRAJECTORY_STATUS,
                                              STREAM_QOS)
        self._commands = IdentifiedSubscription(self, JointTrajectory, names.JOINT_TRAJECTORY,
                                                COMMAND_QOS)
        self._heartbeats = IdentifiedSubscription(self, Header, names.HEARTBEAT, HEARTBEAT_QOS)
        self.queue = CommandQueue(self.driver, self._t0)
        self.create_service(SetBool, names.DRIVER_ENABLE, self._on_enable,
                            qos_profile=SERVICE_QOS)
        self.create_service(Trigger, names.DRIVER_REFERENCE, self._on_reference,
                            qos_profile=SERVICE_QOS)
        # the coordinated cell's panel pushing on the platform (simulation truth, as the rest)
        self.create_subscription(WrenchStamped, names.PANEL_WRENCH,
                                 lambda msg: self.driver.push(m.wrench_of(msg)), STREAM_QOS)
        self.create_timer(1.0 / settings.physics_rate, self._step)
        self.create_timer(settings.diagnostics_period, self._report)
        self.create_timer(GRAPH_PERIOD_S, self._watch_graph)
        self._watch_graph()
        self._report()

    def _now(self) -> float:
        """Seconds since the node started (the drives' time base)."""
        return (self.get_clock().now().nanoseconds - self._t0) * 1e-9

    def _stamp(self, t: float) -> Any:
        return Time(nanoseconds=self._t0 + round(t * 1e9)).to_msg()

    def _on_change(self, settings: DriverSettings, changed: frozenset[str]) -> None:
        self.driver.reconfigure(settings, changed, self._now())
        self._report()

    def _step(self) -> None:
        self._take_commands()
        step = self.driver.step(self._now())
        if step.fault is not None:
            self.get_logger().error(f'{step.fault.message()}; motion stopped')
            self._report()
        if step.stopped is not None:
            self.get_logger().error(step.stopped)
            self._report(step.stopped, 'error')
        if step.publish:
            reading, true_state = self.driver.readings()
            effort = self.driver.effort if self.driver.effort is not None else ()
            stamp = self._stamp(self.driver.servos.time)
            self._states.publish(m.joint_state(JOINT_NAMES, stamp, reading.position,
                                               reading.velocity, effort))
            self._truth.publish(m.joint_state(JOINT_NAMES, stamp, true_state.position,
                                              true_state.velocity, effort))

    def _take_commands(self) -> None:
        """The commander's heartbeats and the commands that came since the last step
        (:class:`~positioning_cell.sim.commands.CommandQueue`)."""
        now = self._now()
        if any(t.sender == self.driver.settings.command.commander
               for t in self._heartbeats.take()):
            self.driver.heartbeat(now)
        for taken in self._commands.take():
            outcomes, stopped = self.queue.receive(taken.data, taken.sender, now)
            if stopped is not None:
                self._report(stopped)
            for outcome in outcomes:
                self._finish(outcome)
        for outcome in self.queue.pump(now):
            self._finish(outcome)

    def _finish(self, outcome: Outcome) -> None:
        """Answer a trajectory and report what became of it."""
        self._answer(outcome)
        if outcome.accepted:
            self._report(outcome.message)
        else:
            self.get_logger().warning(outcome.message)
            self._report(outcome.message, 'warn')

    def _watch_graph(self) -> None:
        """Who publishes on the command topic: the commander seen, others reported."""
        if self.driver.publishers([(e.node, e.gid.hex()) for e in self._commands.endpoints()]):
            if self.driver.foreign:
                self.get_logger().error(f'foreign publisher on {names.JOINT_TRAJECTORY}: '
                                        f'{", ".join(self.driver.foreign)}')
            self._report()

    def close(self) -> None:
        """At shutdown: the checker thread stops (what it checks is not applied)."""
        self.queue.close()

    def _answer(self, outcome: Outcome) -> None:
        """The answer to a trajectory, keyed by its fingerprint (/legs/trajectory_status)."""
        values = {'key': outcome.key, 'accepted': str(outcome.accepted).lower(),
                  'code': outcome.code.value if outcome.code else '',
                  'sequence': str(outcome.sequence)}
        self._answers.publish(m.status(names.STATUS_TRAJECTORY,
                                       'ok' if outcome.accepted else 'error', outcome.message,
                                       values, hardware_id='leg_drives'))

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response) -> Any:
        response.success, response.message = True, self.driver.enable(request.data,
                                                                      self._now())
        self._report(response.message)
        return response

    def _on_reference(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        try:
            response.success, response.message = True, self.driver.reference(self._now())
        except TrajectoryRefusedError as err:
            response.success, response.message = False, str(err)
        self._report(response.message)
        return response

    def _report(self, event: str | None = None, level: str | None = None) -> None:
        level, message, values = self.driver.status(event, level)
        self._diagnostics.publish(m.diagnostic(names.STATUS_DRIVER, level, message, values,
                                               self._stamp(self.driver.servos.time),
                                               hardware_id='leg_drives'))


#: The entry point of ``leg_driver_node`` (alone; ``cell_container`` hosts it with others). It
#: imports no scipy as it spins: its work needs none, and the import beside its first
#: trajectory held its 100 Hz encoder stream up to 0.32 s (test_node_start).
main = NodeStart(LegDriverNode, imports=())


if __name__ == '__main__':
    raise SystemExit(main())
