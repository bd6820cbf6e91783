"""positioning_cell.bag without ROS: write → read round trips through two independent decoders
(rosbags, and mcap + mcap_ros2), splits, compression, metadata.yaml, recovery of truncated
files, replay timing, clear errors on bad input, and a failing disk (faults injected at every
call that writes, a file size limit, a dead disk; a real full tmpfs where mounting is allowed):
the bag closed with every message accepted, or left for recover_bag."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd, Footer
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rosbags.interfaces import QosDurability, QosHistory, QosReliability

from positioning_cell.bag import (
    BagError,
    BagReader,
    BagWriter,
    PlaybackTiming,
    RawMessage,
    TopicSelection,
    play,
    playback_qos,
    recording_qos,
    recover_bag,
    verify_bag,
)
from positioning_cell.bag.metadata import make_qos
from positioning_cell.bag.writer import RESERVE_FILE, BagWriteError, jazzy_typestore
from positioning_cell.errors import InputError
from positioning_cell.names import CELL_TOPICS
from positioning_cell.testing.disks import FaultyDisk, MountError, small_filesystem
from positioning_cell.tools import recover_bag as recover_tool
from positioning_cell.tools.exits import Exit

TS = jazzy_typestore()
T0 = 1_790_000_000_000_000_000
LATCHED = make_qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE,
                   QosDurability.TRANSIENT_LOCAL)
STREAM = make_qos(QosHistory.KEEP_LAST, 100, QosReliability.RELIABLE, QosDurability.VOLATILE)


def _header(i: int) -> object:
    return TS.types['std_msgs/msg/Header'](TS.types['builtin_interfaces/msg/Time'](i, 7 * i),
                                           'base')


def _joint_state(i: int) -> bytes:
    msg = TS.types['sensor_msgs/msg/JointState'](
        _header(i), ['leg1_length', 'leg1_theta'], np.array([0.2 + 1e-6 * i, 0.01 * i]),
        np.zeros(2), np.array([], dtype=float))
    return bytes(TS.serialize_cdr(msg, 'sensor_msgs/msg/JointState'))


def _pose(i: int) -> bytes:
    pose = TS.types['geometry_msgs/msg/Pose'](
        TS.types['geometry_msgs/msg/Point'](1e-3 * i, 0.0, 0.197),
        TS.types['geometry_msgs/msg/Quaternion'](0.0, 0.0, 0.0, 1.0))
    msg = TS.types['geometry_msgs/msg/PoseStamped'](_header(i), pose)
    return bytes(TS.serialize_cdr(msg, 'geometry_msgs/msg/PoseStamped'))


def _diagnostics(i: int) -> bytes:
    status = TS.types['diagnostic_msgs/msg/DiagnosticStatus'](
        0, 'recorder', f'ok {i}', 'cell', [TS.types['diagnostic_msgs/msg/KeyValue']('n', str(i))])
    msg = TS.types['diagnostic_msgs/msg/DiagnosticArray'](_header(i), [status])
    return bytes(TS.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticArray'))


# topic → (type, serializer); a latched topic, two streams and diagnostics
TOPICS = {
    '/positioner/target': ('geometry_msgs/msg/PoseStamped', _pose),
    '/legs/joint_states': ('sensor_msgs/msg/JointState', _joint_state),
    '/positioner/pose': ('geometry_msgs/msg/PoseStamped', _pose),
    '/diagnostics': ('diagnostic_msgs/msg/DiagnosticArray', _diagnostics),
}


def _messages(n: int, period_ns: int = 1_000_000) -> list[RawMessage]:
    """n messages cycling over TOPICS, log times T0 + i·period."""
    names = list(TOPICS)
    out = []
    for i in range(n):
        topic = names[i % len(names)]
        msgtype, make = TOPICS[topic]
        out.append(RawMessage(topic, msgtype, T0 + i * period_ns, make(i)))
    return out


def _write(path: Path, messages: list[RawMessage], **options: object) -> BagWriter:
    with BagWriter(path, **options) as writer:  # type: ignore[arg-type]
        writer.add_topic('/positioner/target', 'geometry_msgs/msg/PoseStamped', [LATCHED])
        for m in messages:
            writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
    return writer


def _read_rosbags(path: Path) -> list[RawMessage]:
    with BagReader(path) as reader:
        return list(reader.raw_messages())


def _read_mcap(files: list[Path]) -> list[tuple[str, int, object]]:
    """(topic, log time, decoded message) of every message, decoded by mcap_ros2."""
    out = []
    for f in files:
        with f.open('rb') as stream:
            reader = make_reader(stream, decoder_factories=[DecoderFactory()])
            assert reader.get_header().profile == 'ros2'
            for _, channel, message, decoded in reader.iter_decoded_messages():
                out.append((channel.topic, message.log_time, decoded))
    return out


def _metadata(path: Path) -> dict:
    return yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


# -- round trip ----------------------------------------------------------------------------
def test_round_trip_both_decoders(tmp_path: Path) -> None:
    written = _messages(400)
    writer = _write(tmp_path / 'bag', written)
    assert [f.name for f in writer.files] == ['bag_0.mcap']

    # rosbags: same bytes, times and order; every message decodes with the stored definitions
    assert _read_rosbags(tmp_path / 'bag') == written
    with BagReader(tmp_path / 'bag') as reader:
        decoded = list(reader.messages())
        assert {t: i.message_count for t, i in reader.topics.items()} == {t: 100 for t in TOPICS}
        assert reader.start_ns == T0 and reader.end_ns == T0 + 399 * 1_000_000
        t, xyz = reader.arrays('/positioner/pose',
                               lambda m: (m.pose.position.x, m.pose.position.y,
                                          m.pose.position.z))
    assert xyz.shape == (100, 3) and t.dtype == np.int64
    np.testing.assert_allclose(xyz[:, 0], 1e-3 * np.arange(2, 400, 4))
    js = [d.message for d in decoded if d.topic == '/legs/joint_states']
    assert js[3].header.stamp.sec == 13 and js[3].header.stamp.nanosec == 91  # stamps kept
    assert list(js[3].name) == ['leg1_length', 'leg1_theta']

    # mcap + mcap_ros2: an independent decoder agrees message for message
    other = _read_mcap(writer.files)
    assert [(t, lt) for t, lt, _ in other] == [(m.topic, m.log_time_ns) for m in written]
    js2 = [d for t, _, d in other if t == '/legs/joint_states']
    assert js2[3].header.stamp.sec == 13
    np.testing.assert_allclose(js2[3].position, js[3].position)
    diag = [d for t, _, d in other if t == '/diagnostics']
    assert diag[5].status[0].message == 'ok 23'


def test_metadata_is_rosbag2_jazzy_v9(tmp_path: Path) -> None:
    _write(tmp_path / 'bag', _messages(40), custom_data={'run': 'unit'})
    info = _metadata(tmp_path / 'bag')
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['ros_distro'] == 'jazzy' and info['custom_data'] == {'run': 'unit'}
    assert info['relative_file_paths'] == ['bag_0.mcap']
    assert info['message_count'] == 40
    assert info['starting_time'] == {'nanoseconds_since_epoch': T0}
    assert info['duration'] == {'nanoseconds': 39 * 1_000_000}
    assert info['files'] == [{'path': 'bag_0.mcap', 'starting_time': {
        'nanoseconds_since_epoch': T0}, 'duration': {'nanoseconds': 39_000_000},
        'message_count': 40}]
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert set(topics) == set(TOPICS)
    target = topics['/positioner/target']['topic_metadata']
    assert target['type'] == 'geometry_msgs/msg/PoseStamped'
    assert target['serialization_format'] == 'cdr'
    assert target['type_description_hash'] == TS.hash_rihs01('geometry_msgs/msg/PoseStamped')
    assert target['offered_qos_profiles'][0]['durability'] == 'transient_local'
    assert target['offered_qos_profiles'][0]['reliability'] == 'reliable'
    assert topics['/legs/joint_states']['message_count'] == 10
    # The QoS survives the round trip (what the player re-offers) ...
    with BagReader(tmp_path / 'bag') as reader:
        assert reader.topics['/positioner/target'].qos == (LATCHED,)
    # ... and each .mcap carries the rosbag2 schema / channel metadata and metadata record.
    with (tmp_path / 'bag' / 'bag_0.mcap').open('rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        channel = next(c for c in summary.channels.values() if c.topic == '/positioner/target')
        assert 'transient_local' in channel.metadata['offered_qos_profiles']
        assert channel.message_encoding == 'cdr'
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert 'message_count: 40' in records['rosbag2']['serialized_metadata']


def test_split_by_size_and_duration(tmp_path: Path) -> None:
    written = _messages(3000, period_ns=1_000_000)  # 3 s of messages
    by_size = _write(tmp_path / 'size', written, split_max_bytes=40_000, chunk_bytes=4096)
    assert len(by_size.files) >= 4
    info = _metadata(tmp_path / 'size')
    assert info['relative_file_paths'] == [f.name for f in by_size.files]
    assert [f['path'] for f in info['files']] == info['relative_file_paths']
    assert sum(f['message_count'] for f in info['files']) == 3000
    # a file may pass the limit by one chunk (4 KiB) plus its summary section (index, schemas)
    assert all(40_000 <= f.stat().st_size < 40_000 + 4096 + 12_288 for f in by_size.files[:-1])
    assert _read_rosbags(tmp_path / 'size') == written
    assert len(_read_mcap(by_size.files)) == 3000

    by_time = _write(tmp_path / 'time', written, split_max_duration_s=1.0)
    spans = [f['duration']['nanoseconds'] for f in _metadata(tmp_path / 'time')['files']]
    assert len(by_time.files) == 3 and max(spans) < 1_000_000_000
    assert _read_rosbags(tmp_path / 'time') == written


def test_zstd_chunk_compression(tmp_path: Path) -> None:
    written = _messages(2000)
    plain = _write(tmp_path / 'plain', written, compression='none')
    packed = _write(tmp_path / 'packed', written, compression='zstd')
    for writer, kind in ((plain, ''), (packed, 'zstd')):
        with writer.files[0].open('rb') as stream:
            summary = make_reader(stream).get_summary()
            assert summary is not None and summary.chunk_indexes
            assert {c.compression for c in summary.chunk_indexes} == {kind}
    assert packed.files[0].stat().st_size < plain.files[0].stat().st_size / 2
    assert _read_rosbags(tmp_path / 'packed') == written
    assert len(_read_mcap(packed.files)) == 2000


def test_every_crc_is_written(tmp_path: Path) -> None:
    """Chunk, data-section and summary CRCs are filled (rosbags' writer leaves them 0) and the
    mcap library validates them; also in split files and in files recovery rewrote."""
    plain = _write(tmp_path / 'plain', _messages(1500), chunk_bytes=4096, split_max_bytes=30_000)
    packed = _write(tmp_path / 'packed', _messages(1500), compression='zstd', chunk_bytes=4096)
    data, _, _ = _killed_recording(tmp_path, 300, 50)
    (tmp_path / 'cut').mkdir()
    (tmp_path / 'cut' / 'cut_0.mcap').write_bytes(data[:len(data) * 2 // 3])
    recover_bag(tmp_path / 'cut')
    files = [*plain.files, *packed.files, tmp_path / 'cut' / 'cut_0.mcap']
    assert len(plain.files) >= 2
    for f in files:
        with f.open('rb') as stream:
            records = list(StreamReader(stream, emit_chunks=True, validate_crcs=True).records)
        chunks = [r for r in records if isinstance(r, Chunk)]
        (data_end,) = [r for r in records if isinstance(r, DataEnd)]
        (footer,) = [r for r in records if isinstance(r, Footer)]
        assert chunks and all(c.uncompressed_crc for c in chunks), f
        assert data_end.data_section_crc and footer.summary_crc, f  # checked by the reader
        raw = f.read_bytes()
        assert footer.summary_crc == zlib.crc32(raw[footer.summary_start:len(raw) - 12])
    for bag in (tmp_path / 'plain', tmp_path / 'packed', tmp_path / 'cut'):
        check = verify_bag(bag)
        assert check.sound and all(c.crc_chunks == c.chunks > 0 for c in check.files)
        assert {(c.data_crc, c.summary_crc) for c in check.files} == {('ok', 'ok')}


def test_flush_puts_chunks_on_disk(tmp_path: Path) -> None:
    writer = BagWriter(tmp_path / 'bag', chunk_bytes=2**20)
    for m in _messages(50):
        writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
    before = writer.files[0].stat().st_size
    writer.flush()
    assert writer.files[0].stat().st_size > before + 50 * 40
    writer.close()
    assert writer.close() == tmp_path / 'bag'  # idempotent
    with pytest.raises(BagError, match='closed'):
        writer.write('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray', _diagnostics(0), T0)


# -- bad input -----------------------------------------------------------------------------
def test_writer_refuses_bad_input(tmp_path: Path) -> None:
    existing = tmp_path / 'old'
    existing.mkdir()
    (existing / 'keep.txt').write_text('x')
    with pytest.raises(BagError, match='exists already'):
        BagWriter(existing)
    assert [p.name for p in existing.iterdir()] == ['keep.txt']
    with pytest.raises(BagError, match='compression'):
        BagWriter(tmp_path / 'a', compression='lz5')
    with pytest.raises(BagError, match='chunk_bytes'):
        BagWriter(tmp_path / 'b', chunk_bytes=10)
    assert not (tmp_path / 'a').exists() and not (tmp_path / 'b').exists()
    with BagWriter(tmp_path / 'c') as writer:
        with pytest.raises(BagError, match='unknown to the ROS 2 Jazzy typestore'):
            writer.add_topic('/x', 'my_msgs/msg/Thing')
        writer.add_topic('/y', 'std_msgs/msg/String')
        with pytest.raises(BagError, match='already recorded as std_msgs/msg/String'):
            writer.add_topic('/y', 'std_msgs/msg/Int32')
    assert [t['topic_metadata']['name'] for t in
            _metadata(tmp_path / 'c')['topics_with_message_count']] == ['/y']


def test_reader_errors_are_specific(tmp_path: Path) -> None:
    with pytest.raises(BagError, match='does not exist'):
        BagReader(tmp_path / 'missing')
    (tmp_path / 'killed').mkdir()
    (tmp_path / 'killed' / 'killed_0.mcap').write_bytes(b'\x89MCAP0\r\n')
    with pytest.raises(BagError, match='run recover_bag'):
        BagReader(tmp_path / 'killed')
    (tmp_path / 'garbage').mkdir()
    (tmp_path / 'garbage' / 'metadata.yaml').write_text('rosbag2_bagfile_information: 3\n')
    with pytest.raises(BagError, match='not a readable bag'):
        BagReader(tmp_path / 'garbage')
    _write(tmp_path / 'ok', _messages(8))
    with BagReader(tmp_path / 'ok') as reader, pytest.raises(BagError, match='no topic /nope'):
        list(reader.raw_messages(['/nope']))


# -- recovery ------------------------------------------------------------------------------
def _killed_recording(tmp_path: Path, n: int, every: int) -> tuple[bytes, list[tuple[int, int]],
                                                                    list[RawMessage]]:
    """File bytes of a recording flushed every ``every`` messages, as a SIGKILL right after the
    last flush leaves them, with (file size, messages written) at each flush."""
    written = _messages(n)
    writer = BagWriter(tmp_path / 'live', chunk_bytes=2**20, compression='zstd')
    points = [(writer.files[0].stat().st_size, 0)]
    for i, m in enumerate(written, 1):
        writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
        if i % every == 0:
            writer.flush()
            points.append((writer.files[0].stat().st_size, i))
    data = writer.files[0].read_bytes()
    writer.close()
    return data, points, written


def test_recover_truncated_at_many_offsets(tmp_path: Path) -> None:
    data, points, written = _killed_recording(tmp_path, 600, 50)
    assert len(data) == points[-1][0]
    cuts = sorted({0, 3, 8, 40, *(s for s, _ in points), *(s + 17 for s, _ in points[:-1]),
                   *(s - 1 for s, _ in points[1:]), len(data) // 3, len(data) // 2})
    for cut in cuts:
        bag = tmp_path / f'cut_{cut}'
        bag.mkdir()
        (bag / 'cut_0.mcap').write_bytes(data[:cut])
        report = recover_bag(bag)
        complete = max((n for size, n in points if size <= cut), default=0)
        upper = min((n for size, n in points if size > cut), default=len(written))
        assert complete <= report.message_count <= upper, cut
        assert report.files[0].status == 'recovered' and report.metadata_written
        assert (bag / 'cut_0.mcap.truncated').read_bytes() == data[:cut]  # original kept
        got = _read_rosbags(bag)
        assert got == written[:len(got)] and len(got) == report.message_count  # a prefix
        assert len(_read_mcap([bag / 'cut_0.mcap'])) == len(got)
        assert _metadata(bag)['message_count'] == len(got)
        again = recover_bag(bag)  # a complete bag is left alone
        assert not again.changed and again.files[0].status == 'complete'


def test_recover_split_bag_and_missing_metadata(tmp_path: Path) -> None:
    written = _messages(3000)
    _write(tmp_path / 'bag', written, split_max_bytes=40_000, chunk_bytes=4096)
    (tmp_path / 'bag' / 'metadata.yaml').unlink()
    last = max((tmp_path / 'bag').glob('*.mcap'), key=lambda p: int(p.stem.split('_')[-1]))
    last.write_bytes(last.read_bytes()[:-100])  # the summary of the last file is cut
    report = recover_bag(tmp_path / 'bag')
    statuses = [f.status for f in report.files]
    assert statuses[:-1] == ['complete'] * (len(statuses) - 1) and statuses[-1] == 'recovered'
    assert report.message_count == 3000  # only the summary was lost: every chunk is whole
    assert _read_rosbags(tmp_path / 'bag') == written


def test_recover_refuses_what_is_not_a_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                           ) -> None:
    with pytest.raises(BagError, match='not a bag directory'):
        recover_bag(tmp_path / 'nothing')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(BagError, match=r'no \.mcap storage files'):
        recover_bag(tmp_path / 'empty')
    bad = tmp_path / 'bad'
    _write(bad, _messages(20))
    (bad / 'metadata.yaml').unlink()
    (bad / 'zz_9.mcap').write_bytes(b'PK\x03\x04 a zip, not an MCAP file')
    before = {p.name: p.read_bytes() for p in bad.iterdir()}
    with pytest.raises(BagError, match='not an MCAP file'):
        recover_bag(bad)
    assert {p.name: p.read_bytes() for p in bad.iterdir()} == before  # nothing changed
    assert recover_tool.main([str(bad)]) == Exit.USAGE
    assert 'not an MCAP file' in capsys.readouterr().err
    (bad / 'zz_9.mcap').unlink()
    assert recover_tool.main([str(bad)]) == Exit.OK
    assert 'wrote' in capsys.readouterr().out
    assert len(_read_rosbags(bad)) == 20


# -- topics, QoS, replay timing ------------------------------------------------------------
def test_topic_selection() -> None:
    default = TopicSelection.from_params([], '')
    assert all(default.matches(t) for t in CELL_TOPICS) and not default.matches('/rosout')
    chosen = TopicSelection.from_params(['/legs/joint_states'], '/sim/.*')
    assert chosen.matches('/legs/joint_states') and chosen.matches('/sim/platform/true_pose')
    assert not chosen.matches('/positioner/pose') and not chosen.matches('/x/sim/y')
    with pytest.raises(InputError, match='not a regular expression'):
        TopicSelection.from_params([], '(')
    with pytest.raises(InputError, match='absolute'):
        TopicSelection.from_params(['legs/joint_states'], '')


def test_qos_choices() -> None:
    best_effort = make_qos(QosHistory.KEEP_LAST, 5, QosReliability.BEST_EFFORT,
                           QosDurability.VOLATILE)
    assert recording_qos([LATCHED], 0).durability == QosDurability.TRANSIENT_LOCAL
    assert recording_qos([LATCHED], 0).history == QosHistory.KEEP_ALL
    assert recording_qos([LATCHED, STREAM], 10).durability == QosDurability.VOLATILE
    assert recording_qos([STREAM, best_effort], 10).reliability == QosReliability.BEST_EFFORT
    assert recording_qos([STREAM], 10).reliability == QosReliability.RELIABLE
    assert recording_qos([], 7).depth == 7
    latched = playback_qos([LATCHED], 1000)
    assert (latched.durability, latched.depth) == (QosDurability.TRANSIENT_LOCAL, 1)
    assert playback_qos([STREAM], 1000).depth == 1000


def test_play_waits_for_due_times() -> None:
    now = [100.0]
    waits: list[float] = []

    def wait(seconds: float) -> bool:
        waits.append(seconds)
        now[0] += seconds
        return False

    sent: list[tuple[float, int]] = []
    msgs = [RawMessage('/a', 't', T0 + k * 500_000_000, b'') for k in range(5)]  # 0.5 s apart
    timing = PlaybackTiming.starting(T0, rate=2.0, start_offset_s=0.5)
    count = play(msgs, timing, lambda m: sent.append((now[0], m.log_time_ns)), wait,
                 clock=lambda: now[0])
    assert count == 4  # the first message is before the start offset
    assert [round(t - 100.0, 9) for t, _ in sent] == [0.0, 0.25, 0.5, 0.75]
    assert waits == pytest.approx([0.25, 0.25, 0.25])
    stopped = play(msgs, PlaybackTiming(1.0, T0), lambda m: None, lambda s: True,
                   clock=lambda: now[0])
    assert stopped == 1  # the first is due at once; the stop request ends the wait for the next
    with pytest.raises(InputError, match='rate'):
        PlaybackTiming(0.0, T0)
    with pytest.raises(InputError, match='start_offset_s'):
        PlaybackTiming.starting(T0, 1.0, -1.0)


# -- a failing disk ----------------------------------------------------------------------------
def _read_back(bag: Path) -> list[RawMessage]:
    """Every message of a closed bag, checked sound first (verify_bag: CRCs, index)."""
    check = verify_bag(bag)
    assert check.sound and all(f.complete for f in check.files), check
    return _read_rosbags(bag)


@pytest.mark.parametrize('code', [errno.ENOSPC, errno.EIO], ids=['ENOSPC', 'EIO'])
@pytest.mark.parametrize('operation', ['write', 'flush', 'split', 'close'])
def test_a_failed_write_closes_the_bag_with_every_message(tmp_path: Path, code: int,
                                                          operation: str,
                                                          monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    """The disk fails once, in the middle of a record, at each call that writes: the bag is
    closed (the torn record cut off, the chunk being filled written after all) with every
    message accepted, and the failure names the errno, the call and the file."""
    disk = FaultyDisk(monkeypatch)
    written = _messages(1200)
    # 'split': chunks only at a flush or a split (1 MiB), a new file every 100 ms of log time
    options: dict[str, Any] = ({'chunk_bytes': 2**20, 'split_max_duration_s': 0.1}
                               if operation == 'split' else {'chunk_bytes': 4096})
    writer = BagWriter(tmp_path / 'bag', **options)
    writer.add_topic('/positioner/target', 'geometry_msgs/msg/PoseStamped', [LATCHED])
    accepted = 0
    with pytest.raises(BagWriteError) as raised:
        for i, m in enumerate(written):
            if i == 450:
                disk.fail(code, after=37)
                if operation == 'flush':
                    writer.flush()
                elif operation == 'close':
                    writer.close()
            accepted += 1
            writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
            if i % 100 == 99 and operation != 'split':  # a split flushes on its own
                writer.flush()
    failure = raised.value.failure
    assert disk.failures == 1 and writer.closed and writer.failure == failure
    assert (failure.operation, failure.errno) == (operation, code)
    assert failure.error == errno.errorcode[code]
    assert failure.file.parent == tmp_path / 'bag' and failure.file.suffix == '.mcap'
    assert failure.closed and failure.lost == 0 and failure.messages == accepted
    assert failure.line() == (f'{errno.errorcode[code]} ({os.strerror(code)}) on {operation} '
                              f'of {failure.file}; bag closed with {accepted} messages, 0 lost')
    assert _read_back(tmp_path / 'bag') == written[:accepted]
    assert not (tmp_path / 'bag' / RESERVE_FILE).exists()
    assert writer.close() == tmp_path / 'bag'  # closed already: nothing more happens
    with pytest.raises(BagError, match='closed'):
        writer.write(*written[0][:2], written[0].data, T0)


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_a_file_size_limit_moves_the_last_chunks_to_one_more_file(
        tmp_path: Path, compression: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """EFBIG for good at 48 kB a file (as RLIMIT_FSIZE): no room for the summary after the last
    chunk, so chunks go back out of the file until it fits, and into a second file; nothing
    is lost."""
    disk = FaultyDisk(monkeypatch)
    disk.limit(48_000)
    written = _messages(20_000)
    writer = BagWriter(tmp_path / 'bag', chunk_bytes=4096, compression=compression,
                       reserve=False)
    accepted = 0
    with pytest.raises(BagWriteError) as raised:
        for m in written:
            accepted += 1
            writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
    failure = raised.value.failure
    assert failure.error == 'EFBIG' and failure.operation == 'write'
    assert failure.closed and failure.lost == 0 and failure.messages == accepted
    assert [f.name for f in writer.files] == ['bag_0.mcap', 'bag_1.mcap']
    assert all(f.stat().st_size <= 48_000 for f in writer.files)
    assert _read_back(tmp_path / 'bag') == written[:accepted]
    assert _metadata(tmp_path / 'bag')['message_count'] == accepted


def test_a_dead_disk_leaves_what_recover_bag_restores(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """EIO for good, cutting back included: the file cannot be finished. No metadata.yaml
    (a reader says to run recover_bag); the failure counts what is on disk, and recover_bag
    restores exactly that, a prefix of what was written."""
    disk = FaultyDisk(monkeypatch)
    written = _messages(2000)
    writer = BagWriter(tmp_path / 'bag', chunk_bytes=4096)
    accepted = 0
    with pytest.raises(BagWriteError) as raised:
        for i, m in enumerate(written):
            if i == 900:
                disk.fail(errno.EIO, after=100, once=False)
                disk.cut_fails = True
            accepted += 1
            writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
    failure = raised.value.failure
    assert failure.error == 'EIO' and not failure.closed
    assert 0 < failure.messages < accepted and failure.lost == accepted - failure.messages
    assert f'bag NOT closed: recover_bag {tmp_path / "bag"} restores {failure.messages} ' \
           f'messages' in failure.line()
    assert not (tmp_path / 'bag' / 'metadata.yaml').exists()
    with pytest.raises(BagError, match='recover_bag'):
        BagReader(tmp_path / 'bag')
    monkeypatch.undo()  # the disk is repaired
    report = recover_bag(tmp_path / 'bag')
    assert report.message_count == failure.messages
    assert _read_back(tmp_path / 'bag') == written[:failure.messages]


def test_the_reserve_grows_with_the_index_and_goes_at_close(tmp_path: Path) -> None:
    writer = BagWriter(tmp_path / 'bag', chunk_bytes=1024)
    reserve = tmp_path / 'bag' / RESERVE_FILE
    first = writer.reserve_bytes
    assert first >= 2 * 1024 and reserve.stat().st_size == first
    for i, m in enumerate(_messages(30_000)):
        writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
        if i % 1000 == 999:
            writer.flush()
    # Closing needs the index of ~3400 chunks now: the reserve grew to twice that at least.
    current = writer._file
    assert current is not None
    assert writer.reserve_bytes >= 2 * current.close_bytes() > first
    assert reserve.stat().st_size == writer.reserve_bytes
    data_bytes, reserved = current.size(), writer.reserve_bytes
    writer.close()
    assert not reserve.exists() and writer.reserve_bytes == 0
    tail = writer.files[0].stat().st_size - data_bytes
    assert tail + len((tmp_path / 'bag' / 'metadata.yaml').read_bytes()) < reserved / 2
    print(f'close wrote {tail} + metadata.yaml bytes; reserve {reserved}')
    assert BagWriter(tmp_path / 'none', reserve=False).reserve_bytes == 0


def test_a_disk_refusing_the_first_bytes_leaves_nothing(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    FaultyDisk(monkeypatch).fail(errno.ENOSPC, after=0, once=False)
    with pytest.raises(BagError, match='cannot start the bag: No space left on device'):
        BagWriter(tmp_path / 'parent' / 'bag')
    assert not (tmp_path / 'parent' / 'bag').exists()


def test_a_full_filesystem_closes_the_bag_with_the_reserve(tmp_path: Path) -> None:
    """A real ENOSPC: a 2 MiB tmpfs filled by the writer. The reserve's space closes the bag
    with every message accepted (needs the right to mount: root, as in CI)."""
    written = _messages(60_000)
    try:
        with small_filesystem(tmp_path / 'disk', 2 * 2**20) as disk:
            writer = BagWriter(disk / 'bag', chunk_bytes=16384, compression='zstd')
            accepted = 0
            with pytest.raises(BagWriteError) as raised:
                for i, m in enumerate(written):
                    accepted += 1
                    writer.write(m.topic, m.msgtype, m.data, m.log_time_ns)
                    if i % 500 == 499:
                        writer.flush()
            failure = raised.value.failure
            assert failure.error == 'ENOSPC' and failure.closed and failure.lost == 0
            assert failure.messages == accepted > 10_000
            assert _read_back(disk / 'bag') == written[:accepted]
    except MountError as err:
        pytest.skip(f'a full filesystem needs a tmpfs: {err}')


def test_library_imports_without_rclpy() -> None:
    code = ('import sys, positioning_cell.bag, positioning_cell.tools.recover_bag; '
            'sys.exit(int("rclpy" in sys.modules))')
    assert subprocess.run([sys.executable, '-c', code], check=False).returncode == 0
