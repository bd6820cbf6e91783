"""The Jazzy main() idiom of the cell's nodes, with the executor each node needs, and a clean
exit on SIGINT and SIGTERM."""

from __future__ import annotations

import gc
import importlib
import sys
import threading
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import rclpy
from rclpy.executors import (
    ConditionReachedException,
    Executor,
    ExternalShutdownException,
    MultiThreadedExecutor,
    ShutdownException,
    TimeoutException,
    TimeoutObject,
)
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from rclpy.utilities import get_default_context

from positioning_cell import files
from positioning_cell.core import compiled
from positioning_cell.errors import PositioningError
from positioning_cell.ros import participant
from positioning_cell.ros.entry import hold_stops, stop_requested
from positioning_cell.ros.unspun import destroy_unspun, helper_node

STOP_POLL_S = 0.1
"""Longest time from SIGINT / SIGTERM to the executor returning (s), besides a running callback."""

HANDOFF_WAIT_S = 0.05
"""Longest wait of a multi-threaded executor for a pool thread to take the callback it handed
out (s), before it hands it out again (:meth:`JoinedMultiThreadedExecutor._spin_once_impl`)."""

SHUTDOWN_WAIT_S = 5.0
"""Longest wait for running callbacks after a stop (s), before the node is destroyed under
them. Not what bounds a stop: a callback still running holds the process at its exit anyway
(the executor's threads are joined), so callbacks must return at a stop: the positioner's do
at once (close() ends a move, :func:`positioning_cell.files.abandon_loads` a file load)."""

SWITCH_INTERVAL_S = 0.001
"""The GIL's switch interval in a process that hosts several nodes (s; CPython's 0.005). A
thread that gives the GIL up (every rclpy call does) waits up to a switch interval for each
busy thread ahead of it to get it back: with four nodes' executors in one process the leg
driver's joint states fell silent long enough for the positioner's 0.2 s watch to abort
homing in 6 of 30 composed starts on a quiet 2-core VM, 0 of 32 with 1 ms and the GC freeze of
:func:`_settle_interpreter` (benchmarks/startup.py, and an ad-hoc loop of its cell start,
separate and composed alternating)."""


class Spin(Enum):
    """EVENTS: rclpy's events executor (several times cheaper per callback; for nodes whose
    callbacks never wait); THREADS: a multi-threaded executor (a service callback waits for a
    move while timers run)."""

    EVENTS = 'events'
    THREADS = 'threads'


#: The scipy modules the library imports at their first use (core.poses.scipy_rotation, the
#: calibration's tests and fits, the screw null space): a node whose work may use them imports
#: them as soon as it spins, in a thread of their own (:func:`_import_aside`), rather than in
#: the first callback that needs one: an import in a callback pauses the executor for 0.2 s or
#: more (the positioner's 0.2 s joint-silence watch; 1.0 s was seen in CI on a loaded machine).
#: Imported before the spin instead, they held every node's first answer back by 0.2-0.3 s
#: (issue 24).
SCIPY_MODULES = ('scipy.linalg', 'scipy.spatial.transform', 'scipy.special')


@dataclass(frozen=True)
class NodeStart:
    """How one of the cell's nodes starts, and its entry point: what builds it (called with no
    arguments, in the initialised default context: the node reads its parameters from the
    process's ``--ros-args``), the executor it needs, and that executor's threads (THREADS
    only). Each node module's ``main`` is one: called, it runs the node alone (:func:`run`);
    ``cell_container`` runs several together (:func:`run_together`). ``imports``: the modules
    its work imports at their first use, imported in a thread of their own from the moment it
    spins (:func:`_import_aside`; none for the nodes whose work never needs scipy: the
    recorder, the bag player, the drives, the tracker, the monitor and the positioner, whose
    calibration imports what it needs as it loads; test_node_start)."""

    factory: Callable[[], Node]
    spin: Spin = Spin.EVENTS
    threads: int = 1
    imports: tuple[str, ...] = SCIPY_MODULES

    def __call__(self, args: Sequence[str] | None = None) -> int:
        """Run the node alone (:func:`run`): the exit status."""
        return run(self, args)

    def executor(self) -> Executor:
        """A new executor of the kind this node needs."""
        return (JoinedMultiThreadedExecutor(num_threads=self.threads)
                if self.spin is Spin.THREADS else EventsExecutor())


