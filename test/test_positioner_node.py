"""The positioner node in the test process, the test client playing the leg driver: the services
reach the mover and answer, every refusal says why on /diagnostics (looked for only after the
call) and moves nothing, busy and stop, a completed move, the pose estimate and markers, and
validated parameters. The mover's state machine itself: test_mover.py."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from cell_harness import LOADED_LIVENESS, Client, InProcess, wait_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from positioning_cell_interfaces.msg import MoveCommand, MoveOutcome, Validity
from positioning_cell_interfaces.srv import CheckPose, MoveToPose
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory
from visualization_msgs.msg import MarkerArray
from workspace import MECH

from positioning_cell.core import kinematics
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.motion.settings import CALIBRATION_FILE, COMPENSATION_MODE
from positioning_cell.moves.fingerprint import fingerprint
from positioning_cell.nodes.kinematics_node import PositionerNode
from positioning_cell.ros.messages import pose_arrays, pose_stamped
from positioning_cell.ros.qos import COMMAND_QOS, DIAGNOSTICS_QOS, STREAM_QOS

pytestmark = pytest.mark.nodes

HOME_P, HOME_Q = MECH.home_position, MECH.home_quaternion


class FakeDriver:
    """Publishes encoder readings and answers each trajectory (accepting it); jumps to its last
    point when told to follow; reports itself enabled and referenced."""

    def __init__(self, client: Client) -> None:
        home = kinematics.inverse(MECH, HOME_P, HOME_Q)
        self.position = np.concatenate([home.lengths[0], home.thetas[0]])
        self.follow = True
        self.trajectories: list[JointTrajectory] = []
        self.lock = threading.Lock()
        node = client.node
        self.pub = node.create_publisher(JointState, '/legs/joint_states', STREAM_QOS)
        self.diag = node.create_publisher(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
        self.answers = node.create_publisher(DiagnosticStatus, '/legs/trajectory_status',
                                             STREAM_QOS)
        node.create_subscription(JointTrajectory, '/legs/joint_trajectory', self._on_traj,
                                 COMMAND_QOS)
        self.enabled = True
        node.create_timer(0.02, self._tick)
        node.create_timer(0.2, lambda: self.report(self.enabled))

    def _on_traj(self, msg: JointTrajectory) -> None:
        with self.lock:
            self.trajectories.append(msg)
            if not msg.points:
                return
            times = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points]
            key = fingerprint(times, [p.positions for p in msg.points])
            self.answers.publish(DiagnosticStatus(
                name='leg_driver: trajectory', message='accepted',
                values=[KeyValue(key='key', value=key), KeyValue(key='accepted', value='true')]))
            if self.follow:
                self.position = np.array(msg.points[-1].positions)

    def _tick(self) -> None:
        msg = JointState(name=list(JOINT_NAMES))
        with self.lock:
            msg.position = [float(v) for v in self.position]
        msg.velocity = [0.0] * 6
        self.pub.publish(msg)

    def report(self, enabled: bool, state: str = 'holding') -> None:
        self.enabled = enabled
        status = DiagnosticStatus(name='leg_driver', level=DiagnosticStatus.OK,
                                  values=[KeyValue(key='enabled', value=str(enabled).lower()),
                                          KeyValue(key='state', value=state),
                                          KeyValue(key='referenced', value='true')])
        self.diag.publish(DiagnosticArray(status=[status]))


def command(p: Any, q: Any, frame: str = 'base', tolerance: float = 0.0,
            mode: int = MoveCommand.ABSOLUTE) -> MoveCommand:
    return MoveCommand(pose=pose_stamped(p, q, PoseStamped().header.stamp, frame), mode=mode,
                       tolerance=float(tolerance))


SERVICES = {'/positioner/check_pose': CheckPose, '/positioner/move_to_pose': MoveToPose}


def done(response: Any) -> bool:
    """A check found the goal valid, or a move settled within tolerance."""
    if hasattr(response, 'valid'):
        return bool(response.valid)
    return bool(response.outcome.code == MoveOutcome.SUCCESS)


class Positioner:
    """The node under test and what the test sees of it."""

    def __init__(self, ros: InProcess, systems_file: Path) -> None:
        self.client = ros.client
        self.driver = FakeDriver(ros.client)
        self.statuses = ros.client.statuses('positioner: state')
        self.poses = ros.client.collect(PoseStamped, '/positioner/pose', STREAM_QOS)
        self.markers = ros.client.collect(MarkerArray, '/positioner/markers', STREAM_QOS)
        self.targets = ros.client.collect(PoseStamped, '/positioner/target', STREAM_QOS)
        # The fake driver shares this process (and its GIL) with the test: a stall here is
        # not a lost driver (nor a late answer: a home move aborted, "timed out after 0.5 s
        # waiting for the leg driver to answer", in a CI's parallel tier); and its readings
        # jump to a trajectory's end on receipt, so they stand still while the trajectory
        # runs, which on a busy machine outlasts the frozen-encoder window. Liveness itself is
        # proven on real processes (test_faults).
        self.node = ros.start(PositionerNode, **{COMPENSATION_MODE: 'none',
                                                 'settle_time': 0.0,
                                                 # the test client plays the driver
                                                 'sources.leg_driver': '/test_client',
                                                 'liveness.joint_silence': 1.0,
                                                 'liveness.answer_timeout':
                                                     LOADED_LIVENESS['answer_timeout'],
                                                 'liveness.freeze_window': 10.0,
                                                 'operator.coordinate_systems_file':
                                                     str(systems_file)})
        wait_until(lambda: self.poses, 30.0, 'the first /positioner/pose')
        wait_until(lambda: self.node.mover.referenced, 10.0, 'the fake drives\' status')

    def plan(self, service: str, cmd: MoveCommand) -> Any:
        kind = SERVICES[service]
        return self.client.call(kind, service, kind.Request(command=cmd))

    def reasons_after(self, mark: int) -> list[str]:
        return [s.message for s in self.statuses[mark:]]

    def wait_reason(self, mark: int, words: str) -> str:
        return wait_until(lambda: next((r for r in self.reasons_after(mark) if words in r), None),
                          10.0, f'a positioner status naming {words!r}')


@pytest.fixture
def positioner(ros: InProcess, tmp_path: Path) -> Iterator[Positioner]:
    yield Positioner(ros, tmp_path / 'coordinate_systems.yaml')


@pytest.mark.parametrize(('p', 'q', 'frame', 'words'), [
    ([0.0, float('nan'), 0.196], HOME_Q, 'base', 'not finite'),
    (HOME_P, [0.0, 0.0, 0.0, 0.0], 'base', 'is zero'),
    (HOME_P, [0.0, 0.0, 0.2, 1.0], 'base', 'not 1'),
    (HOME_P, HOME_Q, 'tracker', "not in frame_id 'tracker'"),
    (HOME_P + [0.0, 0.0, 0.03], HOME_Q,
     'base', 'above the maximum 220.0000 mm'),
])
def test_refusals_say_why_and_move_nothing(positioner: Positioner, p: Any, q: Any, frame: str,
                                           words: str) -> None:
    for service in ('/positioner/check_pose', '/positioner/move_to_pose'):
        mark = len(positioner.statuses)
        response = positioner.plan(service, command(p, q, frame))
        assert not done(response)
        positioner.wait_reason(mark, words)
    assert not positioner.driver.trajectories and not positioner.targets  # nothing moved


def test_a_pivot_is_taken_and_a_bad_one_refused_naming_it(positioner: Positioner) -> None:
    """MoveCommand.pivot: a point a metre off the platform makes a turning move longer (its
    arc, within the linear speed); one that is not finite is refused by both services,
    naming it, and nothing moves."""
    turned = [0.0, 0.0, float(np.sin(0.005)), float(np.cos(0.005))]  # 10 mrad about z
    plain = positioner.plan('/positioner/check_pose', command(HOME_P, turned))
    about = command(HOME_P, turned)
    about.pivot.x = 1.0
    far = positioner.plan('/positioner/check_pose', about)
    assert plain.valid and far.valid and far.duration > plain.duration + 0.1
    about.pivot.x = float('nan')
    for service in ('/positioner/check_pose', '/positioner/move_to_pose'):
        mark = len(positioner.statuses)
        assert not done(positioner.plan(service, about))
        positioner.wait_reason(mark, 'pivot')
    assert not positioner.driver.trajectories and not positioner.targets  # nothing moved


def test_check_pose_returns_the_goal_and_duration_without_moving(
        positioner: Positioner) -> None:
    goal = HOME_P + [0.005, 0.0, 0.0]
    response = positioner.plan('/positioner/check_pose', command(goal, HOME_Q))
    assert response.valid and response.validity.bits == 0 and response.duration > 0.1
    assert response.goal.header.frame_id == 'base'
    np.testing.assert_allclose(pose_arrays(response.goal.pose)[0], goal, atol=1e-12)
    margins = dict(zip(response.validity.margin_names, response.validity.margins, strict=True))
    assert margins['factory.length_max'] > 0 and margins['machine.Tx'] > 0
    assert not positioner.driver.trajectories


def test_check_pose_sets_one_bit_per_violated_constraint(positioner: Positioner) -> None:
    high = positioner.plan('/positioner/check_pose', command(HOME_P + [0, 0, 0.03], HOME_Q))
    assert not high.valid and high.validity.bits & Validity.STROKE
    assert 'stroke' in high.validity.bit_names
    assert any(v.startswith('factory: ') for v in high.validity.violations)
    margins = dict(zip(high.validity.margin_names, high.validity.margins, strict=True))
    assert margins['factory.length_max'] < 0
    bad = positioner.plan('/positioner/check_pose', command(HOME_P, [0.0, 0.0, 0.0, 0.0]))
    assert bad.validity.bits == Validity.INVALID_GOAL
    positioner.driver.report(enabled=False)
    wait_until(lambda: positioner.plan('/positioner/check_pose', command(
        HOME_P, HOME_Q)).validity.bits == Validity.DRIVES_OFF, 20.0, 'the drives-off bit')
    positioner.driver.report(enabled=True)
    wait_until(lambda: positioner.plan('/positioner/check_pose', command(HOME_P, HOME_Q)).valid,
               20.0, 'the drives back on')
    # the measured mode needs the tracker, and there is none here
    assert positioner.client.set_parameter('positioner', COMPENSATION_MODE,
                                           'measured').successful
    silent = positioner.plan('/positioner/check_pose', command(HOME_P, HOME_Q))
    assert silent.validity.bits == Validity.TRACKER_SILENT, silent.validity.violations
    assert 'laser tracker not responding' in silent.validity.violations[0]


def test_a_move_sends_one_trajectory_and_returns_the_executed_path(
        positioner: Positioner) -> None:
    goal = HOME_P + [0.0, 0.003, 0.001]
    mark = len(positioner.statuses)
    response = positioner.plan('/positioner/move_to_pose', command(goal, HOME_Q))
    assert done(response), positioner.reasons_after(mark)
    assert response.outcome.code_name == 'success'
    np.testing.assert_allclose(pose_arrays(response.outcome.attained.pose)[0], goal, atol=1e-9)
    assert np.isnan(response.outcome.uncertainty).all()  # not measured
    # the service answered; its final status may still be on its way
    positioner.wait_reason(mark, 'settled within tolerance')
    (traj,) = positioner.driver.trajectories
    assert list(traj.joint_names) == list(JOINT_NAMES) and len(traj.points) > 10
    ideal = kinematics.inverse(MECH, goal, HOME_Q)
    np.testing.assert_allclose(traj.points[-1].positions,
                               [*ideal.lengths[0], *ideal.thetas[0]], atol=1e-12)
    wait_until(lambda: positioner.targets, 10.0, 'the target')
    np.testing.assert_allclose(pose_arrays(positioner.targets[-1].pose)[0], goal, atol=1e-12)
    # The estimate follows the encoders; markers come with every 5th estimate.
    wait_until(lambda: np.allclose(pose_arrays(positioner.poses[-1].pose)[0], goal, atol=1e-9),
               10.0, 'the pose estimate at the goal')
    wait_until(lambda: positioner.markers, 10.0, 'markers')
    assert {m.ns for m in positioner.markers[-1].markers} == {'legs', 'platform'}


def test_busy_then_stop_aborts(positioner: Positioner) -> None:
    driver = positioner.driver
    driver.follow = False  # the drives never arrive: the move waits
    first: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: first.update(r=positioner.plan(
        '/positioner/move_to_pose', command(HOME_P + [0.002, 0, 0], HOME_Q))))
    mark = len(positioner.statuses)
    thread.start()
    wait_until(lambda: driver.trajectories, 20.0, 'the move to send its trajectory')
    positioner.wait_reason(mark, 'moving')
    mark = len(positioner.statuses)
    second = positioner.plan('/positioner/move_to_pose', command(HOME_P, HOME_Q))
    assert second.outcome.code == MoveOutcome.REFUSED_BUSY
    positioner.wait_reason(mark, 'busy')
    assert len(driver.trajectories) == 1  # the refused move sent nothing
    stop = positioner.client.call(Trigger, '/positioner/stop', Trigger.Request())
    assert stop.success
    thread.join(timeout=30.0)
    assert first['r'].outcome.code == MoveOutcome.ABORTED_STOP
    positioner.wait_reason(mark, 'stopped by /positioner/stop')
    assert len(driver.trajectories[-1].points) == 0  # the stop: an empty trajectory


def test_drives_disabled_refused(positioner: Positioner) -> None:
    driver = positioner.driver
    driver.report(enabled=False)
    # check_pose runs the same validation without moving, so polling it cannot start a move.
    wait_until(lambda: not positioner.plan('/positioner/check_pose', command(
        HOME_P, HOME_Q)).valid, 20.0, 'check_pose refused')
    mark = len(positioner.statuses)
    response = positioner.plan('/positioner/move_to_pose', command(HOME_P, HOME_Q))
    assert response.outcome.code == MoveOutcome.REFUSED_DRIVES_OFF and not driver.trajectories
    positioner.wait_reason(mark, 'drives disabled: enable them with /leg_driver/enable')
    driver.report(enabled=True)
    wait_until(lambda: positioner.plan('/positioner/check_pose', command(
        HOME_P, HOME_Q)).valid, 20.0, 'check_pose accepted again')


def test_home_service_and_parameters(positioner: Positioner) -> None:
    client = positioner.client
    assert done(positioner.plan('/positioner/move_to_pose', command(HOME_P + [0.002, 0, 0],
                                                                    HOME_Q)))
    home = client.call(Trigger, '/positioner/home', Trigger.Request())
    assert home.success and home.message.startswith('at home, referenced')
    np.testing.assert_allclose(positioner.driver.trajectories[-1].points[-1].positions,
                               positioner.driver.trajectories[0].points[0].positions,
                               atol=1e-12)
    refused = client.set_parameter('positioner', COMPENSATION_MODE, 'magic')
    assert not refused.successful
    assert "compensation.mode = 'magic': expected one of none, model, measured" in \
        refused.reason
    refused = client.set_parameter('positioner', 'goal_tolerance.position', -1e-6)
    assert not refused.successful and 'goal_tolerance.position out of range' in refused.reason
    refused = client.set_parameter('positioner', 'compensation.max_iterations', 51)
    assert not refused.successful and 'out of range' in refused.reason.lower()
    refused = client.set_parameter('positioner', 'pose_rate_hz', 10.0)
    assert not refused.successful and 'read-only' in refused.reason.lower()
    assert client.set_parameter('positioner', COMPENSATION_MODE, 'model').successful
    assert positioner.node.mover.mode.value == 'model'


def _calibration_doc(fingerprint: str, length_offset: float) -> dict[str, Any]:
    """A calibration file's content (the current format): a machine with one leg zero
    offset."""
    from positioning_cell.calibration.file import FORMAT
    from positioning_cell.calibration.parameters import PARAMETER_NAMES
    params = {name: {'value': length_offset if name == 'leg1.length_offset' else 0.0,
                     'sigma': 1e-6, 'identified': True} for name in PARAMETER_NAMES}
    covariance = (np.eye(len(PARAMETER_NAMES)) * 1e-12).tolist()
    return {'calibration': {'format': FORMAT, 'mechanism_fingerprint': fingerprint,
                            'parameters': params, 'covariance': covariance}}


def test_a_calibration_file_is_loaded_checked_and_refused_with_the_old_kept(
        positioner: Positioner, tmp_path: Path) -> None:
    from positioning_cell.calibration.file import fingerprint
    client, mover = positioner.client, positioner.node.mover
    good = tmp_path / 'calibration.yaml'
    good.write_text(yaml.safe_dump(_calibration_doc(fingerprint(MECH), 1e-4)))
    assert client.set_parameter('positioner', CALIBRATION_FILE,
                                str(good)).successful
    assert mover.calibration is not None
    assert client.set_parameter('positioner', COMPENSATION_MODE, 'model').successful
    # the calibrated machine's leg 1 reads 0.1 mm short: the command for home says so
    planned = mover.check('base', HOME_P, HOME_Q).lengths[-1]
    nominal = kinematics.inverse(MECH, HOME_P, HOME_Q).lengths[0]
    assert planned[0] == pytest.approx(nominal[0] - 1e-4, abs=1e-9)
    assert planned[1:] == pytest.approx(nominal[1:], abs=1e-9)
    loaded = mover.calibration
    other = tmp_path / 'other.yaml'
    other.write_text(yaml.safe_dump(_calibration_doc('0' * 16, 0.0)))
    for path, words in ((other, 'belongs to mechanism'), (tmp_path / 'missing.yaml',
                                                          'cannot be read')):
        refused = client.set_parameter('positioner', CALIBRATION_FILE, str(path))
        assert not refused.successful and words in refused.reason, refused.reason
        assert mover.calibration is loaded  # the old one stays
        assert client.get_parameter('positioner', CALIBRATION_FILE) == str(good)
