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

With ``--axis-test [FILE]`` (default ``config/axis_test.yaml``) the driver runs the axis test
after the calibration and before the modes (ISO 230-2:2014 per actuator,
:mod:`positioning_cell.tools.axis_test`): a line per measured stop, a marker per stop on
``/cell/axis_test`` (recorded), and at the end the ISO 230-2 table of each axis, also written to
``axis_test.md`` and ``axis_test.json`` in the run folder.

Before each move the driver publishes the step on ``/cell/program`` (std_msgs/String,
transient-local, JSON of :class:`positioning_cell.analysis.ProgramStep`), which is recorded, so
the analysis knows the mode and pose name of every move. Exit status: 0 done; 1 done, but a
move failed or the analysis was partial; 2 could not start (bad program or config, a node did
not come up); 130 interrupted (the processes are stopped and what was recorded is analysed).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml

from positioning_cell import names
from positioning_cell.analysis.axis_test import AxisTest, load_axis_test
from positioning_cell.analysis.program import Program, ProgramStep, load_program
from positioning_cell.calibration import file as calfile
from positioning_cell.calibration.program import ProgramSettings
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import PositioningError
from positioning_cell.parameters import parse
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient, verdict_text
from positioning_cell.ros.domains import DomainError, free_domain
from positioning_cell.ros.processes import Processes, cell_environment
from positioning_cell.sim.campaign import truth_table
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings
from positioning_cell.tools.analyze_bag import EXIT_OK, analyze, describe
from positioning_cell.tools.axis_test import AxisTestError
from positioning_cell.tools.axis_test import run_live as run_axis_test
from positioning_cell.tools.axis_test import write as write_axis_test
from positioning_cell.tools.calibrate_cell import Machine, run_live

T = TypeVar('T')

#: The recorder first, then the cell's nodes (the launch file's list).
STARTED = (names.RECORDER, *names.CELL_NODES)
#: Topics the recorder and the monitor must have subscribed before the program starts.
RECORDED = (names.TARGET, names.MEASURED_POSE, names.TRUE_POSE, names.DIAGNOSTICS,
            names.PROGRAM)
MONITORED = (names.TARGET, names.MEASURED_POSE)
MONITOR_INPUTS = (*MONITORED, names.TRUE_POSE)
EXIT_MOVE_FAILED, EXIT_NOT_STARTED, EXIT_INTERRUPTED = 1, 2, 130
#: ``--axis-test`` without a file: the shipped config/axis_test.yaml.
SHIPPED_AXIS_TEST = Path('<shipped axis_test.yaml>')
#: After the monitor's verdict, wait up to this long (s) for the true pose to settle as well,
#: so the simulation-truth figures have every visit.
TRUTH_WAIT = 1.5


class SignalledError(Exception):
    """SIGINT or SIGTERM arrived."""


class StartError(Exception):
    """The cell did not come up; the message says what is missing."""


def _wait(condition: Callable[[], Any], timeout: float, what: str) -> Any:
    try:
        return wait_until(condition, timeout, what)
    except TimeoutError as err:
        raise StartError(str(err)) from err


def _call(what: Callable[[], Any]) -> Any:
    """A client call; a service that does not answer is a StartError."""
    try:
        return what()
    except TimeoutError as err:
        raise StartError(str(err)) from err


def calibrate(client: CellClient, program: Program, config: Path, run_dir: Path,
              say: Callable[[str], None]) -> str:
    """The run's calibration (``program.calibration``: calibrate_cell on the live cell, the
    result loaded by the positioner); the note the report gives the compensated modes."""
    cal = program.calibration
    if cal is None:
        return ('No calibration in this run: `model` and `measured` use the a-priori clearance '
                'model of the config (positioner.compensation.clearance).')
    say(f'calibrating: {cal.poses} poses + {cal.hold_out} hold-out, {cal.samples} tracker '
        'readings each')
    settings = replace(ProgramSettings(), poses=cal.poses, hold_out=cal.hold_out)
    try:
        status, path = run_live(client, Machine.from_config(config), settings, cal.samples,
                                run_dir / 'calibration', say, load=True)
    except (TimeoutError, PositioningError) as err:
        status, path = 1, None
        say(f'run_cell: calibration failed: {err}')
    if status != 0 or path is None:
        return ('The calibration failed: `model` and `measured` use the a-priori clearance '
                'model of the config.')
    _judge_calibration(path, config, say)
    return (f'`model` and `measured` use the machine the cell identified from its own '
            f'measurements in this run ({path.relative_to(run_dir)}); only the truth table '
            'reads the simulator.')


def _judge_calibration(path: Path, config: Path, say: Callable[[str], None]) -> None:
    """The report's truth table of the calibration (judging only: the simulator's truth from
    the config, against what the cell identified), next to the calibration file."""
    sim = parse(PoseMeasurementSettings,
                node_parameters(load_parameter_file(config), names.NODE_MEASUREMENT))
    nominal = sim.mechanism
    lines = truth_table(calfile.load(path, nominal), sim.true_machine(), nominal)
    table = path.with_name('truth.md')
    table.write_text('# Calibration against the simulation truth\n\n' + '\n'.join(lines) + '\n')
    say(f'truth table: {table}: {lines[-1].split(" (")[0]}')


