"""run_cell (`make run`) end to end with a short program: every node started, recorded, driven,
stopped and analysed; no process left behind, also when interrupted with SIGINT."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import threading
from pathlib import Path

import pytest
import yaml
from cell_harness import executable, wait_until

from positioning_cell.bag import BagReader

SHORT_PROGRAM = {'program': {'cycles': 1, 'modes': ['none', 'measured'], 'poses': {
    'P1': {'position': [0.0, 0.0, 0.196], 'orientation': [0.0, 0.0, 0.0, 1.0]},
    'P2': {'position': [0.004, 0.004, 0.2], 'orientation': [0.0, 0.0, 0.0, 1.0]}}}}


def _cell_processes(marker: Path) -> list[int]:
    """PIDs of processes whose command line names ``marker`` (the run's override file)."""
    found = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            if str(marker).encode() in (proc / 'cmdline').read_bytes():
                found.append(int(proc.name))
    return found


def _run_dir(runs: Path) -> Path:
    dirs = [d for d in runs.iterdir() if d.is_dir()]
    assert len(dirs) == 1, dirs
    return dirs[0]


@pytest.fixture
def program(tmp_path: Path) -> Path:
    path = tmp_path / 'program.yaml'
    path.write_text(yaml.safe_dump(SHORT_PROGRAM))
    return path


def _start(program: Path, runs: Path) -> tuple[subprocess.Popen[str], list[str]]:
    proc = subprocess.Popen([executable('run_cell'), '--program', str(program), '--runs',
                             str(runs)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    lines: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        lines.extend(proc.stdout)

    threading.Thread(target=read, daemon=True).start()
    return proc, lines


def _finish(proc: subprocess.Popen[str], timeout: float) -> int:
    try:
        return proc.wait(timeout=timeout)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_run_cell_runs_a_program_records_and_analyses_it(program: Path, tmp_path: Path) -> None:
    runs = tmp_path / 'runs'
    proc, lines = _start(program, runs)
    code = _finish(proc, 150.0)
    text = ''.join(lines)
    assert code == 0, text
    run = _run_dir(runs)
    assert not _cell_processes(run / 'run_overrides.yaml'), 'a cell process outlived run_cell'
    for line in ('[1/4] none     cycle 1 P1', '[4/4] measured cycle 1 P2',
                 'compensation mode: measured', 'worst AP_p µm',
                 "reproduces the live monitor's figures", f'bag:     {run / "bag"}',
                 f'report:  {run / "report.md"}'):
        assert line in text
    for name in ('report.md', 'summary.json', 'monitor_report.json', 'error_over_time.png',
                 'axis_errors.png', 'clusters.png', 'error_distribution.png',
                 'bag/metadata.yaml'):
        assert (run / name).is_file(), name
    summary = json.loads((run / 'summary.json').read_text())
    assert [m['mode'] for m in summary['modes']] == ['none', 'measured']
    assert [[p['pose'] for p in m['poses']] for m in summary['modes']] == [['P1', 'P2']] * 2
    assert summary['problems'] == []
    assert any('true clearance' in n for n in summary['notes'])
    assert '/cell/program' in summary['topics'] and summary['topics']['/cell/program'][
        'count'] == 4
    live = json.loads((run / 'monitor_report.json').read_text())
    assert live['verdicts'] == summary['monitor']['verdicts']
    assert sum(live['verdicts'].values()) == 1 + 4  # the home pose, then the program's moves


def test_an_interrupted_run_stops_every_process_and_keeps_a_readable_bag(
        program: Path, tmp_path: Path) -> None:
    runs = tmp_path / 'runs'
    proc, lines = _start(program, runs)
    try:
        wait_until(lambda: any(line.startswith('[1/4]') for line in lines), 90.0,
                   'the first move')
        proc.send_signal(signal.SIGINT)
        code = _finish(proc, 60.0)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    text = ''.join(lines)
    assert code == 130, text
    assert 'interrupted (SIGINT): stopping the cell' in text
    run = _run_dir(runs)
    assert not _cell_processes(run / 'run_overrides.yaml'), 'a cell process outlived run_cell'
    assert 'stopped: recorder_node (0)' in text  # the recorder closed its bag itself
    with BagReader(run / 'bag') as bag:
        assert bag.topics['/positioner/target'].message_count >= 1
        assert bag.topics['/metrology/pose'].message_count > 0
    assert (run / 'report.md').is_file()
