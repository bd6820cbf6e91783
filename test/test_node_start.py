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
from cell_harness import isolated_domain, waiting_for_file

from positioning_cell import names
from positioning_cell.ros.processes import cell_environment
from positioning_cell.ros.spin import SCIPY_MODULES, NodeStart

pytestmark = [pytest.mark.nodes, pytest.mark.slow]

#: A module whose import cannot end before the node it is imported for has run a callback: it
#: waits for the file that callback writes (and gives up, raising, after 60 s).
WAITING_MODULE = waiting_for_file(
    'PROBE_MARKER', 'no callback ran while this module was being imported') + 'LOADED = True\n'

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


#: Nodes whose work never needs scipy: importing it beside them only competes for the GIL
#: while they start, and costs each start ~0.4 CPU-s (issue 24: every cell the tests start
#: pays it per node). The leg driver's 100 Hz encoder stream left a 0.17-0.32 s gap (its
#: positioner calls it lost after 0.2 s) when its first trajectory came while scipy's ~180
#: modules were being imported aside (test_driver_commands, on a slow 2-core machine); its own
#: threads never imported scipy in test_cell and the fault matrix (ad hoc, an import hook per
#: driver process), and :func:`test_the_driver_moves_without_scipy` keeps it so. The tracker
#: and the monitor rotate in numpy (their fits, means and ISO 9283 angles): the library tests
#: below and test_cell's look at the running processes keep them so. So does the positioner
#: (its move plans, corrections and status: core.poses' quaternions); a calibration it loads
#: imports scipy.spatial then, for the envelope's hull (calibration.calibrated).
WITHOUT_SCIPY = (names.RECORDER, names.PLAYER, names.DRIVER, names.MEASUREMENT, names.MONITOR,
                 names.POSITIONER)


def test_only_nodes_that_need_scipy_import_it_as_they_spin() -> None:
    """Every other node rotates, tests or fits while it runs: it imports scipy as it
    spins."""
    for node in names.NODE_EXECUTABLES:
        start = importlib.import_module(f'positioning_cell.nodes.{node.executable}').main
        assert isinstance(start, NodeStart)
        expected = () if node in WITHOUT_SCIPY else SCIPY_MODULES
        assert start.imports == expected, node.executable


#: The leg driver's library moving a leg and holding the payload (its efforts) through its
#: command queue, as its node does, in a fresh interpreter: what it imported of scipy.
DRIVER_MOVE = '''
import sys
import numpy as np
from builtin_interfaces.msg import Duration
from rclpy.serialization import serialize_message
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
import positioning_cell.nodes.leg_driver_node
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.parameters import parse
from positioning_cell.sim.commands import CommandQueue
from positioning_cell.sim.drives import DriverSettings, LegDriver

settings = parse(DriverSettings, {'referenced_at_start': True})
home = settings.home_positions()
msg = JointTrajectory(joint_names=list(JOINT_NAMES))
delta = np.array([2e-3, -1e-3, 1e-3, 0.01, -0.01, 0.005])  # m, rad over 1 s (smoothstep)
for t in np.linspace(0.0, 1.0, 21):
    msg.points.append(JointTrajectoryPoint(
        positions=(home + t * t * (3 - 2 * t) * delta).tolist(),
        velocities=(6 * t * (1 - t) * delta).tolist(),
        time_from_start=Duration(sec=int(t), nanosec=int(round(t % 1 * 1e9)))))
driver = LegDriver(settings, 0.0)
queue = CommandQueue(driver, 0)
accepted = []
try:
    queue.receive(serialize_message(msg), settings.command.commander, 0.0)
    now = 0.0
    while now < 2.0:
        driver.heartbeat(now)
        accepted += [(o.accepted, o.message) for o in queue.pump(now)]
        driver.step(now)
        driver.readings()
        now += 1.0 / settings.physics_rate
finally:
    queue.close()
assert [a for a, _ in accepted] == [True], accepted
moved = driver.readings()[1].position - home
assert np.allclose(moved, delta, atol=1e-5), moved
assert driver.effort is not None and np.all(np.isfinite(driver.effort)), driver.effort
print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy')))
'''


