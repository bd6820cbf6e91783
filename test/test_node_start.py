"""How a node starts (positioning_cell.ros.spin.NodeStart): the modules its work imports at
their first use are imported once it is built, before its first callback, since an import
inside a callback pauses the executor (the fault matrix saw the positioner's 0.2 s watch take
1.0 s with scipy imported at its first use). Each check runs in a fresh interpreter: its own
sys.modules and rclpy context."""

from __future__ import annotations

import importlib
import subprocess
import sys

import pytest
from cell_harness import isolated_domain

from positioning_cell import names
from positioning_cell.ros.processes import cell_environment
from positioning_cell.ros.spin import SCIPY_MODULES, NodeStart

pytestmark = [pytest.mark.nodes, pytest.mark.slow]

#: A node whose first timer callback reports whether ``wave`` (a standard-library module
#: nothing else here imports) was loaded, then ends the run.
FIRST_CALLBACK = '''
import sys
from rclpy.node import Node
from positioning_cell.ros.spin import NodeStart, run


class Probe(Node):
    def __init__(self):
        super().__init__('node_start_probe')
        self.exit_status = None
        self.create_timer(0.01, self._tick)

    def _tick(self):
        print('wave loaded:', 'wave' in sys.modules, flush=True)
        self.exit_status = 0


sys.exit(run(NodeStart(Probe, imports=tuple(sys.argv[1:]))))
'''


@pytest.mark.parametrize('imports', [('wave',), ()])
def test_a_nodes_imports_are_loaded_before_its_first_callback(
        imports: tuple[str, ...]) -> None:
    with isolated_domain() as domain:
        done = subprocess.run([sys.executable, '-c', FIRST_CALLBACK, *imports],
                              env=cell_environment(domain), capture_output=True, text=True,
                              timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f'wave loaded: {bool(imports)}' in done.stdout, done.stdout


def test_only_the_recorder_and_the_player_spin_without_scipy() -> None:
    """Every other node rotates, tests or fits while it runs: it imports scipy first."""
    for node in names.NODE_EXECUTABLES:
        start = importlib.import_module(f'positioning_cell.nodes.{node.executable}').main
        assert isinstance(start, NodeStart)
        expected = () if node in (names.RECORDER, names.PLAYER) else SCIPY_MODULES
        assert start.imports == expected, node.executable