class JoinedMultiThreadedExecutor(MultiThreadedExecutor):
    """rclpy's multi-threaded executor whose ``shutdown`` waits for the callbacks it started,
    and which hands each callback out once (:meth:`_spin_once_impl`).

    Jazzy's ``Executor.shutdown`` sets its shutdown flag and then skips its own wait for
    outstanding work (it waits only ``if not self._is_shutdown``), and the multi-threaded
    executor does not join its thread pool: ``shutdown(timeout_sec=5)`` returned at once while
    callbacks still ran, so the node was closed and destroyed under them. A callback handed to
    the pool just before then found the executor's guard condition destroyed ("The following
    exception was never retrieved: cannot use Destroyable because destruction was requested",
    in 7 of 50 positioner stops, ad hoc). Here the pool is shut down first, its queued and
    running callbacks finished (at most ``timeout_sec``), and only then the executor."""

    def _spin_once_impl(self, timeout_sec: float | TimeoutObject | None = None,
                        wait_condition: Callable[[], bool] = lambda: False) -> None:
        """rclpy's (Jazzy) one turn of the loop, with one change: a callback handed to the
        thread pool is waited for until a pool thread has taken it (at most
        :data:`HANDOFF_WAIT_S`), before the next turn.

        rclpy's turn returns at once, and its next one hands the same task out again while
        no pool thread has started it yet (the in-progress tasks are yielded again while
        neither executing nor done), each time after rebuilding its wait set over every
        entity: the positioner at rest, 100 joint states and ~60 timer calls a second, went
        through ~700 turns a second, its executor's own Python taking most of its CPU (yappi,
        ad hoc; benchmarks/idle_cpu.py). With every pool thread busy the wait ends at its
        bound and the task is handed out once more (a pool thread that takes it a second time
        finds it executing or done and returns)."""
        try:
            handler, _, _ = self.wait_for_ready_callbacks(timeout_sec, None, wait_condition)
        except (ExternalShutdownException, ShutdownException, TimeoutException,
                ConditionReachedException):
            return
        taken = threading.Event()

        def run() -> None:
            taken.set()
            handler()

        self._executor.submit(run)
        self._futures.append(handler)
        taken.wait(HANDOFF_WAIT_S)
        for future in self._futures[:]:
            if future.done():
                self._futures.remove(future)
                future.result()  # a callback's exception, raised here as rclpy does

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """Finish the callbacks handed to the thread pool (within ``timeout_sec``; None:
        without bound), then shut the executor down. True if they all finished."""
        pool = self._executor  # rclpy's ThreadPoolExecutor of this executor's callbacks
        drain = threading.Thread(target=pool.shutdown, kwargs={'wait': True}, daemon=True,
                                 name='executor drain')
        drain.start()
        drain.join(timeout_sec)
        finished = not drain.is_alive()
        return super().shutdown(timeout_sec=0) and finished


def run(node: NodeStart, args: Sequence[str] | None = None) -> int:
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
    return run_together([node], args)


def run_together(nodes: Sequence[NodeStart], args: Sequence[str] | None = None) -> int:
    """:func:`run` for several nodes in this one process (ROS 2's composition: one context, one
    DDS participant, one copy of rclpy, numpy, scipy and numba), built in the order given; a
    stop, a node's ``exit_status`` or a node that cannot be built ends them all (closed, then
    destroyed, in reverse order).

    The executors: each node gets the executor it gets alone (:meth:`NodeStart.executor`, the
    one it was written and tested on), spun in a thread of its own (the first node's in this
    thread). Nodes together keep their concurrency exactly: the leg driver, the tracker and
    the monitor one callback at a time each on an events executor (several times cheaper per
    callback than the others, and most of the cell's callbacks are theirs: the driver's
    100 Hz physics timer, the tracker's truth and readings), the positioner
    its threads and callback groups (its service callbacks wait for a move to settle while
    its timers and subscriptions run; its heartbeat alone in a group), its pose and
    diagnostics timers on a node beside it, on an events executor of their own
    (:func:`aside_node`). What the nodes share is the rest: the context and its DDS
    participant, the interpreter and one copy of rclpy, numpy, scipy and numba (the memory
    composition saves), and the GIL.

    Not one executor for all. Measured with the cell's four nodes at rest, as
    benchmarks/idle_cpu.py measures (CPU from /proc, the driver's rate from its stamps; 2
    shared cores, load average 5 to 7: one to four runs each): one multi-threaded executor
    (each node's callbacks mutually exclusive in its default group; it rebuilds its wait set
    over every node's entities at each wake-up) took 0.65 core against the four processes'
    0.50 and held the driver to 47 to 67 % of its publish rate, the tracker's readings up to
    0.6 s apart: the positioner aborted homing (0.5 s without a reading). One single-threaded
    or events executor cannot host the positioner (a service callback waiting for a move would
    block the timers it waits on). One events executor for the driver, the tracker and the
    monitor together: their callbacks wait for one another, 62 to 96 Hz against 95 to 99 Hz
    with one executor each. A node that shuts the context down (the player at the end of its bag)
    ends them all too."""
    # A stop gives up the loads waited on at once (files.within), even while the node is
    # being built (the positioner loads its calibration file then).
    hold_stops(files.abandon_loads)
    if not participant.started():  # (a node's entry point started it before the imports)
        rclpy.init(args=list(args) if args is not None else None,
                   signal_handler_options=SignalHandlerOptions.NO)
    try:
        return _spin(nodes)
    finally:
        participant.end()
        rclpy.try_shutdown()
        # The participant goes now, its shared memory with it, rather than in the interpreter's
        # finalization (which entry.end_process skips): once the node's and the executor's
        # handles are collected, the context is no longer in use and is destroyed at once.
        gc.unfreeze()  # (what _settle_interpreter froze is collectable again)
        gc.collect()
        get_default_context().destroy()


