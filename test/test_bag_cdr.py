"""Vectorised CDR decoding (positioning_cell.bag.cdr) against rosbags' deserialiser: messages
of every fixed-layout type the analysis reads, with hypothesis drawing the field values (NaN,
inf, extreme integers, empty / long / unicode strings), serialised by rosbags and packed at
arbitrary offsets of one buffer, decode to exactly what ``typestore.deserialize_cdr`` gives
(bit for bit for floats); types with sequences are refused; damaged messages (truncated, wrong
encapsulation, over-long string length, missing NUL, trailing bytes, invalid UTF-8) raise a
CdrError naming the type, the topic and the message."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.interfaces import Nodetype
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from positioning_cell.bag.cdr import (
    CdrError,
    Columns,
    NotFixedLayoutError,
    Strings,
    compile_plan,
    decode,
    fixed_layout_plan,
)
from positioning_cell.errors import PositioningError

TYPES = (
    'geometry_msgs/msg/PoseStamped', 'geometry_msgs/msg/PoseWithCovarianceStamped',
    'geometry_msgs/msg/Vector3Stamped', 'geometry_msgs/msg/TransformStamped',
    'geometry_msgs/msg/PointStamped', 'geometry_msgs/msg/QuaternionStamped',
    'geometry_msgs/msg/TwistStamped', 'std_msgs/msg/String', 'std_msgs/msg/Header',
    'builtin_interfaces/msg/Time', 'std_msgs/msg/Float64', 'std_msgs/msg/Int32',
    'std_msgs/msg/Bool', 'std_msgs/msg/Float32', 'std_msgs/msg/Byte', 'std_msgs/msg/Char',
    'std_msgs/msg/UInt64', 'sensor_msgs/msg/Temperature',
)
INTS = {'byte': (-128, 127), 'char': (0, 255), 'int8': (-128, 127), 'uint8': (0, 255),
        'int16': (-2**15, 2**15 - 1), 'uint16': (0, 2**16 - 1), 'int32': (-2**31, 2**31 - 1),
        'uint32': (0, 2**32 - 1), 'int64': (-2**63, 2**63 - 1), 'uint64': (0, 2**64 - 1)}
TEXT = st.one_of(
    st.text(st.characters(blacklist_categories=('Cs',)), max_size=12),
    st.sampled_from(['', 'base', 'tool0', 'ünïcødé 🛰', 'a\x00b']),
    st.text(st.characters(blacklist_categories=('Cs',)), min_size=100, max_size=300))


@functools.cache
def jazzy() -> Typestore:
    return get_typestore(Stores.ROS2_JAZZY)


def _value(base: str) -> st.SearchStrategy[Any]:
    if base == 'string':
        return TEXT
    if base == 'bool':
        return st.booleans()
    if base == 'float64':
        return st.floats(allow_nan=True, allow_infinity=True)
    if base == 'float32':
        return st.floats(allow_nan=True, allow_infinity=True, width=32)
    lo, hi = INTS[base]
    return st.integers(lo, hi)


def _message(msgtype: str, store: Typestore) -> st.SearchStrategy[Any]:
    """Messages of ``msgtype`` (a rosbags object) with every field drawn."""
    parts: list[st.SearchStrategy[Any]] = []
    for _, desc in store.fielddefs[msgtype][1]:
        if desc[0] == Nodetype.NAME:
            parts.append(_message(desc[1], store))
        elif desc[0] == Nodetype.BASE:
            parts.append(_value(desc[1][0]))
        else:
            (_, (base, _)), length = desc[1]
            dtype = {'float64': np.float64, 'float32': np.float32}.get(base, np.int64)
            parts.append(st.lists(_value(base), min_size=length, max_size=length).map(
                lambda v, d=dtype: np.array(v, dtype=d)))
    return st.tuples(*parts).map(lambda values: store.types[msgtype](*values))


def _pack(raws: list[bytes], gaps: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The messages one after the other in one buffer, each after ``gaps[i]`` junk bytes (so
    that no message starts aligned): buffer, offsets, lengths."""
    data = bytearray()
    offsets = []
    for raw, gap in zip(raws, gaps, strict=True):
        data += b'\xa5' * gap
        offsets.append(len(data))
        data += raw
    return (np.frombuffer(bytes(data), dtype=np.uint8), np.array(offsets, dtype=np.int64),
            np.array([len(r) for r in raws], dtype=np.int64))


def _field(message: Any, path: str) -> Any:
    for name in path.split('.'):
        message = getattr(message, name)
    return message


