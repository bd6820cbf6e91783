"""Reading a recorded bag for analysis: the messages of the topics the analysis uses, in
recorded order, as :class:`positioning_cell.analysis.replay.MessageBatch` es of arrays, in
bounded memory; also from a bag whose recording did not end cleanly or whose files are damaged.
This is the one place that reads bags for the analysis.

An MCAP bag is read by :class:`positioning_cell.bag.IndexedBag`, whatever its layout: a file
whose summary has chunk and message indexes (the cell's recorder, rosbags, ``ros2 bag record``
by default) through them, only the chunks and records of the wanted topics parsed; any other
valid file (no summary, no chunk index, no message index: unchunked files as rosbag2's
``fastwrite`` preset writes them, for one) from one sequential scan of its records when it is
opened, then the same way. Each chunk read is checked against its CRC and every message used
against its index record (or the scan's), the whole data section against its CRC (a CRC of 0
is "not computed" and not checked), and the fixed-layout messages (poses, strings) are decoded
as arrays (:mod:`positioning_cell.bag.cdr`); diagnostics are decoded by rosbags, only those
holding the positioner's or the tracker's status. A bag that cannot be read as it is (a file
without footer: the recorder was killed; a corrupt chunk; a data-section CRC mismatch; broken
record framing), whether on opening or half way through, is verified whole
(:func:`positioning_cell.bag.verify_bag`), its sound chunks linked into a temporary folder and
repaired there (:func:`positioning_cell.bag.recover_bag`; the original is left as it is), and
the analysis runs again from the start on the repaired copy; :attr:`Recording.problems` then
names each corrupt chunk with the time range lost (UTC and seconds into the bag) and the
messages lost when the index says. A bag that is not MCAP (rosbag2 sqlite3) is read by rosbags
(:class:`positioning_cell.bag.BagReader`), decoded message by message and batched the same way.
"""

from __future__ import annotations

import math
import os
import shutil
import struct
import tempfile
from collections.abc import Callable, Collection, Iterator, Sequence
from contextlib import suppress
from dataclasses import dataclass, replace
from itertools import islice
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from positioning_cell.accuracy.monitor import PoseMessages
from positioning_cell.accuracy.settle import stamp_seconds
from positioning_cell.analysis.replay import JointSamples, MessageBatch
from positioning_cell.bag import (
    BagError,
    BagMessage,
    BagReader,
    FileCheck,
    FileRecovery,
    recover_bag,
)
from positioning_cell.bag.cdr import Columns, Strings
from positioning_cell.bag.cdr_sequences import (
    LayoutError,
    decode_by_layout,
    diagnostic_array,
    trajectory_end,
)
from positioning_cell.bag.indexed import Block, IndexedBag, IndexedReadError
from positioning_cell.bag.opening import mcap_files
from positioning_cell.bag.verify import BagCheck, storage_files, verify_bag
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.names import (
    AXIS_TEST,
    CALIBRATION,
    COMPLIANCE_TEST,
    DIAGNOSTICS,
    JOINT_STATES,
    JOINT_TRAJECTORY,
    MEASURED_POSE,
    PROGRAM,
    STATUS_MEASUREMENT,
    STATUS_POSITIONER,
    TARGET,
    TRACKER_REGISTRATION,
    TRUE_POSE,
)

T = TypeVar('T')
FloatArray = NDArray[np.float64]

#: The pose topics and the MessageBatch field each fills.
POSE_TOPICS = {TARGET: 'targets', MEASURED_POSE: 'measured', TRUE_POSE: 'truth',
               TRACKER_REGISTRATION: 'registrations'}
#: The text topics (std_msgs/String) and their MessageBatch field.
TEXT_TOPICS = {PROGRAM: 'program', CALIBRATION: 'calibration', AXIS_TEST: 'axis_test',
               COMPLIANCE_TEST: 'compliance_test'}
#: A /diagnostics message is decoded only when it holds one of these statuses: their names
#: as CDR strings (length, bytes, NUL), so that a text that only mentions a name (the
#: positioner's inputs status names /pose_measurement) does not count (either byte order).
DIAGNOSTIC_STATUSES = tuple(struct.pack(order, len(name) + 1) + name.encode() + b'\0'
                            for name in (STATUS_POSITIONER, STATUS_MEASUREMENT)
                            for order in ('<I', '>I'))
