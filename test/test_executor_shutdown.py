"""The positioner's executor (positioning_cell.ros.spin.JoinedMultiThreadedExecutor): its
shutdown waits for the callbacks it has started, within its timeout, where rclpy's (Jazzy)
returns at once and lets the node be destroyed under them."""

from __future__ import annotations

import gc
import threading
import time
import weakref
from collections.abc import Iterator

import pytest
import rclpy
from cell_harness import isolated_domain
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from positioning_cell.ros import spin
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


def test_spinning_in_slices_leaves_no_future_holding_the_wakes(
        node: Node, monkeypatch: pytest.MonkeyPatch) -> None:
    """rclpy's multi-threaded executor adds a done callback to the future it spins until at
    every wake: spin_in_slices gives each slice a future of its own, so the callbacks go with
    it (one future for every slice kept ~280 a second in the positioner at rest)."""
    made: list[weakref.ref[Future]] = []
    held: list[int] = []

    class Tracked(Future):
        def __init__(self) -> None:
            super().__init__()
            made.append(weakref.ref(self))

        def __del__(self) -> None:
            held.append(len(self._callbacks))

    monkeypatch.setattr(spin, 'Future', Tracked)
    ticks: list[int] = []
    node.create_timer(0.002, lambda: ticks.append(1))
    executor = JoinedMultiThreadedExecutor(num_threads=2, context=node.context)
    executor.add_node(node)
    spin.spin_in_slices(executor, lambda: len(ticks) < 300)
    executor.shutdown(timeout_sec=1.0)
    del executor
    gc.collect()
    assert len(made) >= 3 and all(r() is None for r in made)  # a future per slice, all gone
    assert sum(held) >= 300 and max(held) < sum(held) / 2  # the wakes spread over the slices
