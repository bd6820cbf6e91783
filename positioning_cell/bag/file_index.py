"""The index of one MCAP storage file: where its messages are, from its summary when it has
what the fast read needs, else from a sequential scan of its records.

:func:`read_index` opens a file: the footer (last 8 + 29 bytes: record, magic) gives
``summary_start`` and the ``summary_crc`` (CRC-32 of the summary section up to the footer's
``summary_offset_start`` field), checked when nonzero. The summary's Schema, Channel, Chunk
Index and Statistics records are parsed here, the chunk indexes vectorised (a 280 MiB bag has
~4200: ~17 ms here, ~90 ms with the ``mcap`` library's ``get_summary``). The DataEnd record
sits just before the summary. A chunk index lists the file offset of each channel's Message
Index record; the records of one chunk follow each other, so the gap to the next one
(15 + 16·n bytes) says how many messages of a channel the chunk holds (as rosbags' reader
decides). The file is then read through that index
(:class:`positioning_cell.bag.indexed.IndexedBag`: only the wanted chunks and records).

Every valid MCAP file is read (MCAP spec, https://mcap.dev/spec: chunks, message indexes,
the summary and its parts, the CRCs are all optional). The index is used when the summary
has a chunk index and every chunk it lists has message indexes: the files the cell's
recorder, rosbags and ``ros2 bag record`` (default and zstd presets) write. The channels the
message indexes name and their schemas come from the summary, or, for a writer that does not
repeat them there, from the first chunks (read in file order until all are defined).
Otherwise the file's records are scanned once, front to back, when it is opened
(:class:`_Scan`): no summary section at all (``summary_start`` 0), no chunk index (an
unchunked file such as rosbag2's ``fastwrite`` preset writes, or chunks without a chunk
index), chunks without message indexes, definitions outside the chunks. The scan walks the
top-level records (schemas, channels, messages, chunks; message indexes, attachments and
metadata skipped), decompresses each chunk (checked against its CRC when nonzero) and walks
its records, and notes each message's channel, log time and place: the segment (a chunk, or a
run of at most one block of consecutive top-level records) and the byte offset of its record
in the segment's records. The same read then serves both kinds of file: a segment is read as
a chunk is. The data-section CRC is checked during the scan (when nonzero), the messages
found against the statistics (when the summary has them). Memory: 32 bytes per message of a
scanned file.

A file without a footer (a recording killed before it closed the file) raises
:class:`UnindexedBagError`; damage (a CRC mismatch, broken framing, an index that contradicts
itself or the records) :class:`DamagedBagError`; a CRC of 0 means "not computed" and is not
checked.
"""

from __future__ import annotations

import mmap
import os
import struct
import zlib
from array import array
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import lz4.frame
import numpy as np
import zstandard
from mcap.opcode import Opcode
from numpy.typing import NDArray

from positioning_cell.bag.cdr import gather as gather_bytes
from positioning_cell.bag.errors import (
    BagError,
    DamagedBagError,
    UnindexedBagError,
    UnsupportedBagError,
)
from positioning_cell.bag.metadata import FileSummary, TopicMeta, topic_meta
from positioning_cell.bag.verify import MCAP_MAGIC, MIN_MCAP_BYTES, verify_file

#: Default block budget: bytes read per block, and bytes decompressed per block (and the
#: length of a scanned run of unchunked records).
DEFAULT_BLOCK_BYTES = 8 * 2**20
RECORD = 1 + 8                      # opcode, length
FOOTER = RECORD + 8 + 8 + 4         # summary_start, summary_offset_start, summary_crc
DATA_END = RECORD + 4               # data_section_crc
CHUNK_FIXED = 8 + 8 + 8 + 4 + 4     # start, end, uncompressed size, crc, compression length
MESSAGE = RECORD + 2 + 4 + 8 + 8    # + channel, sequence, log time, publish time
INDEX = RECORD + 2 + 4              # + channel, byte length of the (log time, offset) pairs
CHUNK_INDEX_FIXED = 8 + 8 + 8 + 8 + 4
COMPRESSIONS = ('', 'zstd', 'lz4')
MAX_CHUNK = 2**32                   # records of a chunk addressed by 32 bits in file_key
TIME_LIMIT = 2**63                  # log times are returned as int64
U64 = np.dtype('<u8')
#: Record kinds of a data section (MCAP spec; the DataEnd record ends it), as verify_bag has
#: them; a scanned segment of top-level records holds the first three only.
_DATA_RECORDS = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.CHUNK,
                           Opcode.MESSAGE_INDEX, Opcode.ATTACHMENT, Opcode.METADATA,
                           Opcode.DATA_END})
_SEGMENT_RECORDS = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE})
_HEAD = struct.Struct('<BQ').unpack_from            # opcode, length
_MESSAGE_HEAD = struct.Struct('<HIQ').unpack_from   # channel, sequence, log time


