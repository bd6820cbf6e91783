"""The console entry points of the cell's nodes: SIGINT, SIGTERM and SIGHUP (the terminal
closed) stop a node cleanly (exit 0, no traceback) from the first instant, not only once
rclpy is up.

A node's module imports rclpy and numpy (scipy and numba only as its work needs them): a
quarter to half a second in which Python's default handlers would turn SIGINT into a
``KeyboardInterrupt`` traceback and SIGTERM into a kill. This
module is imported first (standard library only) and installs handlers that end the process at
once with exit 0 while rclpy loads: nothing is open yet (no rclpy context, no file), and an
exception raised inside an import would surface as a C extension's ImportError, so none is
raised. Just before ``rclpy.init`` (:func:`positioning_cell.ros.participant.start`, before the
node's own modules load) they are swapped for :func:`hold_stops`: a stop while those load is
honoured once they have, before the node is built (:func:`positioning_cell.ros.spin.run`).
Only the interpreter's own start (some 50 ms, before any of the package runs) is left to
Python's defaults.

Once the node's ``main`` has returned (the node closed and destroyed, the rclpy context shut
down and destroyed: the bag written, the ROS log flushed, Fast DDS's shared memory released),
:func:`end_process` ends the process without the interpreter's finalization: it tears down
every module and object of rclpy, numpy, scipy and numba, 0.4 to 0.6 s here and more than 1.5 s
on a loaded machine, which would put a stop past its 2 s.

A stop that has not ended the process :data:`STOP_DEADLINE_S` after its signal (a callback or a
library call that never returns: "nothing hangs") ends it anyway: every thread's stack is
written to stderr (the node's log) and the process exits with status 1 (``faulthandler``'s
watchdog, a thread of C that needs neither the main thread nor the GIL).
"""

from __future__ import annotations

import contextlib
import ctypes
import faulthandler
import gc
import importlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import NoReturn

#: The signals that stop a node or a tool cleanly. SIGHUP too: a process whose terminal closes
#: is otherwise killed without its DDS participant saying goodbye, and the others keep it for
#: the 5 s lease (config/fastdds_loopback.xml), during which a process started in its place
#: (the same participant number) is not sent their data: ``cell watch`` restarted after its
#: terminal closed showed its first table after 2.8-5.2 s instead of 0.7-1.2 s.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
_stop_requested = threading.Event()

STOP_DEADLINE_S = 10.0
"""Longest time from a stop signal to the end of the process (s) before it is ended with its
threads' stacks written to stderr and status 1: five times issue 21's 2 s for a stop, and
under the 15-20 s after which the tests kill a node that did not stop (so that its log says
where it hung). Read when the first stop signal arrives."""


def _exit_now(signum: int, frame: FrameType | None) -> None:
    """A stop while the node's modules load: nothing to close yet, exit 0 now."""
    os._exit(0)


_on_stop: list[Callable[[], None]] = []


def _remember(signum: int, frame: FrameType | None) -> None:
    if not _stop_requested.is_set():
        faulthandler.dump_traceback_later(STOP_DEADLINE_S, exit=True)
    _stop_requested.set()
    for call in _on_stop:
        call()


def hold_stops(on_stop: Callable[[], None] | None = None) -> None:
    """SIGINT / SIGTERM / SIGHUP only set a flag (:func:`stop_requested`), arm the stop's
    deadline (:data:`STOP_DEADLINE_S`) and call ``on_stop`` (quick, no exception: it runs in
    the main thread between two bytecodes). Installed just
    before ``rclpy.init`` (which installs no handlers of its own): no exception lands in the
    middle of a callback, the context is not shut down under a publishing timer, and the spin
    loop returns between two callbacks once the flag is up."""
    if on_stop is not None:
        _on_stop.append(on_stop)
    for sig in STOP_SIGNALS:
        signal.signal(sig, _remember)


def exit_on_stop() -> None:
    """SIGINT / SIGTERM / SIGHUP end the process at once with exit 0 (while the modules
    load)."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, _exit_now)


def stop_requested() -> bool:
    """Whether a stop signal (:data:`STOP_SIGNALS`) arrived since :func:`hold_stops`."""
    return _stop_requested.is_set()


def end_process(code: int) -> NoReturn:
    """Exit now with ``code``: Python's streams and logging flushed, then C's (``fflush``),
    then ``os._exit`` (module docstring: what is skipped is the interpreter's finalization;
    everything the node has to close is closed by then)."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)
    os._exit(code)


#: The module of ``rosidl_generator_py`` that generates Python code from interface files
#: (rosidl_parser with its lark grammar, rosidl_pycommon, empy). The package's ``__init__`` tries
#: to import it beside ``import_type_support`` and goes on without it on an ImportError
#: (Jazzy); a message's first use imports the package, so every rclpy process loads the
#: generator, 0.035 s of its start here (ad hoc, 3 runs each), and uses none of it.
CODE_GENERATOR = 'rosidl_generator_py.generate_py_impl'


def skip_code_generator() -> None:
    """Make :data:`CODE_GENERATOR` unimportable in this process (``None`` in ``sys.modules``:
    Python's way to block one module), before any message's type support is imported. For a
    process that builds no interfaces: the cell's nodes and command lines, never the tests
    (nothing is blocked in a process that already imported it)."""
    sys.modules.setdefault(CODE_GENERATOR, None)  # type: ignore[arg-type]


def _console(module: str) -> Callable[[], int]:
    def main() -> int:
        exit_on_stop()
        skip_code_generator()
        # No cyclic collection while the modules load and the node is built: they make ~90 000
        # objects and almost no cycles to collect (407 in the positioner's start), and the
        # collector's passes over them cost 0.04 s of that start (ad hoc, 5 runs each).
        # spin.run freezes what exists once the nodes are built and enables the collector.
        gc.disable()
        # rclpy only (~0.1 s), then the context and its participant, discovered by the cell
        # while the node's modules load (positioning_cell.ros.participant); from here a stop
        # is held for the node's run, which honours it before building the node.
        participant = importlib.import_module('positioning_cell.ros.participant')
        hold_stops()
        participant.start()
        node_main: Callable[[], int] = importlib.import_module(module).main
        end_process(node_main())

    main.__doc__ = f'Entry point of ``{module.rsplit(".", 1)[1]}`` (clean stop from the start).'
    return main


def node_module(executable: str) -> str:
    """The module of a node executable (names.NODE_EXECUTABLES): its ``main`` (a
    :class:`positioning_cell.ros.spin.NodeStart`) runs the node alone and says how it starts."""
    return f'positioning_cell.nodes.{executable}'


recorder_node = _console(node_module('recorder_node'))
bag_player_node = _console(node_module('bag_player_node'))
leg_driver_node = _console(node_module('leg_driver_node'))
pose_measurement_node = _console(node_module('pose_measurement_node'))
kinematics_node = _console(node_module('kinematics_node'))
accuracy_monitor_node = _console(node_module('accuracy_monitor_node'))
calibrator_node = _console(node_module('calibrator_node'))
live_view_node = _console(node_module('live_view_node'))
cell_coordinator_node = _console(node_module('cell_coordinator_node'))
panel_simulator_node = _console(node_module('panel_simulator_node'))
cell_container = _console('positioning_cell.ros.container')
