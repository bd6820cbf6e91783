"""``run_cell`` (``make run``): run the positioning cell on its embedded defaults and analyse
the run.

Starts the cell's nodes as separate processes (as ``launch/cell.launch.py`` does on a ROS
install), each in its own process group, on a private ROS_DOMAIN_ID with discovery limited to
this machine; records everything into ``runs/<UTC timestamp>/bag``; drives the program of
``config/program.yaml`` (each compensation mode set on the positioner, then its cycles of
moves through ``/positioner/move_to_pose``), printing a line per move with the monitor's
verdict; stops every process (SIGINT, SIGKILL after a grace period, also on Ctrl-C / SIGTERM);
analyses the bag (``positioning_cell.tools.analyze_bag``) into the same folder; prints the
comparison table and where the bag, report and plots are.

Before each move the driver publishes the step on ``/cell/program`` (std_msgs/String,
transient-local, JSON of :class:`positioning_cell.analysis.ProgramStep`), which is recorded, so
the analysis knows the mode and pose name of every move. Exit status: 0 done; 1 done, but a
move failed or the analysis was partial; 2 could not start (bad program or config, a node did
not come up); 130 interrupted (the processes are stopped and what was recorded is analysed).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from positioning_cell.analysis.program import Program, load_program
from positioning_cell.analysis.replay import PROGRAM_TOPIC, ProgramStep
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.domains import DomainError, free_domain
from positioning_cell.errors import PositioningError
from positioning_cell.mechanism import Mechanism
from positioning_cell.polling import wait_until
from positioning_cell.tools.analyze_bag import EXIT_OK, analyze, describe

#: (executable, node name) of the cell, in start order.
CELL_NODES = (
    ('recorder_node', 'recorder'),
    ('leg_driver_node', 'leg_driver'),
    ('pose_measurement_node', 'pose_measurement'),
    ('kinematics_node', 'positioner'),
    ('accuracy_monitor_node', 'accuracy_monitor'),
)
#: Topics the recorder and the monitor must have subscribed before the program starts.
RECORDED = ('/positioner/target', '/metrology/pose', '/sim/platform/true_pose', '/diagnostics',
            PROGRAM_TOPIC)
MONITORED = ('/positioner/target', '/metrology/pose')
MONITOR_INPUTS = (*MONITORED, '/sim/platform/true_pose')
VERDICT_STATUS = 'accuracy_monitor: settled pose'
# Usable domain IDs (platform.md): 1-101 and 215-232 (0 is everyone's default). The lock
# files are those of test/cell_harness.py, so runs and tests never share a domain.
EXIT_MOVE_FAILED, EXIT_NOT_STARTED, EXIT_INTERRUPTED = 1, 2, 130
#: After the monitor's verdict, wait up to this long (s) for the true pose to settle as well,
#: so the simulation-truth figures have every visit.
TRUTH_WAIT = 1.5


class SignalledError(Exception):
    """SIGINT or SIGTERM arrived."""


class StartError(Exception):
    """The cell did not come up; the message says what is missing."""


def _executable(name: str) -> str:
    found = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if found is None:
        raise StartError(f'{name} is not installed (run `make setup`)')
    return found


class Processes:
    """The cell's processes, each in its own process group; :meth:`stop` ends them all."""

    def __init__(self, env: dict[str, str], log_dir: Path) -> None:
        self.env = env
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, exe: str, params: Sequence[Path]) -> None:
        """Start ``exe --ros-args --params-file P ...``, output to ``<log_dir>/<exe>.log``."""
        args = [_executable(exe), '--ros-args']
        for p in params:
            args += ['--params-file', str(p)]
        with (self.log_dir / f'{exe}.log').open('wb') as log:
            self.procs[exe] = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT,
                                               env=self.env, start_new_session=True)

    def dead(self) -> list[str]:
        """Processes that have exited."""
        return [name for name, p in self.procs.items() if p.poll() is not None]

    def stop(self, grace: float = 10.0) -> dict[str, int]:
        """SIGINT to every process group, SIGKILL to those still there after ``grace`` s;
        the exit codes."""
        for proc in self.procs.values():
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGINT)
        deadline = time.monotonic() + grace
        codes = {}
        for name, proc in self.procs.items():
            try:
                codes[name] = proc.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                codes[name] = proc.wait()
            with contextlib.suppress(ProcessLookupError):  # leftovers of the group
                os.killpg(proc.pid, signal.SIGKILL)
        return codes


def _wait(condition: Callable[[], Any], timeout: float, what: str) -> Any:
    try:
        return wait_until(condition, timeout, what)
    except TimeoutError as err:
        raise StartError(str(err)) from err


