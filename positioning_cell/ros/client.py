"""The tools' one ROS module: an rclpy client of the running cell (its own context, spun in a
background thread) with the calls the tools and tests make. Everything else in ``tools/`` is
plain Python (starting the cell's processes: :mod:`positioning_cell.ros.processes`)."""

from __future__ import annotations

import contextlib
import itertools
import json
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from numpy.typing import ArrayLike
from positioning_cell_interfaces.msg import MoveCommand, MoveOutcome
from positioning_cell_interfaces.srv import CheckPose, MoveToPose
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import ListParameters
from rclpy.action.client import ActionClient
from rclpy.action.graph import get_action_server_names_and_types_by_node
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import (
    ExternalShutdownException,
    ShutdownException,
    SingleThreadedExecutor,
)
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from std_msgs.msg import String
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.accuracy.verdicts import summary_of_values
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.polling import backoff, wait_until
from positioning_cell.ros.messages import pose_stamped, status_values
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, LATCHED_QOS, SERVICE_QOS
from positioning_cell.ros.unspun import acts_for

T = TypeVar('T')

#: How long a parameter's get or set may take, its services' appearance included (s).
PARAMETER_TIMEOUT = 30.0
#: A handshake request unanswered this long is sent again, 1.5 times longer each time up to
#: HANDSHAKE_WAIT_MAX (s): the match of a new client's reader takes tens to hundreds of ms, and
#: a first wait of 2 s put 2 s on a tool's first call (or the benchmarked cell's homing) when
#: the first answer was lost.
HANDSHAKE_WAIT, HANDSHAKE_WAIT_MAX = 0.25, 2.0
#: How long a run-program step waits for its readers' acknowledgement (s).
PROGRAM_ACK_S = 2.0
#: The spin thread's wait per slice (s): how soon it sees :meth:`CellClient.close`.
SPIN_SLICE_S = 0.1
#: Executor errors a client keeps for the message of a call that timed out.
SPIN_ERRORS_KEPT = 10

#: Longest a client's waits go on once its ``stop`` is set (s): long enough for a living node
#: to answer the last calls of a stop (the positioner's mode put back takes milliseconds), short
#: enough that a node stopping at the same time cannot hold the stop past its deadline
#: (:data:`positioning_cell.ros.entry.STOP_DEADLINE_S`, 10 s; the parameter waits are 30 s).
STOPPED_WAIT_S = 2.0


