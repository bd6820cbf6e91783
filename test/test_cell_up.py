"""`cell up` (positioning_cell.tools.cell_up) as a newcomer uses it: the whole cell in the
foreground from the installed command, `cell home` from another process, Ctrl-C: every node
stopped cleanly, nothing left running, the bag closed and readable."""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pytest
from cell_harness import executable, isolated_domain, processes_naming, wait_until
from mcap.reader import make_reader

from positioning_cell import names
from positioning_cell.bag.description import bag_description
from positioning_cell.ros.processes import OWN_PROCESS_GROUP, cell_environment

pytestmark = [pytest.mark.nodes, pytest.mark.slow, pytest.mark.timing]


def test_cell_up_then_cell_home_then_ctrl_c_stops_everything(tmp_path: Path) -> None:
    with isolated_domain() as domain:
        env = cell_environment(domain)
        out = tmp_path / 'up.out'
        with out.open('wb') as log:
            cell_up = subprocess.Popen([executable('cell'), 'up', '--domain', str(domain)],
                                       cwd=tmp_path, env=env, stdout=log,
                                       stderr=subprocess.STDOUT, **OWN_PROCESS_GROUP)
        try:
            wait_until(lambda: 'cell up: ready' in out.read_text() or cell_up.poll() is not None,
                       90.0, 'cell up to say ready')
            assert cell_up.poll() is None, out.read_text()
            text = out.read_text()
            run_dir = next((tmp_path / 'runs').iterdir())
            assert f'logs in {Path("runs") / run_dir.name / "logs"}' in text, text
            assert f'bag {Path("runs") / run_dir.name / "bag"}' in text, text
            home = subprocess.run([executable('cell'), 'home', '--domain', str(domain),
                                   '--json'], cwd=tmp_path, env=env, capture_output=True,
                                  text=True, timeout=120, check=False)
            doc = json.loads(home.stdout)
            assert home.returncode == 0 and doc['outcome']['code_name'] == 'success', \
                home.stdout + home.stderr
            cell_up.send_signal(signal.SIGINT)  # what Ctrl-C sends the foreground process
            assert cell_up.wait(timeout=60) == 0, out.read_text()
        finally:
            if cell_up.poll() is None:
                cell_up.kill()
                cell_up.wait()
    text = out.read_text()
    started = [names.RECORDER, *names.CELL_NODES]
    assert all(f'{n.executable} (exit 0)' in text for n in started), text
    assert processes_naming(run_dir) == []  # every node gone (their params file names it)
    logs = {p.name for p in (run_dir / 'logs').glob('*.log')}
    assert logs == {f'{n.executable}.log' for n in started}
    bags = sorted((run_dir / 'bag').glob('*.mcap'))
    assert bags
    with bags[0].open('rb') as f:  # closed on the signal: its summary is there
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    topics = {c.topic for c in summary.channels.values()}
    assert names.JOINT_STATES in topics and summary.statistics.message_count > 0
    # the bag says it was an operator's session, and carries the configuration it ran with
    described = bag_description(run_dir / 'bag')
    assert described.run()['kind'] == 'interactive', described
    assert described.attachment('config/cell.yaml') is not None
    assert described.keys()['calibration_file'] == names.NO_CALIBRATION  # none taken