def _node_plumbing() -> Any:
    """positioning_cell.nodes.common (QoS profiles, message helpers), imported when the
    driver runs: it needs rclpy, and the type checker's strict library run stays out of it."""
    return importlib.import_module('positioning_cell.nodes.common')


class Driver:
    """The run driver's rclpy node, in its own context on the run's domain, spun in a
    background thread (the main thread keeps the signal handlers). rclpy is imported here,
    not with the module, so the rest of run_cell stays importable without ROS."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import String

        common = _node_plumbing()
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node('run_cell', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._string = String
        self.program_pub = self.node.create_publisher(String, PROGRAM_TOPIC,
                                                     common.LATCHED_QOS)
        self.verdicts: list[Any] = []
        self.states: list[Any] = []
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag,
                                      common.COMMAND_QOS)
        self.clients: dict[str, Any] = {}
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        with contextlib.suppress(Exception):
            self.executor.spin()

    def _on_diag(self, msg: Any) -> None:
        for status in msg.status:
            if status.name == VERDICT_STATUS:
                self.verdicts.append(status)
            elif status.name == 'positioner: state':
                self.states.append(status)

    def call(self, srv_type: Any, name: str, request: Any, timeout: float) -> Any:
        """Call a service and wait for its response (StartError after ``timeout`` s)."""
        if name not in self.clients:
            self.clients[name] = self.node.create_client(srv_type, name)
        client = self.clients[name]
        _wait(client.service_is_ready, min(timeout, 30.0), f'service {name}')
        future = client.call_async(request)
        _wait(future.done, timeout, f'the response of {name}')
        return future.result()

    def subscribed(self, topic: str, node: str) -> bool:
        """Has ``node`` a subscription on ``topic``?"""
        return any(i.node_name == node for i in self.node.get_subscriptions_info_by_topic(topic))

    def set_mode(self, mode: str) -> None:
        """Set the positioner's compensation.mode (StartError if refused)."""
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters

        value = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=mode)
        request = SetParameters.Request(parameters=[Parameter(name='compensation.mode',
                                                              value=value)])
        result = self.call(SetParameters, '/positioner/set_parameters', request, 10.0)
        if not result.results or not result.results[0].successful:
            reason = result.results[0].reason if result.results else 'no result'
            raise StartError(f'the positioner refused compensation.mode = {mode}: {reason}')

    def publish_step(self, step: ProgramStep) -> None:
        """Publish a /cell/program step."""
        self.program_pub.publish(self._string(data=step.to_json()))

    def plan(self, service: str, position: Any, quaternion: Any, tolerance: float,
             timeout: float) -> bool:
        """Call /positioner/move_to_pose or /positioner/check_pose (GetPlan) for a pose in
        the base frame; True when the plan is not empty (moved / would move)."""
        from nav_msgs.srv import GetPlan

        goal = _node_plumbing().pose_stamped(position, quaternion,
                                             self.node.get_clock().now().to_msg())
        response = self.call(GetPlan, service, GetPlan.Request(goal=goal, tolerance=tolerance),
                             timeout)
        return bool(response.plan.poses)

    def truth_visits(self) -> int | None:
        """Settled visits of the true pose so far (None: the monitor has no truth)."""
        truth = self.report()['truth']
        return None if truth is None else len(truth['visits'])

    def report(self) -> dict[str, Any]:
        """The monitor's /accuracy_monitor/report."""
        from std_srvs.srv import Trigger

        doc: dict[str, Any] = json.loads(self.call(Trigger, '/accuracy_monitor/report',
                                                   Trigger.Request(), 10.0).message)
        return doc

    def close(self) -> None:
        """Stop spinning and shut the context down."""
        import rclpy

        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()  # type: ignore[no-untyped-call]
        rclpy.try_shutdown(context=self.context)  # type: ignore[attr-defined]
        self._thread.join(timeout=5.0)


def model_note(params: dict[str, Any]) -> str:
    """Where the `model` mode's clearance parameters come from (the report says it)."""
    comp = node_parameters(params, 'positioner').get('compensation', {}).get('clearance', {})
    truth = node_parameters(params, 'pose_measurement').get('truth', {}).get('clearance', {})
    if comp and all(comp.get(k) == v for k, v in truth.items()):
        return ('The `model` and `measured` modes compensate with the simulator\'s true '
                'clearance parameters (positioner.compensation.clearance = '
                'pose_measurement.truth.clearance in the config): the cell does not yet '
                'identify its own, so `model` shows what a perfectly identified model gives.')
    return ('The `model` mode compensates with positioner.compensation.clearance of the '
            'config, which differs from the simulator\'s true clearance.')


