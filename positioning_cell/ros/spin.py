"""The Jazzy main() idiom of the cell's nodes, with the executor each node needs, and a clean
exit on SIGINT and SIGTERM."""

from __future__ import annotations

import gc
import sys
from collections.abc import Callable, Sequence
from enum import Enum
from pathlib import Path

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from rclpy.utilities import get_default_context

from positioning_cell import files
from positioning_cell.core import compiled
from positioning_cell.errors import PositioningError
from positioning_cell.ros.entry import hold_stops, stop_requested

STOP_POLL_S = 0.1
"""Longest time from SIGINT / SIGTERM to the executor returning (s), besides a running callback."""

SHUTDOWN_WAIT_S = 5.0
"""Longest wait for running callbacks after a stop (s), before the node is destroyed under
them. Not what bounds a stop: a callback still running holds the process at its exit anyway
(the executor's threads are joined), so callbacks must return at a stop: the positioner's do
at once (close() ends a move, :func:`positioning_cell.files.abandon_loads` a file load)."""


class Spin(Enum):
    """EVENTS: rclpy's events executor (several times cheaper per callback; for nodes whose
    callbacks never wait); THREADS: a multi-threaded executor (a service callback waits for a
    move while timers run)."""

    EVENTS = 'events'
    THREADS = 'threads'


def run(node_factory: Callable[[], Node], args: Sequence[str] | None = None,
        spin: Spin = Spin.EVENTS, *, threads: int = 3) -> int:
    """Init, build the node, spin until SIGINT / SIGTERM / shutdown, clean up (the node's
    ``close()`` if it has one, then destroy it, then shut the context down). A node that cannot
    be built (invalid parameters, an unreadable bag: a PositioningError) prints the reason and
    exits 2. A node with an ``exit_status`` attribute ends its own run by setting it (an int,
    not None; also from ``close()``): the spin returns and that is the exit status (else 0).

    rclpy's own signal handlers are not installed: they shut the context down at once, while a
    timer callback may be publishing on it ("publisher's context is invalid", a FATAL log and a
    traceback). SIGINT and SIGTERM only set a flag
    (:func:`~positioning_cell.ros.entry.hold_stops`); the executor spins in slices of
    :data:`STOP_POLL_S` and returns between two callbacks once the flag is up, and only then is
    the node closed and the context shut down. A stop that came before ``rclpy.init`` is
    honoured after it.
    """
    # A stop gives up the loads waited on at once (files.within), even while the node is
    # being built (the positioner loads its calibration file then).
    hold_stops(files.abandon_loads)
    rclpy.init(args=list(args) if args is not None else None,
               signal_handler_options=SignalHandlerOptions.NO)
    try:
        return _spin(node_factory, spin, threads)
    finally:
        rclpy.try_shutdown()
        # The participant goes now, its shared memory with it, rather than in the interpreter's
        # finalization (which entry.end_process skips): once the node's and the executor's
        # handles are collected, the context is no longer in use and is destroyed at once.
        gc.collect()
        get_default_context().destroy()


def _spin(node_factory: Callable[[], Node], spin: Spin, threads: int) -> int:
    """:func:`run` from the node's construction to its destruction (the exit code)."""
    node: Node | None = None
    executor: Executor | None = None
    try:
        if stop_requested():
            return 0
        node = node_factory()
        # Built, its kernels warmed: none is imported or compiled from here on (a pause of
        # the executor), a cold one raises instead (positioning_cell.core.compiled).
        compiled.seal()
        # EventsExecutor.spin() does not run callbacks in this rclpy build (platform.md), and
        # Python's signal handlers run only between two slices: spin in bounded slices.
        executor = (MultiThreadedExecutor(num_threads=threads) if spin is Spin.THREADS
                    else EventsExecutor())
        executor.add_node(node)
        never: Future = Future()
        while rclpy.ok() and not stop_requested() and _exit_status(node) is None:
            executor.spin_until_future_complete(never, timeout_sec=STOP_POLL_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except PositioningError as err:
        if stop_requested():  # stopped while it was being built (a load given up)
            return 0
        print(f'{Path(sys.argv[0]).name}: {err}', file=sys.stderr)
        return 2
    finally:
        # No callback waits for a file any more (a calibration file's load in the positioner's
        # parameter callback: given up since the signal); then close(): it ends what a worker
        # thread may still wait on (a move), so the executor's shutdown then finds its
        # callbacks returning.
        files.abandon_loads()
        if node is not None:
            close = getattr(node, 'close', None)
            if callable(close):
                close()
        if executor is not None:
            executor.shutdown(timeout_sec=SHUTDOWN_WAIT_S)
        if node is not None:
            node.destroy_node()
    return _exit_status(node) or 0


def _exit_status(node: Node | None) -> int | None:
    """The exit status a node asked for (its ``exit_status``), None if it did not."""
    status = getattr(node, 'exit_status', None)
    return status if isinstance(status, int) else None
