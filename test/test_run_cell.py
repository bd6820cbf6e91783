"""run_cell (`make run`) end to end with a short program: every node started, recorded, driven,
stopped and analysed; no process left behind, also when interrupted with SIGINT. The main run
also runs a tiny axis test (``--axis-test``: one axis, three targets, two cycles): its markers
are in the bag, the printed ISO 230-2 tables are those of the recorded markers and of the
analysis report, and the simulation truth shows the machine's zero offset."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from cell_harness import (
    CELL_YAML,
    FAST_MOTION,
    LOADED_COMMAND,
    LOADED_LIVENESS,
    executable,
    processes_naming,
    wait_until,
)

from positioning_cell import names
from positioning_cell.analysis.axis_test import TRUTH, AxisTestMarker, axis_test_figures
from positioning_cell.analysis.fleet import ABORTED_RUN, run_kind
from positioning_cell.bag import BagReader
from positioning_cell.bag.description import bag_description
from positioning_cell.calibration import file as calfile
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.parameters import parse
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings

pytestmark = [pytest.mark.nodes, pytest.mark.slow]

MECH = Mechanism.default()

SHORT_PROGRAM = {'program': {'cycles': 1, 'modes': ['none', 'model'],
                             'calibration': {'poses': 8, 'hold_out': 1, 'samples': 3}, 'poses': {
    'P1': {'position': [0.0, 0.0, 0.196], 'orientation': [0.0, 0.0, 0.0, 1.0]},
    'P2': {'position': [0.004, 0.004, 0.2], 'orientation': [0.0, 0.0, 0.0, 1.0]}}}}


def _run_dir(runs: Path) -> Path:
    dirs = [d for d in runs.iterdir() if d.is_dir()]
    assert len(dirs) == 1, dirs
    return dirs[0]


#: A tiny axis test: one axis, three targets, two bidirectional cycles (12 measured stops).
AXIS_TEST = {'axis_test': {'cycles': 2, 'samples': 4, 'dwell': 0.05, 'axes': {
    'leg2_length': {'targets': [-0.0005, 0.00012, 0.0005], 'overshoot': 0.0002}}}}


@pytest.fixture
def program(tmp_path: Path) -> Path:
    path = tmp_path / 'program.yaml'
    path.write_text(yaml.safe_dump(SHORT_PROGRAM))
    return path


#: Moves three times the shipped speed (within the drives' and the factory's maxima): the test
#: is of the run, not of the motion.
def _fast_config(folder: Path) -> Path:
    """config/cell.yaml with :data:`~cell_harness.FAST_MOTION` and
    :data:`~cell_harness.LOADED_LIVENESS` for the positioner and
    :data:`~cell_harness.LOADED_COMMAND` for the driver (a calibration move aborted by a
    stalled driver or positioner would leave the run without its calibration, as it
    should)."""
    doc = yaml.safe_load(CELL_YAML.read_text())
    doc['positioner']['ros__parameters']['motion'].update(FAST_MOTION)
    doc['positioner']['ros__parameters']['liveness'].update(LOADED_LIVENESS)
    doc['leg_driver']['ros__parameters']['command'].update(LOADED_COMMAND)
    path = folder / 'cell_fast.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


def _start(program: Path, runs: Path, *options: str
           ) -> tuple[subprocess.Popen[str], list[str]]:
    proc = subprocess.Popen([executable('run_cell'), '--program', str(program), '--runs',
                             str(runs), '--config', str(_fast_config(program.parent)),
                             *options], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    lines: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        lines.extend(proc.stdout)

    threading.Thread(target=read, daemon=True).start()
    return proc, lines


def _wait_line(proc: subprocess.Popen[str], lines: list[str], prefix: str,
               timeout: float) -> None:
    """Wait for a line of run_cell's starting with ``prefix``; a failure names what it printed
    (also when it exits first)."""
    def seen() -> bool:
        if any(line.startswith(prefix) for line in lines):
            return True
        assert proc.poll() is None, f'run_cell exited ({proc.returncode}):\n' + ''.join(lines)
        return False
    try:
        wait_until(seen, timeout, f'a line {prefix!r}')
    except TimeoutError as err:
        raise AssertionError(f'{err}; run_cell printed:\n' + ''.join(lines)) from None


def _finish(proc: subprocess.Popen[str], timeout: float) -> int:
    try:
        return proc.wait(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_run_cell_runs_a_program_records_and_analyses_it(program: Path, tmp_path: Path) -> None:
    runs = tmp_path / 'runs'
    axes = tmp_path / 'axis.yaml'
    axes.write_text(yaml.safe_dump(AXIS_TEST, sort_keys=False))
    proc, lines = _start(program, runs, '--axis-test', str(axes))
    code = _finish(proc, 200.0)
    text = ''.join(lines)
    assert code == 0, text
    run = _run_dir(runs)
    assert not processes_naming(run / 'run_overrides.yaml'), 'a cell process outlived run_cell'
    for line in ('calibrating: 8 poses + 1 hold-out', '[9/9] hold_out',
                 'the positioner loaded it',
                 'identified geometric parameters within 3 sigma of the truth',
                 '[1/4] none     cycle 1 P1',
                 '[4/4] model    cycle 1 P2', 'compensation mode: model', 'worst AP_p µm',
                 "reproduces the live monitor's figures", f'bag:     {run / "bag"}',
                 f'report:  {run / "report.md"}'):
        assert line in text
    for name in ('report.md', 'summary.json', 'monitor_report.json', 'error_over_time.png',
                 'axis_errors.png', 'clusters.png', 'error_distribution.png',
                 'bag/metadata.yaml', 'calibration/calibration.yaml',
                 'calibration/calibration_report.md', 'calibration/truth.md'):
        assert (run / name).is_file(), name
    summary = json.loads((run / 'summary.json').read_text())
    assert [m['mode'] for m in summary['modes']] == ['none', 'model']
    assert [[p['pose'] for p in m['poses']] for m in summary['modes']] == [['P1', 'P2']] * 2
    assert summary['problems'] == []
    assert any('identified from its own measurements' in n for n in summary['notes'])
    # The bag describes its run: kind, program, configuration, and the calibration the
    # positioner took, attached as the file it loaded.
    described = bag_description(run / 'bag')
    assert described.run()['kind'] == 'program' and described.run()['program_moves'] == '4'
    assert described.attachment(f'program/{program.name}').data == program.read_bytes()
    config = described.attachment('config/cell_fast.yaml')  # the --config given
    assert config is not None and config.data == (program.parent / 'cell_fast.yaml').read_bytes()
    loaded = described.attachment('calibration/calibration.yaml')
    assert loaded is not None
    assert loaded.data == (run / 'calibration' / 'calibration.yaml').read_bytes()
    assert described.keys()['calibration_attached'] == 'calibration/calibration.yaml'
    assert summary['description']['records'][0]['values']['kind'] == 'program'
    # the program's four steps and its end
    assert '/cell/program' in summary['topics'] and summary['topics']['/cell/program'][
        'count'] == 5
    # Judged against the truth: the calibration the cell made of itself removes the error.
    truth = {m['mode']: m['position_error_rms'] for m in summary['truth_modes']}
    assert truth['none'] > 50e-6 and truth['model'] < 0.1 * truth['none'], truth
    # The recording gives the same calibration offline.
    offline = subprocess.run([executable('calibrate_cell'), '--from-bag', str(run / 'bag'),
                              '--out', str(tmp_path / 'offline')], capture_output=True,
                             text=True, timeout=120.0, check=False)
    assert offline.returncode == 0, offline.stdout + offline.stderr
    a = calfile.load(run / 'calibration' / 'calibration.yaml', MECH)
    b = calfile.load(tmp_path / 'offline' / 'calibration.yaml', MECH)
    assert np.array_equal(a.x, b.x) and np.allclose(a.sigma, b.sigma, equal_nan=True)
    # ... with the poses' conditions: the recorded air temperature and the approaches
    excluded = [yaml.safe_load((d / 'calibration.yaml').read_text())['calibration']['excluded']
                for d in (run / 'calibration', tmp_path / 'offline')]
    assert excluded[0] == excluded[1], excluded
    assert not {'no temperature recorded', 'no approach directions recorded'} & set(
        excluded[0].values()), excluded
    live = json.loads((run / 'monitor_report.json').read_text())
    assert live['verdicts'] == summary['monitor']['verdicts']
    # the home pose, the calibration poses the monitor saw settle, then the program's moves
    assert sum(live['verdicts'].values()) >= 1 + 4
    _check_the_axis_test(run, text, summary)


def _check_the_axis_test(run: Path, text: str, summary: dict[str, object]) -> None:
    """The axis test ran after the calibration, before the program: its markers are in the
    bag, the tables printed, written and in the analysis report are theirs, and by the truth
    the axis's mean deviation is its zero offset (the drives hold their counts)."""
    assert 'axis test (ISO 230-2): 1 axis, 12 measured stops (2 cycles)' in text
    assert '[12/12] leg2_length cycle 2 ↓ P1' in text
    assert 'the recorder took the markers (/cell/axis_test)' in text
    assert text.index('[12/12]') < text.index('[1/4] none     cycle 1 P1')
    with BagReader(run / 'bag') as bag:
        assert bag.topics[names.AXIS_TEST].message_count == 12
        markers = [AxisTestMarker.from_json(item.message.data)
                   for item in bag.messages([names.AXIS_TEST])]
    results = axis_test_figures(markers)
    assert [(r.axis, r.source) for r in results] == [('leg2_length', 'tracker'),
                                                       ('leg2_length', 'truth')]
    for line in results.markdown() + results.summary():
        assert line in text
    expected = json.loads(json.dumps(results.to_dict()))
    assert json.loads((run / 'axis_test.json').read_text()) == expected
    assert summary['axis_tests'] == [expected]
    report = (run / 'report.md').read_text()
    assert all(line in report for line in results.markdown())
    sim = parse(PoseMeasurementSettings, node_parameters(load_parameter_file(CELL_YAML),
                                                         names.NODE_MEASUREMENT))
    offset = sim.true_machine().length_offsets[JOINT_NAMES.index('leg2_length')]
    truth = next(r for r in results if r.source == TRUTH)
    assert abs(float(np.mean(truth.figures.x_mean)) - offset) < 2e-6
    assert truth.figures.E < 2e-6


def test_an_interrupted_run_stops_every_process_and_keeps_a_readable_bag(
        program: Path, tmp_path: Path) -> None:
    runs = tmp_path / 'runs'
    proc, lines = _start(program, runs)
    try:
        # interrupted while it calibrates: the calibration is stopped with the cell
        _wait_line(proc, lines, '[1/9]', 240.0)
        proc.send_signal(signal.SIGINT)
        code = _finish(proc, 60.0)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    text = ''.join(lines)
    assert code == 130, text
    assert 'interrupted (SIGINT): stopping the cell' in text
    run = _run_dir(runs)
    assert not processes_naming(run / 'run_overrides.yaml'), 'a cell process outlived run_cell'
    assert 'stopped: recorder_node (0)' in text  # the recorder closed its bag itself
    with BagReader(run / 'bag') as bag:
        assert bag.topics['/positioner/target'].message_count >= 1
        assert bag.topics['/metrology/pose'].message_count > 0
    assert (run / 'report.md').is_file()
    assert not (run / 'calibration' / 'calibration.yaml').exists()  # nothing half-done
    # its bag says it was a program's run, and none of the program's moves was made
    described = bag_description(run / 'bag')
    assert run_kind(described.keys(), ()) == ABORTED_RUN