def _overrides(run_dir: Path) -> Path:
    path = run_dir / 'run_overrides.yaml'
    path.write_text(yaml.safe_dump({'recorder': {'ros__parameters': {
        'output': str(run_dir / 'bag'), 'topic_pattern': PROGRAM_TOPIC}}}))
    return path


def _more(items: list[Any], count: int) -> bool:
    return len(items) > count


def _truth_settled(driver: Driver, count: int) -> bool:
    return (driver.truth_visits() or 0) > count


def _verdict_text(status: Any) -> str:
    values = {kv.key: kv.value for kv in status.values}
    ok = 'OK' if status.level in (b'\x00', 0) else 'OUT OF TOLERANCE'
    return (f'|Δp| {values.get("position_error_um", "?")} µm, '
            f'{values.get("orientation_error_deg", "?")}°: {ok}')


def drive(driver: Driver, program: Program, note: str, say: Callable[[str], None]) -> int:
    """Run the program: per mode, set it; per move, publish the step, move, wait for the
    monitor's verdict and say so. Returns the number of failed moves."""
    failed = 0
    width = len(str(program.moves))
    begin = time.monotonic()
    for n, (mode, cycle, k) in enumerate(program.steps(), start=1):
        if cycle == 1 and k == 0:
            driver.set_mode(mode)
            say(f'compensation mode: {mode}')
        name = program.names[k]
        driver.publish_step(ProgramStep(mode, time.time(), cycle, name,
                                        note if mode != 'none' else None))
        seen = len(driver.verdicts)
        truth_seen = driver.truth_visits()
        started = time.monotonic()
        moved = driver.plan('/positioner/move_to_pose', program.position[k],
                            program.quaternion[k], program.tolerance, 120.0)
        took = time.monotonic() - started
        head = f'[{n:>{width}}/{program.moves}] {mode:<8} cycle {cycle} {name:<4}'
        if not moved:
            failed += 1
            reason = driver.states[-1].message if driver.states else 'no reason given'
            say(f'{head} move refused or aborted: {reason}')
            continue
        try:
            _wait(partial(_more, driver.verdicts, seen), program.settle_timeout, 'the verdict')
            verdict = _verdict_text(driver.verdicts[seen])
        except StartError:
            verdict = f'monitor saw no settled pose within {program.settle_timeout:.0f} s'
        if truth_seen is not None:  # the true pose settles too before the next target
            with contextlib.suppress(StartError):
                _wait(partial(_truth_settled, driver, truth_seen), TRUTH_WAIT,
                      'the true pose to settle')
        say(f'{head} moved in {took:.1f} s; monitor: {verdict} '
            f'[{time.monotonic() - begin:.0f} s]')
    return failed


def _start(procs: Processes, driver: Driver, config: Path, overrides: Path,
           program: Program, say: Callable[[str], None]) -> None:
    for exe, _ in CELL_NODES:
        procs.start(exe, [config, overrides])
    say(f'started {", ".join(e for e, _ in CELL_NODES)}; waiting for the cell')

    def up(check: Callable[[], bool]) -> Callable[[], bool]:
        def probe() -> bool:
            dead = procs.dead()
            if dead:
                raise StartError(f'{", ".join(dead)} exited during start-up (see the logs)')
            return check()
        return probe

    _wait(up(lambda: all(driver.subscribed(t, 'recorder') for t in RECORDED)
             and all(driver.subscribed(t, 'accuracy_monitor') for t in MONITORED)), 60.0,
          'the recorder and the monitor to subscribe')
    # The monitor's own subscriptions must have matched the publishers (the graph above shows
    # only that they exist): a first target matched late would reach it after the tracker
    # samples that follow it, and the live figures of the first visit would differ from the
    # offline analysis of the bag.
    _wait(up(lambda: all(driver.report()['publishers'].get(t, 0) > 0
                         for t in MONITOR_INPUTS)), 60.0,
          'the monitor to match the target, tracker and truth publishers')

    def ready() -> bool:
        return driver.plan('/positioner/check_pose', program.position[0],
                           program.quaternion[0], 0.0, 30.0)

    _wait(up(ready), 60.0, 'the positioner to accept the first pose (encoder readings)')


def _same_figures(live: dict[str, Any], offline: dict[str, Any]) -> bool:
    a, b = live['measured']['poses'], offline['measured']['poses']
    if len(a) != len(b) or live['verdicts'] != offline['verdicts']:
        return False
    keys = ('ap_p', 'ap_a', 'ap_b', 'ap_c', 'n')
    return all(np.allclose([x[k] for k in keys], [y[k] for k in keys], rtol=1e-9, atol=1e-12)
               for x, y in zip(a, b, strict=True))