DIAGNOSTIC_ARRAY = 'diagnostic_msgs/msg/DiagnosticArray'
#: Messages per batch where a bag is read message by message (not MCAP).
MESSAGES_PER_BATCH = 20_000


@dataclass(frozen=True)
class Recording:
    """A bag open for analysis: every topic with its ROS type and message count, the total
    message count, the log times (ns) of its first and last message (0 for an empty bag), the
    problems found (empty for a sound bag), the verification of its storage files (None when
    not verified whole: a sound bag read through its index, or not MCAP), and :meth:`batches`:
    the wanted messages in recorded order (each call reads the bag again)."""

    path: Path
    topics: dict[str, tuple[str, int]]
    message_count: int
    start_ns: int
    end_ns: int
    problems: tuple[str, ...]
    check: BagCheck | None
    read: Callable[[], Iterator[MessageBatch]]

    def batches(self) -> Iterator[MessageBatch]:
        """The wanted messages, batch by batch, in recorded order."""
        return self.read()


def _pose_rows(columns: Columns, rank: NDArray[np.intp]) -> PoseMessages:
    """A PoseStamped or PoseWithCovarianceStamped column set as rows (the stamp as
    :func:`stamp_seconds` makes it)."""
    pose = 'pose.pose' if 'pose.pose.position.x' in columns.fields else 'pose'
    frame = columns['header.frame_id']
    assert isinstance(frame, Strings)
    stamp = (columns.array('header.stamp.sec').astype(float)
             + columns.array('header.stamp.nanosec').astype(float) * 1e-9)
    position = np.column_stack([columns.array(f'{pose}.position.{a}') for a in 'xyz'])
    quaternion = np.column_stack([columns.array(f'{pose}.orientation.{a}') for a in 'xyzw'])
    covariance = (columns.array('pose.covariance').astype(float).reshape(-1, 6, 6)
                  if pose == 'pose.pose' else None)
    return PoseMessages(rank, stamp, np.array(frame.values, dtype=object)[frame.codes],
                        position.astype(float), quaternion.astype(float), covariance)


def joint_values(names: Sequence[str], values: Sequence[float]) -> FloatArray:
    """Joint values (6,) in JOINT_NAMES order from a message's names and values (NaN for a
    joint it lacks)."""
    found = dict(zip(names, values, strict=False))
    return np.array([float(found.get(n, math.nan)) for n in JOINT_NAMES])


def joint_samples(messages: Sequence[Any]) -> JointSamples:
    """Decoded JointState messages (rosbags objects) as :class:`JointSamples`, one by one:
    the reading of a bag read message by message, and the reference of :func:`_joint_block`."""
    stamps = np.array([stamp_seconds(m.header.stamp.sec, m.header.stamp.nanosec)
                       for m in messages], dtype=float)
    values = np.array([joint_values(list(m.name), list(m.position)) for m in messages],
                      dtype=float).reshape(-1, 6)
    return JointSamples(stamps, values)


def _joint_block(bag: IndexedBag, block: Block, topic: str) -> JointSamples:
    """A block's JointState messages as :class:`JointSamples`, decoded vectorised per layout
    (:func:`positioning_cell.bag.cdr_sequences.decode_by_layout`; the joints named as in each
    layout's template), those of no layout one by one."""
    m = block.topics[topic]
    grouped = decode_by_layout(m.msgtype, bag.typestore, block.buffer, m.offsets, m.lengths)
    n = m.offsets.shape[0]
    stamp, position = np.empty(n), np.full((n, 6), math.nan)
    for group in grouped.groups:
        stamp[group.index] = (group.columns['header.stamp.sec'].astype(float)
                              + group.columns['header.stamp.nanosec'].astype(float) * 1e-9)
        names = list(group.template.name)[:group.columns['position'].shape[1]]
        for j, joint in enumerate(JOINT_NAMES):
            if joint in names:
                position[group.index, j] = group.columns['position'][:, names.index(joint)]
    if grouped.rest.size:  # layouts the vectorised decoding left: one by one
        rest = joint_samples([bag.typestore.deserialize_cdr(block.payload(topic, int(i)),
                                                            m.msgtype) for i in grouped.rest])
        stamp[grouped.rest], position[grouped.rest] = rest.stamp, rest.position
    return JointSamples(stamp, position)


