"""The indexed MCAP reader (positioning_cell.bag.indexed) against rosbags: on synthetic runs
written by both writers (the cell's with CRCs, rosbags' without), uncompressed and zstd, with
several chunk and block sizes, split bags and chunks that overlap in time, any subset of topics
comes out as ``BagReader.raw_messages`` yields it (same order, log times, bytes) and decodes to
what rosbags decodes; memory stays within the block budget; damage raises the specific error
(a flipped byte in a chunk names the chunk, a truncated file is unindexed, a flipped byte in a
chunk that is not read is caught by the data-section CRC). No ROS graph."""

from __future__ import annotations

import functools
import itertools
import shutil
import struct
import tracemalloc
import zlib
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import ChunkIndex
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from positioning_cell.bag import (
    BagError,
    BagReader,
    BagWriter,
    RawMessage,
    TopicInfo,
    message_definition,
)
from positioning_cell.bag.indexed import (
    DamagedBagError,
    IndexedBag,
    IndexedReadError,
    UnindexedBagError,
    UnsupportedBagError,
)
from positioning_cell.names import (
    DIAGNOSTICS,
    JOINT_STATES,
    MEASURED_POSE,
    PROGRAM,
    TARGET,
    TRUE_POSE,
)
from positioning_cell.testing.layouts import LAYOUTS, Layout, rewrite_bag
from positioning_cell.testing.synthetic_run import SyntheticRun, synthetic_run, write_run_bag

ANALYSED = (TARGET, MEASURED_POSE, TRUE_POSE, PROGRAM, DIAGNOSTICS)
SUBSETS: tuple[tuple[str, ...], ...] = (
    ANALYSED, (MEASURED_POSE,), (PROGRAM, DIAGNOSTICS), (*ANALYSED, JOINT_STATES),
    (TARGET, '/no/such/topic'))
POSITIONS = np.array([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2]])
QUATERNIONS = np.tile([0.0, 0.0, 0.0, 1.0], (2, 1))


@pytest.fixture(scope='module')
def run() -> SyntheticRun:
    return synthetic_run(POSITIONS, QUATERNIONS, modes=('none', 'measured'), cycles=1,
                         rate=10.0, dwell_time=1.5, seed=3)


