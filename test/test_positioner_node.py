"""The positioner node alone, with the test client playing the leg driver: every refusal says
why (on /diagnostics) and moves nothing; busy, stop and a completed move."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cell_harness import Client, ProcessGroup, isolated_domain, wait_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped
from nav_msgs.srv import GetPlan
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger
from trajectory_msgs.msg import JointTrajectory
from workspace import MECH

from positioning_cell import kinematics
from positioning_cell.mechanism import JOINT_NAMES
from positioning_cell.nodes.common import COMMAND_QOS, STREAM_QOS, pose_stamped

pytestmark = pytest.mark.nodes


class FakeDriver:
    """Publishes encoder readings; jumps to a trajectory's last point when told to follow."""

    def __init__(self, client: Client) -> None:
        home = kinematics.inverse(MECH, MECH.home_position, MECH.home_quaternion)
        self.position = np.concatenate([home.lengths[0], home.thetas[0]])
        self.follow = False
        self.trajectories: list[JointTrajectory] = []
        self.lock = threading.Lock()
        node = client.node
        self.pub = node.create_publisher(JointState, '/legs/joint_states', STREAM_QOS)
        self.diag = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        node.create_subscription(JointTrajectory, '/legs/joint_trajectory', self._on_traj,
                                 COMMAND_QOS)
        node.create_timer(0.02, self._tick)

    def _on_traj(self, msg: JointTrajectory) -> None:
        with self.lock:
            self.trajectories.append(msg)
            if self.follow and msg.points:
                self.position = np.array(msg.points[-1].positions)

    def _tick(self) -> None:
        msg = JointState(name=list(JOINT_NAMES))
        with self.lock:
            msg.position = [float(v) for v in self.position]
        msg.velocity = [0.0] * 6
        self.pub.publish(msg)

    def report(self, enabled: bool) -> None:
        status = DiagnosticStatus(name='leg_driver: drives', level=DiagnosticStatus.OK,
                                  values=[KeyValue(key='enabled', value=str(enabled).lower()),
                                          KeyValue(key='state', value='holding')])
        self.diag.publish(DiagnosticArray(status=[status]))


def request(p: Any, q: Any, frame: str = 'base') -> GetPlan.Request:
    goal = PoseStamped()
    goal.header.frame_id = frame
    msg = pose_stamped(MECH.home_position, MECH.home_quaternion, goal.header.stamp, frame)
    pos, ori = msg.pose.position, msg.pose.orientation
    pos.x, pos.y, pos.z = (float(v) for v in p)
    ori.x, ori.y, ori.z, ori.w = (float(v) for v in q)
    return GetPlan.Request(goal=msg)


@pytest.fixture(scope='module')
def cell(tmp_path_factory: pytest.TempPathFactory) -> Any:
    log_dir: Path = tmp_path_factory.mktemp('positioner')
    with isolated_domain() as domain, ProcessGroup(domain, log_dir) as procs, \
            Client(domain) as client:
        driver = FakeDriver(client)
        diagnostics = client.collect(DiagnosticArray, '/diagnostics')
        poses = client.collect(PoseStamped, '/positioner/pose', STREAM_QOS)
        procs.start('kinematics_node', label='positioner',
                    overrides={'positioner': {'compensation': {'mode': 'none'}}})
        wait_until(lambda: poses, 30.0, 'the first /positioner/pose')
        yield client, driver, diagnostics, procs
        codes = procs.stop()
        assert codes['positioner'] == 0, procs.log('positioner')


def reasons(diagnostics: list[DiagnosticArray]) -> list[str]:
    return [s.message for d in diagnostics for s in d.status if s.name.startswith('positioner')]


HOME_P, HOME_Q = MECH.home_position, MECH.home_quaternion


