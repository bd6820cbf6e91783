"""cell_coordinator_node (node ``cell_coordinator``): one panel moved by several (issue 27).

The cell file (``cell_file``) names the positioners, each a node set under its namespace.
/cell_coordinator/move (MoveToPose: the panel frame in ``cell``) runs
:meth:`~positioning_cell.coordinated.coordinator.Coordinator.move` on the sets
(:class:`~positioning_cell.ros.set_port.RosSetPort`) in a worker thread, the force watch fed
with each set's tracker readings and plans; one command at a time; a cancel, /…/stop or a
shutdown stops every positioner; /…/relax and /…/relax_forces relax the panel at rest. A new
``cell_file`` (the same positioners) from the next panel move on, without the corrections."""

from __future__ import annotations

import threading
from functools import partial
from itertools import product
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Path
from positioning_cell_interfaces.action import MoveToPose
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.coordinated.coordinator import Coordinator, PanelOutcome
from positioning_cell.coordinated.force_watch import force_watch
from positioning_cell.coordinated.settings import CellCoordinatorSettings, replacing
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.ros import messages as m
from positioning_cell.ros import panel_messages as pm
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.goals import OneGoal, Ran, run_goal
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, LATCHED_QOS, STREAM_QOS
from positioning_cell.ros.qos_watch import QosWatchedNode
from positioning_cell.ros.set_port import RosSetPort
from positioning_cell.ros.spin import NodeStart, Spin

#: Longest wait at shutdown for a running panel move to stop every positioner, s; the status
#: period, s.
CLOSE_WAIT_S, STATUS_PERIOD_S = 10.0, 1.0
#: What each set sends the force watch: its tracker's readings and its plans (QoS).
FED = (('reading', PoseWithCovarianceStamped, names.MEASURED_POSE, STREAM_QOS),
       ('plan', Path, names.PLANNED_PATH, LATCHED_QOS))


