"""Vectorised decoding of messages with sequences (positioning_cell.bag.cdr_sequences): every
numeric field of every message as rosbags decodes it, whatever mix of layouts (joint names,
sequence lengths, frame ids) the messages come in; what it cannot follow is left to the
caller, never decoded wrong. And the analysis's joint states read that way equal those read
message by message through rosbags. No ROS graph."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_array_equal
from rosbags.typesys import Stores, get_typestore

from positioning_cell.analysis.reading import _joint_block, joint_samples
from positioning_cell.bag import BagReader, IndexedBag
from positioning_cell.bag.cdr_sequences import (
    MAX_LAYOUTS,
    LayoutError,
    decode_by_layout,
    diagnostic_array,
    layout,
    trajectory_end,
)
from positioning_cell.names import JOINT_STATES

STORE = get_typestore(Stores.ROS2_JAZZY)
T = STORE.types
JOINT_STATE = 'sensor_msgs/msg/JointState'
TRAJECTORY = 'trajectory_msgs/msg/JointTrajectory'
MAKE_RUN = Path(__file__).resolve().parent / 'data' / 'makerun' / 'bag'


def _joint_state(rng: np.random.Generator, names: list[str], frame: str, velocity: bool
                 ) -> bytes:
    n = len(names)
    msg = T[JOINT_STATE](
        header=T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](
            int(rng.integers(0, 2**31)), int(rng.integers(0, 10**9))), frame_id=frame),
        name=names, position=rng.normal(size=n),
        velocity=rng.normal(size=n) if velocity else np.empty(0),
        effort=np.empty(0))
    return bytes(STORE.serialize_cdr(msg, JOINT_STATE))


def _pack(payloads: list[bytes]) -> tuple[Any, Any, Any]:
    """The payloads in one buffer with 0..3 bytes between them: buffer, offsets, lengths."""
    buffer, offsets = bytearray(), []
    for i, p in enumerate(payloads):
        buffer += bytes(i % 4)
        offsets.append(len(buffer))
        buffer += p
    return (np.frombuffer(bytes(buffer), dtype=np.uint8), np.array(offsets, dtype=np.int64),
            np.array([len(p) for p in payloads], dtype=np.int64))


def _check(msgtype: str, payloads: list[bytes]) -> Any:
    """Every numeric column of every group equals rosbags' decoding of each message; every
    message is in exactly one group or in ``rest``."""
    grouped = decode_by_layout(msgtype, STORE, *_pack(payloads))
    seen = np.concatenate([g.index for g in grouped.groups] + [grouped.rest])
    assert sorted(seen.tolist()) == list(range(len(payloads)))
    for g in grouped.groups:
        for k, i in enumerate(g.index):
            msg = STORE.deserialize_cdr(payloads[int(i)], msgtype)
            assert list(msg.name if msgtype == JOINT_STATE else msg.joint_names) == list(
                g.template.name if msgtype == JOINT_STATE else g.template.joint_names)
            for path, column in g.columns.items():
                value: Any = msg
                for part in path.split('.'):
                    name, _, index = part.partition('[')
                    value = getattr(value, name)
                    if index:
                        value = value[int(index[:-1])]
                assert_array_equal(np.asarray(column[k]), np.asarray(value), err_msg=path)
    return grouped


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.lists(st.tuples(st.integers(0, 7), st.sampled_from(
    ['', 'base', 'platform_frame']), st.booleans()), min_size=1, max_size=60))
def test_every_message_decodes_as_rosbags_decodes_it(seed: int, kinds: list[Any]) -> None:
    rng = np.random.default_rng(seed)
    payloads = [_joint_state(rng, [f'leg{j}' for j in range(n)], frame, velocity)
                for n, frame, velocity in kinds]
    grouped = _check(JOINT_STATE, payloads)
    layouts = len(set(kinds))
    assert len(grouped.groups) == min(layouts, MAX_LAYOUTS)
    assert grouped.rest.size == 0 or layouts > MAX_LAYOUTS


def test_nested_message_sequences_decode_too() -> None:
    """A trajectory: a sequence of messages, each with sequences and a Duration."""
    rng = np.random.default_rng(3)
    point = T['trajectory_msgs/msg/JointTrajectoryPoint']
    payloads = [bytes(STORE.serialize_cdr(T[TRAJECTORY](
        header=T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](5, 6),
                                        frame_id='base'),
        joint_names=['a', 'b', 'c'],
        points=[point(positions=rng.normal(size=3), velocities=np.empty(0),
                      accelerations=np.empty(0), effort=np.empty(0),
                      time_from_start=T['builtin_interfaces/msg/Duration'](k, 7))
                for k in range(n)]), TRAJECTORY)) for n in (1, 2, 2, 1, 3)]
    grouped = _check(TRAJECTORY, payloads)
    assert len(grouped.groups) == 3 and 'points[1].positions' in grouped.groups[1].columns


def test_what_the_walk_cannot_follow_is_left_to_the_caller() -> None:
    """Big-endian CDR and a payload cut short: not decoded, left in ``rest``."""
    rng = np.random.default_rng(1)
    good = _joint_state(rng, ['a', 'b'], 'base', False)
    big = bytes([0, 0]) + good[2:]
    grouped = decode_by_layout(JOINT_STATE, STORE, *_pack([big, good[:-9], good, big]))
    assert grouped.rest.tolist() == [0, 1, 3]
    assert [g.index.tolist() for g in grouped.groups] == [[2]]
    with pytest.raises(ValueError, match=r'past the end|end at byte'):
        layout(JOINT_STATE, good[:-9], STORE)


def test_a_recorded_runs_joint_states_read_vectorised_equal_rosbags_one_by_one() -> None:
    """The `make run` bag's /legs/joint_states: each block decoded per layout gives every
    stamp and joint position that rosbags' message by message decoding gives."""
    with IndexedBag(MAKE_RUN) as bag:
        parts = [_joint_block(bag, block, JOINT_STATES) for block in bag.blocks([JOINT_STATES])]
    with BagReader(MAKE_RUN) as reader:
        reference = joint_samples([m.message for m in reader.messages([JOINT_STATES])])
    assert reference.count > 1000
    assert_array_equal(np.concatenate([p.stamp for p in parts]), reference.stamp)
    assert_array_equal(np.concatenate([p.position for p in parts]), reference.position)