def axis_test(client: CellClient, test: AxisTest, config: Path, run_dir: Path,
              say: Callable[[str], None]) -> bool:
    """The run's axis test (:mod:`positioning_cell.tools.axis_test`): a line per measured
    stop, then the ISO 230-2 table of each axis, written to ``axis_test.md`` and
    ``axis_test.json`` in ``run_dir``. False when it could not be completed (the positioner is
    asked to home so that the run continues)."""
    try:
        _, results = run_axis_test(client, test, config, say)
    except (AxisTestError, TimeoutError, PositioningError) as err:
        say(f'run_cell: axis test failed: {err}')
        with contextlib.suppress(TimeoutError):
            client.home()
        return False
    md, js = write_axis_test(results, run_dir)
    say('axis test, ISO 230-2:2014 per axis (x = actual - commanded):')
    say('\n'.join(results.summary()))
    say('\n'.join(results.markdown()))
    say(f'axis test: {md}, {js}')
    return bool(results.results)


def _overrides(run_dir: Path) -> Path:
    path = run_dir / 'run_overrides.yaml'
    # the run driver's topics, besides the recorder's list of the config
    pattern = '|'.join(re.escape(t) for t in (names.PROGRAM, names.AXIS_TEST))
    path.write_text(yaml.safe_dump({names.NODE_RECORDER: {'ros__parameters': {
        'output': str(run_dir / 'bag'), 'topic_pattern': pattern}}}))
    return path


def _more(items: list[Any], count: int) -> bool:
    return len(items) > count


def _truth_visits(client: CellClient) -> int | None:
    """Settled visits of the true pose so far (None: the monitor has no truth)."""
    truth = _call(client.monitor_report)['truth']
    return None if truth is None else len(truth['visits'])


def _truth_settled(client: CellClient, count: int) -> bool:
    return (_truth_visits(client) or 0) > count


def _set_mode(client: CellClient, mode: str) -> None:
    result = _call(partial(client.set_parameter, names.NODE_POSITIONER, 'compensation.mode',
                           mode))
    if not result.successful:
        raise StartError(f'the positioner refused compensation.mode = {mode}: {result.reason}')


def drive(client: CellClient, program: Program, note: str, say: Callable[[str], None]) -> int:
    """Run the program: per mode, set it; per move, publish the step, move, wait for the
    monitor's verdict and say so. Returns the number of failed moves."""
    failed = 0
    width = len(str(program.moves))
    begin = time.monotonic()
    verdicts = client.statuses(names.STATUS_MONITOR_VERDICT)
    states = client.statuses(names.STATUS_POSITIONER)
    for n, (mode, cycle, k) in enumerate(program.steps(), start=1):
        if cycle == 1 and k == 0:
            _set_mode(client, mode)
            say(f'compensation mode: {mode}')
        name = program.names[k]
        client.publish_program(ProgramStep(mode, time.time(), cycle, name,
                                           note if mode != 'none' else None).to_json())
        seen = len(verdicts)
        truth_seen = _truth_visits(client)
        started = time.monotonic()
        moved = _call(partial(client.plan, names.MOVE_TO_POSE, program.position[k],
                              program.quaternion[k], program.tolerance))
        took = time.monotonic() - started
        head = f'[{n:>{width}}/{program.moves}] {mode:<8} cycle {cycle} {name:<4}'
        if not moved:
            failed += 1
            reason = states[-1].message if states else 'no reason given'
            say(f'{head} move refused or aborted: {reason}')
            continue
        try:
            _wait(partial(_more, verdicts, seen), program.settle_timeout, 'the verdict')
            verdict = verdict_text(verdicts[seen])
        except StartError:
            verdict = f'monitor saw no settled pose within {program.settle_timeout:.0f} s'
        if truth_seen is not None:  # the true pose settles too before the next target
            with contextlib.suppress(StartError):
                _wait(partial(_truth_settled, client, truth_seen), TRUTH_WAIT,
                      'the true pose to settle')
        say(f'{head} moved in {took:.1f} s; monitor: {verdict} '
            f'[{time.monotonic() - begin:.0f} s]')
    return failed