def spin_in_slices(executor: Executor, running: Callable[[], bool]) -> None:
    """Spin ``executor`` while ``running()``, in slices of :data:`STOP_POLL_S`:
    EventsExecutor.spin() does not run callbacks in this rclpy build (platform.md), and
    Python's signal handlers run only between two slices. Each slice waits on a future of
    its own that never completes: rclpy's multi-threaded executor adds a done callback to the
    future it spins until at every wake, so one future for all the slices kept every one of
    them (the positioner at rest: ~280 a second, without bound)."""
    while running():
        executor.spin_until_future_complete(Future(), timeout_sec=STOP_POLL_S)


#: Each node's nodes spun beside it (:func:`aside_node`; made as the node is built).
_aside: weakref.WeakKeyDictionary[Node, list[Node]] = weakref.WeakKeyDictionary()


def aside_node(owner: Node, role: str,
               timers: Sequence[tuple[float, Callable[[], None]]] = ()) -> Node:
    """A :func:`~positioning_cell.ros.unspun.helper_node` of ``owner``'s (``_<owner>_<role>``)
    with ``timers`` on it (each its period s and its callback), for callbacks that never wait:
    spun beside ``owner`` on an events executor of its own, in a thread of its own, wherever
    ``owner`` is spun (:func:`run_together`; a test's executor takes :func:`aside_nodes` too),
    and destroyed just before it.

    The positioner's periodic outputs (its pose at 50 Hz, its diagnostics) are its timers on
    one: on its multi-threaded executor (which its service callbacks need: they wait for a
    move) every timer call cost a rebuild of that executor's wait set over all its entities,
    most of the positioner's Python at rest. Off it, the positioner took 0.149-0.151 core at
    rest against 0.179-0.188, and 0.205-0.215 moving against 0.250-0.258
    (benchmarks/idle_cpu.py, two runs each, alternated, Dec 7). The callbacks on one must
    be safe beside the owner's (the positioner's timers call the mover, which locks). The
    positioner's heartbeat stays on its own executor: a stalled executor stops it, and the
    drives see that."""
    node = helper_node(owner, role)
    for period, callback in timers:
        node.create_timer(period, callback)
    _aside.setdefault(owner, []).append(node)
    return node


def aside_nodes(owner: Node) -> tuple[Node, ...]:
    """The nodes spun beside ``owner`` (:func:`aside_node`), in the order they were made."""
    return tuple(_aside.get(owner, ()))


