"""The leg driver's trajectory decoder (positioning_cell.sim.trajectory_wire) against rclpy's
own deserialiser, measured in the same run: a JointTrajectory of --points points (6 positions
and 6 velocities each), best of --repeat, and the refusal of one with more points than the
driver takes (read up to the points count only).

Run: .venv/bin/python benchmarks/trajectory_wire.py [--points 100000] [--repeat 5]
Target (issue 21): the driver's publication never waits for a command: decoding 100 000
points well under the driver's 10 ms publication period times a few. Prints what it measured;
exits non-zero only if the decoded values differ from rclpy's.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from builtin_interfaces.msg import Duration
from rclpy.serialization import deserialize_message, serialize_message
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.sim.trajectory_wire import TrajectoryWireError, decode_joint_trajectory


def best(call: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """The shortest of ``repeat`` timings (s) and the last result."""
    times, result = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        result = call()
        times.append(time.perf_counter() - start)
    return min(times), result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--points', type=int, default=100_000)
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    values = rng.normal(size=(args.points, 12))
    msg = JointTrajectory(joint_names=list(JOINT_NAMES))
    msg.points = [JointTrajectoryPoint(positions=row[:6].tolist(), velocities=row[6:].tolist(),
                                       time_from_start=Duration(sec=k // 100,
                                                                nanosec=k % 100 * 10_000_000))
                  for k, row in enumerate(values)]
    data = serialize_message(msg)
    ours, decoded = best(lambda: decode_joint_trajectory(data, args.points), args.repeat)
    theirs, reference = best(lambda: deserialize_message(data, JointTrajectory), args.repeat)
    expected = np.array([list(p.positions) + list(p.velocities) for p in reference.points])
    same = np.array_equal(np.hstack([decoded.positions, decoded.velocities]), expected)

    def refuse() -> None:
        try:
            decode_joint_trajectory(data, args.points - 1)
        except TrajectoryWireError:
            return
        raise AssertionError('not refused')

    refused, _ = best(refuse, args.repeat)
    print(f'{args.points} points, {len(data) / 2**20:.1f} MiB serialized, best of {args.repeat}')
    print(f'  decode_joint_trajectory       {ours * 1e3:9.2f} ms')
    print(f'  baseline: rclpy deserialise   {theirs * 1e3:9.2f} ms  ({theirs / ours:.0f}x)')
    print(f'  refusal above max_points      {refused * 1e3:9.3f} ms')
    print(f'  values equal to rclpy\'s: {"yes" if same else "NO"}')
    return 0 if same else 1


if __name__ == '__main__':
    sys.exit(main())
