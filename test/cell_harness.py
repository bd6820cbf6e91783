"""Harness of the node tests: the cell's nodes built in the test process (in-process tier), or
its executables started as separate processes (multi-process tier). Each test gets its own
ROS_DOMAIN_ID (the project's allocator), discovery limited to localhost, and everything it
starts is stopped at the end."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.domains import free_domain as isolated_domain
from positioning_cell.ros.processes import Processes, cell_environment, executable
from positioning_cell.ros.spin import JoinedMultiThreadedExecutor, aside_nodes, spin_in_slices

__all__ = ['CELL_YAML', 'FAST_MOTION', 'LOADED_COMMAND', 'LOADED_LIVENESS', 'REPO', 'Client',
           'InProcess', 'ProcessGroup', 'executable', 'in_process', 'isolated_domain',
           'processes_naming', 'stop_cleanly', 'wait_until']

REPO = Path(__file__).resolve().parent.parent
CELL_YAML = REPO / 'config' / 'cell.yaml'

#: The positioner's ``motion`` for tests of what a move does, not of the motion: three times
#: the default speed, within the drives' and the factory's maxima.
FAST_MOTION = {'linear_speed': 0.03, 'linear_acceleration': 0.15, 'angular_speed': 0.3,
               'angular_acceleration': 1.5}

#: The positioner's ``liveness`` for tests that move the real cell in the parallel tier, where
#: liveness is not under test (test_faults proves it alone, in the timing tier). On a loaded
#: 2-core machine (three workers beside the docs build) the busiest minute held the driver's
#: 100 Hz joint states past the default 0.2 s, and the tracker's 20 Hz readings past the
#: default 0.5 s (0.51 s, a homing aborted in CI): a stalled process, not a lost input. The
#: drives' answer to a trajectory likewise (0.5 s by default: a coordinated test's move aborted
#: under three workers and the docs build), and the frozen-encoder watch (0.5 s: a container
#: stalled that long looked like a frozen encoder, test_coordinated_cell).
LOADED_LIVENESS = {'joint_silence': 1.0, 'tracker_silence': 1.5, 'answer_timeout': 2.0,
                   'freeze_window': 1.5}

#: The leg driver's ``command`` for the same tests: a positioner stalled 0.52 s on a loaded
#: CI runner went without a heartbeat past the default 0.5 s, and the drives stopped a
#: calibration move under control (test_run_cell, correctly so): its liveness is test_faults'.
LOADED_COMMAND = {'heartbeat_timeout': 1.5}


class Client(CellClient):
    """The tests' :class:`CellClient`: rclpy's signal handlers left out unless asked for, so
    that a SIGINT or SIGTERM to pytest ends the run with every fixture's teardown (conftest:
    every process a test started stopped), not only the client's context."""

    def __init__(self, domain: int | None = None, name: str = 'cell_client', *,
                 signals: bool = False, **kwargs: Any) -> None:
        super().__init__(domain, name, signals=signals, **kwargs)


def waiting_for_file(variable: str, reason: str) -> str:
    """Python source for a child process: wait (polling) until the file named by its
    environment variable ``variable`` exists, or raise RuntimeError(``reason``) after 60 s.
    It holds the child at that point until the test lets it go."""
    return f'''
import os
import time

deadline = time.monotonic() + 60.0
while not os.path.exists(os.environ[{variable!r}]):
    if time.monotonic() > deadline:
        raise RuntimeError({reason!r})
    time.sleep(0.005)
'''


def processes_naming(marker: Path) -> list[int]:
    """PIDs of processes whose command line names ``marker`` (e.g. a run's override file)."""
    found = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            if str(marker).encode() in (proc / 'cmdline').read_bytes():
                found.append(int(proc.name))
    return found


def stop_cleanly(procs: Processes, log_chars: int = 2000) -> None:
    """Stop every process of ``procs`` (:meth:`Processes.stop`) and assert that each exited 0:
    the message names first which did not and with what code (a short summary line shows its
    start), then the end of their logs, and of the native stacks of one that did not stop in
    time (gdb lists the main thread last)."""
    codes = procs.stop()
    failed = {label: code for label, code in codes.items() if code != 0}
    assert not failed, ', '.join(f'{label} exited {code}' for label, code in failed.items()) \
        + ''.join(f'\n--- {label}:\n{procs.log(label)[-log_chars:]}'
                  + (f'\n--- {label}, native stacks:\n{stacks[-2 * log_chars:]}'
                     if (stacks := procs.stacks(label)) else '') for label in failed)


class ProcessGroup(Processes):
    """Processes of one test, all in one domain, each started with config/cell.yaml."""

    def __init__(self, domain_id: int, log_dir: Path) -> None:
        super().__init__(cell_environment(domain_id), log_dir)

    def start(self, exe: str, *ros_args: str, params: Any = (CELL_YAML,),  # type: ignore[override]
              **kwargs: Any) -> Any:
        return super().start(exe, *ros_args, params=params, **kwargs)


class InProcess:
    """Nodes of the package built in this process: one rclpy context on ``domain``, one
    multi-threaded executor spinning them in a background thread, and a :class:`Client` in
    the same context (no discovery between them)."""

    def __init__(self, domain: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        # As the cell's nodes spin (ros.spin): the spin ends between two slices, then the
        # executor's shutdown waits for the callbacks it started (rclpy's own left them
        # running as the nodes were destroyed).
        self.executor = JoinedMultiThreadedExecutor(num_threads=4, context=self.context)
        self.nodes: list[Node] = []
        self.client = Client(name='test_client', context=self.context)
        self._spinning = threading.Event()
        self._spinning.set()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        with contextlib.suppress(Exception):  # shutdown races end the spin quietly
            spin_in_slices(self.executor, lambda: self._spinning.is_set() and self.context.ok())

    def start(self, node_class: Any, **overrides: Any) -> Any:
        """Build ``node_class`` with config/cell.yaml and the ``overrides`` (dotted names →
        values) and spin it."""
        node = node_class(context=self.context,
                          cli_args=['--ros-args', '--params-file', str(CELL_YAML)],
                          parameter_overrides=[Parameter(k, value=v)
                                               for k, v in overrides.items()])
        self.nodes.append(node)
        for each in (node, *aside_nodes(node)):
            self.executor.add_node(each)
        return node

    def close(self) -> None:
        """Stop spinning, close and destroy the nodes, shut the context down."""
        self._spinning.clear()
        self._thread.join(timeout=5.0)
        self.executor.shutdown(timeout_sec=5.0)
        for node in self.nodes:
            close = getattr(node, 'close', None)
            if callable(close):
                close()
            for helper in aside_nodes(node):
                helper.destroy_node()
            node.destroy_node()
        self.client.close()
        rclpy.try_shutdown(context=self.context)


@contextlib.contextmanager
def in_process() -> Iterator[InProcess]:
    """An :class:`InProcess` on a free domain, closed at the end."""
    with isolated_domain() as domain:
        ros = InProcess(domain)
        try:
            yield ros
        finally:
            ros.close()
