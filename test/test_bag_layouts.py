"""Bags other tools wrote (issue 21): the recorded `make run` bag (test/data/makerun) written
again by the ``mcap`` library's writer in each layout of positioning_cell.testing.layouts
(chunked or not; message and chunk indexes, both, either or none; statistics, summary offsets,
definitions repeated in the summary, or no summary section at all; none / zstd / lz4 chunks
from 700 B to 8 MiB; with or without CRCs; split into 2 or 3 files with metadata.yaml) carries
the same messages, and every reader of the cell gives what it gives on the original:
analyze_bag (its summary.json: every count, label and verdict, every number to 1e-12), the
fleet digest, calibrate_cell --from-bag (the calibration data; the calibration itself for a
split fastwrite bag), the player (the same topics and QoS, every message in order with its
bytes). Each file is read through its indexes where its summary has them, else from a scan of
its records; every layout is sound for verify_bag and left alone by recover_bag (a CRC of 0
is "not computed", not damage). Damage in a scanned file is still found: a corrupt chunk is
named and the rest analysed, a flipped payload byte of an unchunked file fails the
data-section CRC, a broken record ends the readable part. No ROS graph."""

from __future__ import annotations

import json
import shutil
import struct
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import pytest
import yaml
from json_compare import differences
from mcap.records import Chunk
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader, breakup_chunk

from positioning_cell.accuracy import MonitorSettings
from positioning_cell.analysis import analyse_bag
from positioning_cell.analysis.fleet import digest
from positioning_cell.bag import (
    BagReader,
    DamagedBagError,
    IndexedBag,
    PlaybackTiming,
    RawMessage,
    TopicInfo,
    open_bag,
    play,
    recover_bag,
    verify_bag,
    verify_file,
)
from positioning_cell.calibration.bag import read_bag
from positioning_cell.calibration.collect import Collected
from positioning_cell.config import config_path
from positioning_cell.testing.layouts import LAYOUTS, Layout, rewrite_bag
from positioning_cell.tools import analyze_bag
from positioning_cell.tools.calibrate_cell import main as calibrate_main
from positioning_cell.tools.exits import Exit

MAKE_RUN = Path(__file__).resolve().parent / 'data' / 'makerun' / 'bag'
SETTINGS = MonitorSettings.from_file(config_path('cell.yaml'))
#: The layouts whose files are scanned, and why; the others are read through their indexes
#: (definitions-only-in-chunks too: its channels and schemas from its first chunk).
SCANNED = {
    'fastwrite': 'no chunk index',
    'unchunked-with-crcs': 'no chunk index',
    'chunks-without-any-index': 'no chunk index',
    'chunk-index-only': 'chunks without message indexes',
    'message-index-only': 'no chunk index',
    'no-summary': 'no summary section',
    'no-summary-unchunked': 'no summary section',
    'fastwrite-split-in-2': 'no chunk index',
}
PLAY_FROM_S = 100.0  # a playback that starts into the bag


class Analysed(NamedTuple):
    """What analyze_bag and the fleet give for a bag, without its path."""

    summary: dict[str, Any]
    digest: dict[str, Any]


class Reference(NamedTuple):
    """What the readers give on the original bag."""

    analysed: Analysed
    topics: dict[str, TopicInfo]
    played: list[RawMessage]
    played_from: list[RawMessage]


def _analysed(bag: Path, out: Path) -> Analysed:
    """analyze_bag's work on ``bag`` (its ``analyze``, no plots; no problem found): its
    summary.json, and the fleet's digest of the same analysis as JSON, registrations
    included (the fleet's task, digest_bag, is that digest of analyse_bag's analysis: one
    analysis serves both, each layout read once for them)."""
    output = analyze_bag.analyze(bag, out, plots=False)
    assert not output.analysis.problems, output.analysis.problems
    summary: dict[str, Any] = json.loads(output.summary.read_text())
    summary.pop('bag')
    summary.pop('plots', None)
    digested = digest(output.analysis)
    doc = digested.to_dict()
    doc.pop('bag')
    doc['registrations'] = [asdict(r) for r in digested.registrations]
    return Analysed(summary, json.loads(json.dumps(doc)))


def _played(bag: Path, start_offset_s: float = 0.0,
            ) -> tuple[dict[str, TopicInfo], list[RawMessage]]:
    """What the player node does with ``bag`` (open_bag, every topic, play at rate 1 from
    ``start_offset_s`` into the bag), on a simulated clock: its topics and what it publishes,
    each no earlier than its due time."""
    now = [0.0]
    published: list[RawMessage] = []

    def publish(message: RawMessage) -> None:
        assert now[0] >= timing.due_s(message.log_time_ns) - 1e-9
        published.append(message)

    def wait(seconds: float) -> bool:
        now[0] += seconds
        return False

    with open_bag(bag) as source:
        topics = dict(source.topics)
        timing = PlaybackTiming.starting(source.start_ns, 1.0, start_offset_s)
        count = play(source.raw_messages(sorted(topics), timing.origin_ns), timing, publish,
                     wait, clock=lambda: now[0])
    assert count == len(published)
    return topics, published


