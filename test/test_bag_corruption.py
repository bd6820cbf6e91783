"""Damaged bags: 64 bytes flipped in the middle of a synthetic run's .mcap (no compression, and
zstd) are found by the chunk's CRC (zstd: its decompression or CRC), named with the byte offset,
log-time range and messages lost; analyze_bag analyses the sound chunks (the figures equal the
batch analysis of exactly the messages that survive) and exits 3; recover_bag rewrites the
sound chunks; an empty or 10-byte .mcap is said to be so (exit 2, never "lacks topics"); an
intact bag verifies clean. No ROS graph."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex, Message
from mcap.stream_reader import breakup_chunk

from positioning_cell import accuracy
from positioning_cell.accuracy import MonitorSettings
from positioning_cell.analysis import analyse_bag
from positioning_cell.bag import BagError, BagReader, recover_bag, verify_bag, verify_file
from positioning_cell.bag.verify import MIN_MCAP_BYTES, sound_records, utc
from positioning_cell.config import config_path
from positioning_cell.names import DIAGNOSTICS, MEASURED_POSE, TARGET
from positioning_cell.testing.synthetic_run import SyntheticRun, synthetic_run, write_run_bag
from positioning_cell.tools import recover_bag as recover_tool
from positioning_cell.tools.analyze_bag import main
from positioning_cell.tools.exits import Exit

SETTINGS = MonitorSettings.from_file(config_path('cell.yaml'))
POSITIONS = np.array([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2], [-0.004, -0.004, 0.2],
                      [-0.004, -0.004, 0.192], [0.004, 0.004, 0.192]])
QUATERNIONS = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
LATENCY = 0.002  # write_run_bag's default: log time = stamp + latency


@pytest.fixture(scope='module')
def run() -> SyntheticRun:
    return synthetic_run(POSITIONS, QUATERNIONS, cycles=2, dwell_time=1.5, seed=7)


def _bag(run: SyntheticRun, path: Path, **options: object) -> Path:
    """The run as a bag (the cell's writer, 64 KiB chunks); its one .mcap file."""
    write_run_bag(path, run, joint_state_rate=50.0, **options)  # type: ignore[arg-type]
    (mcap,) = path.glob('*.mcap')
    return mcap


def _chunks(mcap: Path) -> list[ChunkIndex]:
    with mcap.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def _chunk_messages(mcap: Path, ci: ChunkIndex) -> set[tuple[str, int]]:
    """(topic, log time) of every message of an intact chunk, decoded by the mcap library."""
    with mcap.open('rb') as stream:
        summary = make_reader(stream).get_summary()
        assert summary is not None
        topics = {c.id: c.topic for c in summary.channels.values()}
        stream.seek(ci.chunk_start_offset + 9)
        chunk = Chunk.read(ReadDataStream(stream))
    return {(topics[r.channel_id], r.log_time) for r in breakup_chunk(chunk)
            if isinstance(r, Message)}


def _chunk_messages_of(data: bytes, tmp_path: Path, ci: ChunkIndex) -> set[tuple[str, int]]:
    """:func:`_chunk_messages` of the file bytes ``data`` (before they were damaged)."""
    copy = tmp_path / 'intact_copy.mcap'
    copy.write_bytes(data)
    return _chunk_messages(copy, ci)


def _flip(path: Path, at: int, n: int = 64) -> None:
    data = bytearray(path.read_bytes())
    data[at:at + n] = bytes(b ^ 0xFF for b in data[at:at + n])
    path.write_bytes(bytes(data))


def _flip_middle(mcap: Path) -> tuple[int, ChunkIndex]:
    """Flip 64 bytes in the middle of the chunk that holds the file's middle byte (inside its
    compressed data); that chunk's number and index entry."""
    chunks = _chunks(mcap)
    middle = mcap.stat().st_size // 2
    k = max(i for i, c in enumerate(chunks) if c.chunk_start_offset <= middle)
    ci = chunks[k]
    data_start = ci.chunk_start_offset + 9 + 40 + len(ci.compression)
    assert ci.compressed_size > 1000 and 0 < k < len(chunks) - 1
    _flip(mcap, data_start + ci.compressed_size // 2 - 32)
    return k, ci


def _log_ns(t: float) -> int:
    return round((t + LATENCY) * 1e9)


def _same_visit(a: accuracy.Visit, b: accuracy.Visit) -> None:
    assert (a.key, a.cycle, a.samples) == (b.key, b.cycle, b.samples)
    assert a.target_time == pytest.approx(b.target_time, abs=1e-6)
    assert a.settle_time == pytest.approx(b.settle_time, abs=1e-6)
    np.testing.assert_allclose(a.position, b.position, atol=1e-12)
    np.testing.assert_allclose(a.quaternion, b.quaternion, atol=1e-12)


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_an_intact_bag_verifies_clean(run: SyntheticRun, tmp_path: Path,
                                      compression: str) -> None:
    mcap = _bag(run, tmp_path / 'bag', compression=compression)
    check = verify_bag(tmp_path / 'bag')
    assert check.sound and check.damaged == () and check.lines() == []
    (f,) = check.files
    assert f.chunks == len(_chunks(mcap)) >= 10 and f.crc_chunks == f.chunks  # CRCs written
    assert (f.data_crc, f.summary_crc) == ('ok', 'ok')
    assert f.start_ns == _log_ns(run.time[0]) and f.message_count is not None
    analysis = analyse_bag(tmp_path / 'bag', SETTINGS)
    assert analysis.problems == () and len(analysis.replay.visits) == 30


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_a_flipped_chunk_is_named_and_the_rest_is_analysed(
        run: SyntheticRun, tmp_path: Path, capsys: pytest.CaptureFixture[str],
        compression: str) -> None:
    bag = tmp_path / 'bag'
    mcap = _bag(run, bag, compression=compression)
    intact = mcap.read_bytes()
    chunks = _chunks(mcap)
    k, ci = _flip_middle(mcap)
    lost = _chunk_messages_of(intact, tmp_path, ci)
    lost_topics: dict[str, int] = {}
    for topic, _ in lost:
        lost_topics[topic] = lost_topics.get(topic, 0) + 1

    # the verification finds exactly the damaged chunk, with what it covered
    check = verify_bag(bag)
    assert not check.sound
    (damaged,) = check.damaged
    assert (damaged.file, damaged.index, damaged.offset) == (mcap.name, k, ci.chunk_start_offset)
    assert damaged.length == ci.chunk_length
    assert (damaged.start_ns, damaged.end_ns) == (ci.message_start_time, ci.message_end_time)
    assert dict(damaged.topic_counts) == lost_topics and damaged.message_count == len(lost)
    assert ('CRC mismatch' in damaged.reason if compression == 'none' else
            'CRC mismatch' in damaged.reason or 'does not decompress' in damaged.reason)
    assert check.files[0].problems == ()  # nothing else is wrong
    assert check.files[0].data_crc == 'mismatch' and check.files[0].chunks == len(chunks)

    # analyze_bag: exit 3, the chunk and the time range lost are printed and in the report
    out = tmp_path / 'out'
    assert main([str(bag), '--out', str(out)]) == Exit.NOT_ACHIEVED
    err = capsys.readouterr().err
    start_s = (ci.message_start_time - _log_ns(run.time[0])) * 1e-9
    end_s = (ci.message_end_time - _log_ns(run.time[0])) * 1e-9
    for words in (f'{mcap.name}: chunk {k} at byte {ci.chunk_start_offset}', 'is corrupt',
                  utc(ci.message_start_time), utc(ci.message_end_time)[11:],
                  f'({start_s:.3f} s .. {end_s:.3f} s into the bag)', f'{len(lost)} messages',
                  f'{MEASURED_POSE} {lost_topics[MEASURED_POSE]}'):
        assert words in err, words
    summary = json.loads((out / 'summary.json').read_text())
    assert any(f'chunk {k} at byte' in p for p in summary['problems'])
    assert f'chunk {k} at byte {ci.chunk_start_offset}' in (out / 'report.md').read_text()
    assert mcap.read_bytes() != intact and sorted(p.name for p in bag.iterdir()) == [
        'bag_0.mcap', 'metadata.yaml']  # the damaged bag is left as it was

    # the figures cover the rest: exactly the messages outside the lost chunk
    analysis = analyse_bag(bag, SETTINGS)
    keep = np.array([(MEASURED_POSE, _log_ns(t)) not in lost for t in run.time])
    keep_target = np.array([(TARGET, _log_ns(t)) not in lost for t in run.target_time])
    assert analysis.replay.measured.count == keep.sum() == run.time.size - lost_topics[
        MEASURED_POSE]
    keep_end = np.array([(DIAGNOSTICS, _log_ns(t)) not in lost for t in run.end_time])
    batch = accuracy.analyse(run.time[keep], run.position[keep], run.quaternion[keep],
                             run.target_time[keep_target], run.target_position[keep_target],
                             run.target_quaternion[keep_target], SETTINGS.settle,
                             end_times=run.end_time[keep_end])
    visits = analysis.replay.visits
    assert 25 <= len(visits) == len(batch.visits) <= 30
    for mine, theirs in zip(visits, batch.visits, strict=True):
        _same_visit(mine.visit, theirs)
    assert analysis.message_count == sum(f.message_count or 0 for f in check.files) - len(lost)


def test_damage_outside_the_chunks_is_found_and_nothing_is_lost(
        run: SyntheticRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / 'bag'
    mcap = _bag(run, bag)
    ci = _chunks(mcap)[3]
    _flip(mcap, ci.chunk_start_offset + ci.chunk_length + 40, 16)  # in its message indexes
    check = verify_file(mcap)
    assert check.damaged == () and check.data_crc == 'mismatch'
    assert check.problems and 'no message is lost' in check.problems[0]
    assert main([str(bag), '--out', str(tmp_path / 'out')]) == Exit.NOT_ACHIEVED
    assert 'data section CRC mismatch' in capsys.readouterr().err
    assert len(analyse_bag(bag, SETTINGS).replay.visits) == 30


def test_empty_and_tiny_files_say_so(run: SyntheticRun, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / 'empty.mcap'
    empty.write_bytes(b'')
    tiny = tmp_path / 'tiny.mcap'
    tiny.write_bytes(b'\x89MCAP0\r\n\x01\x00')
    folder = tmp_path / 'cut'
    folder.mkdir()
    (folder / 'cut_0.mcap').write_bytes(b'')
    for path, words in ((empty, 'empty (0 bytes)'),
                        (tiny, '10 bytes: too short to be an MCAP file'),
                        (folder, 'cut_0.mcap: empty (0 bytes)')):
        assert main([str(path), '--out', str(tmp_path / 'o')]) == Exit.USAGE
        err = capsys.readouterr().err
        assert err.startswith(f'analyze_bag: error: {path}: ') and words in err, err
        assert 'lacks' not in err and 'nothing to analyse' in err
    assert not (tmp_path / 'o').exists()
    assert (verify_file(empty).kind, verify_file(tiny).kind) == ('empty', 'too short')
    assert MIN_MCAP_BYTES > 10
    # an empty split beside a sound one: the sound one is analysed, the empty one named
    bag = tmp_path / 'bag'
    _bag(run, bag)
    (bag / 'bag_1.mcap').write_bytes(b'')
    assert main([str(bag), '--out', str(tmp_path / 'o2')]) == Exit.NOT_ACHIEVED
    assert 'bag_1.mcap: empty (0 bytes)' in capsys.readouterr().err
    assert len(analyse_bag(bag, SETTINGS).replay.visits) == 30


def test_the_reader_and_recover_bag_name_and_skip_the_corrupt_chunk(
        run: SyntheticRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / 'bag'
    mcap = _bag(run, bag, compression='zstd')
    total = verify_file(mcap).message_count
    original = mcap.read_bytes()
    k, ci = _flip_middle(mcap)
    damaged = mcap.read_bytes()
    with BagReader(bag) as reader, pytest.raises(BagError, match=f'chunk {k} at byte'):
        list(reader.raw_messages())
    with BagReader(bag) as reader:
        assert [d.index for d in reader.verify().damaged] == [k]
    assert recover_tool.main([str(bag)]) == 0
    printed = capsys.readouterr().out
    assert f'{mcap.name}: repaired' in printed and f'left out: {mcap.name}: chunk {k}' in printed
    assert (bag / 'bag_0.mcap.damaged').read_bytes() == damaged != original
    check = verify_bag(bag)
    assert check.sound and total is not None
    with BagReader(bag) as reader:
        times = [m.log_time_ns for m in reader.raw_messages()]
    assert len(times) == total - len(_chunk_messages_of(original, tmp_path, ci))
    assert not any(ci.message_start_time < t < ci.message_end_time for t in times)
    assert max(times) > ci.message_end_time  # the chunks after the damaged one are kept
    assert not recover_bag(bag).changed  # sound now: left alone


def test_a_killed_recording_with_a_corrupt_chunk_keeps_the_chunks_after_it(
        run: SyntheticRun, tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    mcap = _bag(run, bag)
    chunks = _chunks(mcap)
    data = mcap.read_bytes()
    cut = chunks[-3].chunk_start_offset + 100  # inside a late chunk: no summary
    (bag / 'metadata.yaml').unlink()
    mcap.write_bytes(data[:cut])
    ci = chunks[4]
    _flip(mcap, ci.chunk_start_offset + 9 + 40 + ci.compressed_size // 2)
    check = verify_file(mcap)
    assert not check.complete and check.truncated_at == chunks[-3].chunk_start_offset
    (damaged,) = check.damaged
    assert (damaged.index, damaged.offset) == (4, ci.chunk_start_offset)
    assert (damaged.start_ns, damaged.end_ns) == (ci.message_start_time, ci.message_end_time)
    assert damaged.message_count == sum(
        1 for _ in _chunk_messages_of(data, tmp_path, ci))  # from its message indexes
    report = recover_bag(bag)
    (item,) = report.files
    assert item.status == 'recovered' and [d.index for d in item.lost] == [4]
    with BagReader(bag) as reader:
        times = [m.log_time_ns for m in reader.raw_messages()]
    assert max(times) > chunks[-4].message_start_time  # beyond the corrupt chunk
    assert not any(ci.message_start_time < t < ci.message_end_time for t in times)


def test_without_crcs_the_structure_is_checked(run: SyntheticRun, tmp_path: Path) -> None:
    """rosbags' own writer leaves every CRC at 0: a zstd chunk still fails to decompress, and
    broken record framing is found; damage inside a message payload of an uncompressed chunk
    cannot be (the limit of a file without CRCs)."""
    packed = _bag(run, tmp_path / 'packed', writer='rosbags', compression='zstd')
    plain = _bag(run, tmp_path / 'plain', writer='rosbags')
    for mcap in (packed, plain):
        check = verify_file(mcap)
        assert check.sound and check.crc_chunks == 0 and check.chunks >= 1
        assert (check.data_crc, check.summary_crc) == ('absent', 'absent')
    first = _chunks(packed)[0]
    _flip(packed, first.chunk_start_offset + 9 + 40 + 4 + first.compressed_size // 2)
    assert [d.index for d in verify_file(packed).damaged] == [0]
    # framing: the length field of a message record in the middle of the (only) chunk
    data = plain.read_bytes()
    records = [r for r in sound_records(plain) if isinstance(r, Message)]
    middle = records[len(records) // 2]
    at = data.index(middle.data) - 22 - 8  # its length field (opcode, length, fixed fields)
    _flip(plain, at, 8)
    damaged = verify_file(plain).damaged
    assert len(damaged) == 1 and 'runs past its end' in damaged[0].reason
    plain.write_bytes(data)
    _flip(plain, data.index(middle.data) + 4, 16)  # inside the payload: not detectable
    assert verify_file(plain).sound