def _trajectory(rng: np.random.Generator, shapes: list[tuple[int, int, int, int]]) -> bytes:
    point = T['trajectory_msgs/msg/JointTrajectoryPoint']
    return bytes(STORE.serialize_cdr(T[TRAJECTORY](
        header=T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](0, 0),
                                        frame_id=''),
        joint_names=[f'j{k}' for k in range(6)],
        points=[point(*(rng.normal(size=n) for n in shape),
                      time_from_start=T['builtin_interfaces/msg/Duration'](k, 3))
                for k, shape in enumerate(shapes)]), TRAJECTORY))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 300),
       st.tuples(st.integers(0, 7), st.integers(0, 7), st.integers(0, 2), st.integers(0, 1)),
       st.booleans())
def test_a_trajectorys_last_point_is_what_rosbags_decodes(
        seed: int, points: int, shape: tuple[int, int, int, int], uneven: bool) -> None:
    """Points of one shape: read at the last point's offset, equal to rosbags' (bit for
    bit); of mixed shapes or sizes that leave the alignment varying: refused (LayoutError),
    never misread."""
    rng = np.random.default_rng(seed)
    shapes = [shape] * points
    if uneven and points > 2:
        shapes[points // 2] = (shape[0] + 1, *shape[1:])
    data = _trajectory(rng, shapes)
    msg = STORE.deserialize_cdr(data, TRAJECTORY)
    try:
        names, last = trajectory_end(data, STORE)
    except LayoutError:
        assert (uneven and points > 2) or points > 1  # a stride that is no multiple of 8
        return
    assert names == tuple(msg.joint_names)
    if points == 0:
        assert last is None
    else:
        assert not (uneven and points > 2)
        assert_array_equal(last, msg.points[-1].positions)


def test_the_cells_trajectories_are_read_without_rosbags() -> None:
    """Six joints, positions and velocities (what the positioner sends): one stride."""
    rng = np.random.default_rng(5)
    for points in (1, 2, 231):
        data = _trajectory(rng, [(6, 6, 0, 0)] * points)
        names, last = trajectory_end(data, STORE)
        assert last is not None and names == tuple(f'j{k}' for k in range(6))
        assert_array_equal(last, STORE.deserialize_cdr(data, TRAJECTORY).points[-1].positions)


def _as_plain(message: Any) -> Any:
    """A DiagnosticArray (rosbags' or ours) as nested tuples of its fields."""
    return ((message.header.stamp.sec, message.header.stamp.nanosec, message.header.frame_id),
            [(s.level, s.name, s.message, s.hardware_id, [(v.key, v.value) for v in s.values])
             for s in message.status])


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), st.text(max_size=12), st.text(max_size=30),
                          st.lists(st.tuples(st.text(max_size=9), st.text(max_size=20)),
                                   max_size=6)), max_size=4),
       st.text(max_size=7), st.integers(0, 2**31 - 1), st.integers(0, 10**9 - 1))
def test_a_diagnostic_array_reads_as_rosbags_decodes_it(
        statuses: list[Any], frame: str, sec: int, nanosec: int) -> None:
    """Any statuses, names and values (unicode, empty), every string boundary alignment."""
    msg = T['diagnostic_msgs/msg/DiagnosticArray'](
        header=T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec, nanosec),
                                        frame_id=frame),
        status=[T['diagnostic_msgs/msg/DiagnosticStatus'](
            level=level, name=name, message=text, hardware_id='cell',
            values=[T['diagnostic_msgs/msg/KeyValue'](k, v) for k, v in values])
            for level, name, text, values in statuses])
    data = bytes(STORE.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticArray'))
    assert _as_plain(diagnostic_array(data)) == _as_plain(
        STORE.deserialize_cdr(data, 'diagnostic_msgs/msg/DiagnosticArray'))
    with pytest.raises(LayoutError):
        diagnostic_array(data[:-5] if len(data) > 24 else data[:2] + b'\0')
