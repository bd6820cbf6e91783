"""The positioner's executor (positioning_cell.ros.spin.JoinedMultiThreadedExecutor): its
shutdown waits for the callbacks it has started, within its timeout, where rclpy's (Jazzy)
returns at once and lets the node be destroyed under them."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import pytest
import rclpy
from cell_harness import isolated_domain
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from positioning_cell.ros.spin import JoinedMultiThreadedExecutor

pytestmark = pytest.mark.nodes

CALLBACK_S = 0.5  # a callback that runs this long when the stop comes


@pytest.fixture
def node() -> Iterator[Node]:
    with isolated_domain() as domain:
        context = Context()
        rclpy.init(context=context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        node = Node('executor_shutdown_test', context=context)
        try:
            yield node
        finally:
            node.destroy_node()
            rclpy.try_shutdown(context=context)


def _shutdown_during_a_callback(node: Node, executor: MultiThreadedExecutor,
                                timeout_s: float) -> tuple[bool, bool, float]:
    """Start a timer callback that runs CALLBACK_S, shut the executor down while it runs:
    (whether the callback had finished when shutdown returned, shutdown's answer, its
    duration)."""
    started, finished = threading.Event(), threading.Event()

    def callback() -> None:
        timer.cancel()
        started.set()
        time.sleep(CALLBACK_S)  # the work under way (a bounded stand-in)
        finished.set()

    timer = node.create_timer(0.001, callback)
    executor.add_node(node)
    never: Future = Future()
    while not started.is_set():
        executor.spin_until_future_complete(never, timeout_sec=0.05)
    t0 = time.monotonic()
    answer = executor.shutdown(timeout_sec=timeout_s)
    took = time.monotonic() - t0
    was_finished = finished.is_set()
    finished.wait(10.0)  # the plain executor's callback still runs: let it end here
    return was_finished, answer, took


def test_shutdown_waits_for_a_running_callback(node: Node) -> None:
    finished, answer, took = _shutdown_during_a_callback(
        node, JoinedMultiThreadedExecutor(num_threads=2, context=node.context), timeout_s=30.0)
    assert finished and answer, (finished, answer)
    assert took < 30.0


def test_shutdown_waits_at_most_its_timeout(node: Node) -> None:
    finished, answer, took = _shutdown_during_a_callback(
        node, JoinedMultiThreadedExecutor(num_threads=2, context=node.context), timeout_s=0.05)
    assert not finished and not answer, (finished, answer)
    assert took < CALLBACK_S, took


def test_rclpys_own_shutdown_does_not_wait(node: Node) -> None:
    """Why the subclass exists: if this starts failing, rclpy's shutdown waits by itself."""
    finished, answer, _ = _shutdown_during_a_callback(
        node, MultiThreadedExecutor(num_threads=2, context=node.context), timeout_s=30.0)
    assert not finished and answer, (finished, answer)
