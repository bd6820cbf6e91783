"""Harness for tests that start the cell's executables as separate processes.

Each test gets its own ROS_DOMAIN_ID (allocated across processes with a lock file), discovery
limited to localhost, and every process it starts is stopped at the end (SIGINT, then SIGKILL
after a grace period).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import rclpy
import yaml
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile

from positioning_cell.domains import free_domain as isolated_domain  # noqa: F401 - for tests
from positioning_cell.polling import wait_until

REPO = Path(__file__).resolve().parent.parent
CELL_YAML = REPO / 'config' / 'cell.yaml'


def executable(name: str) -> str:
    """Path of a console script of the package in this interpreter's environment."""
    found = shutil.which(name, path=str(Path(sys.executable).parent))
    if found is None:
        raise FileNotFoundError(f'{name} is not installed next to {sys.executable}')
    return found


class ProcessGroup:
    """Processes of one test, all in one domain; logs in ``log_dir``."""

    def __init__(self, domain_id: int, log_dir: Path) -> None:
        self.domain_id = domain_id
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
                        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        self.env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)

    def start(self, exe: str, *ros_args: str, params: Path | None = CELL_YAML,
              overrides: dict[str, dict[str, Any]] | None = None, label: str | None = None,
              extra_args: tuple[str, ...] = ()) -> subprocess.Popen[bytes]:
        """Start ``exe`` with ``--ros-args --params-file params`` plus ``ros_args``.

        ``overrides`` ({node_name: {nested params}}) go in a second params file after the
        first: a node-specific key in a file beats a ``-p`` override, a later file beats both.
        """
        label = label or exe
        args = [executable(exe), *extra_args, '--ros-args']
        if params is not None:
            args += ['--params-file', str(params)]
        if overrides:
            extra = self.log_dir / f'{label}.overrides.yaml'
            extra.write_text(yaml.safe_dump(
                {node: {'ros__parameters': values} for node, values in overrides.items()}))
            args += ['--params-file', str(extra)]
        args += list(ros_args)
        log = open(self.log_dir / f'{label}.log', 'wb')  # noqa: SIM115 - closed in stop()
        proc = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, env=self.env,
                                start_new_session=True)
        proc._log = log  # type: ignore[attr-defined]
        self.procs[label] = proc
        return proc

    def log(self, label: str) -> str:
        """What a process printed so far."""
        path = self.log_dir / f'{label}.log'
        return path.read_text(errors='replace') if path.exists() else ''

    def stop(self, label: str | None = None, sig: int = signal.SIGINT,
             grace: float = 20.0) -> dict[str, int]:
        """Signal processes (all by default), wait, SIGKILL what is left; exit codes."""
        labels = [label] if label else list(self.procs)
        for name in labels:
            proc = self.procs[name]
            if proc.poll() is None:
                proc.send_signal(sig)
        codes = {}
        for name in labels:
            proc = self.procs[name]
            try:
                codes[name] = proc.wait(timeout=grace)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                codes[name] = proc.wait()
            proc._log.close()  # type: ignore[attr-defined]
        return codes

    def __enter__(self) -> ProcessGroup:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class Client:
    """A test-side rclpy node in its own context, spun in a background thread."""

    def __init__(self, domain_id: int, name: str = 'test_client') -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        # Shutdown races (context shut down while spinning) end the spin thread quietly.
        with contextlib.suppress(Exception):
            self.executor.spin()

    def collect(self, msg_type: Any, topic: str, qos: QoSProfile | int = 100) -> list[Any]:
        """Subscribe and return the list the messages are appended to."""
        received: list[Any] = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def call(self, srv_type: Any, name: str, request: Any, timeout: float = 30.0) -> Any:
        """Call a service (waiting for it to appear) and return the response."""
        client = self.node.create_client(srv_type, name)
        if not client.wait_for_service(timeout_sec=min(timeout, 15.0)):
            raise TimeoutError(f'service {name} did not appear')
        future = client.call_async(request)
        wait_until(future.done, timeout, f'response of {name}')
        return future.result()

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._thread.join(timeout=5.0)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
