"""numba (~125 MB of a process) is loaded by no node: importing any node's module or building
the node leaves it out, and forward kinematics (the one kernel a node would need) then runs as
the kernel's Python source, uncompiled (positioning_cell.core.kinematics.forward), even once
the process is sealed (positioning_cell.core.compiled.seal, by the nodes' runner before they
spin), where a kernel that was not warmed raises instead of pausing the executor for numba's
import or a compile (issue 24; the 0.2 s joint-silence watch). scipy likewise: no node's
module imports it, and only the nodes of SCIPY_AT_BUILD load it as they are built; only the
nodes of PLANNER_NODES load the move planner.

Each check runs in a fresh interpreter: sys.modules and the seal are per process."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cell_harness import CELL_YAML, REPO, isolated_domain

from positioning_cell import names
from positioning_cell.ros.processes import cell_environment

# every test here starts a fresh interpreter, and the harness imports rclpy: the library tier
# (-m "not nodes and not slow") must not even import this module
pytestmark = pytest.mark.slow

#: The nodes whose work runs compiled kernels: none (forward kinematics, for the positioner's
#: pose from the encoders, the driver's efforts, the simulated tracker's truth and the
#: calibrator's machine model, runs uncompiled there, one pose at a time; the positioner's axis
#: ranges run compiled in a range worker, a process of their own: test_range_worker).
KERNEL_NODES: set[str] = set()
#: The nodes whose build needs scipy (its import is ~0.2-0.4 s of a node's start, issue 24):
#: none. The simulated tracker locates itself (a matrix to quaternion) and the positioner
#: derives its factory box (Euler angles) in numpy (core.poses); the coordinator sizes its
#: panel's internal force systems with numpy's SVD (mechanics.screw.null_space_rows; scipy
#: until 2026-12-07), and so does the panel simulator. Every node's module imports without it.
SCIPY_AT_BUILD: set[str] = set()
#: The nodes that plan moves, and load the planner (positioning_cell.moves.trajectory, with
#: the clearance model and the statics: ~0.1 s of a node's start, issue 24): the positioner,
#: the calibrator, and the live view, which reads the operator's speed settings (limits.speed,
#: on the planner's MotionLimits). The others only read or answer trajectories.
PLANNER_NODES = {'kinematics_node', 'calibrator_node', 'live_view_node'}
#: Node executable -> the library modules its work needs besides its own module's imports
#: (the bag player cannot be built without a bag: its module and its playback are imported).
LIBRARY = {'bag_player_node': ('positioning_cell.bag.playback',)}

BUILD = '''
import importlib, json, sys
import rclpy
from rclpy.node import Node
from positioning_cell.core import compiled
from positioning_cell.errors import PositioningError
module_name, params, extra = sys.argv[1], sys.argv[2:4], sys.argv[4:]
module = importlib.import_module(module_name)
for name in extra:
    importlib.import_module(name)
report = {'imported': 'numba' in sys.modules, 'scipy_imported': 'scipy' in sys.modules}
rclpy.init(args=['--ros-args', '--params-file', params[0], '--params-file', params[1]])
node_class = next(v for v in vars(module).values() if isinstance(v, type)
                  and issubclass(v, Node) and v.__module__ == module.__name__)
try:
    node = node_class()
    report['built'] = True
except PositioningError as err:
    report['built'] = str(err)
report['after_build'] = 'numba' in sys.modules
report['scipy_after_build'] = 'scipy' in sys.modules
report['planner_after_build'] = 'positioning_cell.moves.trajectory' in sys.modules
compiled.seal()
from positioning_cell.core import kinematics
from positioning_cell.core.mechanism import Mechanism
mech = Mechanism.default()
home = kinematics.inverse(mech, mech.home_position[None], mech.home_quaternion[None])
try:
    kinematics.forward(mech, home.lengths, home.thetas)
    report['forward_after_seal'] = 'ran'
except compiled.ColdKernelError:
    report['forward_after_seal'] = 'cold'
report['numba_at_end'] = 'numba' in sys.modules
print(json.dumps(report))
'''


def _build(executable: str, tmp_path: Path) -> dict[str, object]:
    overrides = tmp_path / 'overrides.yaml'
    overrides.write_text(yaml.safe_dump({
        names.NODE_RECORDER: {'ros__parameters': {'output': str(tmp_path / 'bag')}},
        names.NODE_CALIBRATOR: {'ros__parameters': {'out_dir': str(tmp_path / 'cal')}},
        names.NODE_LIVE_VIEW: {'ros__parameters': {'port': 0}}}))
    module = f'positioning_cell.nodes.{executable}'
    with isolated_domain() as domain:
        done = subprocess.run(
            [sys.executable, '-c', BUILD, module, str(CELL_YAML), str(overrides),
             *LIBRARY.get(executable, ())],
            env=cell_environment(domain), cwd=tmp_path, capture_output=True, text=True,
            timeout=240, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    report: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return report


@pytest.mark.nodes
@pytest.mark.parametrize('executable', [n.executable for n in names.NODE_EXECUTABLES])
def test_no_node_loads_numba_or_scipy_and_forward_kinematics_runs_sealed(
        executable: str, tmp_path: Path) -> None:
    report = _build(executable, tmp_path)
    assert report['imported'] is False, 'importing the node module loaded numba'
    if executable == names.PLAYER.executable:
        assert report['built'] != True  # noqa: E712 (no bag given: it refuses to start)
    else:
        assert report['built'] is True, report['built']
    assert report['scipy_imported'] is False, 'importing the node module loaded scipy'
    if executable not in SCIPY_AT_BUILD:
        assert report['scipy_after_build'] is False, 'building the node loaded scipy'
    assert report['planner_after_build'] is (executable in PLANNER_NODES)
    kernels = executable in KERNEL_NODES
    assert report['after_build'] is kernels
    # After the seal forward kinematics runs, uncompiled, without loading numba.
    assert report['forward_after_seal'] == 'ran'
    assert report['numba_at_end'] is kernels


SEALED = '''
import sys
import numpy as np
from positioning_cell.core import compiled, kinematics
from positioning_cell.core.mechanism import Mechanism
kinematics.warm_up()
import positioning_cell.tolerance.montecarlo as mc  # its kernels declared after the warm-up
compiled.seal()
mech = Mechanism.default()
home = kinematics.inverse(mech, mech.home_position[None], mech.home_quaternion[None])
assert kinematics.forward(mech, home.lengths, home.thetas).converged.all()
try:
    mc.warm_up()
except compiled.ColdKernelError as err:
    print('cold:', err)
out = (np.empty((1, 3)), np.empty((1, 3)), np.empty((1, 3, 3)), np.empty(1, dtype=bool))
for lengths in (home.lengths.copy(), home.lengths.astype(np.float32)):  # float32: would compile
    try:
        kinematics._forward_kernel(lengths, home.thetas.copy(), home.phis.copy(),
                                   *kinematics._closure_constants(mech),
                                   kinematics.FK_TOLERANCE, 40, *out)
        print('ran:', lengths.dtype)
    except TypeError as err:
        print('no compile:', lengths.dtype, str(err).splitlines()[0])
'''


def test_a_sealed_process_neither_loads_nor_compiles_a_kernel() -> None:
    done = subprocess.run([sys.executable, '-c', SEALED], cwd=REPO, capture_output=True,
                          text=True, timeout=240, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.splitlines()
    assert any(line.startswith('cold: kernel positioning_cell.tolerance.montecarlo.')
               for line in lines), done.stdout
    assert 'ran: float64' in lines, done.stdout  # the warmed specialisation
    assert any(line.startswith('no compile: float32') for line in lines), done.stdout
