"""positioning_cell.ros.qos_watch: a node on a multi-threaded executor creates its publishers
without rclpy's QoS event handlers (two Python waitables each in a wait set rebuilt at every
wake, issue 24) and still warns of every subscription it cannot serve, from the graph: one
asking for a QoS its publisher cannot offer, one asking for another type on its topic, each
once. Nodes of two rclpy contexts in this process, on a domain of their own."""

from __future__ import annotations

import importlib
from collections.abc import Iterator

import pytest
import rclpy
from cell_harness import CELL_YAML, isolated_domain, wait_until
from rclpy.context import Context
from rclpy.event_handler import EventHandler
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Header, String

from positioning_cell import names
from positioning_cell.nodes.kinematics_node import PositionerNode
from positioning_cell.ros.qos import HEARTBEAT_QOS, STREAM_QOS
from positioning_cell.ros.qos_watch import QosWatchedNode
from positioning_cell.ros.spin import NodeStart, Spin

pytestmark = pytest.mark.nodes


@pytest.fixture
def contexts() -> Iterator[tuple[Context, Context]]:
    """Two rclpy contexts on a domain of their own: two DDS participants, as two processes
    would be (one participant refuses a second type on a topic it has)."""
    with isolated_domain() as domain:
        pair = Context(), Context()
        for ctx in pair:
            rclpy.init(context=ctx, domain_id=domain,
                       signal_handler_options=SignalHandlerOptions.NO)
        try:
            yield pair
        finally:
            for ctx in pair:
                rclpy.try_shutdown(context=ctx)


def _event_handlers(node: Node) -> int:
    return sum(isinstance(w, EventHandler) for w in node.waitables)


def test_unserved_subscriptions_are_named_once_each(contexts: tuple[Context, Context],
                                                    capfd: pytest.CaptureFixture[str]) -> None:
    watched = QosWatchedNode('qos_watched', context=contexts[0])
    other = Node('qos_subscriber', context=contexts[1])
    try:
        watched.create_publisher(Header, '/qos_watch/beat', HEARTBEAT_QOS)  # best effort
        watched.create_publisher(JointState, '/qos_watch/joints', STREAM_QOS)
        assert _event_handlers(watched) == 0  # /parameter_events' and both of these: none
        reliable = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        other.create_subscription(Header, '/qos_watch/beat', lambda _: None, HEARTBEAT_QOS)
        other.create_subscription(Header, '/qos_watch/beat', lambda _: None, reliable)
        other.create_subscription(String, '/qos_watch/joints', lambda _: None, STREAM_QOS)
        warnings: list[str] = []

        def seen_both() -> bool:
            warnings.extend(watched.unserved_subscriptions())
            return len(warnings) >= 2
        wait_until(seen_both, 20.0, 'the two unserved subscriptions in the graph')
        qos = [w for w in warnings if "topic '/qos_watch/beat'" in w]
        kind = [w for w in warnings if "topic '/qos_watch/joints'" in w]
        assert len(qos) == 1 and 'requesting incompatible QoS' in qos[0], warnings
        assert 'reliab' in qos[0].lower(), qos  # the policy that does not match
        assert len(kind) == 1 and 'Incompatible type' in kind[0], warnings
        assert 'std_msgs/msg/String' in kind[0] and 'sensor_msgs/msg/JointState' in kind[0]
        assert watched.unserved_subscriptions() == []  # each once
        # logged by the node's own timer, within a watch period or two
        fresh = Node('qos_subscriber_2', context=contexts[1])
        fresh.create_subscription(Header, '/qos_watch/beat', lambda _: None, reliable)
        executor = SingleThreadedExecutor(context=contexts[0])
        executor.add_node(watched)
        logged = ''

        def logged_once() -> bool:
            nonlocal logged
            executor.spin_once(timeout_sec=0.1)
            logged += capfd.readouterr().err
            return "topic '/qos_watch/beat', requesting incompatible QoS" in logged
        wait_until(logged_once, 20.0, 'the warning for the new subscription in the log')
        executor.shutdown()
        fresh.destroy_node()
    finally:
        other.destroy_node()
        watched.destroy_node()


def test_the_nodes_on_threads_are_watched_and_their_publishers_have_no_handlers(
        contexts: tuple[Context, Context]) -> None:
    """Every node that spins on a multi-threaded executor is a QosWatchedNode; the
    positioner built: event handlers for its subscriptions only."""
    threaded = []
    for node in names.NODE_EXECUTABLES:
        start = importlib.import_module(f'positioning_cell.nodes.{node.executable}').main
        assert isinstance(start, NodeStart)
        if start.spin is Spin.THREADS:
            threaded.append(node.executable)
            assert isinstance(start.factory, type) and issubclass(start.factory, QosWatchedNode), \
                node.executable
    assert names.POSITIONER.executable in threaded
    positioner = PositionerNode(context=contexts[0],
                                cli_args=['--ros-args', '--params-file', str(CELL_YAML)])
    try:
        assert len(list(positioner.publishers)) > 10
        assert _event_handlers(positioner) == 2 * len(list(positioner.subscriptions))
    finally:
        positioner.close()
        positioner.destroy_node()