def test_the_driver_moves_without_scipy() -> None:
    """:data:`WITHOUT_SCIPY`: the driver's move, its checks, encoders and efforts need none
    of scipy, so none is imported beside it."""
    done = subprocess.run([sys.executable, '-c', DRIVER_MOVE], capture_output=True,
                          text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == '', f'the driver imported scipy: {done.stdout[:300]}'


#: The tracker's library as its node drives it, in a fresh interpreter: located at its build,
#: the truth of a joint stream moving the platform 4 mm in 0.5 s at 50 Hz, readings at 20 Hz
#: (one with a target dropped out by the fault settings), a load applied and taken off, the
#: tracker located again, air temperatures and diagnostics; then what it imported of scipy.
TRACKER_RUN = '''
import sys
import numpy as np
import positioning_cell.nodes.pose_measurement_node
from positioning_cell import names
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse
from positioning_cell.parameters import parse
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings, PoseMeasurementSimulator

params = node_parameters(load_parameter_file(config_path('cell.yaml')), names.NODE_MEASUREMENT)
sim = PoseMeasurementSimulator(parse(PoseMeasurementSettings, params))
mech = sim.truth.mechanism
steps = 50
goal = mech.home_position + np.outer(np.minimum(np.linspace(0.0, 2.0, steps), 1.0),
                                     [0.004, -0.002, 0.003])
joints = inverse(mech, goal, np.repeat(mech.home_quaternion[None], steps, axis=0))
stream = np.hstack([joints.lengths, joints.thetas])
readings = []
for i, row in enumerate(stream):
    sim.joints(row, i, 0.02 * i)
    assert sim.update_truth() is not None, sim.status
    if i % 5 == 0 and (reading := sim.measure()) is not None:
        readings.append(reading)
    sim.air_temperature(0.02 * i)
    sim.diagnostics()
assert len(readings) == 10, sim.status
error = np.linalg.norm(readings[-1].fit.position[0] - sim.true_pose.position)
assert error < 1e-4, error  # a reading of the true pose, within a tracker's noise
sim.apply_load([0.0, 0.0, -200.0])
sim.joints(stream[-1], steps, 0.02 * steps)
assert sim.update_truth() is not None, sim.status
sim.apply_load([0.0, 0.0, 0.0])
assert sim.locate()[0], sim.locate_status
assert sim.measure() is not None, sim.status
print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy')))
'''


def test_the_tracker_measures_without_scipy() -> None:
    """:data:`WITHOUT_SCIPY`: the tracker's truth, readings, fits, load and location need
    none of scipy, so none is imported beside it."""
    done = subprocess.run([sys.executable, '-c', TRACKER_RUN], capture_output=True,
                          text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == '', f'the tracker imported scipy: {done.stdout[:300]}'


#: The monitor's library as its node drives it, in a fresh interpreter: test_accuracy's short
#: run (two poses, two cycles, bad messages, readings with and without the tracker's
#: registration), given on stdin as its messages, fed in groups and released in stamp order,
#: then its report; then what it imported of scipy.
MONITOR_RUN = '''
import pickle
import sys
import positioning_cell.nodes.accuracy_monitor_node
from positioning_cell import accuracy as acc
from positioning_cell.accuracy.stamp_order import MonitorInputs

groups = pickle.load(sys.stdin.buffer)
monitor = acc.Monitor()
inputs = MonitorInputs(monitor)
for group in groups:
    inputs.arrive(**group)
    inputs.release()
inputs.release(flush=True)
report = monitor.report()
print(sum(report['verdicts'].values()), len(report['measured']['poses']))
print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] == 'scipy')))
'''


def test_the_monitor_judges_without_scipy() -> None:
    """:data:`WITHOUT_SCIPY`: the monitor's settling, ISO 9283 figures, means of readings
    (with the registration and without) and verdicts need none of scipy."""
    import pickle

    from test_accuracy import _fed, _stream
    events = _stream(0)
    groups = [_fed(events[k:k + 25], k) for k in range(0, len(events), 25)]
    done = subprocess.run([sys.executable, '-c', MONITOR_RUN], input=pickle.dumps(groups),
                          capture_output=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr.decode()[-3000:]
    counts, imported = (done.stdout.decode() + '\n').split('\n', 1)
    verdicts, poses = map(int, counts.split())
    assert verdicts >= 3 and poses == 2, done.stdout  # the run's visits judged
    assert imported.strip() == '', f'the monitor imported scipy: {imported[:300]}'