def _last_point(message: Any) -> tuple[tuple[str, ...], FloatArray | None]:
    """A decoded JointTrajectory's joint names and its last point's positions (None: no
    point)."""
    return (tuple(message.joint_names), np.asarray(message.points[-1].positions, dtype=float)
            if message.points else None)


def _trajectory_end(store: Any, data: bytes, msgtype: str
                    ) -> tuple[tuple[str, ...], FloatArray | None]:
    """:func:`_last_point` of a JointTrajectory's CDR bytes, without decoding its points
    (:func:`positioning_cell.bag.cdr_sequences.trajectory_end`) where its points share one
    shape, else through rosbags."""
    try:
        return trajectory_end(data, store)
    except LayoutError:
        return _last_point(store.deserialize_cdr(data, msgtype))


def _diagnostic(store: Any, data: bytes, msgtype: str) -> Any:
    """A /diagnostics message decoded: a DiagnosticArray in one pass
    (:func:`positioning_cell.bag.cdr_sequences.diagnostic_array`), else through rosbags."""
    if msgtype == DIAGNOSTIC_ARRAY:
        with suppress(LayoutError):
            return diagnostic_array(data)
    return store.deserialize_cdr(data, msgtype)


def _block_batch(bag: IndexedBag, block: Block, topics: Collection[str]) -> MessageBatch:
    """A block of the indexed read as a MessageBatch."""
    order = block.order
    fields: dict[str, Any] = {}
    for code, name in enumerate(order.names):
        if name not in block.topics or name not in topics:
            continue
        rank = np.flatnonzero(order.topic == code)
        if name in POSE_TOPICS:
            decoded = bag.decode(block, name)
            if decoded.columns is None:
                raise BagError(bag.path, f'{name} is {decoded.msgtype}, not a pose message')
            fields[POSE_TOPICS[name]] = _pose_rows(decoded.columns, rank)
        elif name in TEXT_TOPICS:
            decoded = bag.decode(block, name)
            data = decoded.columns['data'] if decoded.columns is not None else None
            if not isinstance(data, Strings):
                raise BagError(bag.path, f'{name} is {decoded.msgtype}, not std_msgs/String')
            fields[TEXT_TOPICS[name]] = tuple(zip(decoded.log_time_ns.tolist(), data.tolist(),
                                                  strict=True))
        elif name == JOINT_STATES:
            fields['joint_states'] = _joint_block(bag, block, name)
        elif name == JOINT_TRAJECTORY:
            m = block.topics[name]
            fields['trajectories'] = tuple(
                (int(m.log_time_ns[i]), *_trajectory_end(bag.typestore, block.payload(name, i),
                                                         m.msgtype))
                for i in range(m.log_time_ns.shape[0]))  # one per move or correction: few
        elif name == DIAGNOSTICS:
            m = block.topics[name]
            store, msgtype = bag.typestore, m.msgtype
            diagnostics, ranks = [], []
            for i in range(m.log_time_ns.shape[0]):  # few: the statuses that matter only
                raw = block.payload(name, i)
                if any(s in raw for s in DIAGNOSTIC_STATUSES):
                    diagnostics.append((int(m.log_time_ns[i]), _diagnostic(store, raw,
                                                                           msgtype)))
                    ranks.append(int(rank[i]))
            fields['diagnostics'] = tuple(diagnostics)
            fields['diagnostic_ranks'] = tuple(ranks)
    return MessageBatch(**fields)