# -- the index of one file ---------------------------------------------------------------------
class SchemaInfo(NamedTuple):
    """A Schema record: message type name, encoding (``ros2msg``, ``ros2idl``), definition."""

    name: str
    encoding: str
    data: str


class ChannelInfo(NamedTuple):
    """A Channel record: id, schema id (0: none), topic, message encoding, metadata."""

    id: int
    schema_id: int
    topic: str
    encoding: str
    metadata: dict[str, str]


class Chunks(NamedTuple):
    """The segments of a file in file order (arrays (C,) int64): its chunks (from the chunk
    indexes, or from the chunk records a scan found), and in a scanned file also runs of
    top-level records (``plain``: records stored as they are, no chunk record around them;
    ``compressed`` = ``uncompressed`` = ``length``). ``start`` / ``end``: log-time range.
    The message index offsets of an indexed file flattened (arrays (K,): chunk number,
    channel id, file offset, and the messages the spacing of the offsets leaves room for;
    empty for a scanned file)."""

    start: NDArray[np.int64]
    end: NDArray[np.int64]
    offset: NDArray[np.int64]
    length: NDArray[np.int64]
    index_length: NDArray[np.int64]
    compressed: NDArray[np.int64]
    uncompressed: NDArray[np.int64]
    compression: tuple[str, ...]
    plain: NDArray[np.bool_]
    mi_chunk: NDArray[np.int64]
    mi_channel: NDArray[np.int64]
    mi_offset: NDArray[np.int64]
    mi_count: NDArray[np.int64]


class Scanned(NamedTuple):
    """What the scan of a file found (module docstring), every message in file order (arrays
    (M,) int64): its segment number, channel id, log time (ns), and the byte offset of its
    record in the segment's records; ``reason``: why the file was scanned."""

    segment: NDArray[np.int64]
    channel: NDArray[np.int64]
    log: NDArray[np.int64]
    offset: NDArray[np.int64]
    reason: str


@dataclass(frozen=True)
class FileIndex:
    """One storage file opened (``number``: its place in the bag's split order): its data
    section (bytes ``data_start`` .. ``data_end``, the DataEnd record, and the CRC that
    record stores), schemas and channels by id, segments, message counts (total and per
    channel id: the statistics, or what a scan found; None when unknown), and for a scanned
    file where each message is (``scanned``; None: read through its message indexes)."""

    path: Path
    number: int
    data_start: int
    data_end: int
    data_crc: int
    schemas: Mapping[int, SchemaInfo]
    channels: Mapping[int, ChannelInfo]
    chunks: Chunks
    message_count: int | None
    channel_counts: Mapping[int, int] | None
    scanned: Scanned | None = None

    def counts(self) -> dict[int, int]:
        """Messages per channel id: the statistics' counts, what a scan found, or (an indexed
        file without statistics) what the spacing of its message indexes leaves room for."""
        if self.channel_counts is not None:
            return dict(self.channel_counts)
        c = self.chunks
        ids, inverse = np.unique(c.mi_channel, return_inverse=True)
        totals = np.bincount(inverse.reshape(-1), weights=c.mi_count, minlength=ids.shape[0])
        return {int(k): int(n) for k, n in zip(ids.tolist(), totals.tolist(), strict=True)}

    @property
    def log_range(self) -> tuple[int, int] | None:
        """Log times (ns) of the first and last message (from the chunk indexes in an
        indexed file, from the messages in a scanned one); None without any."""
        if self.scanned is not None:
            log = self.scanned.log
            return (int(log.min()), int(log.max())) if log.size else None
        c = self.chunks
        return (int(c.start.min()), int(c.end.max())) if c.start.size else None


def column(rows: NDArray[np.uint8], at: int, dtype: np.dtype[Any]) -> NDArray[Any]:
    """Column ``at`` (bytes) of ``rows`` (N, w) viewed as ``dtype``, int64 for integers."""
    view = rows[:, at:at + dtype.itemsize].view(dtype).reshape(-1)
    return view.astype(np.int64) if dtype.kind in 'iu' else view.copy()


def rows(buffer: NDArray[np.uint8], start: NDArray[np.int64], width: int) -> NDArray[np.uint8]:
    """(N, width) uint8: the bytes at ``start`` (checked by the caller)."""
    return gather_bytes(buffer, start, width).view(np.uint8).reshape(-1, width)


