"""The operator's command-line client `cell` against the real executables (leg driver, tracker,
positioner): home, coordinate systems set and read back, a move in the user CS, a move relative
to the object about the pivot, a refused check with its bits, speeds refused above the factory
maximum, limits, a jog, and Ctrl-C cancelling a move with the drives stopped; every answer read
from `--json` and the exit codes checked. The pure parts of the CLI: test_cell_cli.py."""

from __future__ import annotations

import json
import signal
import subprocess
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
import pytest
from cell_harness import (
    LOADED_COMMAND,
    LOADED_LIVENESS,
    Client,
    ProcessGroup,
    executable,
    isolated_domain,
    stop_cleanly,
    wait_until,
)
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from sensor_msgs.msg import JointState

from positioning_cell import names
from positioning_cell.frames.transforms import Transform, pose6_from_human
from positioning_cell.ros.processes import cell_environment
from positioning_cell.ros.qos import STREAM_QOS

pytestmark = [pytest.mark.nodes, pytest.mark.timing]

USER = [10.0, -5.0, 2.0, 0.0, 0.0, 10.0]  # mm, deg
OBJECT = [0.0, 0.0, 50.0, 0.0, 0.0, 0.0]


class Cell:
    """The running cell and `cell` invocations on its domain."""

    def __init__(self, domain: int, procs: ProcessGroup, client: Client) -> None:
        self.env = cell_environment(domain)
        self.procs, self.client = procs, client

    def cli(self, *args: str, timeout: float = 120.0) -> tuple[int, dict[str, Any]]:
        return self.many(args, timeout=timeout)[0]

    def many(self, *commands: Sequence[str],
             timeout: float = 120.0) -> list[tuple[int, dict[str, Any]]]:
        """Run `cell ... --json` commands at once (each start costs seconds); their exit
        codes and documents."""
        procs = [subprocess.Popen([executable('cell'), *args, '--json'], env=self.env,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for args in commands]
        out = []
        try:
            for args, proc in zip(commands, procs, strict=True):
                try:
                    stdout, stderr = proc.communicate(timeout=timeout)
                except subprocess.TimeoutExpired:  # what it and the positioner said, to tell why
                    proc.kill()
                    stdout, stderr = proc.communicate()
                    raise AssertionError(
                        f'`cell {" ".join(args)}` ended not within {timeout:g} s; its stdout '
                        f'{stdout[-2000:]!r}, stderr {stderr[-2000:]!r}; the positioner\'s log '
                        f'{self.procs.log("kinematics_node")[-2000:]!r}') from None
                assert stdout.strip(), stderr
                out.append((proc.returncode, json.loads(stdout)))
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
        return out


@pytest.fixture(scope='module')
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    log_dir = tmp_path_factory.mktemp('cli')
    # mode model: settled on the encoders' estimate, no tracker corrections (quicker moves;
    # the closed loop is test_cell's). Liveness is not under test here (test_faults'): the
    # loaded bounds, so that a stalled process on a busy runner aborts no move (a relative
    # move aborted in CI with the default 0.2 s joint silence).
    overrides = {names.NODE_POSITIONER: {
        'compensation': {'mode': 'model'}, 'liveness': LOADED_LIVENESS,
        'operator': {'coordinate_systems_file': str(log_dir / 'coordinate_systems.yaml')}},
        names.NODE_DRIVER: {'command': LOADED_COMMAND}}
    with isolated_domain() as domain, ProcessGroup(domain, log_dir) as procs, \
            Client(domain, 'cli_test') as client:
        tracker = client.collect(PoseWithCovarianceStamped, names.MEASURED_POSE, STREAM_QOS)
        poses = client.collect(PoseStamped, names.ESTIMATED_POSE, STREAM_QOS)
        for node in names.CELL_NODES[:3]:  # driver, tracker, positioner
            procs.start(node.executable, overrides={node.name: overrides[node.name]}
                        if node.name in overrides else None)
        wait_until(lambda: poses and tracker, 60.0, 'the cell to come up')
        cell = Cell(domain, procs, client)
        _home(cell)  # once for the module: each test then runs alone too (in any order)
        yield cell
        stop_cleanly(procs)


def _said(doc: dict[str, Any]) -> str:
    """The whole answer as text: pytest cuts a dict's repr short, and an abort's reason is what
    a failure must show."""
    return json.dumps(doc, indent=1)


def _home(cell: Cell) -> None:
    # the encoders may not have been read yet: retry while refused
    def homed() -> tuple[int, dict[str, Any]] | None:
        code, doc = cell.cli('home')
        return None if doc['outcome']['code_name'].startswith('refused') else (code, doc)
    code, doc = wait_until(homed, 60.0, 'cell home')
    assert code == 0 and doc['outcome']['code_name'] == 'success', _said(doc)


def test_frames_moves_and_the_pivot(cell: Cell) -> None:
    code, doc = cell.cli('frames', 'set', '--user', *map(str, USER), '--object',
                         *map(str, OBJECT))
    assert code == 0 and doc['success'], doc
    code, doc = cell.cli('frames', 'get')
    assert code == 0
    np.testing.assert_allclose(doc['coordinate_systems']['user']['human'], USER, atol=1e-9)
    np.testing.assert_allclose(doc['coordinate_systems']['object']['human'], OBJECT, atol=1e-9)
    goal = [1.0, 2.0, 48.0, 0.5, -0.3, 1.0]
    code, doc = cell.cli('move', *map(str, goal))
    assert code == 0 and doc['outcome']['code_name'] == 'success', _said(doc)
    attained = doc['outcome']['attained_user']['human']
    np.testing.assert_allclose(attained[:3], goal[:3], atol=0.015)  # mm: the settle tolerance
    np.testing.assert_allclose(attained[3:], goal[3:], atol=0.01)  # deg

    def status_with_ranges() -> tuple[int, Any] | None:
        """cell status once its axis ranges are no longer pending (the first reader starts
        the positioner's range worker; cell status waits a bounded time for it)."""
        code, doc = cell.cli('status')
        return None if (doc.get('axis_ranges') or {}).get('pending') else (code, doc)

    code, doc = wait_until(status_with_ranges, 60.0, 'cell status with the axis ranges')
    assert code == 0 and doc['referenced'] and doc['state'] == 'settled', doc
    np.testing.assert_allclose(doc['positions']['user']['target']['human'], goal, atol=1e-6)
    # the live axis ranges from there (published while read, latched; found since it settled,
    # or while it settled, within the settle tolerance of the goal), each holding the pose
    ranges, goal_si = doc['axis_ranges'], pose6_from_human(goal)
    assert ranges['valid'], ranges
    np.testing.assert_allclose(ranges['pose'], goal_si, atol=2e-5)
    assert [r['axis'] for r in ranges['ranges']] == ['Tx', 'Ty', 'Tz', 'Rx', 'Ry', 'Rz']
    assert all(r['low'] < ranges['pose'][k] < r['high'] and r['low_binding']
               and r['high_binding'] for k, r in enumerate(ranges['ranges'])), ranges
    # relative to the object: a rotation about the pivot keeps the object origin
    code, doc = cell.cli('move', '--relative-object', '0', '0', '0', '1', '0', '0')
    assert code == 0 and doc['outcome']['code_name'] == 'success', _said(doc)
    code, after = cell.cli('status')
    target = after['positions']['user']['target']
    np.testing.assert_allclose(target['human'][:3], goal[:3], atol=1e-9)  # the pivot stayed
    turned = Transform.from_human(goal).inverse() @ Transform.from_human(target['human'])
    np.testing.assert_allclose(turned.to_human(), [0, 0, 0, 1.0, 0, 0], atol=1e-9)


def test_refusals_name_their_bits_and_change_nothing(cell: Cell) -> None:
    (code, doc), (speed_code, before), (limits_code, limits) = cell.many(
        ('check', '0', '0', '300', '0', '0', '0'), ('speed',), ('limits', 'get'))
    assert code == 3 and not doc['valid'], doc
    assert {'stroke', 'machine_limits'} <= set(doc['bit_names']), doc['bit_names']
    assert any(line.startswith('factory: ') for line in doc['violations'])
    assert limits_code == 0 and limits['limits']['factory_constraints'], limits
    assert speed_code == 0
    code, doc = cell.cli('speed', '--linear', '1000')
    assert code == 3 and 'linear_speed' in doc['reason'], doc
    assert doc['current'] == before['current']  # refused, not clamped


def test_jog_then_ctrl_c_cancels_a_move_and_stops_the_drives(cell: Cell) -> None:
    (code, doc), (refused_code, refused) = cell.many(('jog', 'leg1_length', '0.5'),  # mm
                                                     ('jog', 'leg1_length', '50'))
    assert code == 0 and doc['success'], doc
    assert refused_code == 3 and refused['code_name'] == 'refused_limits', refused
    joints = cell.client.collect(JointState, names.JOINT_STATES, STREAM_QOS)
    statuses = cell.client.statuses(names.STATUS_POSITIONER)
    proc = subprocess.Popen([executable('cell'), 'move', '--frame', 'machine', '0', '0', '8',
                             '0', '0', '0', '--speed-scale', '0.1', '--json'], env=cell.env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_until(lambda: any(s.message.startswith('moving') for s in statuses), 60.0,
                   'the move to start')
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60.0)
    finally:
        if proc.poll() is None:
            proc.kill()
    doc = json.loads(out)
    assert proc.returncode == 4 and doc['outcome']['code_name'] == 'aborted_stop', (doc, err)
    assert doc['cancelled']
    # the drives stopped: the encoders come to rest short of the goal
    wait_until(lambda: joints and max(abs(v) for v in joints[-1].velocity) < 1e-6, 30.0,
               'the axes at rest')
    code, status = cell.cli('status')
    assert status['state'] == 'aborted', status
    assert status['positions']['machine']['estimated']['human'][2] < 7.0