def run(program_path: Path | None = None, config: Path | None = None,
        runs_dir: Path = Path('runs'), say: Callable[[str], None] = print) -> int:
    """The whole run (module docstring); returns the exit status."""
    config = config or config_path('cell.yaml')
    program_path = program_path or config_path('program.yaml')
    try:
        params = load_parameter_file(config)
        mech = Mechanism.from_params(node_parameters(params, 'positioner').get('mechanism', {}))
        program = load_program(program_path, mech)
    except PositioningError as err:
        say(f'run_cell: error: {err}')
        return EXIT_NOT_STARTED
    run_dir = runs_dir / time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())
    while run_dir.exists():
        run_dir = run_dir.with_name(run_dir.name + '_')
    (run_dir / 'logs').mkdir(parents=True)
    bag = run_dir / 'bag'
    say(f'run_cell: {program.moves} moves ({len(program.names)} poses x {program.cycles} '
        f'cycles x modes {", ".join(program.modes)}); run folder {run_dir}')

    def on_signal(signum: int, frame: Any) -> None:
        raise SignalledError(signal.Signals(signum).name)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    status, failed, live = EXIT_OK, 0, None
    try:
        with free_domain() as domain:
            env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1',
                       ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
            env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)
            env.setdefault('ROS_LOG_DIR', str(run_dir / 'logs' / 'ros'))
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
            os.environ.setdefault('ROS_LOG_DIR', env['ROS_LOG_DIR'])
            procs = Processes(env, run_dir / 'logs')
            driver: Driver | None = None
            try:
                driver = Driver(domain)
                say(f'ROS_DOMAIN_ID {domain}, logs in {run_dir / "logs"}')
                _start(procs, driver, config, _overrides(run_dir), program, say)
                failed = drive(driver, program, model_note(params), say)
                live = driver.report()
            except StartError as err:
                say(f'run_cell: error: {err}')
                status = EXIT_NOT_STARTED
            except SignalledError as err:
                say(f'run_cell: interrupted ({err}): stopping the cell')
                status = EXIT_INTERRUPTED
            finally:
                for s in previous:  # stopping is not interrupted
                    signal.signal(s, signal.SIG_IGN)
                if driver is not None:
                    driver.close()
                codes = procs.stop()
                say('stopped: ' + ', '.join(f'{k} ({v})' for k, v in codes.items()))
    except SignalledError:
        status = EXIT_INTERRUPTED  # a second signal while stopping: the processes are gone
    except DomainError as err:
        say(f'run_cell: error: {err}')
        status = EXIT_NOT_STARTED
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if live is not None:
        (run_dir / 'monitor_report.json').write_text(json.dumps(live, indent=1))
    return _analyse(bag, run_dir, config, live, status, failed, say)


def _analyse(bag: Path, run_dir: Path, config: Path, live: dict[str, Any] | None,
             status: int, failed: int, say: Callable[[str], None]) -> int:
    if not bag.exists():
        say(f'run_cell: no bag was recorded (logs in {run_dir / "logs"})')
        return status or EXIT_NOT_STARTED
    say(f'analysing {bag}')
    try:
        output = analyze(bag, run_dir, config)
    except PositioningError as err:
        say(f'run_cell: analysis failed: {err}')
        return status or EXIT_MOVE_FAILED
    say(describe(output).rstrip('\n'))
    if live is not None:
        same = _same_figures(live, output.analysis.monitor)
        say('the offline analysis ' + ('reproduces' if same else 'DIFFERS FROM') +
            ' the live monitor\'s figures (monitor_report.json)')
    say(f'bag:     {bag}')
    if failed:
        say(f'run_cell: {failed} move(s) failed')
    if status == EXIT_OK and (failed or output.analysis.problems):
        status = EXIT_MOVE_FAILED
    return status


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``run_cell [--program F] [--config F] [--runs DIR]``."""
    parser = argparse.ArgumentParser(
        prog='run_cell', description='Run the positioning cell (all nodes, recorder) through '
        'a program of poses under each compensation mode, then analyse the recording.')
    parser.add_argument('--program', type=Path,
                        help='program file (default: the shipped config/program.yaml)')
    parser.add_argument('--config', type=Path,
                        help='ROS 2 parameter file of the cell (default: config/cell.yaml)')
    parser.add_argument('--runs', type=Path, default=Path('runs'),
                        help='folder for the run folders (default: ./runs)')
    args = parser.parse_args(argv)
    try:
        return run(args.program, args.config, args.runs, lambda s: print(s, flush=True))
    except KeyboardInterrupt:  # during the analysis, after every process has stopped
        print('run_cell: interrupted', flush=True)
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    sys.exit(main())
