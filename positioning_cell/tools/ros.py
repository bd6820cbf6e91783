"""The tools' one ROS module: starting the cell's executables as processes on a private
domain, and an rclpy client of the running cell (its own context, spun in a background thread)
with the calls the tools and tests make. Everything else in ``tools/`` is plain Python."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import rclpy
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.srv import GetPlan
from numpy.typing import ArrayLike
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import String
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.nodes.messages import pose_stamped
from positioning_cell.nodes.qos import DIAGNOSTICS_QOS, LATCHED_QOS
from positioning_cell.tools.polling import wait_until


def cell_environment(domain: int, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment of a cell process: ``base`` (default: this process's) on ROS domain
    ``domain`` with discovery limited to this machine. The wheels' bootstrap marker is removed
    so the child sets its own library path (platform.md)."""
    env = dict(os.environ if base is None else base, ROS_DOMAIN_ID=str(domain),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)
    return env


def executable(name: str) -> str:
    """Path of one of the package's console scripts: beside this interpreter first (a venv),
    else on PATH; FileNotFoundError if it is not installed."""
    found = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if found is None:
        raise FileNotFoundError(f'{name} is not installed (run `make setup`)')
    return found


class Processes:
    """Processes started in environment ``env``, each in its own process group, output in
    ``log_dir/<label>.log``; :meth:`stop` ends them (SIGINT, SIGKILL after a grace period)."""

    def __init__(self, env: Mapping[str, str], log_dir: Path) -> None:
        self.env = dict(env)
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self._logs: dict[str, IO[bytes]] = {}

    def start(self, exe: str, *ros_args: str, params: Sequence[Path] = (),
              overrides: Mapping[str, Mapping[str, Any]] | None = None,
              label: str | None = None,
              extra_args: Sequence[str] = ()) -> subprocess.Popen[bytes]:
        """Start ``exe extra_args --ros-args --params-file P ... ros_args``. ``overrides``
        ({node name: {nested params}}) go in one more params file after ``params`` (a later
        file beats an earlier one, and a node's section beats a plain ``-p``)."""
        label = label or exe
        args = [executable(exe), *extra_args, '--ros-args']
        files = list(params)
        if overrides:
            extra = self.log_dir / f'{label}.overrides.yaml'
            extra.write_text(yaml.safe_dump(
                {node: {'ros__parameters': dict(v)} for node, v in overrides.items()}))
            files.append(extra)
        for path in files:
            args += ['--params-file', str(path)]
        args += list(ros_args)
        log = (self.log_dir / f'{label}.log').open('wb')
        self._logs[label] = log
        self.procs[label] = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT,
                                             env=self.env, start_new_session=True)
        return self.procs[label]

    def log(self, label: str) -> str:
        """What a process printed so far."""
        path = self.log_dir / f'{label}.log'
        return path.read_text(errors='replace') if path.exists() else ''

    def dead(self) -> list[str]:
        """Labels of the processes that have exited."""
        return [label for label, p in self.procs.items() if p.poll() is not None]

    def stop(self, label: str | None = None, sig: int = signal.SIGINT,
             grace: float = 20.0) -> dict[str, int]:
        """Send ``sig`` to the process group of ``label`` (default: all), wait up to ``grace``
        s, SIGKILL what is left; the exit codes."""
        labels = [label] if label else list(self.procs)
        for name in labels:
            proc = self.procs[name]
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, sig)
        codes = {}
        for name in labels:
            proc = self.procs[name]
            try:
                codes[name] = proc.wait(timeout=grace)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                codes[name] = proc.wait()
            with contextlib.suppress(ProcessLookupError):  # leftovers of the group
                os.killpg(proc.pid, signal.SIGKILL)
            log = self._logs.pop(name, None)
            if log is not None:
                log.close()
        return codes

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class CellClient:
    """An rclpy node spun in a background thread: what a tool or a test needs of the running
    cell. In its own context on ``domain`` (``signals``: let rclpy install its SIGINT handler;
    a tool that handles signals itself passes False), or in the given ``context`` (which its
    owner shuts down)."""

    def __init__(self, domain: int | None = None, name: str = 'cell_client', *,
                 signals: bool = True, context: Context | None = None) -> None:
        self._owns_context = context is None
        if context is None:
            context = Context()
            options = SignalHandlerOptions.ALL if signals else SignalHandlerOptions.NO
            rclpy.init(context=context, domain_id=domain, signal_handler_options=options)
        self.context = context
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients: dict[str, Any] = {}
        self._statuses: dict[str, list[DiagnosticStatus]] | None = None
        self._program: Any = None
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        # Shutdown races (the context shut down while spinning) end the spin thread quietly.
        with contextlib.suppress(Exception):
            self.executor.spin()

    # -- generic --------------------------------------------------------------------------------
    def collect(self, msg_type: Any, topic: str, qos: QoSProfile | int = 100) -> list[Any]:
        """Subscribe and return the list the messages are appended to."""
        received: list[Any] = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def call(self, srv_type: Any, name: str, request: Any, timeout: float = 30.0) -> Any:
        """Call a service (waiting up to ``min(timeout, 30)`` s for it to appear) and return
        the response; TimeoutError names what did not come."""
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(srv_type, name)
        wait_until(client.service_is_ready, min(timeout, 30.0), f'service {name}')
        future = client.call_async(request)
        wait_until(future.done, timeout, f'the response of {name}')
        return future.result()

    def subscribed(self, topic: str, node: str) -> bool:
        """Has node ``node`` a subscription on ``topic``?"""
        return any(i.node_name == node for i in self.node.get_subscriptions_info_by_topic(topic))

    def set_parameter(self, node: str, name: str, value: Any) -> SetParametersResult:
        """Set one parameter of ``node``; the node's result (``successful``, ``reason``)."""
        request = SetParameters.Request(parameters=[Parameter(name, value=value)
                                                    .to_parameter_msg()])
        return self.call(SetParameters, names.set_parameters_service(node), request).results[0]

    # -- the cell -------------------------------------------------------------------------------
    def statuses(self, name: str) -> list[DiagnosticStatus]:
        """The list the /diagnostics statuses named ``name`` are appended to (subscribed on
        first use)."""
        if self._statuses is None:
            self._statuses = {}
            self.node.create_subscription(DiagnosticArray, names.DIAGNOSTICS,
                                          self._on_diagnostics, DIAGNOSTICS_QOS)
        return self._statuses.setdefault(name, [])

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        assert self._statuses is not None
        for status in msg.status:
            if status.name in self._statuses:
                self._statuses[status.name].append(status)

    def plan(self, service: str, position: ArrayLike, quaternion: ArrayLike,
             tolerance: float = 0.0, timeout: float = 120.0) -> bool:
        """Call /positioner/move_to_pose or /positioner/check_pose for a pose in the base
        frame; True when the plan is not empty (moved / would move)."""
        goal = pose_stamped(position, quaternion, self.node.get_clock().now().to_msg())
        response = self.call(GetPlan, service,
                             GetPlan.Request(goal=goal, tolerance=float(tolerance)), timeout)
        return bool(response.plan.poses)

    def monitor_report(self) -> dict[str, Any]:
        """The accuracy monitor's /accuracy_monitor/report."""
        doc: dict[str, Any] = json.loads(self.call(Trigger, names.MONITOR_REPORT,
                                                   Trigger.Request(), 10.0).message)
        return doc

    def advertise_program(self) -> None:
        """Offer /cell/program (latched), so the recorder subscribes before the first step."""
        if self._program is None:
            self._program = self.node.create_publisher(String, names.PROGRAM, LATCHED_QOS)

    def publish_program(self, text: str) -> None:
        """Publish a run-program step on /cell/program."""
        self.advertise_program()
        self._program.publish(String(data=text))

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        if self._owns_context:
            rclpy.try_shutdown(context=self.context)  # type: ignore[attr-defined]
        self._thread.join(timeout=5.0)

    def __enter__(self) -> CellClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def status_ok(status: DiagnosticStatus) -> bool:
    """A status of level OK."""
    return status.level in (b'\x00', 0)


def status_values(status: DiagnosticStatus) -> dict[str, str]:
    """The key-value pairs of a status."""
    return {kv.key: kv.value for kv in status.values}