def spread(starts: NDArray[np.int64], counts: NDArray[np.int64], step: int,
           ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """For groups of ``counts`` items at ``starts + step·j``: every item's position, and the
    number of its group ((sum counts,) each)."""
    group = np.repeat(np.arange(counts.shape[0]), counts)
    first = np.cumsum(counts) - counts
    j = np.arange(group.shape[0]) - first[group]
    return starts[group] + step * j, group


class _Records:
    """Parsing of MCAP records in ``data`` (``base``: its file offset, for messages): one
    file's summary section (:meth:`walk`), or the schema and channel records a scan meets
    (``what`` names where they are)."""

    def __init__(self, path: Path, data: bytes | mmap.mmap, base: int,
                 what: str = 'the summary section') -> None:
        self.path = path
        self.data = data
        self.base = base
        self.what = what
        self.schemas: dict[int, SchemaInfo] = {}
        self.channels: dict[int, ChannelInfo] = {}
        self.statistics: tuple[int, dict[int, int]] | None = None
        self.chunk_index: list[tuple[int, int]] = []

    def damaged(self, what: str) -> DamagedBagError:
        return DamagedBagError(self.path, f'{self.what} does not parse ({what})')

    def string(self, at: int, end: int) -> tuple[str, int]:
        (n,) = struct.unpack_from('<I', self.data, at)
        if at + 4 + n > end:
            raise self.damaged(f'a string at byte {self.base + at} runs past its record')
        return bytes(self.data[at + 4:at + 4 + n]).decode(), at + 4 + n

    def walk(self) -> None:
        """Walk the summary's records (one loop iteration per record: ~4300 in a 280 MiB
        bag, so it is kept tight); chunk indexes are only located here."""
        data, pos, size = self.data, 0, len(self.data)
        head = _HEAD
        index = self.chunk_index
        chunk_index = int(Opcode.CHUNK_INDEX)
        others = {int(Opcode.SCHEMA): self.schema, int(Opcode.CHANNEL): self.channel,
                  int(Opcode.STATISTICS): self.stats}
        try:
            while pos < size:
                op, length = head(data, pos)
                end = pos + RECORD + length
                if op == chunk_index:
                    index.append((pos + RECORD, end))
                elif op in others:
                    others[op](pos + RECORD, end)
                pos = end
        except (struct.error, UnicodeDecodeError) as err:
            raise self.damaged(f'record at byte {self.base + pos}: {err}') from err
        if pos != size:
            raise self.damaged(f'its last record runs {pos - size} bytes past it')

    def schema(self, at: int, end: int) -> None:
        (sid,) = struct.unpack_from('<H', self.data, at)
        name, at = self.string(at + 2, end)
        encoding, at = self.string(at, end)
        text, _ = self.string(at, end)
        self.schemas[sid] = SchemaInfo(name, encoding, text)

    def channel(self, at: int, end: int) -> None:
        cid, sid = struct.unpack_from('<HH', self.data, at)
        topic, at = self.string(at + 4, end)
        encoding, at = self.string(at, end)
        (n,) = struct.unpack_from('<I', self.data, at)
        stop, at = at + 4 + n, at + 4
        if stop > end:
            raise self.damaged(f'channel {cid}: its metadata runs past its record')
        metadata: dict[str, str] = {}
        while at < stop:
            key, at = self.string(at, stop)
            metadata[key], at = self.string(at, stop)
        self.channels[cid] = ChannelInfo(cid, sid, topic, encoding, metadata)

    def stats(self, at: int, end: int) -> None:
        count = struct.unpack_from('<Q', self.data, at)[0]
        (n,) = struct.unpack_from('<I', self.data, at + 42)
        if at + 46 + n > end or n % 10:
            raise self.damaged('the statistics record\'s channel counts run past it')
        counts = dict(struct.iter_unpack('<HQ', self.data[at + 46:at + 46 + n]))
        self.statistics = (int(count), counts)

    def chunks(self) -> Chunks:
        """The chunk indexes, parsed vectorised (MCAP spec, Chunk Index record: start, end,
        chunk_start_offset, chunk_length uint64; message_index_offsets map<uint16, uint64>
        with a uint32 byte length; message_index_length uint64; compression string;
        compressed_size, uncompressed_size uint64)."""
        buf = np.frombuffer(self.data, dtype=np.uint8)
        body = np.array([b for b, _ in self.chunk_index], dtype=np.int64)
        end = np.array([e for _, e in self.chunk_index], dtype=np.int64)
        short = end - body < CHUNK_INDEX_FIXED + 8 + 4 + 16
        if short.any():
            raise self.damaged(f'a chunk index record at byte {self.base + int(body[short][0])}'
                               ' is too short')
        fixed = rows(buf, body, CHUNK_INDEX_FIXED)
        start, stop, offset, length = (column(fixed, 8 * k, U64) for k in range(4))
        map_bytes = column(fixed, 32, np.dtype('<u4'))
        after = body + CHUNK_INDEX_FIXED + map_bytes
        bad = (map_bytes % 10 != 0) | (after + 8 + 4 + 16 > end)
        if bad.any():
            raise self.damaged(f'the channel map of the chunk index at byte '
                               f'{self.base + int(body[bad][0])} runs past it')
        tail = rows(buf, after, 12)
        index_length = column(tail, 0, U64)
        name_bytes = column(tail, 8, np.dtype('<u4'))
        sizes_at = after + 12 + name_bytes
        bad = sizes_at + 16 > end
        if bad.any():
            raise self.damaged(f'the compression of the chunk index at byte '
                               f'{self.base + int(body[bad][0])} runs past it')
        sizes = rows(buf, sizes_at, 16)
        names = [''] * body.shape[0]
        for n in np.unique(name_bytes).tolist():  # a few distinct compression names
            sel = np.flatnonzero(name_bytes == n)
            keys = gather_bytes(buf, after[sel] + 12, n) if n else np.zeros(sel.shape[0], 'V1')
            distinct, inverse = np.unique(keys, return_inverse=True)
            decoded = [k.tobytes().decode(errors='replace') if n else '' for k in distinct]
            for i, k in zip(sel.tolist(), inverse.reshape(-1).tolist(), strict=True):
                names[i] = decoded[k]
        per_chunk = map_bytes // 10
        entry_at, chunk_of = spread(body + CHUNK_INDEX_FIXED, per_chunk, 10)
        entries = rows(buf, entry_at, 10)
        order = np.argsort(offset, kind='stable')
        rank = np.empty_like(order)
        rank[order] = np.arange(order.shape[0])
        mi_chunk = rank[chunk_of]
        mi_channel = column(entries, 0, np.dtype('<u2'))
        mi_offset = column(entries, 2, U64)
        chunks = Chunks(start[order], stop[order], offset[order], length[order],
                        index_length[order], column(sizes, 0, U64)[order],
                        column(sizes, 8, U64)[order], tuple(names[i] for i in order),
                        np.zeros(body.shape[0], dtype=bool), mi_chunk, mi_channel, mi_offset,
                        np.zeros(0, np.int64))
        return _with_counts(chunks)


def _with_counts(c: Chunks) -> Chunks:
    """The message index entries sorted by offset, with the number of messages the gap to
    the next one (or to the end of the chunk's message indexes) leaves room for."""
    order = np.lexsort((c.mi_offset, c.mi_chunk))
    chunk, channel, offset = c.mi_chunk[order], c.mi_channel[order], c.mi_offset[order]
    limit = (c.offset + c.length + c.index_length)[chunk]
    nxt = np.append(offset[1:], 0)
    same = np.append(chunk[1:] == chunk[:-1], False)
    bound = np.where(same, nxt, limit)
    count = np.maximum(bound - offset - INDEX, 0) // 16
    return c._replace(mi_chunk=chunk, mi_channel=channel, mi_offset=offset, mi_count=count)


def pread(fd: int, path: Path, view: memoryview, offset: int) -> None:
    """Fill ``view`` from file offset ``offset``; DamagedBagError if the file ends first."""
    done = 0
    while done < len(view):
        try:
            n = os.preadv(fd, [view[done:]], offset + done)
        except OSError as err:
            raise BagError(path, f'cannot read bytes at {offset + done}: '
                                 f'{err.strerror or err}') from err
        if n <= 0:
            raise DamagedBagError(path, f'the file ends at byte {offset + done}, before the '
                                        f'{len(view)} bytes its index places at byte {offset}')
        done += n


def _check_chunks(path: Path, c: Chunks, data_start: int, data_end: int) -> None:
    """The chunk index is consistent: chunks in order, not overlapping, inside the data
    section, their message indexes inside the chunk's message index area."""
    region_end = c.offset + c.length + c.index_length
    prev_end = np.concatenate([[data_start], region_end[:-1]])
    bad = (c.offset < prev_end) | (region_end > data_end) | (c.length < RECORD + CHUNK_FIXED
                                                             + 8) | (c.start > c.end)
    if bad.any():
        i = int(np.argmax(bad))
        raise DamagedBagError(path, 'the summary\'s chunk index is inconsistent (chunk '
                                    'outside the data section, overlapping another, or its '
                                    'times reversed)', i, int(c.offset[i]))
    lo = (c.offset + c.length)[c.mi_chunk]
    bad = (c.mi_offset < lo) | (c.mi_offset + INDEX > region_end[c.mi_chunk])
    if bad.any():
        i = int(c.mi_chunk[np.argmax(bad)])
        raise DamagedBagError(path, 'the chunk index places a message index outside the '
                                    'chunk\'s message indexes', i, int(c.offset[i]))
    big = (c.uncompressed >= MAX_CHUNK) | (c.end >= TIME_LIMIT)
    if big.any():
        i = int(np.argmax(big))
        raise UnsupportedBagError(path, f'chunk {i}: {int(c.uncompressed[i])} bytes or log '
                                        'times past 2**63 ns: not read by the indexed reader')


def _not_mcap(path: Path, file: Path) -> BagError:
    """BagError for a file that is no MCAP file, worded as verify_bag says it."""
    lines = verify_file(file).lines() or [f'{file.name}: not an MCAP file']
    return BagError(path, f'not a readable bag: {"; ".join(lines)}')


def read_index(bag: Path, path: Path, number: int, fd: int, segment_bytes: int) -> FileIndex:
    """The index of the storage file ``path`` (open as ``fd``; number ``number`` of the bag
    ``bag``): from its summary, or from a scan of its records (module docstring; a scan cuts
    runs of top-level records into segments of about ``segment_bytes``)."""
    size = os.fstat(fd).st_size
    head = bytearray(len(MCAP_MAGIC) + RECORD)
    if size >= MIN_MCAP_BYTES:
        pread(fd, path, memoryview(head), 0)
    if size < MIN_MCAP_BYTES or bytes(head[:len(MCAP_MAGIC)]) != MCAP_MAGIC:
        raise _not_mcap(bag, path)
    op, header_length = struct.unpack_from('<BQ', head, len(MCAP_MAGIC))
    data_start = len(head) + header_length
    if op != Opcode.HEADER or data_start > size:
        raise DamagedBagError(path, 'the file does not start with a header record')
    tail = bytearray(FOOTER + len(MCAP_MAGIC))
    footer = size - len(tail)
    pread(fd, path, memoryview(tail), footer)
    if bytes(tail[FOOTER:]) != MCAP_MAGIC:
        raise UnindexedBagError(path, f'no footer ({size} bytes, no closing magic): the '
                                      'recording did not end cleanly; nothing is indexed')
    op, length, summary_start, _, summary_crc = struct.unpack_from('<BQQQI', tail)
    if op != Opcode.FOOTER or length != FOOTER - RECORD:
        raise DamagedBagError(path, f'the footer record at byte {footer} is damaged')
    if not summary_start:
        if summary_crc and zlib.crc32(memoryview(tail)[:FOOTER - 4]) != summary_crc:
            raise DamagedBagError(path, 'summary section CRC mismatch: the footer is damaged')
        return _scan(path, number, fd, data_start, footer, None, None, segment_bytes,
                     'no summary section')
    if not data_start + DATA_END <= summary_start <= footer:
        raise DamagedBagError(path, f'the footer\'s summary offset {summary_start} lies '
                                    'outside the file')
    data_end = summary_start - DATA_END
    raw = bytearray(footer + FOOTER - 4 - data_end)
    pread(fd, path, memoryview(raw), data_end)
    op, length, data_crc = struct.unpack_from('<BQI', raw)
    if op != Opcode.DATA_END or length != 4:
        raise DamagedBagError(path, f'no DataEnd record at byte {data_end}, before the summary')
    if summary_crc and zlib.crc32(memoryview(raw)[DATA_END:]) != summary_crc:
        raise DamagedBagError(path, 'summary section CRC mismatch: the summary (chunk index, '
                                    'statistics) is damaged')
    summary = _Records(path, bytes(raw[DATA_END:footer - data_end]), summary_start)
    summary.walk()
    stats = summary.statistics
    chunks = summary.chunks()
    nothing = not chunks.offset.size and stats is not None and not stats[0]  # no message
    reason = '' if nothing else _not_indexed(chunks)
    schemas, channels = summary.schemas, summary.channels
    if not reason:
        _check_chunks(path, chunks, data_start, data_end)
        if _undefined(schemas, channels, chunks):
            found = _definitions(path, fd, chunks, summary)
            if found is None:
                reason = f'{_undefined(schemas, channels, chunks)} in the file'
            else:
                schemas, channels = found
    if reason:
        return _scan(path, number, fd, data_start, summary_start, data_end, summary,
                     segment_bytes, reason)
    return FileIndex(path, number, data_start, data_end, int(data_crc), schemas, channels,
                     chunks, stats[0] if stats else None, stats[1] if stats else None)


def _not_indexed(chunks: Chunks) -> str:
    """Why the chunk indexes do not say where every message is ('' when they do)."""
    if not chunks.offset.size:
        return 'no chunk index'
    indexes = np.bincount(chunks.mi_chunk, minlength=chunks.offset.shape[0])
    if not indexes.all():
        return 'chunks without message indexes'
    return ''


def _undefined(schemas: Mapping[int, SchemaInfo], channels: Mapping[int, ChannelInfo],
               chunks: Chunks) -> str:
    """A channel the message indexes name, or a schema such a channel uses, that ``channels``
    / ``schemas`` do not define ('' when they define all)."""
    missing = sorted(set(np.unique(chunks.mi_channel).tolist()) - set(channels))
    if missing:
        return f'no channel record {missing[0]}'
    used = {ch.schema_id for ch in channels.values()} - {0}
    undefined = sorted(used - set(schemas))
    return f'no schema record {undefined[0]}' if undefined else ''


def _definitions(path: Path, fd: int, chunks: Chunks, summary: _Records,
                 ) -> tuple[dict[int, SchemaInfo], dict[int, ChannelInfo]] | None:
    """The summary's schemas and channels completed from the records of the chunks (a writer
    that does not repeat them in the summary puts them in the chunk of their first message),
    read in file order until every channel the message indexes name and its schema are
    defined; None if the chunks do not define them all."""
    with mmap.mmap(fd, 0, access=mmap.ACCESS_READ) as data:
        scan = _Scan(path, data, DEFAULT_BLOCK_BYTES)
        for at, length in zip(chunks.offset.tolist(), chunks.length.tolist(), strict=True):
            if _HEAD(data, at) != (Opcode.CHUNK, length - RECORD):
                raise DamagedBagError(path, 'no chunk record at the offset the summary\'s '
                                            'chunk index gives', scan.chunks, at)
            try:
                scan.chunk(at, at + length)
            except (struct.error, UnicodeDecodeError) as err:
                raise DamagedBagError(path, f'a record does not parse ({err})',
                                      scan.chunks - 1, at) from err
            schemas, channels = scan.definitions(summary)
            if not _undefined(schemas, channels, chunks):
                return schemas, channels
    return None


# -- the scan of a file without the index the fast read needs ---------------------------------
class _Scan:
    """One file's data section walked record by record (module docstring): the schemas and
    channels met, each message found (``found``: segment, channel, log time, offset, four
    uint64 per message) and the segments (start, end, offset, length, compressed and
    uncompressed size, compression, plain)."""

    def __init__(self, path: Path, data: mmap.mmap, segment_bytes: int) -> None:
        self.path = path
        self.data = data
        self.top = _Records(path, data, 0, 'the data section')
        self.inner: list[_Records] = []
        self.found = array('Q')
        self.segments: list[tuple[int, int, int, int, int, int, str, bool]] = []
        self.segment_bytes = max(1, min(segment_bytes, MAX_CHUNK // 2))
        self.run = -1          # where the open run of top-level records starts (-1: none)
        self.run_found = 0     # len(found) when it started
        self.chunks = 0        # chunk records met
        self.zstd = zstandard.ZstdDecompressor()
        self.released = 0      # the pages before this offset are out of this process's memory

    def release(self, upto: int) -> None:
        """Drop the file's pages before ``upto`` from this process's memory once a block of
        them is walked (they stay in the page cache): the scan of a long file holds about one
        block of it, not the whole file."""
        end = upto - upto % mmap.PAGESIZE
        if end - self.released >= DEFAULT_BLOCK_BYTES:
            self.data.madvise(mmap.MADV_DONTNEED, self.released, end - self.released)
            self.released = end

    def crc(self, end: int) -> int:
        """CRC-32 of the file's bytes 0 .. ``end``, a block at a time (each released once
        fed to it)."""
        crc, at = 0, 0
        with memoryview(self.data) as view:
            while at < end:
                stop = min(end, at + DEFAULT_BLOCK_BYTES)
                with view[at:stop] as part:
                    crc = zlib.crc32(part, crc)
                pages = (stop - at) - (stop - at) % mmap.PAGESIZE
                if pages:
                    self.data.madvise(mmap.MADV_DONTNEED, at, pages)
                at = stop
        return crc

    def damaged(self, reason: str, chunk: int | None = None, offset: int | None = None,
                ) -> DamagedBagError:
        return DamagedBagError(self.path, reason, chunk, offset)

    def walk(self, start: int, stop: int) -> int:
        """Walk the top-level records from ``start``; the offset of the DataEnd record (the
        walk must meet it before ``stop``)."""
        data, found, head, message = self.data, self.found, _HEAD, _MESSAGE_HEAD
        pos = start
        while True:
            if pos + RECORD > stop:
                raise self.damaged(f'no DataEnd record: the records end at byte {pos}')
            op, length = head(data, pos)
            end = pos + RECORD + length
            if op not in _DATA_RECORDS or end > stop:
                raise self.damaged(f'the record at byte {pos} is damaged (opcode 0x{op:02x}, '
                                   f'length {length})')
            if op in _SEGMENT_RECORDS:
                if self.run < 0 or end - self.run > self.segment_bytes:
                    self.close_run(pos)
                    self.run, self.run_found = pos, len(found)
                if op == Opcode.MESSAGE:
                    if length < MESSAGE - RECORD:
                        raise self.damaged(f'the message record at byte {pos} is too short')
                    channel, _, log = message(data, pos + RECORD)
                    found.extend((len(self.segments), channel, log, pos - self.run))
                elif op == Opcode.SCHEMA:
                    self.top.schema(pos + RECORD, end)
                else:
                    self.top.channel(pos + RECORD, end)
            else:
                self.close_run(pos)
                if op == Opcode.DATA_END:
                    return pos
                if op == Opcode.CHUNK:
                    self.chunk(pos, end)
            pos = end
            if pos - self.released > DEFAULT_BLOCK_BYTES:
                self.release(pos)

    def close_run(self, pos: int) -> None:
        """End the open run of top-level records at ``pos``: a segment if it holds messages."""
        if self.run >= 0 and len(self.found) > self.run_found:
            log = self.found[self.run_found + 2::4]
            self.segments.append((min(log), max(log), self.run, pos - self.run, pos - self.run,
                                  pos - self.run, '', True))
        self.run = -1

    def chunk(self, pos: int, end: int) -> None:
        """A chunk record (MCAP spec: start, end, uncompressed size uint64, uncompressed CRC
        uint32, compression string, records with a uint64 length): decompressed, checked
        against its CRC (when nonzero), its records walked."""
        data, number = self.data, self.chunks
        self.chunks += 1
        body = pos + RECORD
        if end - body < CHUNK_FIXED + 8:
            raise self.damaged('the chunk record is too short', number, pos)
        start, stop, size, crc, n = struct.unpack_from('<QQQII', data, body)
        at = body + CHUNK_FIXED + n
        if at + 8 > end:
            raise self.damaged('its compression runs past the record', number, pos)
        name = bytes(data[body + CHUNK_FIXED:at]).decode(errors='replace')
        (stored,) = struct.unpack_from('<Q', data, at)
        if at + 8 + stored != end:
            raise self.damaged('its records do not end with the record', number, pos)
        if start > stop or stop >= TIME_LIMIT or size >= MAX_CHUNK:
            raise UnsupportedBagError(self.path, f'chunk {number} at byte {pos}: '
                                                 f'{size} bytes or log times past 2**63 ns, '
                                                 'or reversed: not read')
        records = decompress(self.path, number, pos, name, bytes(data[at + 8:end]), size,
                             self.zstd)
        if crc and zlib.crc32(records) != crc:
            raise self.damaged(f'chunk CRC mismatch: stored {crc:08x}, computed '
                               f'{zlib.crc32(records):08x}', number, pos)
        inner = _Records(self.path, records, 0, f'chunk {number} at byte {pos}')
        found, head, message, segment = self.found, _HEAD, _MESSAGE_HEAD, len(self.segments)
        p = 0
        while p < size:
            if size - p < RECORD:
                raise self.damaged(f'a record header at byte {p} of its records is cut off',
                                   number, pos)
            op, length = head(records, p)
            e = p + RECORD + length
            if op not in _SEGMENT_RECORDS or e > size:
                raise self.damaged(f'the record at byte {p} of its records is damaged (opcode '
                                   f'0x{op:02x}, length {length})', number, pos)
            if op == Opcode.MESSAGE:
                if length < MESSAGE - RECORD:
                    raise self.damaged(f'the message at byte {p} of its records is too short',
                                       number, pos)
                channel, _, log = message(records, p + RECORD)
                if not start <= log <= stop:
                    raise self.damaged(f'the message at byte {p} of its records has log time '
                                       f'{log}, outside the chunk\'s range', number, pos)
                found.extend((segment, channel, log, p))
            elif op == Opcode.SCHEMA:
                inner.schema(p + RECORD, e)
            else:
                inner.channel(p + RECORD, e)
            p = e
        self.inner.append(inner)
        self.segments.append((start, stop, pos, end - pos, stored, size, name, False))

    def definitions(self, summary: _Records | None,
                    ) -> tuple[dict[int, SchemaInfo], dict[int, ChannelInfo]]:
        """The schemas and channels by id: the summary's, then those of the records."""
        schemas = dict(summary.schemas) if summary is not None else {}
        channels = dict(summary.channels) if summary is not None else {}
        for part in (self.top, *self.inner):
            for sid, schema in part.schemas.items():
                schemas.setdefault(sid, schema)
            for cid, channel in part.channels.items():
                channels.setdefault(cid, channel)
        return schemas, channels


def _scan(path: Path, number: int, fd: int, data_start: int, stop: int, data_end: int | None,
          summary: _Records | None, segment_bytes: int, reason: str) -> FileIndex:
    """The index of a file from a scan of its records, up to its DataEnd record (at
    ``data_end`` when the summary says where; else before ``stop``); ``reason``: why the
    summary does not do (module docstring)."""
    with mmap.mmap(fd, 0, access=mmap.ACCESS_READ) as data:
        scan = _Scan(path, data, segment_bytes)
        try:
            end = scan.walk(data_start, stop)
        except (struct.error, UnicodeDecodeError) as err:  # a record cut short inside
            raise DamagedBagError(path, f'a record does not parse ({err})') from err
        if data_end is not None and end != data_end:
            raise DamagedBagError(path, f'a DataEnd record at byte {end}, the summary starts '
                                        f'at byte {data_end + DATA_END}')
        _, length, data_crc = struct.unpack_from('<BQI', data, end) if end + DATA_END <= stop \
            else (0, 0, 0)
        if length < 4:
            raise DamagedBagError(path, f'the DataEnd record at byte {end} is damaged')
        if data_crc:
            computed = scan.crc(end)
            if computed != data_crc:
                raise DamagedBagError(path, f'data section CRC mismatch (stored '
                                            f'{data_crc:08x}, computed {computed:08x}): bytes 0 '
                                            f'.. {end - 1} are damaged somewhere')
    found = np.frombuffer(scan.found, dtype=np.uint64).reshape(-1, 4)
    if (found[:, 2] >= TIME_LIMIT).any():
        raise UnsupportedBagError(path, 'log times past 2**63 ns: not read')
    segment, channel, log, offset = (found[:, k].astype(np.int64) for k in range(4))
    schemas, channels = scan.definitions(summary)
    ids, counts = np.unique(channel, return_counts=True)
    by_channel = dict(zip(ids.tolist(), counts.tolist(), strict=True))
    undefined = sorted(set(by_channel) - set(channels))
    if undefined:
        raise DamagedBagError(path, f'{by_channel[undefined[0]]} messages on channel '
                                    f'{undefined[0]}, which no channel record defines')
    stats = summary.statistics if summary is not None else None
    if stats is not None and (stats[0] != len(log) or any(
            by_channel.get(cid, 0) != n for cid, n in stats[1].items() if n)):
        raise DamagedBagError(path, f'the statistics count {stats[0]} messages, the records '
                                    f'hold {len(log)} (or not as many per channel)')
    segs = scan.segments
    first, last, at, length, stored, size = (np.array([s[k] for s in segs], dtype=np.int64)
                                             for k in range(6))
    empty = np.zeros(0, np.int64)
    chunks = Chunks(first, last, at, length, np.zeros(len(segs), np.int64), stored, size,
                    tuple(s[6] for s in segs), np.array([s[7] for s in segs], dtype=bool),
                    empty, empty, empty, empty)
    return FileIndex(path, number, data_start, end, data_crc, schemas, channels, chunks,
                     len(log), by_channel, Scanned(segment, channel, log, offset, reason))


def decompress(path: Path, chunk: int, offset: int, name: str, data: bytes | memoryview,
               size: int, zstd: zstandard.ZstdDecompressor) -> bytes:
    """The records of chunk ``chunk`` (its record at byte ``offset`` of ``path``): ``data``
    decompressed with ``name`` ('' stored as is, zstd, lz4) to ``size`` bytes, as its header
    or index states. UnsupportedBagError for another compression; DamagedBagError when it
    does not decompress, or not to ``size`` bytes."""
    if name not in COMPRESSIONS:
        raise UnsupportedBagError(path, f'chunk {chunk} at byte {offset}: unknown compression '
                                        f'{name!r}')
    try:
        records = (bytes(data) if not name else zstd.decompress(data, max_output_size=size)
                   if name == 'zstd' else lz4.frame.decompress(data))
    except Exception as err:  # whatever a decompressor raises on a damaged stream
        raise DamagedBagError(path, f'does not decompress ({name}: '
                                    f'{err or type(err).__name__})', chunk, offset) from err
    if len(records) != size:
        raise DamagedBagError(path, f'decompresses to {len(records)} bytes, not the {size} '
                                    'its header states', chunk, offset)
    return bytes(records)


def summarise(path: Path, segment_bytes: int = DEFAULT_BLOCK_BYTES,
              ) -> tuple[FileSummary, tuple[TopicMeta, ...]]:
    """One storage file's summary (its name, log-time range, message counts per topic) and
    topics (one per channel), from its index or a scan (:func:`read_index`); BagError (an
    IndexedReadError) when it cannot be read as it is."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError as err:
        raise BagError(path, f'cannot open: {err.strerror or err}') from err
    try:
        index = read_index(path, path, 0, fd, segment_bytes)
    finally:
        os.close(fd)
    counts = index.counts()
    topics: dict[str, int] = {}
    for cid, ch in index.channels.items():
        topics[ch.topic] = topics.get(ch.topic, 0) + counts.get(cid, 0)
    first, last = index.log_range or (0, 0)
    total = sum(topics.values())
    return (FileSummary(path.name, first if total else 0, last if total else 0, total, topics),
            tuple(topic_meta(ch.topic, schema.name if schema is not None else '', ch.encoding,
                             ch.metadata, path)
                  for ch in index.channels.values()
                  for schema in (index.schemas.get(ch.schema_id),)))
