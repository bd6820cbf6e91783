"""The leg driver as a process, commanded by this test (its ``command.commander``), probed as
issue 21 probed it: a trajectory stamped 0.6 s in the past is refused as too old (it used to be
accepted, then fault the drive), one stamped 4 s ahead as too far in the future; a 100 000-point
trajectory is refused before its points are read and a 50 000-point one is taken, and neither
holds up the encoder publication (it used to stall 1.49 s); SIGINT then stops the driver
within 2 s.

Multi-process tier: the driver runs in its own process, so the time this test spends building
its big messages does not hold up the driver; the driver's publication is judged from the
stamps it gives (its own clock), not from when this process received it."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Duration
from cell_harness import Client, ProcessGroup, isolated_domain, wait_until
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.duration import Duration as RosDuration
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from positioning_cell import names
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.nodes.messages import status_values
from positioning_cell.nodes.qos import COMMAND_QOS, HEARTBEAT_QOS, STREAM_QOS

pytestmark = [pytest.mark.nodes, pytest.mark.slow]

CLIENT = 'driver_commands_test'
#: Largest interval between two encoder publications the driver may leave while it takes a
#: command (its period is 0.01 s; a loaded 2-core machine delays a timer by tens of ms).
LARGEST_GAP_S = 0.1
STOP_BOUND_S = 2.0


class Driver:
    """The driver process and this test as its commander: heartbeat, trajectories, answers,
    encoder readings."""

    def __init__(self, procs: ProcessGroup, client: Client) -> None:
        self.procs, self.client = procs, client
        node = client.node
        beat = node.create_publisher(Header, names.HEARTBEAT, HEARTBEAT_QOS)
        node.create_timer(0.05, lambda: beat.publish(Header()))
        self.trajectories = node.create_publisher(JointTrajectory, names.JOINT_TRAJECTORY,
                                                  COMMAND_QOS)
        self.states: list[JointState] = client.collect(JointState, names.JOINT_STATES,
                                                       STREAM_QOS)
        self.answers: list[DiagnosticStatus] = client.collect(
            DiagnosticStatus, names.TRAJECTORY_STATUS, STREAM_QOS)
        status = client.statuses(names.STATUS_DRIVER)
        wait_until(lambda: any(status_values(s).get('commander_seen') == 'True'
                               for s in list(status)), 60.0,
                   'the driver to see its commander')

    def here(self) -> np.ndarray:
        return np.array(wait_until(lambda: self.states and self.states[-1], 10.0,
                                   'an encoder reading').position)

    def send(self, msg: JointTrajectory) -> tuple[DiagnosticStatus, float]:
        """Publish ``msg`` and wait for the driver's answer to it: (answer, the largest
        interval between the driver's encoder stamps from just before the send until well
        after the answer, s)."""
        seen, count = len(self.answers), len(self.states)
        self.trajectories.publish(msg)
        answer = wait_until(lambda: self.answers[seen] if len(self.answers) > seen else None,
                            30.0, 'the answer')
        after = len(self.states)
        wait_until(lambda: len(self.states) > after + 20, 10.0, 'encoder readings after it')
        stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
                           for m in list(self.states)[max(count - 5, 0):]])
        return answer, float(np.max(np.diff(stamps)))


def trajectory(start: np.ndarray, points: int, stamp: Any = None) -> JointTrajectory:
    """``points`` points holding ``start``, 0.01 s apart."""
    msg = JointTrajectory(joint_names=list(JOINT_NAMES))
    if stamp is not None:
        msg.header.stamp = stamp
    point = start.tolist()
    msg.points = [JointTrajectoryPoint(positions=point, velocities=[0.0] * 6,
                                       time_from_start=Duration(sec=k // 100,
                                                                nanosec=k % 100 * 10_000_000))
                  for k in range(points)]
    return msg


@pytest.fixture
def driver(tmp_path: Path) -> Iterator[Driver]:
    with isolated_domain() as domain, ProcessGroup(domain, tmp_path) as procs, \
            Client(domain, CLIENT) as client:
        procs.start(names.NODE_DRIVER + '_node', overrides={names.NODE_DRIVER: {
            'referenced_at_start': True, 'command': {'commander': f'/{CLIENT}'}}})
        yield Driver(procs, client)


def test_old_and_future_stamps_and_long_trajectories(driver: Driver) -> None:
    here = driver.here()
    clock = driver.client.node.get_clock()
    for stamp, code, words in (
            (clock.now() - RosDuration(seconds=0.6), 'old_header_timestamp', 's in the past'),
            (clock.now() + RosDuration(seconds=4.0), 'future_header_timestamp', 's ahead')):
        answer, _ = driver.send(trajectory(here, 3, stamp.to_msg()))
        assert status_values(answer)['code'] == code and words in answer.message, answer
    huge = trajectory(here, 100_000)
    answer, gap = driver.send(huge)
    assert status_values(answer)['code'] == 'too_many_points', answer
    assert '100000 points: more than max_points = 60000' in answer.message
    assert gap < LARGEST_GAP_S, f'encoder publication held up {gap:.3f} s'
    huge.points = huge.points[:50_000]
    answer, gap = driver.send(huge)
    assert status_values(answer)['accepted'] == 'true', answer
    assert '50000 points' in answer.message
    assert gap < LARGEST_GAP_S, f'encoder publication held up {gap:.3f} s'
    driver.trajectories.publish(JointTrajectory(joint_names=list(JOINT_NAMES)))  # stop
    started = time.monotonic()
    codes = driver.procs.stop(sig=signal.SIGINT, grace=10.0)
    assert codes == {names.NODE_DRIVER + '_node': 0}
    assert time.monotonic() - started < STOP_BOUND_S

