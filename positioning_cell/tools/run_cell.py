"""``run_cell`` (``make run``): run the positioning cell on its embedded defaults and analyse
the run.

Starts the cell's nodes as separate processes (as ``launch/cell.launch.py`` does on a ROS
install), each in its own process group, on a private ROS_DOMAIN_ID with discovery limited to
this machine; records everything into ``runs/<UTC timestamp>/bag``; drives the program of
``config/program.yaml`` (each compensation mode set on the positioner, then its cycles of
moves through ``/positioner/move_to_pose``), printing a line per move with the monitor's
verdict; stops every process (SIGINT, SIGKILL after a grace period, also on Ctrl-C / SIGTERM);
analyses the bag (``positioning_cell.tools.analyze_bag``) into the same folder; prints the
comparison table and where the bag, report and plots are. The run itself (calibration, axis
test, program) is :mod:`positioning_cell.procedures.program_run` on the ROS port; the start of
the cell is :mod:`positioning_cell.ros.cell_start`.

With ``--axis-test [FILE]`` (default ``config/axis_test.yaml``) the driver runs the axis test
after the calibration and before the modes (ISO 230-2:2014 per actuator,
:mod:`positioning_cell.procedures.axis_test`): a line per measured stop, a marker per stop on
``/cell/axis_test`` (recorded), and at the end the ISO 230-2 table of each axis, also written to
``axis_test.md`` and ``axis_test.json`` in the run folder.

Before each move the driver publishes the step on ``/cell/program`` (std_msgs/String,
transient-local, JSON of :class:`positioning_cell.analysis.ProgramStep`), which is recorded, so
the analysis knows the mode and pose name of every move. Exit status
(:mod:`positioning_cell.tools.exits`): 0 done; 1 done, but a move failed, a mode was refused,
the axis test or the analysis was partial; 2 a bad program or config (nothing started); 5 the
cell did not come up or stopped answering; 130 interrupted (the processes are stopped and what
was recorded is analysed).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from positioning_cell import names
from positioning_cell.analysis.axis_test import load_axis_test
from positioning_cell.analysis.program import load_program
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import PositioningError
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.procedures.program_run import RunOutcome, calibrate_and_load, run_program
from positioning_cell.ros.cell_start import StartError, run_overrides, start_cell
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.domains import DomainError, free_domain
from positioning_cell.ros.port import RosCellPort
from positioning_cell.ros.processes import Processes, cell_environment
from positioning_cell.tools.analyze_bag import analyze, describe
from positioning_cell.tools.exits import Exit, exit_table
from positioning_cell.tools.interruption import Interrupted, interruptible

#: ``--axis-test`` without a file: the shipped config/axis_test.yaml.
SHIPPED_AXIS_TEST = Path('<shipped axis_test.yaml>')


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
        return Exit.USAGE
    run_dir = runs_dir / time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())
    while run_dir.exists():
        run_dir = run_dir.with_name(run_dir.name + '_')
    (run_dir / 'logs').mkdir(parents=True)
    bag = run_dir / 'bag'
    say(f'run_cell: {program.moves} moves ({len(program.names)} poses x {program.cycles} '
        f'cycles x modes {", ".join(program.modes)}); run folder {run_dir}')
    status: int = Exit.OK
    outcome: RunOutcome | None = None
    live: dict[str, Any] | None = None
    with interruptible() as signals:
        try:
            with free_domain() as domain:
                os.environ.setdefault('ROS_LOG_DIR', str(run_dir / 'logs' / 'ros'))
                os.environ.update(cell_environment(domain))  # this process's client: loopback
                procs = Processes(cell_environment(domain), run_dir / 'logs')
                client: CellClient | None = None
                try:
                    client = CellClient(domain, 'run_cell', signals=False)
                    client.advertise_program()
                    say(f'ROS_DOMAIN_ID {domain}, logs in {run_dir / "logs"}')
                    start_cell(procs, client, config, run_overrides(run_dir),
                               (program.position[0], program.quaternion[0]),
                               program.settle_timeout, say)
                    outcome = run_program(RosCellPort(client), program, config, run_dir, say,
                                          calibrator=calibrate_and_load,
                                          axis_test_plan=axes)
                    live = client.monitor_report()
                except (StartError, ProcedureError, TimeoutError) as err:
                    say(f'run_cell: error: {err}')
                    status = Exit.NOT_THERE
                except Interrupted as err:
                    say(f'run_cell: interrupted ({err}): stopping the cell')
                    status = Exit.INTERRUPTED
                finally:
                    with signals.ignored():  # stopping is not interrupted
                        if client is not None:
                            client.close()
                        codes = procs.stop()
                        say('stopped: ' + ', '.join(f'{k} ({v})' for k, v in codes.items()))
        except Interrupted:
            status = Exit.INTERRUPTED  # a signal while leaving the domain: the cell is stopped
        except DomainError as err:
            say(f'run_cell: error: {err}')
            status = Exit.NOT_THERE
    if live is not None:
        (run_dir / 'monitor_report.json').write_text(json.dumps(live, indent=1))
    try:
        with interruptible():  # the analysis of what was recorded, also after an interrupt
            return _analyse(bag, run_dir, config, live, status, outcome, say)
    except Interrupted:
        say('run_cell: interrupted')
        return Exit.INTERRUPTED


def _analyse(bag: Path, run_dir: Path, config: Path, live: dict[str, Any] | None,
             status: int, outcome: RunOutcome | None, say: Callable[[str], None]) -> int:
    if not bag.exists():
        say(f'run_cell: no bag was recorded (logs in {run_dir / "logs"})')
        return status or Exit.NOT_THERE
    say(f'analysing {bag}')
    try:
        output = analyze(bag, run_dir, config)
    except PositioningError as err:
        say(f'run_cell: analysis failed: {err}')
        return status or Exit.NOT_ACHIEVED
    say(describe(output).rstrip('\n'))
    if live is not None:
        same = _same_figures(live, output.analysis.monitor)
        say('the offline analysis ' + ('reproduces' if same else 'DIFFERS FROM') +
            ' the live monitor\'s figures (monitor_report.json)')
    say(f'bag:     {bag}')
    if outcome is not None:
        driven = outcome.driven
        if driven.failed:
            say(f'run_cell: {driven.failed} move(s) failed')
        for mode, reason in driven.refused_modes:
            say(f'run_cell: mode {mode} refused, its moves left out: {reason}')
        if outcome.axis_test_failed:
            say('run_cell: the axis test failed')
    if status == Exit.OK and ((outcome is not None and not outcome.achieved)
                              or output.analysis.problems):
        status = Exit.NOT_ACHIEVED
    return status


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``run_cell [--program F] [--config F] [--runs DIR] [--axis-test [F]]``."""
    parser = argparse.ArgumentParser(
        prog='run_cell', formatter_class=argparse.RawDescriptionHelpFormatter,
        description='Run the positioning cell (all nodes, recorder) through a program of poses '
        'under each compensation mode, then analyse the recording.',
        epilog='exit status:\n' + exit_table())
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
    return run(args.program, args.config, args.runs, lambda s: print(s, flush=True), axis_file)


if __name__ == '__main__':
    sys.exit(main())
