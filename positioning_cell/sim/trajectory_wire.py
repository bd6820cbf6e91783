"""The drives' command as it arrives: a ``trajectory_msgs/msg/JointTrajectory`` decoded from its
serialized (CDR) bytes into arrays in time linear in its size, with the work bounded before
it starts (a points count above the limit is refused after reading 4 bytes of it).

rclpy turns a message into Python objects point by point: 0.73 s for 100 000 points on this
machine, during which the driver's timer publishes nothing. This decoder reads the header and
the joint names field by field (a handful), then every point at once with numpy: a trajectory
whose points all carry the same number of positions, velocities, accelerations and efforts
(what every controller requires: the same joints at every point) has a point layout that
repeats with a period of one or two points (a non-empty float64 array is aligned to 8 bytes,
so the padding depends on where the point starts modulo 8), and its fields are gathered with
one fancy index each. A point whose counts differ from point 0's is refused, naming it.

The wire format is plain CDR as ROS 2 writes it (:mod:`positioning_cell.bag.cdr`): a 4-byte
encapsulation header (``00 01``: little endian), then the fields in declaration order, each
primitive aligned to its size relative to the byte after the header; a string is a uint32
length counting its NUL, the bytes, the NUL; a sequence a uint32 count, then its elements
(an empty float64 sequence takes no alignment padding). Times in s, positions in the message's
units (m, rad), columns in the message's joint order.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]
_HEADER = 4  # encapsulation bytes; alignment is relative to the byte after them
#: The four float64 sequences of a JointTrajectoryPoint, in wire order.
POINT_FIELDS = ('positions', 'velocities', 'accelerations', 'effort')
#: Most joint names a trajectory may carry (the decoder reads them one by one).
MAX_JOINT_NAMES = 64


class TrajectoryWireError(InputError):
    """Bytes that are not a JointTrajectory this decoder accepts (the message says where)."""


class WireTrajectory(NamedTuple):
    """A decoded JointTrajectory: ``stamp`` (sec, nanosec) of its header, its ``joint_names``,
    per point its ``times`` (N,) s (time_from_start) and its ``positions`` (N, P),
    ``velocities`` (N, V) and ``accelerations`` (N, A) (V, A: 0 or the joint count, as sent)."""

    stamp: tuple[int, int]
    joint_names: list[str]
    times: FloatArray
    positions: FloatArray
    velocities: FloatArray
    accelerations: FloatArray

    @property
    def stamp_is_zero(self) -> bool:
        """A zero header stamp: start on receipt (the ROS convention)."""
        return self.stamp == (0, 0)


def _align(offset: int, size: int) -> int:
    return (offset + size - 1) // size * size


class _Cursor:
    """Sequential reads of the payload (offsets relative to the byte after the header)."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.size = len(data) - _HEADER
        self.at = 0

    def need(self, count: int, what: str) -> None:
        if self.at + count > self.size:
            raise TrajectoryWireError(f'message ends inside {what} ({len(self.data)} bytes)')

    def u32(self, what: str) -> int:
        self.at = _align(self.at, 4)
        self.need(4, what)
        value = int.from_bytes(self.data[_HEADER + self.at:_HEADER + self.at + 4], 'little')
        self.at += 4
        return value

    def i32(self, what: str) -> int:
        value = self.u32(what)
        return value - (1 << 32) if value >= 1 << 31 else value

    def string(self, what: str) -> str:
        length = self.u32(what)
        self.need(length, what)
        raw = self.data[_HEADER + self.at:_HEADER + self.at + length]
        if length == 0 or raw[-1] != 0:
            raise TrajectoryWireError(f'{what} is not a NUL-terminated string')
        self.at += length
        try:
            return raw[:-1].decode('utf-8')
        except UnicodeDecodeError as err:
            raise TrajectoryWireError(f'{what} is not UTF-8') from err


class _Layout(NamedTuple):
    """Where a point's fields lie relative to its start, for a start at ``phase`` (mod 8):
    the count and the data offset of each float64 sequence, the time_from_start offset, and
    the point's length."""

    counts: tuple[int, ...]
    count_offsets: tuple[int, ...]
    data_offsets: tuple[int, ...]
    time_offset: int
    length: int


def _layout(phase: int, counts: tuple[int, ...]) -> _Layout:
    at = phase
    count_offsets, data_offsets = [], []
    for n in counts:
        at = _align(at, 4)
        count_offsets.append(at - phase)
        at += 4
        if n:
            at = _align(at, 8)
        data_offsets.append(at - phase)
        at += 8 * n
    at = _align(at, 4)
    time_offset = at - phase
    return _Layout(counts, tuple(count_offsets), tuple(data_offsets), time_offset,
                   at + 8 - phase)


def _rows(payload: NDArray[np.uint8], first: int, count: int, stride: int,
          width: int) -> NDArray[np.uint8]:
    """``count`` rows of ``width`` bytes starting at ``first``, ``first + stride``, ... (a
    read-only view; the caller has checked they lie inside ``payload``)."""
    if count == 0:
        return np.empty((0, width), dtype=np.uint8)
    view: NDArray[np.uint8] = np.lib.stride_tricks.as_strided(
        payload[first:], shape=(count, width), strides=(stride, 1), writeable=False)
    return view


def _read_to_points(data: bytes) -> tuple[_Cursor, tuple[int, int], list[str], int]:
    """The header, the joint names and the points count; the cursor after the count."""
    if len(data) < _HEADER + 4 or data[0:2] != b'\x00\x01':
        raise TrajectoryWireError('not a little-endian CDR message (encapsulation '
                                  f'{data[0:2].hex() or "missing"})')
    cur = _Cursor(data)
    stamp = (cur.i32('header.stamp.sec'), cur.u32('header.stamp.nanosec'))
    cur.string('header.frame_id')
    count = cur.u32('joint_names')
    if count > MAX_JOINT_NAMES:
        raise TrajectoryWireError(f'{count} joint names (at most {MAX_JOINT_NAMES})')
    names = [cur.string(f'joint_names[{k}]') for k in range(count)]
    return cur, stamp, names, cur.u32('points')