def _same(expected: Any, got: Any, base: str) -> bool:
    """Exactly equal: floats bit for bit (float32 via the float32 rosbags read, NaN as NaN)."""
    if base == 'float32':
        want = np.asarray(expected, dtype=np.float32)
        return bool(np.all((want == got) | (np.isnan(want) & np.isnan(got))))
    if base == 'float64':
        return np.asarray(expected, dtype=np.float64).tobytes() == np.asarray(got).tobytes()
    return bool(np.all(np.asarray(expected) == np.asarray(got)))


def _check(msgtype: str, store: Typestore, messages: list[Any], gaps: list[int]) -> Columns:
    raws = [bytes(store.serialize_cdr(m, msgtype)) for m in messages]
    buffer, offsets, lengths = _pack(raws, gaps)
    plan = compile_plan(msgtype, store)
    columns = decode(plan, buffer, offsets, lengths, topic='/t')
    assert columns.count == len(messages)
    assert list(columns.fields) == [f.path for f in plan.fields]
    for i, raw in enumerate(raws):
        expected = store.deserialize_cdr(raw, msgtype)
        for f in plan.fields:
            column = columns[f.path]
            if f.is_string:
                assert isinstance(column, Strings)
                assert column.values[column.codes[i]] == _field(expected, f.path), f.path
            else:
                assert isinstance(column, np.ndarray)
                assert column.shape == ((len(messages), f.count) if f.count
                                        else (len(messages),)), f.path
                assert _same(_field(expected, f.path), column[i], f.base), (f.path, i)
    return columns


@pytest.mark.parametrize('msgtype', TYPES)
@settings(max_examples=8)
@given(data=st.data())
def test_decoding_equals_rosbags(msgtype: str, data: st.DataObject) -> None:
    store = jazzy()
    messages = data.draw(st.lists(_message(msgtype, store), min_size=1, max_size=4))
    gaps = data.draw(st.lists(st.integers(0, 9), min_size=len(messages),
                              max_size=len(messages)))
    _check(msgtype, store, messages, gaps)


def test_many_messages_one_frame_id_and_categories() -> None:
    """Hundreds of messages: a repeated frame id is one category; distinct strings of equal
    and different lengths each get theirs; the categorical concatenates across blocks."""
    store = jazzy()
    T = store.types
    names = ['base', 'tool', 'base', 'user', 'b', '', 'tool'] * 40
    messages = [T['geometry_msgs/msg/PointStamped'](T['std_msgs/msg/Header'](
        T['builtin_interfaces/msg/Time'](i, 7 * i), name), T['geometry_msgs/msg/Point'](
        i * 0.25, -1.0, math.nan)) for i, name in enumerate(names)]
    columns = _check('geometry_msgs/msg/PointStamped', store, messages, [i % 5 for i in
                                                                       range(len(names))])
    frames = columns.strings('header.frame_id')
    assert sorted(frames.values) == ['', 'b', 'base', 'tool', 'user']
    assert frames.tolist() == names
    same = columns.strings('header.frame_id')
    assert len(set(same.codes[[0, 2]].tolist())) == 1
    both = Columns.concatenate([columns, columns])
    assert both.count == 2 * len(names)
    assert both.strings('header.frame_id').tolist() == names + names
    np.testing.assert_array_equal(both.array('point.x')[len(names):], columns.array('point.x'))
    with pytest.raises(TypeError):
        columns.array('header.frame_id')


def test_no_message_gives_empty_columns() -> None:
    plan = compile_plan('geometry_msgs/msg/PoseWithCovarianceStamped', jazzy())
    columns = decode(plan, np.zeros(0, np.uint8), [], [])
    assert columns.count == 0
    assert columns.array('pose.covariance').shape == (0, 36)
    assert columns.array('header.stamp.sec').dtype == np.int32
    assert columns.strings('header.frame_id').values == ()


def test_types_with_sequences_are_refused() -> None:
    store = jazzy()
    for msgtype, field in [('sensor_msgs/msg/JointState', 'name'),
                           ('diagnostic_msgs/msg/DiagnosticArray', 'status'),
                           ('sensor_msgs/msg/PointCloud2', 'fields')]:
        with pytest.raises(NotFixedLayoutError, match=f'field {field} is a sequence') as err:
            compile_plan(msgtype, store)
        assert err.value.field == field
        assert isinstance(err.value, PositioningError)
        assert fixed_layout_plan(msgtype, store) is None
    custom = get_typestore(Stores.ROS2_JAZZY)
    custom.register(get_types_from_msg('string[2] names', 'test_msgs/msg/Names'))
    custom.register(get_types_from_msg('geometry_msgs/Point[3] corners',
                                       'test_msgs/msg/Corners'))
    custom.register(get_types_from_msg('float64[<=3] bounded', 'test_msgs/msg/Bounded'))
    with pytest.raises(NotFixedLayoutError, match='names is an array of string'):
        compile_plan('test_msgs/msg/Names', custom)
    with pytest.raises(NotFixedLayoutError, match='corners is an array of geometry_msgs'):
        compile_plan('test_msgs/msg/Corners', custom)
    with pytest.raises(NotFixedLayoutError, match='bounded is a sequence'):
        compile_plan('test_msgs/msg/Bounded', custom)
    with pytest.raises(NotFixedLayoutError, match='unknown to the typestore'):
        compile_plan('no_msgs/msg/Such', custom)