@pytest.mark.parametrize(('p', 'q', 'frame', 'words'), [
    ([0.0, float('nan'), 0.196], HOME_Q, 'base', 'not finite'),
    (HOME_P, [0.0, 0.0, 0.0, 0.0], 'base', 'is zero'),
    (HOME_P, [0.0, 0.0, 0.2, 1.0], 'base', 'not 1'),
    (HOME_P, HOME_Q, 'tracker', "goal frame 'tracker' is not 'base'"),
    (HOME_P + [0.0, 0.0, 0.03], HOME_Q, 'base', 'length'),
])
def test_refusals_say_why_and_move_nothing(cell: Any, p: Any, q: Any, frame: str,
                                           words: str) -> None:
    client, driver, diagnostics, _ = cell
    sent = len(driver.trajectories)
    for service in ('/positioner/check_pose', '/positioner/move_to_pose'):
        response = client.call(GetPlan, service, request(p, q, frame))
        assert len(response.plan.poses) == 0
    wait_until(lambda: any(words in r for r in reasons(diagnostics)), 10.0,
               f'a refusal naming {words!r} on /diagnostics')
    assert len(driver.trajectories) == sent  # nothing moved


def test_outside_limits_names_leg_and_excess(cell: Any) -> None:
    client, _, diagnostics, _ = cell
    client.call(GetPlan, '/positioner/check_pose', request(HOME_P + [0, 0, 0.03], HOME_Q))
    wait_until(lambda: any('leg 1 length' in r and 'above the maximum 220.0000 mm by' in r
                           for r in reasons(diagnostics)), 10.0, 'limit refusal in words')


def test_check_pose_returns_the_path_without_moving(cell: Any) -> None:
    client, driver, _, _ = cell
    sent = len(driver.trajectories)
    goal = HOME_P + [0.005, 0.0, 0.0]
    response = client.call(GetPlan, '/positioner/check_pose', request(goal, HOME_Q))
    poses = response.plan.poses
    assert len(poses) > 10 and response.plan.header.frame_id == 'base'
    last = poses[-1].pose.position
    np.testing.assert_allclose([last.x, last.y, last.z], goal, atol=1e-12)
    assert len(driver.trajectories) == sent


def test_busy_then_stop_aborts(cell: Any) -> None:
    client, driver, diagnostics, _ = cell
    driver.follow = False  # the drives never arrive: the move waits
    first: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: first.update(r=client.call(
        GetPlan, '/positioner/move_to_pose', request(HOME_P + [0.002, 0, 0], HOME_Q))))
    thread.start()
    sent = len(driver.trajectories)
    wait_until(lambda: len(driver.trajectories) > sent - 1 and any(
        r.startswith('moving') for r in reasons(diagnostics)), 20.0, 'the move to start')
    second = client.call(GetPlan, '/positioner/move_to_pose', request(HOME_P, HOME_Q))
    assert len(second.plan.poses) == 0
    wait_until(lambda: any('busy' in r for r in reasons(diagnostics)), 10.0, 'busy refusal')
    stop = client.call(Trigger, '/positioner/stop', Trigger.Request())
    assert stop.success
    thread.join(timeout=30.0)
    assert len(first['r'].plan.poses) == 0
    assert any('stopped by /positioner/stop' in r for r in reasons(diagnostics))
    assert len(driver.trajectories[-1].points) == 0  # the stop: an empty trajectory


def test_drives_disabled_refused(cell: Any) -> None:
    client, driver, diagnostics, _ = cell
    driver.report(enabled=False)
    sent = len(driver.trajectories)
    # check_pose runs the same validation without moving, so polling it cannot start a move.
    wait_until(lambda: len(client.call(GetPlan, '/positioner/check_pose', request(
        HOME_P, HOME_Q)).plan.poses) == 0 and any(
        'drives disabled' in r for r in reasons(diagnostics)), 20.0, 'drives disabled refusal')
    response = client.call(GetPlan, '/positioner/move_to_pose', request(HOME_P, HOME_Q))
    assert len(response.plan.poses) == 0 and len(driver.trajectories) == sent
    driver.report(enabled=True)


def test_completed_move_returns_executed_path(cell: Any) -> None:
    client, driver, diagnostics, _ = cell
    driver.report(enabled=True)
    driver.follow = True
    goal = HOME_P + [0.0, 0.003, 0.001]
    response = client.call(GetPlan, '/positioner/move_to_pose', request(goal, HOME_Q))
    assert response.plan.poses, reasons(diagnostics)[-3:]
    last = response.plan.poses[-1].pose.position
    np.testing.assert_allclose([last.x, last.y, last.z], goal, atol=1e-9)
    assert any(r.startswith('settled') for r in reasons(diagnostics))