@pytest.fixture(scope='module')
def bags(run: SyntheticRun, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Bags of the run: both writers, none / zstd, the cell's at two chunk sizes."""
    root = tmp_path_factory.mktemp('indexed')
    out = {}
    for name, options in {
            'cell-none-1k': {'writer': 'cell', 'compression': 'none', 'chunk_bytes': 1024},
            'cell-zstd-1k': {'writer': 'cell', 'compression': 'zstd', 'chunk_bytes': 1024},
            'cell-none-64k': {'writer': 'cell', 'compression': 'none'},
            'rosbags-none': {'writer': 'rosbags', 'compression': 'none'},
            'rosbags-zstd': {'writer': 'rosbags', 'compression': 'zstd'}}.items():
        write_run_bag(root / name, run, joint_state_rate=60.0, **options)  # type: ignore[arg-type]
        out[name] = root / name
    return out


class _Rosbags(NamedTuple):
    """What rosbags reads from a bag: its topics, and the messages of each subset of topics."""

    topics: dict[str, TopicInfo]
    subsets: dict[tuple[str, ...], list[RawMessage]]


@functools.cache
def _rosbags(bag: Path) -> _Rosbags:
    """One rosbags reader per bag (opening one takes longer than reading these bags)."""
    with BagReader(bag) as reader:
        return _Rosbags(dict(reader.topics), {
            s: list(reader.raw_messages([t for t in s if t in reader.topics]))
            for s in (*SUBSETS, ('/a', '/b', '/c'), ('/a', '/c'), (MEASURED_POSE,), ANALYSED)})


def _reference(bag: Path, topics: tuple[str, ...]) -> list[RawMessage]:
    """What ``BagReader.raw_messages(topics)`` yields (topics the bag has)."""
    return _rosbags(bag).subsets[topics]


def _chunk_indexes(mcap: Path) -> list[ChunkIndex]:
    with mcap.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def _copy(bag: Path, target: Path) -> Path:
    shutil.copytree(bag, target)
    (mcap,) = target.glob('*.mcap')
    return mcap


def _flip(mcap: Path, offset: int) -> None:
    data = bytearray(mcap.read_bytes())
    data[offset] ^= 0x5A
    mcap.write_bytes(bytes(data))


@pytest.mark.parametrize('name', ['cell-none-1k', 'cell-zstd-1k', 'cell-none-64k',
                                  'rosbags-none', 'rosbags-zstd'])
def test_same_messages_as_rosbags(bags: dict[str, Path], name: str) -> None:
    bag = bags[name]
    topics = _rosbags(bag).topics
    for block_bytes, subsets in ((1, SUBSETS[:1]), (5000, SUBSETS), (1 << 23, SUBSETS[:1])):
        with IndexedBag(bag, block_bytes=block_bytes, crc_thread=block_bytes != 1) as indexed:
            assert indexed.topics == topics
            for subset in subsets:
                assert list(indexed.raw_messages(subset)) == _reference(bag, subset), subset


def test_single_mcap_file_and_unknown_topics(bags: dict[str, Path]) -> None:
    (mcap,) = bags['cell-none-1k'].glob('*.mcap')
    with IndexedBag(mcap) as indexed, BagReader(mcap) as reader:
        assert indexed.topics == reader.topics
        assert indexed.message_count == reader.message_count
        assert list(indexed.raw_messages(ANALYSED)) == list(reader.raw_messages(ANALYSED))
        assert list(indexed.blocks(['/no/such/topic'])) == []
        assert list(indexed.blocks([])) == []
        assert set(indexed.read(['/no/such/topic', PROGRAM]).topics) == {PROGRAM}


def test_split_bag(bags: dict[str, Path], tmp_path: Path) -> None:
    source = _rosbags(bags['cell-none-1k'])
    everything = source.subsets[ANALYSED]
    topics = {name: source.topics[name] for name in ANALYSED}
    split = tmp_path / 'split'
    with BagWriter(split, chunk_bytes=2048, split_max_bytes=30_000) as writer:
        for name, info in topics.items():
            writer.add_topic(name, info.msgtype, info.qos)
        for m in everything:
            writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
    assert len(list(split.glob('*.mcap'))) >= 3
    with IndexedBag(split, block_bytes=20_000) as indexed:
        assert [f.name for f in indexed.files][:3] == ['split_0.mcap', 'split_1.mcap',
                                                       'split_2.mcap']
        assert indexed.topics == _rosbags(split).topics
        assert {b.file_index for b in indexed.blocks(ANALYSED)} == set(range(len(
            indexed.files)))
        for subset in SUBSETS[:3]:
            assert list(indexed.raw_messages(subset)) == _reference(split, subset)


def _overlapping_bag(path: Path, seed: int, compression: str = 'none') -> Path:
    """Three topics whose log times are written out of order (jitter up to 0.3 s, repeated
    log times): chunks of 1 KiB that overlap in time, ties within and across chunks."""
    rng = np.random.default_rng(seed)
    with BagWriter(path, chunk_bytes=1024, compression=compression) as writer:
        for topic in ('/a', '/b', '/c'):
            writer.add_topic(topic, 'std_msgs/msg/String')
        for i in range(600):
            t = 1_700_000_000_000_000_000 + i * 1_000_000 + int(rng.integers(0, 300)) * 1_000_000
            if rng.random() < 0.2:
                t = 1_700_000_000_000_000_000 + (i // 7) * 7_000_000  # ties
            topic = ('/a', '/b', '/c')[int(rng.integers(0, 3))]
            text = f'{topic} {i}' + 'x' * int(rng.integers(0, 40))
            data = b'\x00\x01\x00\x00' + struct.pack('<I', len(text) + 1) + text.encode() + b'\0'
            writer.write(topic, 'std_msgs/msg/String', data, t)
    return path


@pytest.mark.parametrize(('seed', 'compression'), [(1, 'none'), (2, 'zstd')])
def test_chunks_overlapping_in_time(tmp_path: Path, seed: int, compression: str) -> None:
    bag = _overlapping_bag(tmp_path / 'bag', seed, compression)
    (mcap,) = bag.glob('*.mcap')
    chunks = _chunk_indexes(mcap)
    assert any(b.message_start_time < a.message_end_time
               for a, b in itertools.pairwise(chunks))
    for block_bytes in (1, 3000):
        with IndexedBag(bag, block_bytes=block_bytes, crc_thread=block_bytes != 1) as indexed:
            for subset in (('/a', '/b', '/c'), ('/a', '/c')):
                assert list(indexed.raw_messages(subset)) == _reference(bag, subset)
            times = [b.topics['/a'].log_time_ns for b in indexed.blocks(['/a'])]
            assert np.all(np.diff(np.concatenate(times)) >= 0)  # across blocks too
            if block_bytes == 3000:
                assert len(times) > 5


def test_unindexed_files_out_of_time_order(tmp_path: Path) -> None:
    """The same records out of log-time order, unchunked (rosbags refuses such a file) or in
    chunks without any index (rosbags too: it reads them in file order): scanned, they come
    out in rosbags' order for the indexed files, (log time, place in the file): as rosbags
    reads them from one chunk holding them all, and from the 1 KiB chunks of the original."""
    bag = _overlapping_bag(tmp_path / 'bag', 3)
    one_chunk = rewrite_bag(bag, tmp_path / 'one', Layout(compression='none', chunk_size=2**24))
    unchunked = rewrite_bag(bag, tmp_path / 'flat', LAYOUTS['fastwrite'])
    unindexed = rewrite_bag(bag, tmp_path / 'noindex', Layout(index='none', chunk_size=1024))
    with BagReader(unchunked) as reader, pytest.raises(BagError, match='not in timestamp'):
        list(reader.raw_messages())
    for subset in (('/a', '/b', '/c'), ('/a', '/c')):
        assert _reference(one_chunk, subset) == _reference(bag, subset)
        for scanned in (unchunked, unindexed):
            with IndexedBag(scanned, block_bytes=3000) as indexed:
                assert indexed.scans and indexed.topics == _rosbags(one_chunk).topics
                assert list(indexed.raw_messages(subset)) == _reference(bag, subset)


def test_read_decodes_like_rosbags(bags: dict[str, Path]) -> None:
    bag = bags['cell-zstd-1k']
    with IndexedBag(bag, block_bytes=20_000) as indexed:
        got = indexed.read((*ANALYSED, '/no/such/topic'))
    with BagReader(bag) as reader:
        expected = list(reader.messages(ANALYSED))
    assert set(got.topics) == set(ANALYSED)
    names = got.order.names
    assert [names[c] for c in got.order.topic.tolist()] == [m.topic for m in expected]
    for topic, decoded in got.topics.items():
        mine = [m for m in expected if m.topic == topic]
        assert decoded.count == len(mine)
        assert decoded.log_time_ns.tolist() == [m.log_time_ns for m in mine]
        if topic == DIAGNOSTICS:  # sequences: rosbags, message by message
            assert decoded.columns is None and decoded.messages is not None
            assert [m.status[0].values[0].value for m in decoded.messages] == [
                m.message.status[0].values[0].value for m in mine]
            continue
        assert decoded.columns is not None
        stamps = decoded.columns.array('header.stamp.sec') if topic != PROGRAM else None
        if stamps is not None:
            assert stamps.tolist() == [m.message.header.stamp.sec for m in mine]
            assert decoded.columns.strings('header.frame_id').values == ('base',)
        if topic == MEASURED_POSE:
            np.testing.assert_array_equal(decoded.columns.array('pose.pose.position.x'),
                                          [m.message.pose.pose.position.x for m in mine])
            assert decoded.columns.array('pose.covariance').shape == (len(mine), 36)
        if topic == PROGRAM:
            assert decoded.columns.strings('data').tolist() == [m.message.data for m in mine]
    position = got.order.position
    for code, name in enumerate(names):
        assert position[got.order.topic == code].tolist() == list(range(got.topics[name].count))


def test_blocks_carry_payload_offsets_and_file_keys(bags: dict[str, Path]) -> None:
    with IndexedBag(bags['cell-none-1k'], block_bytes=4096) as indexed:
        expected = _reference(bags['cell-none-1k'], (MEASURED_POSE,))
        got = []
        previous = -1
        for block in indexed.blocks([MEASURED_POSE]):
            m = block.topics[MEASURED_POSE]
            assert m.msgtype == 'geometry_msgs/msg/PoseWithCovarianceStamped'
            assert m.file_key[0] > previous and np.all(np.diff(m.file_key) > 0)
            previous = int(m.file_key[-1])
            got += [block.buffer[o:o + n].tobytes() for o, n in zip(m.offsets, m.lengths,
                                                                            strict=True)]
            decoded = indexed.decode(block, MEASURED_POSE)
            assert decoded.columns is not None and decoded.count == block.message_count
        assert got == [m.data for m in expected]


def test_memory_stays_within_the_block_budget(run: SyntheticRun, tmp_path: Path) -> None:
    bag = tmp_path / 'long'
    write_run_bag(bag, run, joint_state_rate=100.0, compression='zstd', chunk_bytes=2048)
    size = sum(f.stat().st_size for f in bag.glob('*.mcap'))
    budget = 6 * 1024
    assert size > 12 * budget
    with IndexedBag(bag, block_bytes=budget) as indexed:
        indexed.read(ANALYSED)  # the buffers allocated, the decoders built
        blocks = sum(1 for _ in indexed.blocks(ANALYSED))
        assert blocks > 10
        peaks, largest, count = [], 0, 0
        tracemalloc.start()
        for k, block in enumerate(indexed.blocks(ANALYSED)):
            largest = max(largest, block.buffer.nbytes)
            count += block.message_count
            for topic in block.topics:
                indexed.decode(block, topic)
            if k in (blocks // 4, blocks - 1):
                peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert count == sum(indexed.topics[t].message_count for t in ANALYSED)
    assert largest <= 3 * budget  # raw + decompressed, a chunk of slack
    # The whole bag needs no more than its first quarter: nothing accumulates; the fixed part
    # is the file's index arrays, the thread pool and a block's arrays and decoded columns.
    assert peaks[1] < 1.25 * peaks[0] + 4096, peaks
    assert peaks[1] < 4 * budget + 48 * 1024, peaks


def test_flipped_byte_in_a_chunk_names_the_chunk(bags: dict[str, Path], tmp_path: Path,
                                                 ) -> None:
    for name in ('cell-none-1k', 'cell-zstd-1k'):
        mcap = _copy(bags[name], tmp_path / name)
        chunks = _chunk_indexes(mcap)
        number = len(chunks) // 2
        chunk = chunks[number]
        _flip(mcap, chunk.chunk_start_offset + chunk.chunk_length - 40)
        with IndexedBag(mcap.parent) as indexed, pytest.raises(DamagedBagError) as err:
            list(indexed.blocks(ANALYSED + (JOINT_STATES,)))
        assert err.value.chunk == number
        assert err.value.offset == chunk.chunk_start_offset
        assert f'chunk {number} at byte {chunk.chunk_start_offset}' in str(err.value)
        assert mcap.name in str(err.value)
        assert 'CRC mismatch' in err.value.reason or 'decompress' in err.value.reason
        assert isinstance(err.value, IndexedReadError) and isinstance(err.value, BagError)


def test_damaged_index_without_crcs(bags: dict[str, Path], tmp_path: Path) -> None:
    """rosbags' writer stores no CRC: a message record that does not match its index is
    still caught (here: its log time, its channel, its opcode)."""
    for field, want in ((9 + 6, 'log time'), (9, 'is on channel'), (0, 'no message record')):
        mcap = _copy(bags['rosbags-none'], tmp_path / f'b{field}')
        chunk = _chunk_indexes(mcap)[0]
        records = chunk.chunk_start_offset + 9 + 8 + 8 + 8 + 4 + 4 + 8  # compression ''
        data = mcap.read_bytes()
        cid = next(iter(chunk.message_index_offsets))
        at = chunk.message_index_offsets[cid] + 9 + 2 + 4
        _, offset = struct.unpack_from('<QQ', data, at)
        _flip(mcap, records + offset + field)
        with IndexedBag(mcap.parent) as indexed, pytest.raises(DamagedBagError,
                                                               match=want) as err:
            list(indexed.blocks([*indexed.topics]))
        assert err.value.chunk == 0


def test_truncated_recording_is_unindexed(run: SyntheticRun, tmp_path: Path) -> None:
    bag = tmp_path / 'killed'
    write_run_bag(bag, run, truncate_to=0.7)
    with pytest.raises(UnindexedBagError, match='no footer') as err:
        IndexedBag(bag)
    assert err.value.path.name == 'killed_0.mcap' or err.value.path.suffix == '.mcap'


def test_skipped_chunk_damage_is_caught_by_the_data_section_crc(run: SyntheticRun,
                                                                 tmp_path: Path) -> None:
    bag = tmp_path / 'js'
    write_run_bag(bag, run, joint_state_rate=150.0, chunk_bytes=1024)
    (mcap,) = bag.glob('*.mcap')
    with mcap.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    js = next(c.id for c in summary.channels.values() if c.topic == JOINT_STATES)
    chunks = _chunk_indexes(mcap)
    number, chunk = next((i, c) for i, c in enumerate(chunks)
                         if set(c.message_index_offsets) == {js})
    _flip(mcap, chunk.chunk_start_offset + chunk.chunk_length - 60)
    with IndexedBag(bag, block_bytes=8192) as indexed:
        blocks = indexed.blocks([MEASURED_POSE])
        got = 0
        with pytest.raises(DamagedBagError, match='data section CRC mismatch') as err:
            for block in blocks:
                got += block.message_count
        assert got == indexed.topics[MEASURED_POSE].message_count  # reported at the end
        assert err.value.chunk is None
        with pytest.raises(DamagedBagError, match=f'chunk {number} at byte '
                                                  f'{chunk.chunk_start_offset}: chunk CRC'):
            list(indexed.blocks([JOINT_STATES]))


def test_summary_damage(bags: dict[str, Path], tmp_path: Path) -> None:
    mcap = _copy(bags['cell-none-64k'], tmp_path / 'summary')
    data = bytearray(mcap.read_bytes())
    summary_start = struct.unpack_from('<Q', data, len(data) - 8 - 20)[0]
    data[summary_start + 20] ^= 1
    mcap.write_bytes(bytes(data))
    with pytest.raises(DamagedBagError, match='summary section CRC mismatch'):
        IndexedBag(mcap.parent)
    struct.pack_into('<Q', data, len(data) - 8 - 20, 0)  # a footer that says: no summary
    mcap.write_bytes(bytes(data))
    with pytest.raises(DamagedBagError, match='summary section CRC mismatch: the footer'):
        IndexedBag(mcap.parent)  # its CRC covers the footer's fields too
    struct.pack_into('<I', data, len(data) - 8 - 4, 0)  # and no CRC: a valid unindexed file
    mcap.write_bytes(bytes(data))
    with IndexedBag(mcap.parent) as indexed:
        assert indexed.scans == {mcap.name: 'no summary section'}
        assert list(indexed.raw_messages(ANALYSED)) == _reference(bags['cell-none-64k'],
                                                                  ANALYSED)


def test_unknown_compression(bags: dict[str, Path], tmp_path: Path) -> None:
    """rosbags' writer (no CRCs): 'zstd' renamed 'zstx' in a chunk and in its index."""
    mcap = _copy(bags['rosbags-zstd'], tmp_path / 'zstx')
    data = mcap.read_bytes()
    mcap.write_bytes(data.replace(b'\x04\x00\x00\x00zstd', b'\x04\x00\x00\x00zstx'))
    with IndexedBag(mcap.parent) as indexed, pytest.raises(UnsupportedBagError,
                                                           match="unknown compression 'zstx'"):
        list(indexed.blocks(ANALYSED))


def test_not_a_bag(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='does not exist'):
        IndexedBag(tmp_path / 'missing')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagError, match=r'no \.mcap storage file'):
        IndexedBag(tmp_path / 'empty')
    text = tmp_path / 'text.mcap'
    text.write_bytes(b'not an mcap file at all, just some text' * 3)
    with pytest.raises(BagError, match=r'not a readable bag: text\.mcap: not an MCAP file') as err:
        IndexedBag(text)
    assert not isinstance(err.value, IndexedReadError)
    (tmp_path / 'zero.mcap').write_bytes(b'')
    with pytest.raises(BagError, match='empty'):
        IndexedBag(tmp_path / 'zero.mcap')


def test_close_is_idempotent(bags: dict[str, Path]) -> None:
    indexed = IndexedBag(bags['rosbags-none'])
    with indexed:
        assert indexed.message_count > 0
    indexed.close()
    assert indexed.closed
    with pytest.raises(BagError, match='closed'):
        list(indexed.blocks(ANALYSED))


def test_data_section_crc_is_the_writers(bags: dict[str, Path]) -> None:
    """The CRC the reader checks is the one the writer stored (a sanity check of the pass
    covering every byte up to DataEnd)."""
    (mcap,) = bags['cell-none-1k'].glob('*.mcap')
    data = mcap.read_bytes()
    summary_start = struct.unpack_from('<Q', data, len(data) - 8 - 20)[0]
    stored = struct.unpack_from('<I', data, summary_start - 4)[0]
    assert stored == zlib.crc32(data[:summary_start - 13]) != 0


def test_bag_without_messages(tmp_path: Path) -> None:
    bag = tmp_path / 'empty'
    with BagWriter(bag) as writer:
        writer.add_topic(TARGET, 'geometry_msgs/msg/PoseStamped')
        writer.add_topic(DIAGNOSTICS, 'diagnostic_msgs/msg/DiagnosticArray')
    with IndexedBag(bag) as indexed, BagReader(bag) as reader:
        assert indexed.topics == reader.topics
        got = indexed.read(ANALYSED)
    assert set(got.topics) == {TARGET, DIAGNOSTICS}
    target = got.topics[TARGET]
    assert target.count == 0 and target.columns is not None
    assert target.columns.array('pose.position.x').shape == (0,)
    assert got.topics[DIAGNOSTICS].messages == ()
    assert got.order.topic.shape == (0,)


def test_types_from_the_bags_own_definitions(tmp_path: Path) -> None:
    """A type the Jazzy typestore does not know is decoded with the definition the bag
    stores (as rosbags' AnyReader does): vectorised when fixed-layout, else by rosbags."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg('float64 value\nstring unit\nint16[3] counts\n'
                                      'std_msgs/Header header', 'test_msgs/msg/Reading'))
    store.register(get_types_from_msg('float64[] values', 'test_msgs/msg/Series'))
    bag = tmp_path / 'custom'
    with BagWriter(bag, typestore=store) as writer:
        for i in range(50):
            reading = store.types['test_msgs/msg/Reading'](
                i / 7, 'mm' if i % 3 else 'µm', np.array([i, -i, 7], dtype=np.int16),
                store.types['std_msgs/msg/Header'](
                    store.types['builtin_interfaces/msg/Time'](i, i), 'x' * (i % 5)))
            writer.write('/reading', 'test_msgs/msg/Reading',
                         bytes(store.serialize_cdr(reading, 'test_msgs/msg/Reading')), 10 + i)
            series = store.types['test_msgs/msg/Series'](np.arange(i % 4, dtype=np.float64))
            writer.write('/series', 'test_msgs/msg/Series',
                         bytes(store.serialize_cdr(series, 'test_msgs/msg/Series')), 10 + i)
    with IndexedBag(bag) as indexed, BagReader(bag) as reader:
        got = indexed.read(['/reading', '/series'])
        expected = list(reader.messages(['/reading', '/series']))
    columns = got.topics['/reading'].columns
    assert columns is not None
    readings = [m.message for m in expected if m.topic == '/reading']
    np.testing.assert_array_equal(columns.array('value'), [m.value for m in readings])
    assert columns.strings('unit').tolist() == [m.unit for m in readings]
    np.testing.assert_array_equal(columns.array('counts'), [m.counts for m in readings])
    assert columns.strings('header.frame_id').tolist() == [m.header.frame_id for m in readings]
    series = got.topics['/series'].messages
    assert series is not None
    assert [s.values.tolist() for s in series] == [m.message.values.tolist() for m in expected
                                                   if m.topic == '/series']


@pytest.mark.parametrize('compression', ['lz4', 'zstd', 'unchunked'])
def test_files_of_the_mcap_library(bags: dict[str, Path], tmp_path: Path,
                                   compression: str) -> None:
    """A third writer, the ``mcap`` library's (lz4 or zstd chunks, all CRCs; or no chunks at
    all: no chunk index, read by a scan of the records)."""
    source = _rosbags(bags['cell-none-1k'])
    messages = source.subsets[ANALYSED]
    types = {name: source.topics[name].msgtype for name in ANALYSED}
    mcap = tmp_path / 'other.mcap'
    kinds = {'lz4': CompressionType.LZ4, 'zstd': CompressionType.ZSTD,
             'unchunked': CompressionType.NONE}
    with mcap.open('wb') as stream:
        writer = McapWriter(stream, chunk_size=3000, compression=kinds[compression],
                            use_chunking=compression != 'unchunked', enable_data_crcs=True)
        writer.start(profile='ros2')
        channels = {}
        for name, msgtype in types.items():
            schema = writer.register_schema(msgtype, 'ros2msg',
                                            message_definition(msgtype)[0].encode())
            channels[name] = writer.register_channel(name, 'cdr', schema)
        for m in messages:
            writer.add_message(channels[m.topic], m.log_time_ns, m.data, m.log_time_ns)
        writer.finish()
    with IndexedBag(mcap, block_bytes=10_000) as indexed:
        assert indexed.scans == ({mcap.name: 'no chunk index'} if compression == 'unchunked'
                                 else {})
        assert list(indexed.raw_messages(ANALYSED)) == messages
        assert list(indexed.raw_messages((PROGRAM,))) == [m for m in messages
                                                          if m.topic == PROGRAM]