def _start(procs: Processes, client: CellClient, config: Path, overrides: Path,
           program: Program, say: Callable[[str], None]) -> None:
    for node in STARTED:
        procs.start(node.executable, params=[config, overrides])
    say(f'started {", ".join(n.executable for n in STARTED)}; waiting for the cell')

    def up(check: Callable[[], T]) -> Callable[[], T]:
        def probe() -> T:
            dead = procs.dead()
            if dead:
                raise StartError(f'{", ".join(dead)} exited during start-up (see the logs)')
            return check()
        return probe

    _wait(up(lambda: all(client.subscribed(t, names.NODE_RECORDER) for t in RECORDED)
             and all(client.subscribed(t, names.NODE_MONITOR) for t in MONITORED)), 60.0,
          'the recorder and the monitor to subscribe')
    # The monitor's own subscriptions must have matched the publishers (the graph above shows
    # only that they exist): a first target matched late would reach it after the tracker
    # samples that follow it, and the live figures of the first visit would differ from the
    # offline analysis of the bag.
    _wait(up(lambda: all(_call(client.monitor_report)['publishers'].get(t, 0) > 0
                         for t in MONITOR_INPUTS)), 60.0,
          'the monitor to match the target, tracker and truth publishers')

    def ready() -> bool:
        return bool(_call(partial(client.plan, names.CHECK_POSE, program.position[0],
                                  program.quaternion[0], 0.0, 30.0)))

    done, message = _call(client.home)
    if not done:
        raise StartError(f'homing failed: {message}')
    say(f'homed: {message}')
    _wait(up(ready), 60.0, 'the positioner to accept the first pose (encoder readings)')

    def home_settled() -> bool:
        """The monitor's verdict on the home pose is in (and the true pose settled there):
        a verdict arriving later would be taken for that of the program's first move."""
        report = _call(client.monitor_report)
        truth = report['truth']
        return (sum(report['verdicts'].values()) >= 1
                and (truth is None or len(truth['visits']) >= 1))

    try:
        _wait(up(home_settled), program.settle_timeout, 'the monitor to see the home pose settle')
    except StartError as err:
        say(f'run_cell: {err}; the first verdict may be late')


def _same_figures(live: dict[str, Any], offline: dict[str, Any]) -> bool:
    a, b = live['measured']['poses'], offline['measured']['poses']
    if len(a) != len(b) or live['verdicts'] != offline['verdicts']:
        return False
    keys = ('ap_p', 'ap_a', 'ap_b', 'ap_c', 'n')
    return all(np.allclose([x[k] for k in keys], [y[k] for k in keys], rtol=1e-9, atol=1e-12)
               for x, y in zip(a, b, strict=True))


def run(program_path: Path | None = None, config: Path | None = None,
        runs_dir: Path = Path('runs'), say: Callable[[str], None] = print,
        axis_test_path: Path | None = None) -> int:
    """The whole run (module docstring); returns the exit status. ``axis_test_path``: run
    that axis test after the calibration (None: none)."""
    config = config or config_path('cell.yaml')
    program_path = program_path or config_path('program.yaml')
    try:
        params = load_parameter_file(config)
        mech = Mechanism.from_params(node_parameters(params, names.NODE_POSITIONER)
                                     .get('mechanism', {}))
        program = load_program(program_path, mech)
        axes = None if axis_test_path is None else load_axis_test(axis_test_path, mech)
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
            os.environ.setdefault('ROS_LOG_DIR', str(run_dir / 'logs' / 'ros'))
            os.environ.update(cell_environment(domain))  # this process's client: loopback too
            procs = Processes(cell_environment(domain), run_dir / 'logs')
            client: CellClient | None = None
            try:
                client = CellClient(domain, 'run_cell', signals=False)
                client.advertise_program()
                say(f'ROS_DOMAIN_ID {domain}, logs in {run_dir / "logs"}')
                _start(procs, client, config, _overrides(run_dir), program, say)
                note = calibrate(client, program, config, run_dir, say)
                if axes is not None and not axis_test(client, axes, config, run_dir, say):
                    failed += 1
                failed += drive(client, program, note, say)
                live = _call(client.monitor_report)
            except StartError as err:
                say(f'run_cell: error: {err}')
                status = EXIT_NOT_STARTED
            except SignalledError as err:
                say(f'run_cell: interrupted ({err}): stopping the cell')
                status = EXIT_INTERRUPTED
            finally:
                for s in previous:  # stopping is not interrupted
                    signal.signal(s, signal.SIG_IGN)
                if client is not None:
                    client.close()
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
    """Command line: ``run_cell [--program F] [--config F] [--runs DIR] [--axis-test [F]]``."""
    parser = argparse.ArgumentParser(
        prog='run_cell', description='Run the positioning cell (all nodes, recorder) through '
        'a program of poses under each compensation mode, then analyse the recording.')
    parser.add_argument('--program', type=Path,
                        help='program file (default: the shipped config/program.yaml)')
    parser.add_argument('--config', type=Path,
                        help='ROS 2 parameter file of the cell (default: config/cell.yaml)')
    parser.add_argument('--runs', type=Path, default=Path('runs'),
                        help='folder for the run folders (default: ./runs)')
    parser.add_argument('--axis-test', type=Path, nargs='?', const=SHIPPED_AXIS_TEST,
                        metavar='FILE', help='after the calibration, run the axis test '
                        '(ISO 230-2 per actuator) of FILE (default: the shipped '
                        'config/axis_test.yaml)')
    args = parser.parse_args(argv)
    axis_file = args.axis_test
    if axis_file == SHIPPED_AXIS_TEST:
        axis_file = config_path('axis_test.yaml')
    try:
        return run(args.program, args.config, args.runs, lambda s: print(s, flush=True),
                   axis_file)
    except KeyboardInterrupt:  # during the analysis, after every process has stopped
        print('run_cell: interrupted', flush=True)
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    sys.exit(main())
