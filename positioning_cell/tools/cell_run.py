"""The work of ``run_cell`` (:mod:`positioning_cell.tools.run_cell`: the command line and the
exit status): :func:`run` starts the cell, drives the program and analyses the recording;
imported once the command line is parsed."""
from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from positioning_cell import names
from positioning_cell.analysis.acceptance import AcceptanceLimits, check_program
from positioning_cell.analysis.axis_test import load_axis_test
from positioning_cell.analysis.program import load_program
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import PositioningError
from positioning_cell.procedures.port import ProcedureError
from positioning_cell.procedures.program_run import RunOutcome, calibrate_and_load, run_program
from positioning_cell.recording.description import write_description_file
from positioning_cell.ros.cell_start import StartError, new_run_folder, run_overrides, start_cell
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.domains import DomainError, free_domain
from positioning_cell.ros.port import RosCellPort
from positioning_cell.ros.processes import Processes, cell_environment
from positioning_cell.tools.analyze_bag import analyze, describe
from positioning_cell.tools.exits import Exit
from positioning_cell.tools.interruption import Interrupted, interruptible


def _same_figures(live: dict[str, Any], offline: dict[str, Any]) -> bool:
    a, b = live['measured']['poses'], offline['measured']['poses']
    if (len(a) != len(b) or live['verdicts'] != offline['verdicts']
            or live['decisions'] != offline['decisions']):
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
        AcceptanceLimits.from_program(program_path)  # checked now, not after the run
        check_program(program_path, program)  # what it judges, the program can measure
        axes = None if axis_test_path is None else load_axis_test(axis_test_path, mech)
    except PositioningError as err:
        say(f'run_cell: error: {err}')
        return Exit.USAGE
    run_dir = new_run_folder(runs_dir)
    bag = run_dir / 'bag'
    say(f'run_cell: {program.moves} moves ({len(program.names)} poses x {program.cycles} '
        f'cycles x modes {", ".join(program.modes)}); run folder {run_dir}')
    outcome: RunOutcome | None = None
    live: dict[str, Any] | None = None

    def work(procs: Processes, client: CellClient) -> int:
        nonlocal outcome, live
        client.advertise_program()
        described = write_description_file(
            run_dir, 'program', [config], program_path, program.moves, sys.argv)
        start_cell(procs, client, config, run_overrides(run_dir, described),
                   (program.position[0], program.quaternion[0]), program.settle_timeout, say)
        outcome = run_program(RosCellPort(client), program, config, run_dir, say,
                              calibrator=calibrate_and_load, axis_test_plan=axes)
        live = client.monitor_report()
        return Exit.OK

    status = in_running_cell(run_dir, say, work)
    if live is not None:
        (run_dir / 'monitor_report.json').write_text(json.dumps(live, indent=1))
    try:
        with interruptible():  # the analysis of what was recorded, also after an interrupt
            return _analyse(bag, run_dir, config, live, status, outcome, say, program_path)
    except Interrupted:
        say('run_cell: interrupted')
        return Exit.INTERRUPTED


def in_running_cell(run_dir: Path, say: Callable[[str], None],
                    work: Callable[[Processes, CellClient], int]) -> int:
    """``work(procs, client)`` on a free ROS domain of this machine's loopback (this process's
    client too; logs in ``run_dir/logs``); every process it started stopped afterwards
    (SIGINT, SIGKILL after a grace period), also when it raised or was interrupted; the exit
    status: its own, NOT_THERE when the cell did not come up or answer (StartError,
    ProcedureError, TimeoutError), INTERRUPTED on a signal."""
    status: int = Exit.OK
    with interruptible() as signals:
        try:
            with free_domain() as domain:
                os.environ.setdefault('ROS_LOG_DIR', str(run_dir / 'logs' / 'ros'))
                os.environ.update(cell_environment(domain))  # this process's client: loopback
                procs = Processes(cell_environment(domain), run_dir / 'logs')
                client: CellClient | None = None
                try:
                    client = CellClient(domain, 'run_cell', signals=False)
                    say(f'ROS_DOMAIN_ID {domain}, logs in {run_dir / "logs"}')
                    status = work(procs, client)
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
    return status


def _analyse(bag: Path, run_dir: Path, config: Path, live: dict[str, Any] | None,
             status: int, outcome: RunOutcome | None, say: Callable[[str], None],
             program_path: Path) -> int:
    if not bag.exists():
        say(f'run_cell: no bag was recorded (logs in {run_dir / "logs"})')
        return status or Exit.NOT_THERE
    say(f'analysing {bag}')
    try:
        output = analyze(bag, run_dir, config, program=program_path)
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
        if outcome.compliance_failed:
            say('run_cell: the compliance test failed')
    if status == Exit.OK and ((outcome is not None and not outcome.achieved)
                              or output.analysis.problems):
        status = Exit.NOT_ACHIEVED
    return status