def _spin(starts: Sequence[NodeStart]) -> int:
    """:func:`run_together` from the nodes' construction to their destruction (the exit
    code)."""
    nodes: list[Node] = []
    spinning: list[Executor] = []
    workers: list[threading.Thread] = []
    done = threading.Event()
    failures: list[BaseException] = []

    def spin(executor: Executor) -> None:
        spin_in_slices(executor, lambda: (not done.is_set() and rclpy.ok()
                                          and not stop_requested()
                                          and _exit_status(nodes) is None))

    def spin_aside(executor: Executor) -> None:
        try:
            spin(executor)
        except ExternalShutdownException:
            pass
        except BaseException as err:  # a callback's: raised in this thread once all stop
            failures.append(err)
        finally:
            done.set()  # one executor ended: all end

    try:
        for start in starts:
            if stop_requested():
                return 0
            nodes.append(start.factory())
        # The hidden node that made the participant (positioning_cell.ros.participant) stays
        # until the end (run_together's finally): destroyed here, just as the nodes' endpoints
        # went out, a running client sometimes saw those endpoints only ~1 s later.
        # All built and their kernels warmed: no kernel is compiled from here on (a pause of an
        # executor), a cold kernel raises instead (positioning_cell.core.compiled).
        compiled.seal()
        _settle_interpreter(len(nodes))
        for start, node in zip(starts, nodes, strict=True):
            spinning.append(start.executor())
            spinning[-1].add_node(node)
        # each node but the first in a thread of its own, and beside each the nodes of its
        # callbacks that never wait, each on an events executor (aside_node)
        spun = list(zip(spinning[1:], nodes[1:], strict=True))
        for helper in (h for node in nodes for h in aside_nodes(node)):
            spinning.append(EventsExecutor())
            spinning[-1].add_node(helper)
            spun.append((spinning[-1], helper))
        workers = [threading.Thread(target=spin_aside, args=(executor,), daemon=True,
                                    name=f'spin {node.get_name()}') for executor, node in spun]
        modules = tuple(dict.fromkeys(m for start in starts for m in start.imports))
        if modules:
            workers.append(threading.Thread(target=_import_aside,
                                            args=(modules, failures, done), daemon=True,
                                            name='imports'))
        for worker in workers:
            worker.start()
        spin(spinning[0])
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except PositioningError as err:
        if stop_requested():  # stopped while it was being built (a load given up)
            return 0
        print(f'{Path(sys.argv[0]).name}: {err}', file=sys.stderr)
        return 2
    finally:
        done.set()  # the other executors stop between two callbacks (within STOP_POLL_S)
        for worker in workers:
            worker.join(timeout=SHUTDOWN_WAIT_S)
        # No callback waits for a file any more (a calibration file's load in the positioner's
        # parameter callback: given up since the signal); then close(): it ends what a worker
        # thread may still wait on (a move), so the executor's shutdown then finds its
        # callbacks returning.
        files.abandon_loads()
        for node in reversed(nodes):
            close = getattr(node, 'close', None)
            if callable(close):
                close()
        for executor in spinning:
            executor.shutdown(timeout_sec=SHUTDOWN_WAIT_S)
        for node in reversed(nodes):
            destroy_unspun(node)  # its readers' nodes, not left to the collection below
            for helper in aside_nodes(node):
                helper.destroy_node()
            node.destroy_node()
    if failures:  # a callback raised in another executor's thread: as if in this one
        raise failures[0]
    return _exit_status(nodes) or 0


def _import_aside(modules: Sequence[str], failures: list[BaseException],
                  done: threading.Event) -> None:
    """Import ``modules`` while the nodes spin (a thread of its own), then take what they
    built out of the collector's view as :func:`_settle_interpreter` did the rest. A callback
    that needs one of them meanwhile waits for its import (Python's module lock), at most as
    long as the import takes, which is what the node's start took before this thread: the
    nodes answer 0.2-0.3 s sooner (issue 24). An import that fails ends the run, as a
    callback's exception does (kept in ``failures``, ``done`` set)."""
    try:
        for module in modules:
            importlib.import_module(module)
        gc.freeze()
    except BaseException as err:
        failures.append(err)
        done.set()


def _settle_interpreter(hosted: int) -> None:
    """Once the ``hosted`` nodes are built: what exists now (the modules, the models, the
    nodes) leaves the cyclic garbage collector's view (``gc.freeze``: a full collection scans
    only what came after; before, 30-100 ms pauses of every thread of the composed cell), and
    the collector runs from now on (a node's entry point disables it while the node loads,
    :mod:`positioning_cell.ros.entry`); with several nodes the GIL switches every
    :data:`SWITCH_INTERVAL_S`."""
    gc.freeze()
    gc.enable()
    if hosted > 1:
        sys.setswitchinterval(SWITCH_INTERVAL_S)


def _exit_status(nodes: Sequence[Node]) -> int | None:
    """The exit status the first of ``nodes`` that asked for one asked for (its
    ``exit_status``), None if none did."""
    for node in nodes:
        status = getattr(node, 'exit_status', None)
        if isinstance(status, int):
            return status
    return None