class Peek(NamedTuple):
    """What a serialized JointTrajectory says before its points: its header ``stamp`` (sec,
    nanosec) and its number of ``points`` (0: the empty trajectory, a stop)."""

    stamp: tuple[int, int]
    points: int


def peek(data: bytes) -> Peek:
    """The stamp and the points count of a serialized JointTrajectory, read without its
    points (microseconds whatever its size); TrajectoryWireError as
    :func:`decode_joint_trajectory`."""
    _, stamp, _, points = _read_to_points(data)
    return Peek(stamp, points)


def decode_joint_trajectory(data: bytes, max_points: int) -> WireTrajectory:
    """Decode a serialized JointTrajectory (module docstring); TrajectoryWireError naming what
    is wrong: not little-endian CDR, truncated, more than ``max_points`` points (refused before
    they are read), or a point whose counts differ from point 0's."""
    cur, stamp, names, n = _read_to_points(data)
    if n > max_points:
        raise TrajectoryWireError(f'{n} points: more than max_points = {max_points}')
    if n == 0:
        empty = np.empty((0, 0))
        return WireTrajectory(stamp, names, np.empty(0), empty, empty, empty)
    start = _align(cur.at, 4)
    counts = _point_counts(cur)
    payload = np.frombuffer(data, dtype=np.uint8, offset=_HEADER)
    runs = _runs(start, n, counts, cur.size)
    _check_points(payload, runs, counts, n)
    values = []
    for index, width in enumerate(counts[:3]):
        out = np.empty((n, width))
        for run in runs:
            raw = _rows(payload, run.origin + run.layout.data_offsets[index], run.rows,
                        run.stride, 8 * width)
            out[run.points] = raw.copy().view('<f8')
        values.append(out)
    times = np.empty(n)
    for run in runs:
        raw = _rows(payload, run.origin + run.layout.time_offset, run.rows, run.stride,
                    8).copy()
        seconds = raw[:, :4].copy().view('<i4')[:, 0]
        nanoseconds = raw[:, 4:].copy().view('<u4')[:, 0]
        times[run.points] = seconds + nanoseconds * 1e-9
    return WireTrajectory(stamp, names, times, *values)


class _Run(NamedTuple):
    """Points laid out alike at equal spacing: the first at ``origin``, ``rows`` of them
    ``stride`` bytes apart (``inside`` of them within the message), which points they are
    (``points``: a slice of the point index) and their ``layout``."""

    origin: int
    rows: int
    inside: int
    stride: int
    points: slice
    layout: _Layout


def _runs(start: int, n: int, counts: tuple[int, ...], size: int) -> list[_Run]:
    """The points of a trajectory whose points all have ``counts``, as runs. A point's layout
    depends only on where it starts modulo 8 (0 or 4), so the phases of the points follow
    φ_k+1 = φ_k + length(φ_k) mod 8: constant, alternating, or point 0 alone and then
    constant."""
    first = _layout(start % 8, counts)
    second = _layout((start + first.length) % 8, counts)
    third_phase = (start + first.length + second.length) % 8
    if second.length == first.length and (start + first.length) % 8 == start % 8:
        shapes = [(start, n, first.length, slice(0, n, 1), first)]
    elif third_phase == start % 8:
        period = first.length + second.length
        shapes = [(start, (n + 1) // 2, period, slice(0, n, 2), first),
                  (start + first.length, n // 2, period, slice(1, n, 2), second)]
    else:
        shapes = [(start, 1, first.length, slice(0, 1, 1), first),
                  (start + first.length, n - 1, second.length, slice(1, n, 1), second)]
    return [_Run(origin, rows, max(0, min(rows, (size - origin - layout.length) // stride + 1)),
                 stride, points, layout)
            for origin, rows, stride, points, layout in shapes]


def _point_counts(cur: _Cursor) -> tuple[int, ...]:
    """Walk point 0 (checking it fits), returning its four counts."""
    counts = []
    for field in POINT_FIELDS:
        c = cur.u32(f'points[0].{field}')
        if c:
            cur.at = _align(cur.at, 8)
            cur.need(8 * c, f'points[0].{field}')
            cur.at += 8 * c
        counts.append(c)
    cur.i32('points[0].time_from_start.sec')
    cur.u32('points[0].time_from_start.nanosec')
    return tuple(counts)


def _check_points(payload: NDArray[np.uint8], runs: list[_Run], counts: tuple[int, ...],
                  n: int) -> None:
    """Refuse the first point whose counts differ from point 0's, or that runs past the end
    of the message. (A point that differs shifts every later one, so only the first
    difference is real, and within it the first field that differs.)"""
    first_bad, what = n, ''
    for run in runs:
        step = run.points.step or 1
        for index, offset in enumerate(run.layout.count_offsets):
            got = _rows(payload, run.origin + offset, run.inside, run.stride,
                        4).copy().view('<u4')[:, 0]
            wrong = np.flatnonzero(got != counts[index])
            k = run.points.start + step * int(wrong[0]) if wrong.size else n
            if k < first_bad:
                first_bad = k
                what = (f'point {k} has {int(got[wrong[0]])} {POINT_FIELDS[index]}, '
                        f'point 0 has {counts[index]}: every point must carry the same fields')
        k = run.points.start + step * run.inside
        if run.inside < run.rows and k < first_bad:
            first_bad, what = k, f'message ends inside points[{k}]'
    if what:
        raise TrajectoryWireError(what)
