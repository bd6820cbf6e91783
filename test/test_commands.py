"""The drives' command queue without DDS (positioning_cell.sim.commands): commands applied in
the order received after their checks on the checker thread, a foreign sender refused at
once, a stop at once superseding what waits, stamps on the drives' clock."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Duration
from rclpy.serialization import serialize_message
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.parameters import parse
from positioning_cell.polling import wait_until
from positioning_cell.sim.commands import CommandQueue
from positioning_cell.sim.drives import DriverSettings, LegDriver, Outcome

#: rclpy serialises the reference messages in this process.
pytestmark = pytest.mark.nodes

SETTINGS = parse(DriverSettings, {'referenced_at_start': True})
HOME = SETTINGS.home_positions()
ME = SETTINGS.command.commander


def data(delta: float = 1e-3, points: int = 21) -> bytes:
    """A rest-to-rest-ish move of leg 1 by ``delta`` over 1 s (smoothstep), serialized."""
    t = np.linspace(0.0, 1.0, points)
    shape, rate = t * t * (3 - 2 * t), 6 * t * (1 - t)
    msg = JointTrajectory(joint_names=list(JOINT_NAMES))
    for k in range(points):
        p = HOME.copy()
        p[0] += shape[k] * delta
        v = np.zeros(6)
        v[0] = rate[k] * delta
        msg.points.append(JointTrajectoryPoint(
            positions=p.tolist(), velocities=v.tolist(),
            time_from_start=Duration(sec=0, nanosec=int(t[k] * 1e9)) if t[k] < 1 else
            Duration(sec=1)))
    return serialize_message(msg)


def pumped(queue: CommandQueue, now: float) -> list[Outcome]:
    """Pump until the checks of everything that waits are done; the outcomes."""
    got: list[Outcome] = []
    wait_until(lambda: got.extend(queue.pump(now)) or (got and not queue._waiting
                                                        and queue._work is None),
               10.0, 'the checks')
    return got


def test_commands_are_applied_in_order_after_their_checks() -> None:
    driver = LegDriver(SETTINGS)
    queue = CommandQueue(driver, 0)
    try:
        assert queue.receive(data(1e-3), ME, 0.0) == ([], None)
        assert queue.receive(data(2e-3), ME, 0.0) == ([], None)
        first, second = pumped(queue, 0.0)
        assert first.accepted and second.accepted and (first.sequence, second.sequence) == (1, 2)
        assert abs(driver.servos.setpoint(10.0)[0][0] - (HOME[0] + 2e-3)) < 1e-12  # the last won
    finally:
        queue.close()


def test_a_foreign_sender_is_refused_at_once_and_a_stop_supersedes_what_waits() -> None:
    driver = LegDriver(SETTINGS)
    queue = CommandQueue(driver, 0)
    try:
        (refused,), stop = queue.receive(data(), '/rogue', 0.0)
        assert not refused.accepted and refused.code.value == 'foreign_sender'
        assert stop is None and driver.foreign == ('/rogue',)
        queue.receive(data(1e-3), ME, 0.0)
        queue.receive(data(2e-3), ME, 0.0)
        queue.pump(0.0)  # the first one is being checked
        empty = serialize_message(JointTrajectory(joint_names=list(JOINT_NAMES)))
        outcomes, stop = queue.receive(empty, ME, 0.0)
        assert stop is not None and stop.startswith('stop')
        assert [o.code.value for o in outcomes] == ['superseded']  # the waiting one
        later = pumped(queue, 0.0)
        assert [o.code.value for o in later] == ['superseded']  # the one being checked
        assert 'superseded by a stop before it started' in later[0].message
        np.testing.assert_array_equal(driver.servos.setpoint(5.0)[0], HOME)  # nothing moved
        (bad,), _ = queue.receive(b'\x00\x01\x00\x00', ME, 0.0)
        assert bad.code.value == 'invalid_goal' and 'not a trajectory' in bad.message
    finally:
        queue.close()


def test_stamps_are_put_on_the_drives_clock() -> None:
    queue = CommandQueue(LegDriver(SETTINGS), epoch_ns=5_000_000_000)
    try:
        assert queue.start_time((0, 0)) is None
        assert queue.start_time((7, 250_000_000)) == 2.25
    finally:
        queue.close()
