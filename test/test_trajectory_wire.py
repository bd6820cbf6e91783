"""The driver's trajectory decoder against rclpy's own deserialiser: every layout of points
(counts per field, header and name lengths that shift the 8-byte alignment), the refusals of
points that differ, of a cut message and of too many points."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Duration
from hypothesis import given
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from positioning_cell.sim.trajectory_wire import TrajectoryWireError, decode_joint_trajectory

#: rclpy serialises the reference messages in this process.
pytestmark = pytest.mark.nodes

FLOATS = st.floats(allow_nan=False, allow_infinity=False, width=64)


def message(names: list[str], frame: str, stamp: tuple[int, int], rows: int,
            counts: tuple[int, int, int, int], values: list[float],
            times: list[tuple[int, int]]) -> JointTrajectory:
    msg = JointTrajectory(joint_names=names)
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp
    it = iter(values * (1 + sum(counts) * rows // max(len(values), 1)))
    for k in range(rows):
        fields = [[next(it) for _ in range(c)] for c in counts]
        msg.points.append(JointTrajectoryPoint(
            positions=fields[0], velocities=fields[1], accelerations=fields[2],
            effort=fields[3], time_from_start=Duration(sec=times[k % len(times)][0],
                                                       nanosec=times[k % len(times)][1])))
    return msg


@given(names=st.lists(st.text(max_size=9), max_size=7), frame=st.text(max_size=11),
       stamp=st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, 999_999_999)),
       rows=st.integers(0, 9), counts=st.tuples(*[st.integers(0, 7)] * 4),
       values=st.lists(FLOATS, min_size=1, max_size=20),
       times=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 999_999_999)),
                      min_size=1, max_size=5))
def test_the_decoder_gives_what_rclpy_gives(names: list[str], frame: str,
                                           stamp: tuple[int, int], rows: int,
                                           counts: tuple[int, int, int, int],
                                           values: list[float],
                                           times: list[tuple[int, int]]) -> None:
    data = serialize_message(message(names, frame, stamp, rows, counts, values, times))
    decoded = decode_joint_trajectory(data, 100)
    reference = deserialize_message(data, JointTrajectory)
    assert decoded.stamp == stamp and decoded.joint_names == list(reference.joint_names)
    assert decoded.times.shape == (rows,)
    for field, got in (('positions', decoded.positions), ('velocities', decoded.velocities),
                       ('accelerations', decoded.accelerations)):
        expected = np.array([list(getattr(p, field)) for p in reference.points]).reshape(
            rows, -1 if rows else 0)
        assert got.shape == expected.shape or (rows == 0 and got.size == 0)
        assert np.array_equal(got, expected)  # the same doubles, bit for bit: a copy
    expected_t = [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9
                  for p in reference.points]
    np.testing.assert_allclose(decoded.times, expected_t, rtol=0.0, atol=1e-12)


def six(rows: int) -> JointTrajectory:
    return message(['a', 'b', 'c', 'd', 'e', 'f'], '', (0, 0), rows, (6, 6, 0, 0),
                   [0.5, 1.5], [(0, 10_000_000)])


@pytest.mark.parametrize('k', [1, 2, 7])
def test_a_point_that_differs_is_refused_naming_it(k: int) -> None:
    msg = six(10)
    msg.points[k].velocities = []
    with pytest.raises(TrajectoryWireError, match=f'point {k} has 0 velocities, point 0 has 6: '
                                                   'every point must carry the same fields'):
        decode_joint_trajectory(serialize_message(msg), 100)


def test_a_cut_message_and_too_many_points_are_refused_before_reading_them() -> None:
    data = serialize_message(six(10))
    with pytest.raises(TrajectoryWireError, match='message ends inside points'):
        decode_joint_trajectory(data[:300], 100)
    with pytest.raises(TrajectoryWireError, match='10 points: more than max_points = 9'):
        decode_joint_trajectory(data, 9)
    with pytest.raises(TrajectoryWireError, match='not a little-endian CDR message'):
        decode_joint_trajectory(b'\x00\x00' + data[2:], 100)
    with pytest.raises(TrajectoryWireError, match='message ends inside'):
        decode_joint_trajectory(data[:30], 100)


def test_a_hundred_thousand_points_decode_as_arrays() -> None:
    """The probe of issue 21 (a 100 000-point trajectory): decoded whole, equal to rclpy's
    (the time this takes is benchmarks/faults.py's business, not a unit test's)."""
    msg = six(3)
    msg.points = msg.points * 33_334
    data = serialize_message(msg)
    decoded = decode_joint_trajectory(data, 200_000)
    assert decoded.positions.shape == (100_002, 6)
    np.testing.assert_array_equal(decoded.positions[-1], list(msg.points[-1].positions))


def _keys_on_both_ends(times: list[float]) -> tuple[str, str]:
    """The key the positioner makes of its trajectory and the one the drives make of what
    they decode from the wire (positioning_cell.moves.fingerprint)."""
    from positioning_cell.moves.fingerprint import fingerprint
    from positioning_cell.ros.messages import duration

    positions = np.tile([0.2, 0.2, 0.2, 0.0, 0.0, 0.0], (len(times), 1))
    msg = JointTrajectory(joint_names=[f'j{k}' for k in range(6)], points=[
        JointTrajectoryPoint(positions=row.tolist(), time_from_start=duration(t))
        for row, t in zip(positions, times, strict=True)])
    wire = decode_joint_trajectory(serialize_message(msg), 10_000)
    return fingerprint(times, positions), fingerprint(wire.times, wire.positions)


def test_a_duration_on_a_half_microsecond_keys_the_same_on_both_ends() -> None:
    """make run aborted a move whose planned duration went over the wire as 1 113 625 500 ns:
    keyed by µs, the two ends rounded it apart and the drives' answer matched nothing."""
    for last in (1.1136255, np.nextafter(1.1136255, 0.0), np.nextafter(1.1136255, 2.0),
                 0.0000005, 2.0000015):
        sent, received = _keys_on_both_ends([0.0, 0.01, float(last)])
        assert sent == received, last


@given(st.lists(st.floats(0.0, 1e4, allow_nan=False), min_size=1, max_size=8))
def test_any_times_key_the_same_on_both_ends(times: list[float]) -> None:
    sent, received = _keys_on_both_ends(sorted(times))
    assert sent == received
