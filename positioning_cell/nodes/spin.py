"""The Jazzy main() idiom of the cell's nodes, with the executor each node needs, and a clean
exit on SIGINT and SIGTERM."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from enum import Enum
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.task import Future

from positioning_cell.errors import PositioningError
from positioning_cell.nodes.entry import hold_stops, stop_requested


class Spin(Enum):
    """EVENTS: rclpy's events executor (several times cheaper per callback; for nodes whose
    callbacks never wait); THREADS: a multi-threaded executor (a service callback waits for a
    move while timers run)."""

    EVENTS = 'events'
    THREADS = 'threads'


def run(node_factory: Callable[[], Node], args: Sequence[str] | None = None,
        spin: Spin = Spin.EVENTS, *, threads: int = 3) -> int:
    """Init, build the node, spin until SIGINT / SIGTERM / shutdown, clean up (the node's
    ``close()`` if it has one, then destroy it). A node that cannot be built (invalid
    parameters, an unreadable bag: a PositioningError) prints the reason and exits 2.

    rclpy's own signal handlers shut the context down on SIGINT and SIGTERM; Python's handlers
    only set a flag first (:func:`~positioning_cell.nodes.entry.hold_stops`), so no
    KeyboardInterrupt lands in the middle of a callback (under the events executor that would
    abort the process), and a stop that came before ``rclpy.init`` is honoured after it.
    """
    hold_stops()
    rclpy.init(args=list(args) if args is not None else None)
    node: Node | None = None
    try:
        if stop_requested():
            return 0
        node = node_factory()
        if spin is Spin.THREADS:
            executor = MultiThreadedExecutor(num_threads=threads)
            executor.add_node(node)
            executor.spin()
        else:
            events = EventsExecutor()
            events.add_node(node)
            # EventsExecutor.spin() does not run callbacks in this rclpy build (platform.md):
            # spin in bounded slices until shutdown.
            never: Future = Future()
            while rclpy.ok():
                events.spin_until_future_complete(never, timeout_sec=1.0)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except PositioningError as err:
        print(f'{Path(sys.argv[0]).name}: {err}', file=sys.stderr)
        return 2
    except Exception:
        if rclpy.ok():
            raise
        # SIGINT / SIGTERM while the node was being built: rclpy failed on the shut-down
        # context. A stop while starting is a stop, not a failure.
    finally:
        if node is not None:
            close = getattr(node, 'close', None)
            if callable(close):
                close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