class CellCoordinatorNode(QosWatchedNode):
    """The ``cell_coordinator`` node (module docstring)."""

    NAME = names.NODE_COORDINATOR
    SETTINGS = CellCoordinatorSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS, self._new_cell, self._check_cell)
        settings = self.params.settings
        self.cell, self._strain = settings.cell(), settings.relax.strain_map()  # kept over files
        self._watch = force_watch(self.cell, settings.mechanism)  # ConfigError: not held
        self._client: CellClient | None = None
        self._coordinator: Coordinator | None = None
        self._lock = threading.Lock()
        self._goal = OneGoal(self.get_logger(), 'panel move')
        self.last: PanelOutcome | None = None
        self.pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                              DIAGNOSTICS_QOS)
        group = ReentrantCallbackGroup()
        self._server = ActionServer(self, MoveToPose, names.COORDINATED_MOVE_ACTION,
                                    self._execute, goal_callback=self._goal.accept,
                                    cancel_callback=lambda _: CancelResponse.ACCEPT,
                                    callback_group=group)
        for name, serve in ((names.COORDINATED_STOP, self._srv_stop),
                            (names.COORDINATED_RELAX, partial(self._srv_relax, 'relax')),
                            (names.COORDINATED_RELAX_FORCES,
                             partial(self._srv_relax, 'relax_forces'))):
            self.create_service(Trigger, name, serve, callback_group=group)
        self.create_timer(STATUS_PERIOD_S, self._status)
        for entry, (kind, kind_type, topic, qos) in product(self.cell.positioners, FED):
            self.create_subscription(kind_type, names.in_set(topic, entry.name), partial(
                self._feed, entry.name, kind), qos, callback_group=group)

    def _check_cell(self, settings: CellCoordinatorSettings, changed: frozenset[str]) -> None:
        """A new ``cell_file``: refused during a move, or unless of the same positioners."""
        if 'cell_file' in changed and self._goal.busy:
            raise ConfigError('cell_file: refused while a panel move runs')
        if 'cell_file' in changed:  # ConfigError: other positioners, or a panel not held
            force_watch(replacing(self.cell, settings.cell()), settings.mechanism)

    def _new_cell(self, settings: CellCoordinatorSettings, changed: frozenset[str]) -> None:
        if 'cell_file' in changed:
            with self._lock:  # the coordinator is built again on it at its next use
                self.cell, self._coordinator = settings.cell(), None
                self._watch = force_watch(self.cell, settings.mechanism)
            self.get_logger().info(f'cell_file: {settings.cell_file} from the next panel move')

    def _feed(self, name: str, kind: str, msg: Any) -> None:
        """A tracker reading or a plan of positioner ``name`` to the watch (a bad plan: logged)."""
        if kind == 'reading':
            self._watch.reading(name, m.seconds(msg.header.stamp), *m.pose_arrays(msg.pose.pose))
            return
        try:
            self._watch.plan(name, *m.path_arrays(msg))
        except InputError as err:
            self.get_logger().error(f'plan ignored: {err}')

    @property
    def coordinator(self) -> Coordinator:
        """The coordinator on the node sets, built at the first goal or stop: its client node
        spins in a thread of its own, which a coordinator nobody asks does not start."""
        with self._lock:
            if self._coordinator is None:
                settings = self.params.settings
                self._client = self._client or CellClient(  # its waits end at a close
                    name=f'{self.NAME}_client', context=self.context, stop=self._goal.closing)
                ports = [RosSetPort(self._client, e.name, settings.answer_timeout)
                         for e in self.cell.positioners]
                self._coordinator = Coordinator(self.cell, settings.mechanism, ports,
                                                settings.timing, watch=self._watch,
                                                relax=settings.relax, strain=self._strain)
            return self._coordinator

    def _execute(self, goal_handle: Any) -> MoveToPose.Result:
        try:
            with self._goal.running():
                return self._move(goal_handle)
        finally:
            self._status()

    def _move(self, goal_handle: Any) -> MoveToPose.Result:
        command = goal_handle.request.command
        p, q = m.pose_arrays(command.pose.pose)
        request = pm.panel_request(command)
        if isinstance(request, PanelOutcome):  # refused
            return self._end(goal_handle, request, p, q)

        def work(stop: threading.Event, feedback: Any) -> PanelOutcome:
            def progress(share: float) -> None:
                feedback(MoveToPose.Feedback(phase=MoveToPose.Feedback.MOVING,
                                             phase_name='moving', progress=share))
            return self.coordinator.move(request, stop, progress)

        ran: Ran[PanelOutcome] = run_goal(goal_handle, work, closing=self._goal.closing)
        outcome = ran.value or PanelOutcome(ResultCode.ABORTED_FAULT, f'{ran.error!r}')
        return self._end(goal_handle, outcome, p, q, ran.canceled)

    def _end(self, goal_handle: Any, outcome: PanelOutcome, p: Any, q: Any,
             canceled: bool = False) -> MoveToPose.Result:
        """The result: the code and reason, the mean panel pose the positioners' attained
        poses imply (cell frame) and its error against the goal."""
        self.last = outcome
        stamp = self.get_clock().now().to_msg()
        result = MoveToPose.Result(outcome=pm.panel_outcome(outcome, (p, q), stamp))
        (goal_handle.succeed if outcome.code is ResultCode.SUCCESS
         else goal_handle.canceled if canceled else goal_handle.abort)()
        self.get_logger().info(f'panel move: {outcome.code.value}: {outcome.reason}')
        return result

    def _srv_relax(self, how: str, _: Any, response: Trigger.Response) -> Trigger.Response:
        """Relax the panel (:meth:`Coordinator.relax` or ``relax_forces``), one at a time."""
        if self._goal.accept(None) != GoalResponse.ACCEPT:
            response.success, response.message = False, 'refused: a panel move is running'
            return response
        with self._goal.running():
            self.last = outcome = getattr(self.coordinator, how)(self._goal.closing)
        self._status()
        response.success = outcome.code is ResultCode.SUCCESS
        response.message = f'{outcome.code.value}: {outcome.reason}'
        return response

    def _srv_stop(self, _request: Any, response: Trigger.Response) -> Trigger.Response:
        """Stop every positioner (a running panel move then ends, naming the first stopped)."""
        try:
            self.coordinator.stop_all()
            response.success, response.message = True, 'every positioner stopping'
        except RuntimeError as err:
            response.success, response.message = False, str(err)
        return response

    def _status(self) -> None:
        last, state = self.last, 'moving' if self._goal.busy else 'idle'
        values = pm.coordinator_values(state, ' '.join(e.name for e in self.cell.positioners),
                                       last)
        level = 'ok' if last is None or last.code is ResultCode.SUCCESS else 'warn'
        self.pub_diag.publish(m.diagnostic(names.STATUS_COORDINATOR, level, state, values,
                                           self.get_clock().now().to_msg()))

    def close(self) -> None:
        """At shutdown: a running panel move stops every positioner before the node goes."""
        self._goal.close(CLOSE_WAIT_S)
        if self._client is not None:
            self._client.close()


#: The entry point of ``cell_coordinator_node`` (alone; ``cell_container`` hosts it too).
main = NodeStart(CellCoordinatorNode, Spin.THREADS, threads=4)

if __name__ == '__main__':
    raise SystemExit(main())