def _message_batch(messages: Sequence[BagMessage], offset: int) -> MessageBatch:
    """Decoded messages (rosbags objects, in recorded order) as a MessageBatch."""
    poses: dict[str, list[tuple[int, Any]]] = {name: [] for name in POSE_TOPICS}
    texts: dict[str, list[tuple[int, str]]] = {name: [] for name in TEXT_TOPICS}
    diagnostics: list[tuple[int, Any]] = []
    diagnostic_ranks: list[int] = []
    trajectories: list[tuple[int, tuple[str, ...], FloatArray | None]] = []
    joints: list[Any] = []
    for rank, item in enumerate(messages, start=offset):
        if item.topic in POSE_TOPICS:
            poses[item.topic].append((rank, item.message))
        elif item.topic in TEXT_TOPICS:
            texts[item.topic].append((item.log_time_ns, item.message.data))
        elif item.topic == DIAGNOSTICS:
            diagnostics.append((item.log_time_ns, item.message))
            diagnostic_ranks.append(rank)
        elif item.topic == JOINT_STATES:
            joints.append(item.message)
        elif item.topic == JOINT_TRAJECTORY:
            trajectories.append((item.log_time_ns, *_last_point(item.message)))
    rows: dict[str, PoseMessages] = {}
    for topic, found in poses.items():
        pose = [getattr(m.pose, 'pose', m.pose) for _, m in found]
        rows[topic] = PoseMessages(
            np.array([r for r, _ in found], dtype=np.intp),
            np.array([stamp_seconds(m.header.stamp.sec, m.header.stamp.nanosec)
                      for _, m in found], dtype=float),
            np.array([m.header.frame_id for _, m in found], dtype=object),
            np.array([(p.position.x, p.position.y, p.position.z) for p in pose],
                     dtype=float).reshape(-1, 3),
            np.array([(p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w)
                      for p in pose], dtype=float).reshape(-1, 4),
            np.array([m.pose.covariance for _, m in found], dtype=float).reshape(-1, 6, 6)
            if found and hasattr(found[0][1].pose, 'covariance') else None)
    return MessageBatch(targets=rows[TARGET], measured=rows[MEASURED_POSE],
                        truth=rows[TRUE_POSE], registrations=rows[TRACKER_REGISTRATION],
                        program=tuple(texts[PROGRAM]),
                        diagnostics=tuple(diagnostics), calibration=tuple(texts[CALIBRATION]),
                        axis_test=tuple(texts[AXIS_TEST]),
                        compliance_test=tuple(texts[COMPLIANCE_TEST]),
                        diagnostic_ranks=tuple(diagnostic_ranks),
                        joint_states=joint_samples(joints),
                        trajectories=tuple(trajectories))


def message_batches(messages: Iterator[BagMessage], size: int = MESSAGES_PER_BATCH
                    ) -> Iterator[MessageBatch]:
    """Decoded messages (rosbags objects, in recorded order) as MessageBatch es of ``size``
    messages: the analysis of a bag read message by message, and an independent way into the
    replay for tests."""
    offset = 0
    while True:
        chunk = list(islice(messages, size))
        if not chunk:
            return
        yield _message_batch(chunk, offset)
        offset += len(chunk)


def _indexed(path: Path, bag: IndexedBag, topics: Collection[str],
             problems: tuple[str, ...] = (), check: BagCheck | None = None) -> Recording:
    present = [t for t in topics if t in bag.topics]
    start, end = (bag.start_ns, bag.end_ns) if bag.message_count else (0, 0)

    def read() -> Iterator[MessageBatch]:
        for block in bag.blocks(present):
            yield _block_batch(bag, block, present)

    return Recording(path, {t.name: (t.msgtype, t.message_count) for t in bag.topics.values()},
                     bag.message_count, start, end, problems, check, read)


def _rosbags(path: Path, reader: BagReader, topics: Collection[str]) -> Recording:
    present = [t for t in topics if t in reader.topics]
    return Recording(path, {t.name: (t.msgtype, t.message_count)
                            for t in reader.topics.values()},
                     reader.message_count, reader.start_ns, reader.end_ns, (), None,
                     lambda: message_batches(reader.messages(present)) if present
                     else iter(()))


def _place(source: Path, target: Path) -> None:
    """``target`` names ``source`` (a symbolic link; a copy where links are not possible).
    Recovery only ever replaces the names of the folder it repairs, never the files' bytes."""
    try:
        os.symlink(source.resolve(), target)
    except OSError:
        shutil.copyfile(source, target)