def _calibration(bag: Path) -> Collected:
    """What calibrate_cell --from-bag identifies from: the data of the bag's last run."""
    return read_bag(bag, say=lambda _: None)


@pytest.fixture(scope='module')
def original(tmp_path_factory: pytest.TempPathFactory) -> Reference:
    out = tmp_path_factory.mktemp('original')
    topics, played = _played(MAKE_RUN)
    with BagReader(MAKE_RUN) as reader:  # rosbags: the order and bytes the player must give
        assert played == list(reader.raw_messages()) and len(played) == 13016
        assert topics == reader.topics
    _, played_from = _played(MAKE_RUN, PLAY_FROM_S)
    start = played[0].log_time_ns + round(PLAY_FROM_S * 1e9)
    assert played_from == [m for m in played if m.log_time_ns >= start]
    return Reference(_analysed(MAKE_RUN, out), topics, played, played_from)


@pytest.fixture(scope='module')
def original_calibration() -> Collected:
    """What calibrate_cell --from-bag reads from the original bag."""
    calibration = _calibration(MAKE_RUN)
    assert len(calibration.fit.joints) == 30 and len(calibration.hold_out.joints) == 6
    return calibration


@pytest.fixture(scope='module', params=sorted(LAYOUTS))
def variant(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The make run bag written again in one layout."""
    name: str = request.param
    return rewrite_bag(MAKE_RUN, tmp_path_factory.mktemp('layouts') / name, LAYOUTS[name])


def test_each_layout_is_laid_out_as_named_and_read_the_way_it_allows(variant: Path,
                                                                       tmp_path: Path) -> None:
    layout = LAYOUTS[variant.name]
    check = verify_bag(variant)
    assert check.sound, check.lines()
    assert len(check.files) == layout.files and (variant / 'metadata.yaml').is_file()
    for f in check.files:
        assert (f.chunks > 0) == layout.chunked
        assert f.crc_chunks == (f.chunks if layout.crcs else 0)
        assert f.data_crc == ('ok' if layout.data_crc else 'absent')
        assert f.summary_crc == ('ok' if layout.crcs else 'absent')
        assert (f.message_count is not None) == (layout.statistics and layout.summary)
    with IndexedBag(variant) as bag:
        reason = SCANNED.get(variant.name)
        assert bag.scans == ({f.name: reason for f in bag.files} if reason else {})
        assert bag.message_count == 13016
    copy = tmp_path / 'copy'
    shutil.copytree(variant, copy)
    report = recover_bag(copy)
    assert not report.changed and {f.status for f in report.files} == {'complete'}
    assert sorted(p.name for p in copy.iterdir()) == sorted(p.name for p in variant.iterdir())


@pytest.fixture(scope='module')
def analysed(variant: Path, tmp_path_factory: pytest.TempPathFactory) -> Analysed:
    """The layout analysed (once for the two tests below)."""
    return _analysed(variant, tmp_path_factory.mktemp('analysed'))


def test_analyze_bag_gives_the_same_figures(analysed: Analysed, original: Reference) -> None:
    assert differences(original.analysed.summary, analysed.summary) == []


def test_the_fleet_digest_is_the_same(analysed: Analysed, original: Reference) -> None:
    assert differences(original.analysed.digest, analysed.digest) == []


def test_calibrate_from_bag_gets_the_same_data(variant: Path,
                                               original_calibration: Collected) -> None:
    got, want = _calibration(variant), original_calibration
    for part in ('fit', 'hold_out'):
        for a, b in zip(getattr(got, part), getattr(want, part), strict=True):
            if a is None or b is None:  # conditions not recorded: in neither
                assert a is None and b is None
                continue
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0.0)
    for part in ('fit_commanded', 'hold_out_commanded'):
        for a, b in zip(getattr(got, part), getattr(want, part), strict=True):
            np.testing.assert_array_equal(a, b)
    assert got.skipped == want.skipped


def test_the_player_plays_every_message_in_order(variant: Path, original: Reference) -> None:
    topics, played = _played(variant)
    assert topics == original.topics  # types, counts and the QoS the player offers again
    assert played == original.played
    assert _played(variant, PLAY_FROM_S)[1] == original.played_from


def _calibration_file(out: Path) -> dict[str, Any]:
    """The identified parameters calibrate_cell wrote into ``out``."""
    doc: dict[str, Any] = yaml.safe_load((out / 'calibration.yaml').read_text())
    return doc['calibration']['parameters']  # type: ignore[no-any-return]


def test_calibrate_cell_identifies_the_same_calibration_from_a_split_fastwrite_bag(
        tmp_path: Path) -> None:
    """The whole command on a bag of two unchunked files without index or CRC: the same
    parameters and uncertainties as from the original."""
    bag = rewrite_bag(MAKE_RUN, tmp_path / 'fastwrite', LAYOUTS['fastwrite-split-in-2'])
    assert calibrate_main(['--from-bag', str(MAKE_RUN), '--out', str(tmp_path / 'a')]) == 0
    assert calibrate_main(['--from-bag', str(bag), '--out', str(tmp_path / 'b')]) == 0
    before, after = _calibration_file(tmp_path / 'a'), _calibration_file(tmp_path / 'b')
    assert len(before) >= 20 and differences(before, after) == []


# -- damage in a scanned file ------------------------------------------------------------------
def _records(mcap: Path) -> Iterator[tuple[int, int, int]]:
    """(offset, opcode, end) of each top-level record of a whole MCAP file's data section."""
    data = mcap.read_bytes()
    pos = 8
    while True:
        op, length = struct.unpack_from('<BQ', data, pos)
        if op == 0x0F:  # DataEnd
            return
        yield pos, op, pos + 9 + length
        pos += 9 + length


def _flip(mcap: Path, at: int, n: int = 1) -> None:
    data = bytearray(mcap.read_bytes())
    data[at:at + n] = bytes(b ^ 0xFF for b in data[at:at + n])
    mcap.write_bytes(bytes(data))


def _analyze(bag: Path, out: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """analyze_bag on a damaged bag: it exits 3 (analysed in part); what it printed."""
    assert analyze_bag.main([str(bag), '--out', str(out), '--no-plots']) == \
        Exit.NOT_ACHIEVED
    return capsys.readouterr().err


def test_a_corrupt_chunk_of_a_file_without_indexes_is_named_and_the_rest_analysed(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = rewrite_bag(MAKE_RUN, tmp_path / 'bag', Layout(index='none', chunk_size=64 * 1024))
    (mcap,) = bag.glob('*.mcap')
    chunks = [(at, end) for at, op, end in _records(mcap) if op == 0x06]
    with mcap.open('rb') as stream:
        counts = [sum(isinstance(r, McapMessage) for r in breakup_chunk(r))
                  for r in StreamReader(stream, emit_chunks=True).records
                  if isinstance(r, Chunk)]
    number = len(chunks) // 2
    at, end = chunks[number]
    _flip(mcap, (at + end) // 2, 16)
    with pytest.raises(DamagedBagError, match=r'CRC mismatch|decompress') as err:
        IndexedBag(bag)
    assert (err.value.chunk, err.value.offset) == (number, at)
    printed = _analyze(bag, tmp_path / 'out', capsys)
    assert f'chunk {number} at byte {at}' in printed
    analysis = analyse_bag(bag, SETTINGS)
    assert analysis.message_count == sum(counts) - counts[number] and counts[number] > 0
    assert any(f'1 corrupt chunk ({mcap.name} chunk {number})' in p for p in analysis.problems)


def test_a_flipped_payload_byte_of_an_unchunked_file_fails_the_data_section_crc(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = rewrite_bag(MAKE_RUN, tmp_path / 'bag', LAYOUTS['unchunked-with-crcs'])
    (mcap,) = bag.glob('*.mcap')
    ends = [end for _, op, end in _records(mcap) if op == 0x05]
    _flip(mcap, ends[len(ends) // 2] - 1)  # the last byte of a message's payload
    with pytest.raises(DamagedBagError, match='data section CRC mismatch'):
        IndexedBag(bag)
    (line,) = verify_file(mcap).problems
    assert 'the 13016 messages stored outside chunks (one may be corrupt' in line
    assert line in _analyze(bag, tmp_path / 'out', capsys)
    assert analyse_bag(bag, SETTINGS).message_count == 13016  # none lost


def test_a_broken_record_of_an_unchunked_file_ends_its_readable_part(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = rewrite_bag(MAKE_RUN, tmp_path / 'bag', LAYOUTS['fastwrite'])
    (mcap,) = bag.glob('*.mcap')
    messages = [at for at, op, _ in _records(mcap) if op == 0x05]
    at = messages[5000]
    data = bytearray(mcap.read_bytes())
    struct.pack_into('<Q', data, at + 1, 2**40)  # its length runs past the file
    mcap.write_bytes(bytes(data))
    with pytest.raises(DamagedBagError, match=f'the record at byte {at} is damaged'):
        IndexedBag(bag)
    assert f'bytes {at} ..' in _analyze(bag, tmp_path / 'out', capsys)
    assert analyse_bag(bag, SETTINGS).message_count == 5000
