"""The cell client's own executor (positioning_cell.ros.client): what raises in its spin thread
(a callback, or rclpy racing a create or destroy from another thread) is logged and kept, the
client goes on answering, and a call that times out says so."""

from __future__ import annotations

import threading
import time

import pytest
from cell_harness import Client, isolated_domain
from positioning_cell_interfaces.action import Home
from rcl_interfaces.srv import ListParameters
from rclpy.action import ActionServer
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.task import Future
from std_msgs.msg import String

from positioning_cell.polling import wait_until
from positioning_cell.ros import client as client_module
from positioning_cell.ros.client import PARAMETER_TIMEOUT, STOPPED_WAIT_S, GoalClient

pytestmark = pytest.mark.nodes


def test_a_callback_that_raises_does_not_stop_the_client() -> None:
    with isolated_domain() as domain, Client(domain, 'client_under_test') as client:
        def broken(msg: String) -> None:
            raise RuntimeError(f'a broken callback got {msg.data!r}')

        node = client.node
        node.create_subscription(String, '/client_test/broken', broken, 10)
        publisher = node.create_publisher(String, '/client_test/broken', 10)
        wait_until(lambda: publisher.get_subscription_count() > 0, 10.0, 'the match')
        publisher.publish(String(data='first'))
        wait_until(lambda: client.spin_errors, 10.0, 'the callback\'s error')
        assert "a broken callback got 'first'" in client.spin_errors[-1]
        # Still spinning: its own node's parameter service answers through the same executor.
        answer = client.call(ListParameters, f'/{node.get_name()}/list_parameters',
                             ListParameters.Request(), timeout=10.0)
        assert 'use_sim_time' in answer.result.names
        with pytest.raises(TimeoutError, match="errors in its executor, the last: "
                                               "RuntimeError: a broken callback"):
            client._answer(Future(), 0.1, 'an answer that never comes')
    assert not client._thread.is_alive()  # close() ended the spinning


def test_a_stop_cuts_every_wait_short() -> None:
    """A client whose ``stop`` is set (a goal's stop: the calibrator stopped while it waits
    for the positioner) ends its waits within STOPPED_WAIT_S, not their 30 s: a calibrator
    stopped together with the positioner hung in its parameter set past the stop deadline
    (exit 1 with its threads' stacks)."""
    stop = threading.Event()
    with isolated_domain() as domain, Client(domain, 'client_under_test', stop=stop) as client:
        timer = threading.Timer(0.2, stop.set)
        timer.start()
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match='stopping'):
            client.set_parameter('a_node_that_is_not_there', 'x', 1.0)
        took = time.monotonic() - t0
        timer.join()
        assert took < PARAMETER_TIMEOUT / 2, took
        # and at once for a wait that begins once the grace has run out
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match='stopping'):
            client.get_parameter('a_node_that_is_not_there', 'x')
        assert time.monotonic() - t0 < 1.0
    print(f'the set gave up {took:.2f} s after it began, the stop after 0.2 s '
          f'(grace {STOPPED_WAIT_S} s)')


def test_a_goal_client_builds_itself_anew_once_when_its_server_does_not_show(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """GoalClient.ready: each client's node has a name of its own; without the server after
    REBUILD_AFTER the action client is built anew once, which then finds a server that came
    meanwhile; none at all times out saying so."""
    monkeypatch.setattr(client_module, 'REBUILD_AFTER', 0.3)
    with isolated_domain() as domain, Client(domain, 'goal_test') as client:
        with GoalClient(client, Home, '/nobody/homing') as goals:
            first = goals.node.get_name()
            with pytest.raises(TimeoutError, match='built twice'):
                goals.ready(1.0)
            assert goals.node.get_name() not in (first, 'goal_test_goals')
        late = Node('late', context=client.context)
        executor = SingleThreadedExecutor(context=client.context)
        with GoalClient(client, Home, '/late/homing') as goals:
            built = goals.node
            done: list[BaseException | None] = []

            def wait() -> None:
                try:
                    goals.ready(30.0)
                    done.append(None)
                except BaseException as err:
                    done.append(err)

            waiter = threading.Thread(target=wait)
            waiter.start()
            wait_until(lambda: goals.node is not built, 10.0, 'the client built anew')
            ActionServer(late, Home, '/late/homing', lambda handle: Home.Result())
            executor.add_node(late)
            spinner = threading.Thread(target=executor.spin, daemon=True)
            spinner.start()
            waiter.join(30.0)
            assert done == [None]
        executor.shutdown(timeout_sec=1.0)
        late.destroy_node()
