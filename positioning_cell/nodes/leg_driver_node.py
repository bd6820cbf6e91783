"""leg_driver_node (node ``leg_driver``): the simulated drives and encoders of the three legs
(:mod:`positioning_cell.sim.drives`).

Follows /legs/joint_trajectory from its commander alone (``command.commander``, the
positioner: each message is taken with the node that published it,
:mod:`positioning_cell.nodes.senders`) after checking it against the command bounds and every
axis limit (an empty one stops with controlled deceleration; a zero header stamp starts on
receipt), and answers each on /legs/trajectory_status; stops a move when the commander's
heartbeat (/positioner/heartbeat) falls silent; reports any other publisher on its command
topic; publishes the encoder readings on /legs/joint_states and the truth on
/sim/legs/true_joint_states. One physics timer does it all, in this order: take the commands
that came (decoded as arrays, :mod:`positioning_cell.sim.trajectory_wire`, so a long
trajectory costs milliseconds, not a stalled publication), integrate, publish. Switched by
/leg_driver/enable, referenced by /leg_driver/reference; reports on /diagnostics.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from std_srvs.srv import SetBool, Trigger
from trajectory_msgs.msg import JointTrajectory

from positioning_cell import names
from positioning_cell.core import kinematics
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.nodes import messages as m
from positioning_cell.nodes.parameters import NodeParameters
from positioning_cell.nodes.qos import (
    COMMAND_QOS,
    DIAGNOSTICS_QOS,
    HEARTBEAT_QOS,
    SERVICE_QOS,
    STREAM_QOS,
)
from positioning_cell.nodes.senders import IdentifiedSubscription, Taken
from positioning_cell.nodes.spin import run
from positioning_cell.sim.drives import (
    DriverSettings,
    LegDriver,
    Outcome,
    Prepared,
    foreign_sender,
)
from positioning_cell.sim.guard import Refusal, TrajectoryRefusedError
from positioning_cell.sim.trajectory_wire import (
    Peek,
    TrajectoryWireError,
    decode_joint_trajectory,
    peek,
)

#: How often the graph is asked who publishes on the command topic, s.
GRAPH_PERIOD_S = 0.25


class LegDriverNode(Node):
    """The ``leg_driver`` node (README: nodes, topics, services)."""

    NAME = names.NODE_DRIVER
    SETTINGS = DriverSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS, self._on_change)
        settings = self.params.settings
        kinematics.warm_up()  # compiled FK ready for the efforts
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
        # Trajectories from the commander wait here, in order, for the checker thread.
        self._queue: deque[tuple[Taken, float, Peek]] = deque()
        self._checker = ThreadPoolExecutor(max_workers=1, thread_name_prefix='trajectory_checks')
        self._work: Future[Prepared | Outcome] | None = None
        self._cancelled = False
        self.create_service(SetBool, names.DRIVER_ENABLE, self._on_enable,
                            qos_profile=SERVICE_QOS)
        self.create_service(Trigger, names.DRIVER_REFERENCE, self._on_reference,
                            qos_profile=SERVICE_QOS)
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
        """The commander's heartbeats and every trajectory that came since the last step: a
        foreign one refused and a stop applied at once, the others queued for the checker
        thread (:meth:`_pump`)."""
        now, command = self._now(), self.driver.settings.command
        if any(t.sender == command.commander for t in self._heartbeats.take()):
            self.driver.heartbeat(now)
        for taken in self._commands.take():
            if taken.sender != command.commander:
                if self.driver.note_foreign(taken.sender):
                    self.get_logger().error(f'foreign publisher on {names.JOINT_TRAJECTORY}: '
                                            f'{taken.sender}')
                self._finish(self.driver.refuse(Refusal.FOREIGN_SENDER,
                                                foreign_sender(taken.sender, command)))
                continue
            try:
                header = peek(taken.data)
            except TrajectoryWireError as err:
                self._finish(self.driver.refuse(Refusal.INVALID_GOAL,
                                                f'not a trajectory the drives take: {err}'))
                continue
            if header.points == 0:
                self._stop_now(now)
            else:
                self._queue.append((taken, now, header))
        self._pump(now)

    def _stop_now(self, now: float) -> None:
        """The commander's stop: at once; what it sent before and is not following yet is
        superseded."""
        superseded = len(self._queue) + (self._work is not None)
        self._queue.clear()
        self._cancelled = self._work is not None
        self._report(self.driver.stop(now))
        for _ in range(superseded - self._cancelled):
            self._finish(self.driver.refuse(Refusal.SUPERSEDED, 'superseded by a stop before '
                                            'it was checked'))

    def _pump(self, now: float) -> None:
        """Apply the trajectory the checker thread has finished (in the order received), then
        hand it the next: the checks of a long trajectory (tens of ms for 50 000 points) run
        beside the physics and publication, never in their way."""
        if self._work is not None:
            if not self._work.done():
                return
            prepared = self._work.result()
            self._work = None
            if self._cancelled:
                self._cancelled = False
                key = prepared.key
                self._finish(self.driver.refuse(Refusal.SUPERSEDED, 'superseded by a stop '
                                                'before it started', key))
            else:
                self._finish(self.driver.apply(prepared, now))
        if self._queue and self._work is None:
            taken, received, header = self._queue.popleft()
            start = (None if header.stamp == (0, 0) else
                     (Time(seconds=header.stamp[0], nanoseconds=header.stamp[1]).nanoseconds
                      - self._t0) * 1e-9)
            self._work = self._checker.submit(self._prepare, taken, received, start,
                                              self.driver.setpoint_at(start, received))

    def _prepare(self, taken: Taken, received: float, start: float | None,
                 setpoint: tuple[Any, Any]) -> Prepared | Outcome:
        """On the checker thread: decode and check (:meth:`LegDriver.prepare`)."""
        try:
            msg = decode_joint_trajectory(taken.data, self.driver.settings.command.max_points)
        except TrajectoryWireError as err:
            code = Refusal.TOO_MANY_POINTS if 'max_points' in str(err) else Refusal.INVALID_GOAL
            return Outcome(False, f'trajectory refused: not a trajectory the drives take: '
                                  f'{err}', '', code)
        return self.driver.prepare(msg.joint_names, msg.times, msg.positions, msg.velocities,
                                   start, received, taken.sender, setpoint)

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
        if self.driver.publishers(self._commands.publishers()):
            if self.driver.foreign:
                self.get_logger().error(f'foreign publisher on {names.JOINT_TRAJECTORY}: '
                                        f'{", ".join(self.driver.foreign)}')
            self._report()

    def close(self) -> None:
        """At shutdown: the checker thread stops (what it checks is not applied)."""
        self._checker.shutdown(wait=False, cancel_futures=True)

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


def main(args: list[str] | None = None) -> int:
    """Entry point of ``leg_driver_node``."""
    return run(LegDriverNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
