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
from typing import Any

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
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from positioning_cell import names
from positioning_cell.analysis.axis_test import TRUTH, AxisTestMarker, axis_test_figures
from positioning_cell.analysis.fleet import ABORTED_RUN, run_kind
from positioning_cell.bag import BagReader
from positioning_cell.bag.description import bag_description
from positioning_cell.calibration import file as calfile
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.core.kinematics import inverse, leg_directions, platform_points
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.parameters import parse
from positioning_cell.robot.tree import RobotTree
from positioning_cell.robot.urdf import MOVING_JOINT_NAMES
from positioning_cell.ros.processes import OWN_PROCESS_GROUP
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
                            text=True, **OWN_PROCESS_GROUP)
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
    _check_the_machine_as_ros_tools_see_it(run / 'bag')


def _check_the_machine_as_ros_tools_see_it(bag: Path) -> None:
    """The bag shows the machine to Foxglove's 3-D panel and RViz: /robot_description, /tf
    and /tf_static decoded with the standard message definitions (rosbags' Jazzy typestore, not
    the bag's schemas); each of the positioner's /tf states, composed along the tree with
    scipy, puts the platform at its pose estimate of that instant and every leg's rod and S
    joint where the inverse kinematics puts them (1e-9 m, 1e-9 rad); the tracker's frame and
    measured pose are there, and /joint_states names every joint."""
    store = get_typestore(Stores.ROS2_JAZZY)
    topics = (names.ROBOT_DESCRIPTION, names.TF, names.TF_STATIC, names.ROBOT_JOINT_STATES,
              names.ESTIMATED_POSE)
    found: dict[str, list[tuple[str, Any]]] = {t: [] for t in topics}
    with AnyReader([bag], default_typestore=store) as reader:
        for conn, _, raw in reader.messages([c for c in reader.connections if c.topic in topics]):
            found[conn.topic].append((conn.msgtype, store.deserialize_cdr(raw, conn.msgtype)))
    assert {t: {kind for kind, _ in found[t]} for t in topics[:4]} == {
        names.ROBOT_DESCRIPTION: {'std_msgs/msg/String'}, names.TF: {'tf2_msgs/msg/TFMessage'},
        names.TF_STATIC: {'tf2_msgs/msg/TFMessage'},
        names.ROBOT_JOINT_STATES: {'sensor_msgs/msg/JointState'}}
    tree = RobotTree.parse(found[names.ROBOT_DESCRIPTION][0][1].data)
    assert tree.root == names.BASE_FRAME
    static = {t.child_frame_id: t for _, m in found[names.TF_STATIC] for t in m.transforms}
    assert {names.PLATFORM_FRAME, names.MACHINE_FRAME, names.USER_FRAME, names.OBJECT_FRAME,
            names.TRACKER_FRAME} <= set(static)
    states = [m for _, m in found[names.ROBOT_JOINT_STATES]]
    assert states and all(list(m.name) == list(MOVING_JOINT_NAMES) for m in states)
    estimates = {(m.header.stamp.sec, m.header.stamp.nanosec): m.pose
                 for _, m in found[names.ESTIMATED_POSE]}
    # the tree's states with the estimate of their instant (the recorder takes each topic once
    # it has discovered it: the first states may come before the first estimate it took)
    tree_states = [(m, estimates.get((m.transforms[0].header.stamp.sec,
                                      m.transforms[0].header.stamp.nanosec)))
                   for _, m in found[names.TF] if len(m.transforms) == len(MOVING_JOINT_NAMES)]
    paired = [(m, pose) for m, pose in tree_states if pose is not None]
    measured = [m for _, m in found[names.TF]
                if [t.child_frame_id for t in m.transforms] == [names.PLATFORM_MEASURED_FRAME]]
    assert len(paired) >= 100 and len(paired) >= 0.95 * len(tree_states), (
        len(paired), len(tree_states))
    assert len(measured) >= 100, len(measured)
    worst = [0.0, 0.0]
    for message, pose in paired[::10]:
        p = np.array([pose.position.x, pose.position.y, pose.position.z])
        q = np.array([pose.orientation.x, pose.orientation.y, pose.orientation.z,
                      pose.orientation.w])
        frames = _compose({t.child_frame_id: t for t in (*static.values(), *message.transforms)})
        b = platform_points(MECH, p[None], q[None])[0]
        joints = inverse(MECH, p, q)
        u = leg_directions(MECH, joints.phis, joints.thetas)[0]
        at, turned = frames[names.PLATFORM_FRAME]
        worst = [max(worst[0], float(np.abs(at - p).max())),
                 max(worst[1], (turned.inv() * Rotation.from_quat(q)).magnitude())]
        for leg in (1, 2, 3):
            rod_at, rod_turned = frames[f'leg{leg}_rod']
            ball_at, ball_turned = frames[f'leg{leg}_s']
            worst[0] = max(worst[0], float(np.abs(rod_at - b[leg - 1]).max()),
                           float(np.abs(ball_at - b[leg - 1]).max()),
                           float(np.abs(rod_turned.apply([0.0, 0.0, 1.0]) - u[leg - 1]).max()))
            worst[1] = max(worst[1], (ball_turned.inv() * Rotation.from_quat(q)).magnitude())
    assert worst[0] < 1e-9 and worst[1] < 1e-9, worst


def _compose(transforms: dict[str, Any]) -> dict[str, tuple[np.ndarray, Rotation]]:
    """Each frame's pose in ``base`` from TransformStamped messages by child frame."""
    out: dict[str, tuple[np.ndarray, Rotation]] = {names.BASE_FRAME: (np.zeros(3),
                                                                     Rotation.identity())}

    def pose(frame: str) -> tuple[np.ndarray, Rotation]:
        if frame not in out:
            t = transforms[frame]
            parent_at, parent_turned = pose(t.header.frame_id)
            v, r = t.transform.translation, t.transform.rotation
            out[frame] = (parent_at + parent_turned.apply([v.x, v.y, v.z]),
                          parent_turned * Rotation.from_quat([r.x, r.y, r.z, r.w]))
        return out[frame]

    for frame in transforms:
        pose(frame)
    return out


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