def _unusable(path: Path, files: Sequence[FileCheck]) -> BagError:
    what = '; '.join('; '.join(f.problems) if f.path == path
                     else f'{f.path.name}: {"; ".join(f.problems)}' for f in files)
    return BagError(path, f'{what}: nothing to analyse')


def _problems(check: BagCheck, first: str | None, kept: int,
              rewritten: Sequence[FileRecovery]) -> tuple[str, ...]:
    """The problems of a bag read from a repaired copy: what was wrong, what was lost."""
    out: list[str] = []
    damaged = check.damaged
    if damaged or any(f.usable and f.problems for f in check.files):
        counts = [d.message_count for d in damaged]
        lost = (f', {sum(n or 0 for n in counts)} in corrupt chunks lost'
                if damaged and None not in counts else '')
        what = (f'{len(damaged)} corrupt chunk{"s" if len(damaged) > 1 else ""} ('
                + ', '.join(f'{d.file} chunk {d.index}' for d in damaged) + ')'
                if damaged else 'damage outside the chunks')
        out.append(f'the bag is damaged: {what}; analysed its sound part ({kept} messages'
                   f'{lost}) from a repaired copy')
    if first is not None or any(f.usable and not f.complete for f in check.files):
        reason = f' ({first})' if first is not None else ''
        out.append(f'the bag is not complete{reason}; analysed its readable part ({kept} '
                   'messages) from a repaired copy')
    out += [f'{line}: not analysed' if not f.usable else line
            for f in check.files for line in f.lines(check.start_ns)]
    for r in rewritten:
        what = 'truncated' if r.status == 'recovered' else 'repaired'
        out.append(f'{r.path.name}: {what}, {r.message_count} messages readable')
    return tuple(out)


def _repaired(path: Path, topics: Collection[str], work: Callable[[Recording], T],
              first: str | None) -> T:
    """``work`` on a repaired copy of the MCAP bag at ``path`` (module docstring)."""
    files = storage_files(path) if path.is_dir() else [path]
    check = verify_bag(path, files)
    usable = [f for f in check.files if f.usable]
    if not usable:
        raise _unusable(path, check.files)
    with tempfile.TemporaryDirectory(prefix='analyze_bag_') as tmp:
        copy = Path(tmp) / 'bag'
        copy.mkdir()
        for f in usable:
            _place(f.path, copy / f.path.name)
        try:
            report = recover_bag(copy, checked=[replace(f, path=copy / f.path.name)
                                                for f in usable])
            bag = IndexedBag(copy)
        except BagError as err:  # name the user's bag, not the copy
            raise BagError(path, f'not a readable bag: {err.reason}'
                                 f'{f" ({first})" if first else ""}') from err
        with bag:
            problems = _problems(check, first, bag.message_count,
                                 [r for r in report.files if r.status != 'complete'])
            return work(_indexed(path, bag, topics, problems, check))


def with_recording(path: str | Path, topics: Collection[str],
                   work: Callable[[Recording], T]) -> T:
    """Run ``work`` on the bag at ``path`` (a rosbag2 folder or an ``.mcap`` file) opened for
    the messages of ``topics`` (those it has); returns what ``work`` returns. Should the
    indexed read find damage while ``work`` reads, ``work`` runs again from the start on the
    repaired copy (module docstring), so it must not keep state between calls. BagError when
    nothing readable is there (no bag, or no storage file that is an MCAP file)."""
    path = Path(path)
    if not path.exists():
        raise BagError(path, 'no such file or folder')
    if mcap_files(path) is None:
        try:
            reader = BagReader(path)
        except BagError as err:
            raise BagError(path, f'not a bag ({err.reason})') from err
        with reader:
            return work(_rosbags(path, reader, topics))
    try:
        bag = IndexedBag(path)
    except BagError as err:  # no summary, a damaged one, a file that is not MCAP among others
        return _repaired(path, topics, work, err.reason)
    with bag:
        try:
            return work(_indexed(path, bag, topics))
        except IndexedReadError as err:  # damage found while reading: start again, repaired
            first = err.reason
    return _repaired(path, topics, work, first)