class CellClient:
    """An rclpy node spun in a background thread: what a tool or a test needs of the running
    cell. In its own context on ``domain`` (``signals``: let rclpy install its SIGINT handler;
    a tool that handles signals itself passes False), or in the given ``context`` (which its
    owner shuts down), or on the given ``node`` (a node started already, its context taken and
    shut down with this client: :func:`positioning_cell.ros.early.start_node`; ``domain``,
    ``name`` and ``signals`` are then the node's own). Once ``stop`` is set (a goal's stop),
    every wait of the client ends within :data:`STOPPED_WAIT_S` s (TimeoutError)."""

    def __init__(self, domain: int | None = None, name: str = 'cell_client', *,
                 signals: bool = True, context: Context | None = None,
                 node: Node | None = None, stop: threading.Event | None = None) -> None:
        if node is not None:
            context = node.context
        self._owns_context = context is None or node is not None
        if context is None:
            context = Context()
            options = SignalHandlerOptions.ALL if signals else SignalHandlerOptions.NO
            rclpy.init(context=context, domain_id=domain, signal_handler_options=options)
        self.context = context
        self.node = node if node is not None else Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients: dict[str, Any] = {}
        self._parameter_clients: dict[str, AsyncParameterClient] = {}
        self._known: set[str] = set()
        self._in_flight: list[Future] = []
        self._statuses: dict[str, list[DiagnosticStatus]] | None = None
        self._programs: dict[str, Any] = {}
        #: What raised in the spin thread (kept; each also logged), for a call that times out.
        self.spin_errors: list[str] = []
        self._closing = False
        self._stop = stop
        self._stopped_at = math.inf
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        """Run the client's callbacks until :meth:`close`. What raises meanwhile (a callback,
        or rclpy itself when entities are created and destroyed from other threads while it
        waits: ros2/rclpy#1355, #1385) is logged and kept in :attr:`spin_errors`, and the
        spinning goes on; a shutdown ends it. (The first such exception used to end this
        thread without a word: every later call then waited out its timeout.)"""
        while not self._closing and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=SPIN_SLICE_S)
            except (ExternalShutdownException, ShutdownException):
                return
            except Exception as err:  # kept and logged: the spin goes on
                if self._closing or not self.context.ok():
                    return
                self.spin_errors.append(f'{type(err).__name__}: {err}')
                del self.spin_errors[:-SPIN_ERRORS_KEPT]
                with contextlib.suppress(Exception):
                    self.node.get_logger().error(f'the client\'s executor: '
                                                 f'{self.spin_errors[-1]}; spinning on')

    def _cutoff(self) -> float:
        """The monotonic time the client's waits end by: :data:`STOPPED_WAIT_S` after its
        ``stop`` was first seen set (inf: not set)."""
        if self._stop is not None and self._stop.is_set() and self._stopped_at == math.inf:
            self._stopped_at = time.monotonic()
        return self._stopped_at + STOPPED_WAIT_S

    def _wait(self, condition: Any, timeout: float, what: str) -> Any:
        """:func:`positioning_cell.polling.wait_until`, cut short by the client's ``stop``."""
        return wait_until(condition, timeout, what, cutoff=self._cutoff)

    # -- generic --------------------------------------------------------------------------------
    def collect(self, msg_type: Any, topic: str, qos: QoSProfile | int = 100) -> list[Any]:
        """Subscribe and return the list the messages are appended to."""
        received: list[Any] = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def heard_for(self, msg_type: Any, topic: str, seconds: float, timeout: float,
                  qos: QoSProfile | int = 100) -> list[Any]:
        """The messages of ``topic`` heard over ``seconds`` s from the first one (a measuring
        window), subscribed for that while only; TimeoutError when none comes within
        ``timeout`` s."""
        received: list[tuple[float, Any]] = []  # (monotonic s heard, message)
        subscription = self.node.create_subscription(
            msg_type, topic, lambda msg: received.append((time.monotonic(), msg)), qos)
        try:
            self._wait(lambda: received, timeout, f'a message on {topic}')
            end = received[0][0] + seconds
            self._wait(lambda: time.monotonic() >= end, seconds + timeout,
                       f'{seconds:g} s of {topic}')
        finally:
            self.node.destroy_subscription(subscription)
        return [msg for t, msg in received if t <= end]

    def service(self, srv_type: Any, name: str, wait: float = 30.0) -> Any:
        """The client of service ``name`` (one per name, queue sized for bursts of calls:
        SERVICE_QOS), once the service is there (TimeoutError after ``wait`` s)."""
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(srv_type, name,
                                                                   qos_profile=SERVICE_QOS)
        self._wait(client.service_is_ready, wait, f'service {name}')
        if name not in self._known:  # the server has matched this new client: :meth:`handshake`
            self.handshake(serving_node(name), wait)
            self._known.add(name)
        return client

    def forget(self, node: str) -> None:
        """Node ``node`` was restarted: its services are handshaken again before the next
        call (the new process has not matched this client's endpoints)."""
        self._known = {name for name in self._known if serving_node(name) != node}

    def handshake(self, node: str, timeout: float = 30.0) -> None:
        """Wait until node ``node`` knows every endpoint this client created so far: one
        idempotent request of a new client (its /<node>/list_parameters) answered, sent again
        after :data:`HANDSHAKE_WAIT` s unanswered, 1.5 times longer each time up to
        :data:`HANDSHAKE_WAIT_MAX` s (TimeoutError after ``timeout`` s). Discovery is not
        symmetric: a server that has not yet matched a new client's response reader answers
        into the void (the request arrives, a move may run, the answer is lost). A
        participant announces its readers in order on one reliable channel, so the answer to a
        newer reader shows that the older ones are matched too."""
        service = f'/{node}/list_parameters'
        ping = self.node.create_client(ListParameters, service, qos_profile=SERVICE_QOS)
        deadline = time.monotonic() + timeout
        try:
            self._wait(ping.service_is_ready, timeout, f'service {service}')
            for attempt in itertools.count():
                future = ping.call_async(ListParameters.Request())
                left = deadline - time.monotonic()
                wait = backoff(attempt, HANDSHAKE_WAIT, HANDSHAKE_WAIT_MAX)
                try:
                    self._wait(future.done, max(min(wait, left), 0.0), 'an answer')
                    return
                except TimeoutError:
                    if time.monotonic() > self._cutoff():
                        raise
                    if time.monotonic() >= deadline:
                        raise TimeoutError(f'timed out after {timeout:.1f} s waiting for '
                                           f'{node} to answer {service}') from None
        finally:
            self.node.destroy_client(ping)

    def call(self, srv_type: Any, name: str, request: Any, timeout: float = 30.0) -> Any:
        """Call a service (waiting up to ``min(timeout, 30)`` s for it to appear) and return
        the response; TimeoutError names what did not come."""
        future = self.service(srv_type, name, min(timeout, 30.0)).call_async(request)
        return self._answer(future, timeout, f'the response of {name}')

    def _answer(self, future: Future, timeout: float, what: str) -> Any:
        """The result of a request's ``future`` within ``timeout`` s (TimeoutError naming
        ``what``); counted in flight meanwhile (:meth:`answered`)."""
        self._in_flight.append(future)
        try:
            self._wait(future.done, timeout, what)
        except TimeoutError as err:
            raise TimeoutError(f'{err}{self._spin_state()}') from None
        finally:
            self._in_flight.remove(future)
        return future.result()

    def _spin_state(self) -> str:
        """What a timed-out call adds about this client's own executor: '' when it spins
        and nothing raised in it."""
        said = []
        if not self._thread.is_alive():
            said.append('its spin thread has ended')
        if self.spin_errors:
            said.append(f'{len(self.spin_errors)} errors in its executor, the last: '
                        f'{self.spin_errors[-1]}')
        return f' (this client: {"; ".join(said)})' if said else ''

    def parameters(self, node: str, wait: float = 30.0) -> AsyncParameterClient:
        """rclpy's parameter client of node ``node`` (one per node, queue sized as
        SERVICE_QOS), once the node's parameter services are there and it knows this client
        (:meth:`handshake`; TimeoutError after ``wait`` s)."""
        client = self._parameter_clients.get(node)
        if client is None:
            client = self._parameter_clients[node] = AsyncParameterClient(
                self.node, node, qos_profile=SERVICE_QOS)
        self._wait(client.services_are_ready, wait, f'the parameter services of /{node}')
        key = f'/{node}/parameters'  # forgotten with the node (:meth:`forget`)
        if key not in self._known:
            self.handshake(node, wait)
            self._known.add(key)
        return client

    def answered(self) -> bool:
        """Every call this client made has its response (a call left by an exception, e.g. an
        interrupt, included)."""
        self._in_flight = [f for f in self._in_flight if not f.done()]
        return not self._in_flight

    def call_many(self, srv_type: Any, name: str, requests: Sequence[Any]) -> list[Future]:
        """Send every request at once (the service must be there: :meth:`service`); their
        futures."""
        client = self.service(srv_type, name, 0.0)
        return [client.call_async(r) for r in requests]

    def home(self, timeout: float = 60.0, namespace: str = '') -> tuple[bool, str]:
        """Home the positioner (of the node set ``namespace``; '': the single cell's; it
        references the drives first): (success, message). Retries while it refuses for want
        of encoder or tracker readings (the cell is still coming up: the tracker locates
        itself before it measures)."""
        not_yet = (ResultCode.REFUSED_DRIVER_SILENT.value, ResultCode.REFUSED_NO_ESTIMATE.value,
                   ResultCode.REFUSED_TRACKER_SILENT.value)

        def attempt() -> tuple[bool, str] | None:
            done, message = self.trigger(names.in_set(names.HOME, namespace))
            return None if not done and message.startswith(not_yet) else (done, message)

        result: tuple[bool, str] = self._wait(attempt, timeout, 'the positioner to home')
        return result

    def spinning(self, node: str, timeout: float = 2.0) -> bool:
        """Does node ``node`` (a name) answer its parameter service within ``timeout`` s (it
        is built and its executor spins)?"""
        try:
            self.call(ListParameters, f'/{node}/list_parameters', ListParameters.Request(),
                      timeout)
        except TimeoutError:
            return False
        return True

    def subscribed(self, topic: str, node: str) -> bool:
        """Has node ``node`` a subscription on ``topic``, itself or through a node it keeps
        beside it (:func:`~positioning_cell.ros.unspun.acts_for`: its readers')?"""
        return any(acts_for(i.node_name, node)
                   for i in self.node.get_subscriptions_info_by_topic(topic))

    def get_parameter(self, node: str, name: str) -> Any:
        """The value of one parameter of ``node`` (:meth:`parameters`; TimeoutError after
        :data:`PARAMETER_TIMEOUT` s)."""
        timeout = PARAMETER_TIMEOUT
        future = self.parameters(node, timeout).get_parameters([name])
        response = self._answer(future, timeout, f'the parameter {name} of /{node}')
        return parameter_value_to_python(response.values[0])

    def set_parameter(self, node: str, name: str, value: Any) -> SetParametersResult:
        """Set one parameter of ``node``; the node's result (``successful``, ``reason``;
        TimeoutError after :data:`PARAMETER_TIMEOUT` s)."""
        timeout = PARAMETER_TIMEOUT
        future = self.parameters(node, timeout).set_parameters(
            [Parameter(name, value=value)])
        response = self._answer(future, timeout, f'the answer of /{node} to setting {name}')
        result: SetParametersResult = response.results[0]
        return result

    # -- the cell -------------------------------------------------------------------------------
    def statuses(self, name: str) -> list[DiagnosticStatus]:
        """The list the /diagnostics statuses named ``name`` are appended to (subscribed on
        first use)."""
        if self._statuses is None:
            self._statuses = {}
            self.node.create_subscription(DiagnosticArray, names.DIAGNOSTICS,
                                          self._on_diagnostics, DIAGNOSTICS_QOS)
        return self._statuses.setdefault(name, [])

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        assert self._statuses is not None
        for status in msg.status:
            if status.name in self._statuses:
                self._statuses[status.name].append(status)

    def plan(self, service: str, position: ArrayLike, quaternion: ArrayLike,
             tolerance: float = 0.0, timeout: float = 120.0) -> bool:
        """Call /positioner/move_to_pose (moved and settled within tolerance?) or
        /positioner/check_pose (would it move?) for an absolute goal in the base frame (either
        of a node set: names.in_set)."""
        command = MoveCommand(pose=pose_stamped(position, quaternion,
                                                self.node.get_clock().now().to_msg()),
                              mode=MoveCommand.ABSOLUTE, tolerance=float(tolerance))
        if service.endswith(names.CHECK_POSE):
            return bool(self.call(CheckPose, service, CheckPose.Request(command=command),
                                  timeout).valid)
        response = self.call(MoveToPose, service, MoveToPose.Request(command=command), timeout)
        return bool(response.outcome.code == MoveOutcome.SUCCESS)

    def trigger(self, service: str, timeout: float = 120.0) -> tuple[bool, str]:
        """Call a std_srvs/Trigger service (home, stop, ...): (success, message)."""
        response = self.call(Trigger, service, Trigger.Request(), timeout)
        return bool(response.success), str(response.message)

    def monitor_report(self) -> dict[str, Any]:
        """The accuracy monitor's /accuracy_monitor/report."""
        doc: dict[str, Any] = json.loads(self.call(Trigger, names.MONITOR_REPORT,
                                                   Trigger.Request(), 10.0).message)
        return doc

    def advertise_program(self, topic: str = names.PROGRAM) -> None:
        """Offer ``topic`` (/cell/program, /cell/panel_program; latched), so the recorder
        subscribes before the first step."""
        if topic not in self._programs:
            self._programs[topic] = self.node.create_publisher(String, topic, LATCHED_QOS)

    def publish_program(self, text: str, topic: str = names.PROGRAM) -> None:
        """Publish a run-program step on ``topic`` and wait (up to :data:`PROGRAM_ACK_S`)
        until every matched reader, the recorder among them, has acknowledged it: the step is
        in the bag before its move, and the end-of-program marker before run_cell stops the
        recorder (a bag once lacked it: 4 markers of 5)."""
        self.advertise_program(topic)
        self._programs[topic].publish(String(data=text))
        self._programs[topic].wait_for_all_acked(Duration(seconds=PROGRAM_ACK_S))

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        self._closing = True
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        if self._owns_context:
            rclpy.try_shutdown(context=self.context)  # type: ignore[attr-defined]
        self._thread.join(timeout=5.0)

    def __enter__(self) -> CellClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def serving_node(name: str) -> str:
    """The node that serves service or action ``name``: the cell's names are
    /<node>/<what> (:mod:`positioning_cell.names`), a node set's /<namespace>/<node>/<what>
    (names.in_set): the node is what precedes the last part, its namespace with it."""
    parts = name.strip('/').split('/')
    if len(parts) < 2:
        raise ValueError(f'{name!r} is not /<node>/<service>')
    return '/'.join(parts[:-1])


