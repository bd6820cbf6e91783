"""How a node starts (positioning_cell.ros.spin.NodeStart): the modules its work imports at
their first use are imported in a thread of their own from the moment it spins, so that they
neither hold its first answer back (0.2-0.3 s of scipy, issue 24) nor pause a callback for a
whole import (the fault matrix saw the positioner's 0.2 s watch take 1.0 s with scipy imported
at its first use). Each check runs in a fresh interpreter: its own sys.modules and rclpy
context."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest
from cell_harness import isolated_domain

from positioning_cell import names
from positioning_cell.ros.processes import cell_environment
from positioning_cell.ros.spin import SCIPY_MODULES, NodeStart

pytestmark = [pytest.mark.nodes, pytest.mark.slow]

#: A module whose import cannot end before the node it is imported for has run a callback: it
#: waits for the file that callback writes (and gives up, raising, after 60 s).
WAITING_MODULE = '''
import os
import time

deadline = time.monotonic() + 60.0
while not os.path.exists(os.environ['PROBE_MARKER']):
    if time.monotonic() > deadline:
        raise RuntimeError('no callback ran while this module was being imported')
    time.sleep(0.005)
LOADED = True
'''

#: A node whose first timer callback writes the marker the waiting module waits for, then,
#: once that module is imported, reports it and ends the run.
PROBE_NODE = '''
import os
import sys
from pathlib import Path
from rclpy.node import Node
from positioning_cell.ros.spin import NodeStart, run


class Probe(Node):
    def __init__(self):
        super().__init__('node_start_probe')
        self.exit_status = None
        self.create_timer(0.01, self._tick)

    def _tick(self):
        marker = Path(os.environ['PROBE_MARKER'])
        if not marker.exists():
            print('first callback ran', flush=True)
            marker.write_text('spinning')
        elif (self.exit_status is None
              and getattr(sys.modules.get('waiting_module'), 'LOADED', False)):
            print('waiting_module loaded', flush=True)
            self.exit_status = 0


sys.exit(run(NodeStart(Probe, imports=tuple(sys.argv[1:]))))
'''


def _run_probe(tmp_path: Path, *imports: str) -> subprocess.CompletedProcess[str]:
    (tmp_path / 'waiting_module.py').write_text(WAITING_MODULE)
    with isolated_domain() as domain:
        env = cell_environment(domain)
        env['PYTHONPATH'] = f'{tmp_path}:{env.get("PYTHONPATH", "")}'.rstrip(':')
        env['PROBE_MARKER'] = str(tmp_path / 'marker')
        return subprocess.run([sys.executable, '-c', PROBE_NODE, *imports], env=env,
                              capture_output=True, text=True, timeout=120, check=False)


def test_a_nodes_imports_load_while_it_spins(tmp_path: Path) -> None:
    """The import cannot finish before a callback has run: the node spins meanwhile, and the
    module is there once imported."""
    done = _run_probe(tmp_path, 'waiting_module')
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.splitlines() == ['first callback ran', 'waiting_module loaded'], \
        done.stdout


def test_an_import_that_fails_ends_the_node_with_its_error(tmp_path: Path) -> None:
    done = _run_probe(tmp_path, 'no_module_of_this_name')
    assert done.returncode != 0, done.stdout
    assert "No module named 'no_module_of_this_name'" in done.stderr, done.stderr[-3000:]


def test_only_the_recorder_and_the_player_spin_without_scipy() -> None:
    """Every other node rotates, tests or fits while it runs: it imports scipy as it
    spins."""
    for node in names.NODE_EXECUTABLES:
        start = importlib.import_module(f'positioning_cell.nodes.{node.executable}').main
        assert isinstance(start, NodeStart)
        expected = () if node in (names.RECORDER, names.PLAYER) else SCIPY_MODULES
        assert start.imports == expected, node.executable