def _pose_raws(n: int = 3) -> list[bytes]:
    store = jazzy()
    T = store.types
    return [bytes(store.serialize_cdr(T['geometry_msgs/msg/PoseStamped'](
        T['std_msgs/msg/Header'](T['builtin_interfaces/msg/Time'](i, 0), 'base'),
        T['geometry_msgs/msg/Pose'](T['geometry_msgs/msg/Point'](1.0, 2.0, 3.0),
                                    T['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0, 1.0))),
        'geometry_msgs/msg/PoseStamped')) for i in range(n)]


def _decode_damaged(raws: list[bytes]) -> Columns:
    buffer, offsets, lengths = _pack(raws, [3] * len(raws))
    plan = compile_plan('geometry_msgs/msg/PoseStamped', jazzy())
    return decode(plan, buffer, offsets, lengths, topic='/positioner/target')


def _rosbags_refuses(raw: bytes) -> None:
    with pytest.raises(SerdeError):
        jazzy().deserialize_cdr(raw, 'geometry_msgs/msg/PoseStamped')


@pytest.mark.parametrize(('damage', 'message'), [
    (lambda r: r[:-1], r'message 1: pose.position.x .. pose.orientation.w at byte 28 runs '
                       r'past the end of the message \(83 bytes\)'),
    (lambda r: r[:18], r'message 1: header.frame_id: string length 5 runs past the end of the '
                       r'message \(18 bytes\)'),
    (lambda r: r[:14], r'message 1: header.frame_id \(string length\) at byte 12 runs past '
                       r'the end of the message \(14 bytes\)'),
    (lambda r: b'\x00\x00' + r[2:], r'message 1: big-endian CDR'),
    (lambda r: b'\x00\x07' + r[2:], r'message 1: encapsulation 0x0007 is not CDR little '
                                    r'endian'),
    (lambda r: r[:12] + (10**6).to_bytes(4, 'little') + r[16:],
     r'message 1: header.frame_id: string length 1000000 runs past the end'),
    (lambda r: r[:12] + (0).to_bytes(4, 'little') + r[16:], r'string length 0'),
    (lambda r: r[:20] + b'x' + r[21:], r'header.frame_id: string without its NUL terminator'),
    (lambda r: r + b'\x00' * 4, r'message 1: 4 bytes after the last field'),
    (lambda r: r[:16] + b'\xff\xfe\xfd\xfc' + r[20:], r'header.frame_id: not UTF-8'),
    (lambda r: r[:3], r'message 1: shorter \(3 bytes\) than the CDR encapsulation header'),
])
def test_damaged_messages_are_named(damage: Any, message: str) -> None:
    raws = _pose_raws()
    raws[1] = damage(raws[1])
    if len(raws[1]) >= 4 and raws[1][:2] == b'\x00\x01':
        _rosbags_refuses(raws[1])  # rosbags refuses it too
    with pytest.raises(CdrError, match=message) as err:
        _decode_damaged(raws)
    assert err.value.index == 1
    assert err.value.msgtype == 'geometry_msgs/msg/PoseStamped'
    assert str(err.value).startswith('/positioner/target (geometry_msgs/msg/PoseStamped): ')


def test_trailing_padding_up_to_three_bytes() -> None:
    """rmw pads a payload to 4 bytes; rosbags accepts up to 3 bytes after the last field."""
    raws = _pose_raws()
    for pad in range(4):
        padded = [r + b'\x00' * pad for r in raws]
        jazzy().deserialize_cdr(padded[0], 'geometry_msgs/msg/PoseStamped')
        columns = _decode_damaged(padded)
        assert columns.array('header.stamp.sec').tolist() == [0, 1, 2]


def test_messages_outside_the_buffer_are_refused() -> None:
    raw = _pose_raws(1)[0]
    buffer = np.frombuffer(raw, dtype=np.uint8)
    plan = compile_plan('geometry_msgs/msg/PoseStamped', jazzy())
    with pytest.raises(CdrError, match='message 0: outside the buffer'):
        decode(plan, buffer, [1], [len(raw)])
    with pytest.raises(ValueError, match='differ in shape'):
        decode(plan, buffer, [0, 0], [len(raw)])