#: Numbers the nodes of the GoalClients of a process: each its own name.
_GOAL_NODES = itertools.count(1)
#: How long (s) :meth:`GoalClient.ready` waits for the server before it builds its action
#: client anew, once.
REBUILD_AFTER = 10.0


class GoalClient:
    """An action client on a node of its own in ``client``'s context, spun only by the thread
    that uses it (:meth:`spin_once`, :meth:`until`). rclpy's ActionClient registers a goal,
    cancel or result request only after sending it (no lock, Jazzy): an answer that another
    thread's executor takes in between is dropped ("Ignoring unexpected goal response") and
    the caller waits forever. Spun by its caller alone, the answer is taken after it is
    registered.

    Each GoalClient's node has a name of its own (``<client>_goals_<n>``): action clients
    made and destroyed in quick succession under one name have been seen to stay unmatched
    with a server DDS announces (once in the suite, 30 s; eProsima/Fast-DDS#5359 reports
    the like), and :meth:`ready` builds its client anew once when the server does not show
    within :data:`REBUILD_AFTER`."""

    def __init__(self, client: CellClient, action_type: Any, name: str) -> None:
        self.cell, self.name, self._type = client, name, action_type
        self._build()

    def _build(self) -> None:
        """The node, its executor and the action client."""
        client = self.cell
        self.node = Node(f'{client.node.get_name()}_goals_{next(_GOAL_NODES)}',
                         context=client.context)
        self.executor = SingleThreadedExecutor(context=client.context)
        self.executor.add_node(self.node)
        self.action = ActionClient(self.node, self._type, self.name)

    def spin_once(self, timeout: float) -> None:
        """Take what came for the action (feedback, answers), waiting up to ``timeout`` s."""
        self.executor.spin_once(timeout_sec=timeout)

    def until(self, condition: Callable[[], T], timeout: float, what: str) -> T:
        """Spin until ``condition()`` is truthy and return it (TimeoutError naming ``what``)."""
        deadline = time.monotonic() + timeout
        while not (value := condition()):
            if time.monotonic() > deadline:
                raise TimeoutError(f'timed out after {timeout:.1f} s waiting for {what}')
            self.spin_once(0.02)
        return value

    def ready(self, timeout: float) -> None:
        """Wait for the server, then for its node to know this client
        (:meth:`CellClient.handshake`: its answers would be lost otherwise); after
        :data:`REBUILD_AFTER` s without it, the action client is built anew (class
        docstring) and waits the rest of ``timeout``."""
        deadline = time.monotonic() + timeout
        what = f'the action server {self.name}'
        try:
            wait_until(self.action.server_is_ready, min(REBUILD_AFTER, timeout), what)
        except TimeoutError as err:
            left = deadline - time.monotonic()
            if left <= 0.0:
                raise TimeoutError(f'{err} ({self._graph_view()})') from None
            self.close()
            self._build()
            try:
                wait_until(self.action.server_is_ready, left, what)
            except TimeoutError as again:
                raise TimeoutError(f'{again} after {timeout:.0f} s in all, the client built '
                                   f'twice ({self._graph_view()})') from None
        self.cell.handshake(serving_node(self.name), timeout)

    def _graph_view(self) -> str:
        """What this client's graph knows of the server: whether its node announces the action
        (not discovered at all) or does (discovered, this client's endpoints not matched)."""
        node = serving_node(self.name)
        try:
            served = get_action_server_names_and_types_by_node(self.node, node, '/')
        except Exception:  # rclpy raises when the node is unknown to the graph
            return f'node /{node} not in the graph'
        if any(name == self.name for name, _ in served):
            return (f'/{node} announces it: its endpoints are known, this client\'s are not '
                    'matched with them yet')
        return f'/{node} announces only {sorted(name for name, _ in served)}'

    def send(self, goal: Any, feedback: Callable[[Any], None] | None = None,
             timeout: float = 30.0) -> Any:
        """Send ``goal`` (``feedback(msg.feedback)`` for each feedback); its goal handle
        (accepted or not)."""
        future = self.action.send_goal_async(
            goal, feedback_callback=None if feedback is None else
            (lambda msg: feedback(msg.feedback)))
        return self.until(lambda: future.result() if future.done() else None, timeout,
                          f'the answer to the goal of {self.name}')

    def result(self, handle: Any, timeout: float) -> Any:
        """The result response (``status``, ``result``) of an accepted goal."""
        future = handle.get_result_async()
        self.until(future.done, timeout, f'the result of {self.name}')
        return future.result()

    def cancel(self, handle: Any, timeout: float = 30.0) -> Any:
        """Ask to cancel a goal; the cancel response."""
        future = handle.cancel_goal_async()
        self.until(future.done, timeout, f'the answer to the cancel of {self.name}')
        return future.result()

    def close(self) -> None:
        """Destroy the action client and its node."""
        self.action.destroy()
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()

    def __enter__(self) -> GoalClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def verdict_text(status: DiagnosticStatus) -> str:
    """A monitor verdict (status ``accuracy_monitor: settled pose``) in a few words, as
    :meth:`positioning_cell.accuracy.verdicts.Verdict.short` gives it."""
    return summary_of_values(status_values(status))


