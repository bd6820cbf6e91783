"""Reading chosen topics of an MCAP bag through its index: one sequential pass over each file
in blocks of whole chunks, only the wanted channels' message records touched, in bounded
memory, in exactly the order rosbags' ``AnyReader.messages`` yields them.

:class:`IndexedBag` opens a bag (its summaries only); :meth:`IndexedBag.blocks` streams the
messages of chosen topics as :class:`Block` s (log times, file keys, payload offsets into a
reused buffer, the order across topics); :meth:`IndexedBag.decode` decodes a topic of a block
(vectorised with :mod:`positioning_cell.bag.cdr` for fixed-layout types, else rosbags message
by message); :meth:`IndexedBag.read` does both for the whole bag. What it cannot read raises
an :class:`IndexedReadError` so that the caller falls back to the slow path
(``positioning_cell.analysis.reading.read_bag``: verify, recover, rosbags).

How (MCAP spec, https://mcap.dev/spec):

* **Summary.** The footer (last 8 + 29 bytes: record, magic) gives ``summary_start`` and the
  ``summary_crc`` (CRC-32 of the summary section up to the footer's ``summary_offset_start``
  field), checked when nonzero. The summary's Schema, Channel, Chunk Index and Statistics
  records are parsed here, the chunk indexes vectorised (a 280 MiB bag has ~4200: ~17 ms
  here, ~90 ms with the ``mcap`` library's ``get_summary``). The DataEnd record sits just
  before the summary. A file without footer, summary or chunk index (a recording killed before
  it closed the file, an unchunked file) raises :class:`UnindexedBagError`.
* **Chunks wanted.** A chunk index lists the file offset of each channel's Message Index
  record; the records of one chunk follow each other, so the gap to the next one (15 + 16·n
  bytes) says whether the chunk holds messages of a channel (as rosbags' reader decides).
  Chunks without a wanted channel are never parsed.
* **Blocks.** Each file is read front to back with ``os.preadv``, a block of whole chunks
  (with their message indexes and what lies between them) at a time: at most ``block_bytes``
  read and at most ``block_bytes`` decompressed, or a single chunk when it is larger. A worker
  thread reads one block ahead into the other of two reused buffers and feeds every byte from
  the file start to the DataEnd record to ``zlib.crc32`` (which releases the GIL), checked
  against DataEnd's ``data_section_crc`` once the file is read, when it is nonzero: it
  covers the chunks not parsed too. (A file without that CRC is read only where wanted
  chunks are.)
* **Wanted chunks.** The chunk record's header must agree with the chunk index (vectorised
  over the block's chunks). Its records are checked against ``uncompressed_crc`` when
  nonzero, after zstd / lz4 decompression to ``uncompressed_size``. The message index
  records of the wanted channels (channel id, then pairs of uint64 log time and byte offset
  of the Message record in the chunk's records) are read with numpy, and every indexed
  Message record is checked (vectorised): opcode 0x05, its length within the chunk, its
  channel, its log time equal to the index's and within the chunk's time range, records not
  overlapping. Any failure raises :class:`DamagedBagError` naming file, chunk and byte offset.
* **Order.** rosbags merges the chunks of a file with a heap keyed by (log time, chunk
  offset), each chunk's messages stable-sorted by log time, the files of a split bag one
  after the other: the order of (log time, chunk number, record offset in the chunk) within a
  file. A block emits its messages up to the earliest ``message_start_time`` of a wanted chunk
  not yet read; later ones (chunks overlapping in time) are copied aside and emitted with a
  later block, so the stream is globally in that order.
* **Completeness.** When the summary has Statistics, the messages indexed for each wanted
  channel must add up to its ``channel_message_counts`` at the end of the file.

A chunk without a CRC (rosbags' own writer) is checked through its index only: damage inside
a message's payload is then not detected (verify_bag has the same limit). Memory: two block
buffers, the files' index arrays (~1 MB per 4000 chunks) and the decoded output; bags whose
chunks overlap in time hold back more (the messages after the earliest start of an unread
chunk wait until that chunk is read).
"""

from __future__ import annotations

import contextlib
import os
import struct
import zlib
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple, TypeVar

import lz4.frame
import numpy as np
import yaml
import zstandard
from mcap.opcode import Opcode
from numpy.typing import NDArray
from rosbags.interfaces import Qos
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.metadata import parse_qos
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.base import TypesysError
from rosbags.typesys.store import Typestore

from positioning_cell.bag.cdr import (
    CdrError,
    Columns,
    ColumnsBuilder,
    DecodePlan,
    decode,
    fixed_layout_plan,
)
from positioning_cell.bag.cdr import gather as gather_bytes
from positioning_cell.bag.errors import BagError
from positioning_cell.bag.metadata import METADATA_FILE, parse_qos_yaml
from positioning_cell.bag.reader import RawMessage, TopicInfo
from positioning_cell.bag.verify import MCAP_MAGIC, MIN_MCAP_BYTES, storage_files, verify_file
from positioning_cell.bag.writer import jazzy_typestore

#: Default block budget: bytes read per block, and bytes decompressed per block.
DEFAULT_BLOCK_BYTES = 8 * 2**20
_RECORD = 1 + 8                      # opcode, length
_FOOTER = _RECORD + 8 + 8 + 4        # summary_start, summary_offset_start, summary_crc
_DATA_END = _RECORD + 4              # data_section_crc
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4     # start, end, uncompressed size, crc, compression length
_MESSAGE = _RECORD + 2 + 4 + 8 + 8   # + channel, sequence, log time, publish time
_INDEX = _RECORD + 2 + 4             # + channel, byte length of the (log time, offset) pairs
_CHUNK_INDEX_FIXED = 8 + 8 + 8 + 8 + 4
_COMPRESSIONS = ('', 'zstd', 'lz4')
_MAX_CHUNK = 2**32                   # records of a chunk addressed by 32 bits in file_key
_TIME_LIMIT = 2**63                  # log times are returned as int64
_U64 = np.dtype('<u8')
_T = TypeVar('_T')
_YAML_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)  # libyaml: 100x ruamel's speed


class IndexedReadError(BagError):
    """The indexed read cannot read this bag; the slow path (verify, recover, rosbags) can
    tell more. ``path`` is the storage file, ``reason`` what is wrong."""


class UnindexedBagError(IndexedReadError):
    """A storage file has no footer, summary or chunk index (a recording that did not end
    cleanly, or a writer that does not index)."""


class DamagedBagError(IndexedReadError):
    """A storage file is damaged: a chunk (``chunk``: its number in the file, in file order;
    ``offset``: byte offset of its record) that fails its CRC, does not decompress or does
    not match its index; a summary or data section that fails its CRC; an index that
    contradicts itself. ``chunk`` / ``offset`` are None when no chunk is concerned."""

    def __init__(self, path: str | Path, reason: str, chunk: int | None = None,
                 offset: int | None = None) -> None:
        where = f'chunk {chunk} at byte {offset}: ' if chunk is not None else ''
        super().__init__(path, where + reason)
        self.chunk = chunk
        self.offset = offset


class UnsupportedBagError(IndexedReadError):
    """A storage file uses something this reader does not handle (an unknown chunk
    compression, a topic with channels of different types, chunks past 4 GiB)."""


class TopicMessages(NamedTuple):
    """The messages of one topic in a block, in stream order: log times (N,) int64 ns,
    ``file_key`` (N,) int64 = chunk number in the file · 2**32 + byte offset of the message
    record in the chunk's (uncompressed) records (increasing in file order), and each CDR
    payload as ``offsets`` (N,) / ``lengths`` (N,) into the block's buffer."""

    topic: str
    msgtype: str
    log_time_ns: NDArray[np.int64]
    file_key: NDArray[np.int64]
    offsets: NDArray[np.int64]
    lengths: NDArray[np.int64]


class MessageOrder(NamedTuple):
    """The stream order of messages across topics: message k is message ``position[k]`` of
    topic ``names[topic[k]]`` (arrays (M,))."""

    names: tuple[str, ...]
    topic: NDArray[np.int16]
    position: NDArray[np.int64]


@dataclass(frozen=True)
class Block:
    """Messages of the wanted topics read from one storage file (``file``, number
    ``file_index`` in split order): per topic that has some (``topics``), and their
    order across topics. ``buffer`` (uint8) holds the payloads and is reused by the next
    block: decode or copy what is needed before asking for the next one."""

    file: Path
    file_index: int
    buffer: NDArray[np.uint8]
    topics: Mapping[str, TopicMessages]
    order: MessageOrder

    @property
    def message_count(self) -> int:
        """Messages in the block."""
        return int(self.order.topic.shape[0])

    def payload(self, topic: str, i: int) -> bytes:
        """The CDR bytes of message ``i`` of ``topic`` (a copy)."""
        m = self.topics[topic]
        start = int(m.offsets[i])
        return self.buffer[start:start + int(m.lengths[i])].tobytes()


@dataclass(frozen=True)
class Decoded:
    """Decoded messages of one topic, in stream order: log times (N,) int64 ns, and either
    ``columns`` (a fixed-layout type, :class:`positioning_cell.bag.cdr.Columns`) or
    ``messages`` (rosbags message objects, one per message: other types)."""

    topic: str
    msgtype: str
    log_time_ns: NDArray[np.int64]
    columns: Columns | None
    messages: tuple[Any, ...] | None

    @property
    def count(self) -> int:
        """Number of messages."""
        return int(self.log_time_ns.shape[0])


@dataclass(frozen=True)
class BagRead:
    """Everything :meth:`IndexedBag.read` read: each wanted topic the bag has (possibly with
    no message) decoded, and the stream order across them."""

    topics: Mapping[str, Decoded]
    order: MessageOrder


# -- the summary of one file -------------------------------------------------------------------
class _Schema(NamedTuple):
    name: str
    encoding: str
    data: str


class _Channel(NamedTuple):
    id: int
    schema_id: int
    topic: str
    encoding: str
    metadata: dict[str, str]


class _Chunks(NamedTuple):
    """The chunk indexes of a file sorted by offset (arrays (C,) int64), and their message
    index offsets flattened (arrays (K,): chunk number, channel id, file offset, and the
    messages the spacing of the offsets leaves room for)."""

    start: NDArray[np.int64]
    end: NDArray[np.int64]
    offset: NDArray[np.int64]
    length: NDArray[np.int64]
    index_length: NDArray[np.int64]
    compressed: NDArray[np.int64]
    uncompressed: NDArray[np.int64]
    compression: tuple[str, ...]
    mi_chunk: NDArray[np.int64]
    mi_channel: NDArray[np.int64]
    mi_offset: NDArray[np.int64]
    mi_count: NDArray[np.int64]


@dataclass(frozen=True)
class _FileIndex:
    path: Path
    number: int
    data_start: int
    data_end: int
    data_crc: int
    schemas: Mapping[int, _Schema]
    channels: Mapping[int, _Channel]
    chunks: _Chunks
    message_count: int | None
    channel_counts: Mapping[int, int] | None


def _column(rows: NDArray[np.uint8], at: int, dtype: np.dtype[Any]) -> NDArray[Any]:
    """Column ``at`` (bytes) of ``rows`` (N, w) viewed as ``dtype``, int64 for integers."""
    view = rows[:, at:at + dtype.itemsize].view(dtype).reshape(-1)
    return view.astype(np.int64) if dtype.kind in 'iu' else view.copy()


def _rows(buffer: NDArray[np.uint8], start: NDArray[np.int64], width: int) -> NDArray[np.uint8]:
    """(N, width) uint8: the bytes at ``start`` (checked by the caller)."""
    return gather_bytes(buffer, start, width).view(np.uint8).reshape(-1, width)


def _spread(starts: NDArray[np.int64], counts: NDArray[np.int64], step: int,
            ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """For groups of ``counts`` items at ``starts + step·j``: every item's position, and the
    number of its group ((sum counts,) each)."""
    group = np.repeat(np.arange(counts.shape[0]), counts)
    first = np.cumsum(counts) - counts
    j = np.arange(group.shape[0]) - first[group]
    return starts[group] + step * j, group


class _Summary:
    """Parsing of one file's summary section (bytes ``data``; ``base`` its file offset)."""

    def __init__(self, path: Path, data: bytes, base: int) -> None:
        self.path = path
        self.data = data
        self.base = base
        self.schemas: dict[int, _Schema] = {}
        self.channels: dict[int, _Channel] = {}
        self.statistics: tuple[int, dict[int, int]] | None = None
        self.chunk_index: list[tuple[int, int]] = []

    def damaged(self, what: str) -> DamagedBagError:
        return DamagedBagError(self.path, f'the summary section does not parse ({what})')

    def string(self, at: int, end: int) -> tuple[str, int]:
        (n,) = struct.unpack_from('<I', self.data, at)
        if at + 4 + n > end:
            raise self.damaged(f'a string at byte {self.base + at} runs past its record')
        return self.data[at + 4:at + 4 + n].decode(), at + 4 + n

    def walk(self) -> None:
        """Walk the summary's records (one loop iteration per record: ~4300 in a 280 MiB
        bag, so it is kept tight); chunk indexes are only located here."""
        data, pos, size = self.data, 0, len(self.data)
        head = struct.Struct('<BQ').unpack_from
        index = self.chunk_index
        chunk_index = int(Opcode.CHUNK_INDEX)
        others = {int(Opcode.SCHEMA): self.schema, int(Opcode.CHANNEL): self.channel,
                  int(Opcode.STATISTICS): self.stats}
        try:
            while pos < size:
                op, length = head(data, pos)
                end = pos + _RECORD + length
                if op == chunk_index:
                    index.append((pos + _RECORD, end))
                elif op in others:
                    others[op](pos + _RECORD, end)
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
        self.schemas[sid] = _Schema(name, encoding, text)

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
        self.channels[cid] = _Channel(cid, sid, topic, encoding, metadata)

    def stats(self, at: int, end: int) -> None:
        count = struct.unpack_from('<Q', self.data, at)[0]
        (n,) = struct.unpack_from('<I', self.data, at + 42)
        if at + 46 + n > end or n % 10:
            raise self.damaged('the statistics record\'s channel counts run past it')
        counts = dict(struct.iter_unpack('<HQ', self.data[at + 46:at + 46 + n]))
        self.statistics = (int(count), counts)

    def chunks(self) -> _Chunks:
        """The chunk indexes, parsed vectorised (MCAP spec, Chunk Index record: start, end,
        chunk_start_offset, chunk_length uint64; message_index_offsets map<uint16, uint64>
        with a uint32 byte length; message_index_length uint64; compression string;
        compressed_size, uncompressed_size uint64)."""
        buf = np.frombuffer(self.data, dtype=np.uint8)
        body = np.array([b for b, _ in self.chunk_index], dtype=np.int64)
        end = np.array([e for _, e in self.chunk_index], dtype=np.int64)
        short = end - body < _CHUNK_INDEX_FIXED + 8 + 4 + 16
        if short.any():
            raise self.damaged(f'a chunk index record at byte {self.base + int(body[short][0])}'
                               ' is too short')
        fixed = _rows(buf, body, _CHUNK_INDEX_FIXED)
        start, stop, offset, length = (_column(fixed, 8 * k, _U64) for k in range(4))
        map_bytes = _column(fixed, 32, np.dtype('<u4'))
        after = body + _CHUNK_INDEX_FIXED + map_bytes
        bad = (map_bytes % 10 != 0) | (after + 8 + 4 + 16 > end)
        if bad.any():
            raise self.damaged(f'the channel map of the chunk index at byte '
                               f'{self.base + int(body[bad][0])} runs past it')
        tail = _rows(buf, after, 12)
        index_length = _column(tail, 0, _U64)
        name_bytes = _column(tail, 8, np.dtype('<u4'))
        sizes_at = after + 12 + name_bytes
        bad = sizes_at + 16 > end
        if bad.any():
            raise self.damaged(f'the compression of the chunk index at byte '
                               f'{self.base + int(body[bad][0])} runs past it')
        sizes = _rows(buf, sizes_at, 16)
        names = [''] * body.shape[0]
        for n in np.unique(name_bytes).tolist():  # a few distinct compression names
            sel = np.flatnonzero(name_bytes == n)
            keys = gather_bytes(buf, after[sel] + 12, n) if n else np.zeros(sel.shape[0], 'V1')
            distinct, inverse = np.unique(keys, return_inverse=True)
            decoded = [k.tobytes().decode(errors='replace') if n else '' for k in distinct]
            for i, k in zip(sel.tolist(), inverse.reshape(-1).tolist(), strict=True):
                names[i] = decoded[k]
        per_chunk = map_bytes // 10
        entry_at, chunk_of = _spread(body + _CHUNK_INDEX_FIXED, per_chunk, 10)
        entries = _rows(buf, entry_at, 10)
        order = np.argsort(offset, kind='stable')
        rank = np.empty_like(order)
        rank[order] = np.arange(order.shape[0])
        mi_chunk = rank[chunk_of]
        mi_channel = _column(entries, 0, np.dtype('<u2'))
        mi_offset = _column(entries, 2, _U64)
        chunks = _Chunks(start[order], stop[order], offset[order], length[order],
                         index_length[order], _column(sizes, 0, _U64)[order],
                         _column(sizes, 8, _U64)[order], tuple(names[i] for i in order),
                         mi_chunk, mi_channel, mi_offset, np.zeros(0, np.int64))
        return _with_counts(chunks)


def _with_counts(c: _Chunks) -> _Chunks:
    """The message index entries sorted by offset, with the number of messages the gap to
    the next one (or to the end of the chunk's message indexes) leaves room for."""
    order = np.lexsort((c.mi_offset, c.mi_chunk))
    chunk, channel, offset = c.mi_chunk[order], c.mi_channel[order], c.mi_offset[order]
    limit = (c.offset + c.length + c.index_length)[chunk]
    nxt = np.append(offset[1:], 0)
    same = np.append(chunk[1:] == chunk[:-1], False)
    bound = np.where(same, nxt, limit)
    count = np.maximum(bound - offset - _INDEX, 0) // 16
    return c._replace(mi_chunk=chunk, mi_channel=channel, mi_offset=offset, mi_count=count)


def _pread(fd: int, path: Path, view: memoryview, offset: int) -> None:
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


def _check_chunks(path: Path, c: _Chunks, data_start: int, data_end: int) -> None:
    """The chunk index is consistent: chunks in order, not overlapping, inside the data
    section, their message indexes inside the chunk's message index area."""
    region_end = c.offset + c.length + c.index_length
    prev_end = np.concatenate([[data_start], region_end[:-1]])
    bad = (c.offset < prev_end) | (region_end > data_end) | (c.length < _RECORD + _CHUNK_FIXED
                                                             + 8) | (c.start > c.end)
    if bad.any():
        i = int(np.argmax(bad))
        raise DamagedBagError(path, 'the summary\'s chunk index is inconsistent (chunk '
                                    'outside the data section, overlapping another, or its '
                                    'times reversed)', i, int(c.offset[i]))
    lo = (c.offset + c.length)[c.mi_chunk]
    bad = (c.mi_offset < lo) | (c.mi_offset + _INDEX > region_end[c.mi_chunk])
    if bad.any():
        i = int(c.mi_chunk[np.argmax(bad)])
        raise DamagedBagError(path, 'the chunk index places a message index outside the '
                                    'chunk\'s message indexes', i, int(c.offset[i]))
    big = (c.uncompressed >= _MAX_CHUNK) | (c.end >= _TIME_LIMIT)
    if big.any():
        i = int(np.argmax(big))
        raise UnsupportedBagError(path, f'chunk {i}: {int(c.uncompressed[i])} bytes or log '
                                        'times past 2**63 ns: not read by the indexed reader')


def _not_mcap(path: Path, file: Path) -> BagError:
    """BagError for a file that is no MCAP file, worded as verify_bag says it."""
    lines = verify_file(file).lines() or [f'{file.name}: not an MCAP file']
    return BagError(path, f'not a readable bag: {"; ".join(lines)}')


def _read_index(bag: Path, path: Path, number: int, fd: int) -> _FileIndex:
    """The summary of the storage file ``path`` (see the module docstring)."""
    size = os.fstat(fd).st_size
    head = bytearray(len(MCAP_MAGIC) + _RECORD)
    if size >= MIN_MCAP_BYTES:
        _pread(fd, path, memoryview(head), 0)
    if size < MIN_MCAP_BYTES or bytes(head[:len(MCAP_MAGIC)]) != MCAP_MAGIC:
        raise _not_mcap(bag, path)
    op, header_length = struct.unpack_from('<BQ', head, len(MCAP_MAGIC))
    data_start = len(head) + header_length
    if op != Opcode.HEADER or data_start > size:
        raise DamagedBagError(path, 'the file does not start with a header record')
    tail = bytearray(_FOOTER + len(MCAP_MAGIC))
    footer = size - len(tail)
    _pread(fd, path, memoryview(tail), footer)
    if bytes(tail[_FOOTER:]) != MCAP_MAGIC:
        raise UnindexedBagError(path, f'no footer ({size} bytes, no closing magic): the '
                                      'recording did not end cleanly; nothing is indexed')
    op, length, summary_start, _, summary_crc = struct.unpack_from('<BQQQI', tail)
    if op != Opcode.FOOTER or length != _FOOTER - _RECORD:
        raise DamagedBagError(path, f'the footer record at byte {footer} is damaged')
    if not summary_start:
        raise UnindexedBagError(path, 'no summary section: the file is not indexed')
    if not data_start + _DATA_END <= summary_start <= footer:
        raise DamagedBagError(path, f'the footer\'s summary offset {summary_start} lies '
                                    'outside the file')
    data_end = summary_start - _DATA_END
    raw = bytearray(footer + _FOOTER - 4 - data_end)
    _pread(fd, path, memoryview(raw), data_end)
    op, length, data_crc = struct.unpack_from('<BQI', raw)
    if op != Opcode.DATA_END or length != 4:
        raise DamagedBagError(path, f'no DataEnd record at byte {data_end}, before the summary')
    if summary_crc and zlib.crc32(memoryview(raw)[_DATA_END:]) != summary_crc:
        raise DamagedBagError(path, 'summary section CRC mismatch: the summary (chunk index, '
                                    'statistics) is damaged')
    summary = _Summary(path, bytes(raw[_DATA_END:footer - data_end]), summary_start)
    summary.walk()
    if not summary.chunk_index and (summary.statistics is None or summary.statistics[0]):
        raise UnindexedBagError(path, 'the summary has no chunk index')
    chunks = summary.chunks()
    _check_chunks(path, chunks, data_start, data_end)
    stats = summary.statistics
    return _FileIndex(path, number, data_start, data_end, int(data_crc), summary.schemas,
                      summary.channels, chunks, stats[0] if stats else None,
                      stats[1] if stats else None)


# -- the data section, block by block --------------------------------------------------------
def _run(pool: ThreadPoolExecutor | None, task: Callable[[], _T]) -> Future[_T]:
    """``task`` in the worker thread (``pool``), or at once (its outcome in a done future)."""
    if pool is not None:
        return pool.submit(task)
    done: Future[_T] = Future()
    try:
        done.set_result(task())
    except BaseException as err:  # handed over as the pool would
        done.set_exception(err)
    return done


class _Carry(NamedTuple):
    """Messages held back to a later block: their keys and payloads (``data``, compact)."""

    log: NDArray[np.int64]
    key: NDArray[np.int64]
    topic: NDArray[np.int16]
    offsets: NDArray[np.int64]
    lengths: NDArray[np.int64]
    data: NDArray[np.uint8]


def _no_carry() -> _Carry:
    empty = np.zeros(0, np.int64)
    return _Carry(empty, empty, np.zeros(0, np.int16), empty, empty, np.zeros(0, np.uint8))


def _compact(buffer: NDArray[np.uint8], offsets: NDArray[np.int64], lengths: NDArray[np.int64],
             ) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """The payloads at ``offsets``/``lengths`` copied one after the other, and their new
    offsets."""
    new = np.cumsum(lengths) - lengths
    total = int(lengths.sum())
    if not total:
        return np.zeros(0, np.uint8), new
    index, _ = _spread(offsets, lengths, 1)  # every byte of every payload
    return buffer[index], new


class _Found(NamedTuple):
    """Messages found in a block (arrays (N,)): log times, file keys, topic codes, payload
    offsets in the buffer and lengths."""

    log: NDArray[np.int64]
    key: NDArray[np.int64]
    topic: NDArray[np.int16]
    offsets: NDArray[np.int64]
    lengths: NDArray[np.int64]


class _Wanted(NamedTuple):
    """A file's wanted message index entries (K,), chunks (bool (C,)) and, per chunk, the
    earliest start time of a wanted chunk at or after it ((C + 1,), the last = no more)."""

    chunk: NDArray[np.int64]
    channel: NDArray[np.int64]
    topic: NDArray[np.int16]
    offset: NDArray[np.int64]
    room: NDArray[np.int64]
    chunks: NDArray[np.bool_]
    later_start: NDArray[np.int64]


class _FileRead:
    """One storage file read block by block (see the module docstring)."""

    def __init__(self, bag: IndexedBag, index: _FileIndex, fd: int, names: Sequence[str],
                 pool: ThreadPoolExecutor | None) -> None:
        self.bag = bag
        self.index = index
        self.fd = fd
        self.path = index.path
        self.names = tuple(names)
        self.pool = pool
        self.crc = 0  # the data section's running CRC-32, updated by the reading task only
        self.check_crc = bool(index.data_crc)  # 0: the writer did not compute it
        self.carry = _no_carry()
        self.counts: dict[int, int] = {}
        self.wanted = self._wanted(names)
        c = index.chunks
        self.name_len = np.array([len(x.encode()) for x in c.compression], dtype=np.int64)
        self.packed = self.name_len > 0
        self.unpacked = np.where(self.wanted.chunks & self.packed, c.uncompressed, 0)

    def _wanted(self, names: Sequence[str]) -> _Wanted:
        c = self.index.chunks
        code = {name: k for k, name in enumerate(names)}
        top = max(max(self.index.channels, default=0), int(c.mi_channel.max(initial=0)))
        topic_of = np.full(top + 1, -1, dtype=np.int16)  # channel id -> topic code
        for cid, ch in self.index.channels.items():
            if ch.topic in code:
                topic_of[cid] = code[ch.topic]
        keep = (topic_of[c.mi_channel] >= 0) & (c.mi_count > 0)
        chunks = np.zeros(c.offset.shape[0], dtype=bool)
        chunks[c.mi_chunk[keep]] = True
        starts = np.where(chunks, c.start, _TIME_LIMIT - 1)
        later = np.minimum.accumulate(np.append(starts, _TIME_LIMIT - 1)[::-1])[::-1]
        return _Wanted(c.mi_chunk[keep], c.mi_channel[keep], topic_of[c.mi_channel[keep]],
                       c.mi_offset[keep], c.mi_count[keep], chunks, later)

    def damaged(self, chunk: int, reason: str) -> DamagedBagError:
        return DamagedBagError(self.path, reason, chunk, int(self.index.chunks.offset[chunk]))

    def plan(self, budget: int) -> Iterator[tuple[int, int]]:
        """Blocks as (first, last + 1) chunk numbers: at most ``budget`` bytes from the first
        chunk's record to the end of the last one's message indexes, at most ``budget``
        decompressed bytes of wanted chunks (a larger chunk alone)."""
        c = self.index.chunks
        region_end = c.offset + c.length + c.index_length
        unpacked = self.unpacked
        n = c.offset.shape[0]
        first = 0
        while first < n:
            last = int(np.searchsorted(region_end, int(c.offset[first]) + budget, side='right'))
            cum = np.cumsum(unpacked[first:last])
            last = max(first + int(np.searchsorted(cum, budget, side='right')), first + 1)
            yield first, last
            first = last

    def blocks(self, budget: int) -> Iterator[Block]:
        """The blocks of the file, then the end-of-file checks. The file is read one block
        ahead in the worker thread (into the other of two buffers), which also feeds the
        data-section CRC, the bytes between blocks and after the last chunk included."""
        c = self.index.chunks
        region_end = c.offset + c.length + c.index_length
        plan = list(self.plan(budget))
        if not self.check_crc:  # no data-section CRC to feed: only blocks with wanted chunks
            plan = [(first, last) for first, last in plan if self.wanted.chunks[first:last].any()]
        spans = [(int(c.offset[first]), int(region_end[last - 1])) for first, last in plan]
        gaps = [0] + [stop for _, stop in spans]
        sizes = [stop - start + int(self.unpacked[first:last].sum())
                 for (first, last), (start, stop) in zip(plan, spans, strict=True)]

        def fetch(k: int) -> Future[NDArray[np.uint8]]:
            start, stop = spans[k]
            return _run(self.pool, lambda: self.fetch(k % 2, gaps[k], start, stop, sizes[k],
                                                      budget))

        pending = fetch(0) if plan else None
        for k, (first, last) in enumerate(plan):
            assert pending is not None
            buf = pending.result()
            pending = fetch(k + 1) if k + 1 < len(plan) else None
            start, stop = spans[k]
            block = self.block(buf, first, last, start, stop)
            if block is not None:
                yield block
        _run(self.pool, lambda: self.stream(gaps[-1], self.index.data_end, budget)).result()
        self.finish()

    def fetch(self, slot: int, gap: int, start: int, stop: int, size: int, budget: int,
              ) -> NDArray[np.uint8]:
        """The reading task: file bytes ``gap`` .. ``start`` through the data-section CRC
        only, then ``start`` .. ``stop`` into buffer ``slot`` (at least ``size`` bytes) and
        the CRC. (Two calls that release the GIL per block: the chunks' own CRCs are computed
        by the main thread, where a call per chunk does not wait for the GIL.)"""
        self.stream(gap, start, budget, slot)
        buf = self.bag._buffer(size, slot)
        view = memoryview(buf)[:stop - start]  # type: ignore[arg-type]
        _pread(self.fd, self.path, view, start)
        if self.check_crc:
            self.crc = zlib.crc32(view, self.crc)
        return buf

    def stream(self, start: int, stop: int, budget: int, slot: int = 0) -> None:
        """File bytes ``start`` .. ``stop`` through the data-section CRC only (not read when
        the file has no data-section CRC)."""
        while self.check_crc and start < stop:
            n = min(stop - start, budget)
            view = memoryview(self.bag._buffer(n, slot))[:n]  # type: ignore[arg-type]
            _pread(self.fd, self.path, view, start)
            self.crc = zlib.crc32(view, self.crc)
            start += n

    def block(self, buf: NDArray[np.uint8], first: int, last: int, start: int, stop: int,
              ) -> Block | None:
        """Chunks ``first`` .. ``last - 1`` (file bytes ``start`` .. ``stop``, read into
        ``buf``): check and find the wanted messages, emit what is due (module docstring);
        None when nothing is."""
        w = self.wanted
        chunks = first + np.flatnonzero(w.chunks[first:last])
        if not chunks.size:
            return None
        raw = stop - start
        at = raw + int(self.unpacked[first:last].sum())
        carry = self.carry
        if buf.shape[0] < at + carry.data.shape[0]:  # rare: a large carry
            grown = np.empty(at + carry.data.shape[0], dtype=np.uint8)
            grown[:raw] = buf[:raw]
            buf = grown
        view = memoryview(buf)  # type: ignore[arg-type]
        base = self.records(buf, view, chunks, start, raw)
        log, key, topic, offsets, lengths = self.messages(buf, base, first, last, start)
        buf[at:at + carry.data.shape[0]] = carry.data
        log = np.concatenate([carry.log, log])
        key = np.concatenate([carry.key, key])
        topic = np.concatenate([carry.topic, topic])
        offsets = np.concatenate([carry.offsets + at, offsets])
        lengths = np.concatenate([carry.lengths, lengths])
        due = log <= w.later_start[last]
        held = np.flatnonzero(~due)
        if held.size:
            data, moved = _compact(buf, offsets[held], lengths[held])
            self.carry = _Carry(log[held], key[held], topic[held], moved, lengths[held], data)
        else:
            self.carry = _no_carry()
        emit = np.flatnonzero(due)
        emit = emit[np.lexsort((key[emit], log[emit]))]
        if not emit.size:
            return None
        return self.bag._make_block(self.index, buf, self.names, log[emit], key[emit],
                                   topic[emit], offsets[emit], lengths[emit])

    def fail(self, bad: NDArray[np.bool_], chunk: NDArray[np.int64], reason: str,
             *details: NDArray[np.int64]) -> None:
        """DamagedBagError for the first ``bad`` entry (its ``chunk``); ``reason`` formatted
        with the ``details`` at that entry."""
        if bad.any():
            k = int(np.argmax(bad))
            raise self.damaged(int(chunk[k]), reason.format(*(int(d[k]) for d in details)))

    def records(self, buf: NDArray[np.uint8], view: memoryview, chunks: NDArray[np.int64],
                start: int, raw: int) -> NDArray[np.int64]:
        """Check the wanted chunks' records (header against the index, decompression, CRC);
        (C,) where each one's records start in ``buf`` (decompressed ones after ``raw``).
        Chunk record (MCAP spec): start, end, uncompressed_size uint64, uncompressed_crc
        uint32, compression string, records bytes with a uint64 length."""
        c = self.index.chunks
        rel = c.offset[chunks] - start
        head = _rows(buf, rel, _RECORD + _CHUNK_FIXED)
        name_len = self.name_len[chunks]
        self.fail(head[:, 0] != Opcode.CHUNK, chunks, 'no chunk record at the offset the '
                  'summary\'s chunk index gives')
        self.fail((_column(head, 1, _U64) != c.length[chunks] - _RECORD)
                  | (_column(head, 9, _U64) != c.start[chunks])
                  | (_column(head, 17, _U64) != c.end[chunks])
                  | (_column(head, 25, _U64) != c.uncompressed[chunks])
                  | (_column(head, 37, np.dtype('<u4')) != name_len), chunks,
                  'its header (length, log times, size or compression) disagrees with the '
                  'summary\'s chunk index')
        at = rel + _RECORD + _CHUNK_FIXED + name_len
        self.fail(_column(_rows(buf, at, 8), 0, _U64) != c.compressed[chunks], chunks,
                  'its compressed size disagrees with the summary\'s chunk index')
        at = at + 8
        self.fail(at + c.compressed[chunks] != rel + c.length[chunks], chunks,
                  'its records do not end with the record')
        for name in {c.compression[i] for i in chunks.tolist()} - {''}:
            sel = np.flatnonzero(np.array([c.compression[i] == name for i in chunks.tolist()]))
            code = np.frombuffer(name.encode(), dtype=np.uint8)
            stored = _rows(buf, at[sel] - 8 - code.shape[0], code.shape[0])
            self.fail((stored != code).any(axis=1), chunks[sel], 'its compression disagrees '
                      'with the summary\'s chunk index')
        crcs = _column(head, 33, np.dtype('<u4'))
        size = c.uncompressed[chunks]
        base = np.zeros(c.offset.shape[0], dtype=np.int64)
        plain = ~self.packed[chunks]
        base[chunks[plain]] = at[plain]
        out = raw
        for k in np.flatnonzero(~plain).tolist():  # decompressed after the raw bytes
            i, n = int(chunks[k]), int(size[k])
            records = self.decompress(i, c.compression[i], view[int(at[k]):int(at[k]) +
                                                                  int(c.compressed[i])], n)
            buf[out:out + n] = np.frombuffer(records, dtype=np.uint8)
            base[i], out = out, out + n
        check = np.flatnonzero(crcs != 0)
        starts, ends = base[chunks[check]], base[chunks[check]] + size[check]
        computed = np.array([zlib.crc32(view[a:b]) for a, b in zip(starts.tolist(),
                                                                   ends.tolist(), strict=True)],
                            dtype=np.int64)
        self.fail(computed != crcs[check], chunks[check], 'chunk CRC mismatch: stored {0:08x}, '
                  'computed {1:08x}', crcs[check], computed)
        return base

    def decompress(self, chunk: int, name: str, data: memoryview, size: int) -> bytes:
        """The records of a compressed chunk (``size`` bytes, as its index states)."""
        if name not in _COMPRESSIONS:
            raise UnsupportedBagError(self.path, f'chunk {chunk} at byte '
                                                 f'{int(self.index.chunks.offset[chunk])}: '
                                                 f'unknown compression {name!r}')
        try:
            records = (self.bag._zstd.decompress(data, max_output_size=size) if name == 'zstd'
                       else lz4.frame.decompress(data))
        except Exception as err:  # whatever a decompressor raises on a damaged stream
            raise self.damaged(chunk, f'does not decompress ({name}: '
                                      f'{err or type(err).__name__})') from err
        if len(records) != size:
            raise self.damaged(chunk, f'decompresses to {len(records)} bytes, not the {size} '
                                      'its index states')
        return bytes(records)

    def messages(self, buf: NDArray[np.uint8], base: NDArray[np.int64], first: int, last: int,
                 start: int) -> _Found:
        """The indexed messages of the wanted channels in chunks ``first`` .. ``last - 1``,
        checked against their records: log times, file keys, topic codes, payload offsets in
        ``buf`` and lengths."""
        c, w = self.index.chunks, self.wanted
        lo, hi = np.searchsorted(w.chunk, [first, last])
        chunk, channel, code = w.chunk[lo:hi], w.channel[lo:hi], w.topic[lo:hi]
        rel = w.offset[lo:hi] - start
        head = _rows(buf, rel, _INDEX)
        length = _column(head, 1, _U64)
        nbytes = _column(head, 11, np.dtype('<u4'))
        self.fail((head[:, 0] != Opcode.MESSAGE_INDEX) | (_column(head, 9, np.dtype('<u2'))
                                                          != channel), chunk,
                  'no message index record of channel {0} at byte {1}, where the chunk index '
                  'places it', channel, rel + start)
        self.fail((length != nbytes + 6) | (nbytes % 16 != 0)
                  | (nbytes // 16 > w.room[lo:hi]), chunk,
                  'the message index of channel {0} at byte {1} is damaged (its lengths '
                  'disagree)', channel, rel + start)
        at, group = _spread(rel + _INDEX, nbytes // 16, 16)
        pairs = _rows(buf, at, 16)
        log, offset = _column(pairs, 0, _U64), _column(pairs, 8, _U64)
        chunk, channel, code = chunk[group], channel[group], code[group]
        size = c.uncompressed[chunk]
        self.fail((offset < 0) | (offset + _MESSAGE > size), chunk, 'its message index '
                  'points past its records (byte {0})', offset)
        pos = base[chunk] + offset
        rec = _rows(buf, pos, _MESSAGE)
        length = _column(rec, 1, _U64)
        self.fail(rec[:, 0] != Opcode.MESSAGE, chunk, 'no message record at byte {0} of its '
                  'records, where its message index points', offset)
        self.fail((length < _MESSAGE - _RECORD) | (offset + _RECORD + length > size), chunk,
                  'the message record at byte {0} of its records runs past them', offset)
        self.fail(_column(rec, 9, np.dtype('<u2')) != channel, chunk, 'the message record at '
                  'byte {0} of its records is on channel {1}, its index says {2}', offset,
                  _column(rec, 9, np.dtype('<u2')), channel)
        self.fail(_column(rec, 15, _U64) != log, chunk, 'the message record at byte {0} of '
                  'its records has log time {1}, its index says {2}', offset,
                  _column(rec, 15, _U64), log)
        self.fail((log < c.start[chunk]) | (log > c.end[chunk]), chunk, 'the message at byte '
                  '{0} of its records has log time {1}, outside the chunk\'s range', offset, log)
        order = np.lexsort((offset, chunk))
        ends = (offset + _RECORD + length)[order]
        overlap = np.zeros(order.shape[0], dtype=bool)
        overlap[1:] = (chunk[order][1:] == chunk[order][:-1]) & (offset[order][1:] < ends[:-1])
        self.fail(overlap, chunk[order], 'two indexed message records overlap at byte {0} of '
                  'its records', offset[order])
        ids, counts = np.unique(channel, return_counts=True)
        for cid, n in zip(ids.tolist(), counts.tolist(), strict=True):
            self.counts[cid] = self.counts.get(cid, 0) + n
        return _Found(log, chunk << 32 | offset, code, pos + _MESSAGE,
                      length - (_MESSAGE - _RECORD))

    def finish(self) -> None:
        """End of the file: the data-section CRC, the messages against the statistics."""
        computed = self.crc
        stored = self.index.data_crc
        if self.check_crc and computed != stored:
            raise DamagedBagError(self.path, f'data section CRC mismatch (stored {stored:08x}, '
                                             f'computed {computed:08x}): bytes 0 .. '
                                             f'{self.index.data_end - 1} are damaged somewhere '
                                             '(a chunk not read here, a chunk or record '
                                             'header, a message index or the metadata)')
        self.check_counts()

    def check_counts(self) -> None:
        """The messages indexed for each wanted channel against the statistics (if any)."""
        expected = self.index.channel_counts
        if expected is None:
            return
        for cid, ch in sorted(self.index.channels.items()):
            if ch.topic in self.names and self.counts.get(cid, 0) != expected.get(cid, 0):
                raise DamagedBagError(self.path, f'{ch.topic} (channel {cid}): the message '
                                                 f'indexes list {self.counts.get(cid, 0)} '
                                                 f'messages, the statistics '
                                                 f'{expected.get(cid, 0)}')


# -- the bag ---------------------------------------------------------------------------------
def _bag_typestore(path: Path, schemas: Sequence[_Schema]) -> Typestore:
    """A typestore of the definitions the schemas store, as rosbags' AnyReader builds it."""
    found: dict[str, Any] = {}
    try:
        for schema in schemas:
            if schema.encoding == 'ros2msg':
                found.update(get_types_from_msg(schema.data, schema.name))
            elif schema.encoding == 'ros2idl':
                sep = '=' * 80 + '\n'
                parts = (schema.data.split(sep)[1:] if schema.data.startswith(f'{sep}IDL: ')
                         else [schema.data])
                for part in parts:
                    found.update(get_types_from_idl(part.split('\n', 1)[1]
                                                    if part.startswith('IDL: ') else part))
        if not found:
            return jazzy_typestore()
        store = get_typestore(Stores.EMPTY)
        store.register(found)
    except (TypesysError, ValueError, IndexError) as err:
        raise BagError(path, f'the message definitions stored in the bag do not parse: '
                             f'{err}') from err
    return store


def _metadata_qos(path: Path) -> dict[str, tuple[Qos, ...]] | None:
    """Offered QoS per topic from the bag's metadata.yaml (None without one)."""
    meta = path / METADATA_FILE if path.is_dir() else None
    if meta is None or not meta.is_file():
        return None
    try:
        info = yaml.load(meta.read_text(encoding='utf-8'), Loader=_YAML_LOADER)
        return {t['topic_metadata']['name']: tuple(dict.fromkeys(parse_qos(
            t['topic_metadata'].get('offered_qos_profiles', []))))
            for t in info['rosbag2_bagfile_information']['topics_with_message_count']}
    except (OSError, yaml.YAMLError, ReaderError, KeyError, TypeError, ValueError,
            AttributeError) as err:
        raise BagError(path, f'unreadable {METADATA_FILE}: {err}') from err


class IndexedBag:
    """An open bag (a rosbag2 directory: its ``.mcap`` files in split order; or one
    ``.mcap`` file) read through its MCAP index: a context manager; :meth:`close` is
    idempotent.

    Opening reads each file's summary: :attr:`topics` (type, message count from the
    statistics, QoS offered from metadata.yaml when there is one, else from the channels).
    :meth:`blocks` streams the messages of chosen topics; :meth:`decode` decodes a topic of a
    block; :meth:`read` does both for a whole bag; :meth:`raw_messages` yields what
    ``BagReader.raw_messages`` does. A missing path or a file that is no MCAP file raises
    BagError; a file the indexed read cannot use raises an :class:`IndexedReadError`
    (:class:`UnindexedBagError`, :class:`DamagedBagError`, :class:`UnsupportedBagError`),
    on opening or while reading: the caller falls back to the slow path
    (``positioning_cell.analysis.reading.read_bag``). ``block_bytes`` bounds each block's
    read and decompressed bytes; ``crc_thread``: the data-section CRC in a worker thread.
    """

    def __init__(self, path: str | Path, *, block_bytes: int = DEFAULT_BLOCK_BYTES,
                 crc_thread: bool = True) -> None:
        path = Path(path)
        if not path.exists():
            raise BagError(path, 'does not exist')
        if block_bytes < 1:
            raise BagError(path, f'block_bytes = {block_bytes}: must be positive')
        files = storage_files(path) if path.is_dir() else [path]
        if not files:
            raise BagError(path, 'no .mcap storage file in the bag directory')
        self.path = path
        self.files = tuple(files)
        self._block_bytes = block_bytes
        self._crc_thread = crc_thread
        self._fds: list[int] = []
        self._index: list[_FileIndex] = []
        self._buffers = [np.zeros(0, dtype=np.uint8), np.zeros(0, dtype=np.uint8)]
        self._typestore: Typestore | None = None
        self._plans: dict[str, DecodePlan | None] = {}
        self._zstd = zstandard.ZstdDecompressor()
        try:
            for number, file in enumerate(files):
                try:
                    fd = os.open(file, os.O_RDONLY)
                except OSError as err:
                    raise BagError(file, f'cannot open: {err.strerror or err}') from err
                self._fds.append(fd)
                self._index.append(_read_index(path, file, number, fd))
            self.topics = self._topics()
        except BaseException:
            self.close()
            raise

    def _topics(self) -> dict[str, TopicInfo]:
        qos_meta = _metadata_qos(self.path)
        types: dict[str, set[str]] = {}
        counts: dict[str, int] = {}
        qos: dict[str, dict[Qos, None]] = {}
        for index in self._index:
            by_channel = index.channel_counts
            if by_channel is None:
                c = index.chunks
                by_channel = {int(k): int(c.mi_count[c.mi_channel == k].sum())
                              for k in np.unique(c.mi_channel).tolist()}
            for cid, ch in index.channels.items():
                schema = index.schemas.get(ch.schema_id)
                types.setdefault(ch.topic, set()).add(schema.name if schema else '')
                counts[ch.topic] = counts.get(ch.topic, 0) + by_channel.get(cid, 0)
                offered = qos.setdefault(ch.topic, {})
                if qos_meta is None and ch.metadata.get('offered_qos_profiles'):
                    offered.update(dict.fromkeys(parse_qos_yaml(
                        ch.metadata['offered_qos_profiles'], index.path)))
        return {name: TopicInfo(name, next(iter(types[name])) if len(types[name]) == 1 else '',
                                counts[name], qos_meta.get(name, ()) if qos_meta is not None
                                else tuple(qos[name]))
                for name in sorted(types)}

    # -- state ---------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran."""
        return not self._fds and not self._index

    @property
    def message_count(self) -> int:
        """Messages in the bag (by the summaries)."""
        return sum(t.message_count for t in self.topics.values())

    @property
    def start_ns(self) -> int:
        """Log time of the first message (ns since the epoch, the chunk indexes' earliest
        ``message_start_time``; 0 for a bag without chunks), as ``BagReader.start_ns``."""
        starts = [int(i.chunks.start.min()) for i in self._index if i.chunks.start.size]
        return min(starts, default=0)

    @property
    def end_ns(self) -> int:
        """Log time of the last message (ns since the epoch, the latest
        ``message_end_time``; 0 for a bag without chunks), as ``BagReader.end_ns``."""
        ends = [int(i.chunks.end.max()) for i in self._index if i.chunks.end.size]
        return max(ends, default=0)

    @property
    def typestore(self) -> Typestore:
        """The types the bag's own schemas define (``ros2msg`` / ``ros2idl``), as rosbags'
        AnyReader builds its typestore (faster than building the Jazzy typestore: only the
        bag's types); the Jazzy typestore if the bag stores no definition."""
        if self._typestore is None:
            self._typestore = _bag_typestore(
                self.path, [s for index in self._index for s in index.schemas.values()])
        return self._typestore

    def _buffer(self, size: int, slot: int = 0) -> NDArray[np.uint8]:
        """Reusable block buffer ``slot`` (0 or 1: read ahead into one while the other is
        used), at least ``size`` bytes (grown when needed)."""
        if self._buffers[slot].shape[0] < size:
            self._buffers[slot] = np.empty(max(size, self._buffers[slot].shape[0] * 5 // 4),
                                           dtype=np.uint8)
        return self._buffers[slot]

    # -- reading -------------------------------------------------------------------------
    def _names(self, topics: Collection[str]) -> tuple[str, ...]:
        if self.closed:
            raise BagError(self.path, 'the bag is closed')
        names = tuple(dict.fromkeys(t for t in topics if t in self.topics))
        mixed = [t for t in names if not self.topics[t].msgtype]
        if mixed:
            raise UnsupportedBagError(self.path, f'{", ".join(mixed)}: channels of different '
                                                 'types')
        return names

    def blocks(self, topics: Collection[str]) -> Iterator[Block]:
        """The messages of ``topics`` (those the bag has; others are ignored), block by
        block, in rosbags' order (module docstring). Each block's buffer is reused by the
        next. Files without any wanted message are not read. IndexedReadError on damage; the
        data-section CRC and the statistics of a file are checked after its last block."""
        names = self._names(topics)
        if not names:
            return
        pool = ThreadPoolExecutor(1, thread_name_prefix='bag-crc') if self._crc_thread \
            else None
        try:
            for index, fd in zip(self._index, self._fds, strict=True):
                read = _FileRead(self, index, fd, names, pool)
                if read.wanted.chunks.any():
                    yield from read.blocks(self._block_bytes)
                else:
                    read.check_counts()  # nothing wanted indexed: nothing there?
        finally:
            if pool is not None:
                pool.shutdown(wait=True)

    def _make_block(self, index: _FileIndex, buf: NDArray[np.uint8], names: tuple[str, ...],
                   log: NDArray[np.int64], key: NDArray[np.int64], topic: NDArray[np.int16],
                   offsets: NDArray[np.int64], lengths: NDArray[np.int64]) -> Block:
        """A block from its messages in stream order (arrays (M,))."""
        position = np.empty(topic.shape[0], dtype=np.int64)
        per_topic: dict[str, TopicMessages] = {}
        for code in np.unique(topic).tolist():
            sel = np.flatnonzero(topic == code)
            position[sel] = np.arange(sel.shape[0])
            name = names[code]
            per_topic[name] = TopicMessages(name, self.topics[name].msgtype, log[sel], key[sel],
                                            offsets[sel], lengths[sel])
        return Block(index.path, index.number, buf, per_topic,
                     MessageOrder(names, topic, position))

    def plan(self, msgtype: str) -> DecodePlan | None:
        """The CDR decoding plan of ``msgtype`` with the bag's typestore (None: not
        fixed-layout, decoded message by message)."""
        if msgtype not in self._plans:
            self._plans[msgtype] = fixed_layout_plan(msgtype, self.typestore)
        return self._plans[msgtype]

    def decode(self, block: Block, topic: str) -> Decoded:
        """The messages of ``topic`` in ``block`` decoded: vectorised when its type is
        fixed-layout (:mod:`positioning_cell.bag.cdr`), else with rosbags, one by one
        (e.g. ``diagnostic_msgs/msg/DiagnosticArray``). None of the result refers to the
        block's buffer. BagError naming the file, topic, log time and what is wrong if a
        message does not decode."""
        info = self.topics[topic]
        empty = np.zeros(0, np.int64)
        m = block.topics.get(topic) or TopicMessages(topic, info.msgtype, empty, empty, empty,
                                                     empty)
        plan = self.plan(info.msgtype)
        if plan is not None:
            try:
                columns = decode(plan, block.buffer, m.offsets, m.lengths, topic=topic)
            except CdrError as err:
                raise BagError(block.file, f'{err} (log time {int(m.log_time_ns[err.index])} '
                                           'ns)') from err
            return Decoded(topic, info.msgtype, m.log_time_ns, columns, None)
        store = self.typestore
        messages = []
        for i, (start, size) in enumerate(zip(m.offsets.tolist(), m.lengths.tolist(),
                                              strict=True)):
            try:
                messages.append(store.deserialize_cdr(block.buffer[start:start + size]
                                                      .tobytes(), info.msgtype))
            except (SerdeError, KeyError, ValueError) as err:
                raise BagError(block.file, f'{topic} ({info.msgtype}): message {i} at log '
                                           f'time {int(m.log_time_ns[i])} ns does not decode: '
                                           f'{err}') from err
        return Decoded(topic, info.msgtype, m.log_time_ns, None, tuple(messages))

    def read(self, topics: Collection[str]) -> BagRead:
        """Every message of ``topics`` (those the bag has) decoded, and their order across
        topics: :meth:`blocks` + :meth:`decode`, each block's columns added to arrays sized
        by the summary's message counts (no concatenation at the end)."""
        names = self._names(topics)
        empty = Block(self.path, 0, np.zeros(0, np.uint8), {}, MessageOrder(
            (), np.zeros(0, np.int16), np.zeros(0, np.int64)))
        builders: dict[str, ColumnsBuilder] = {}
        messages: dict[str, list[Any]] = {}
        for name in names:
            first = self.decode(empty, name)  # the fields, dtypes and shapes
            if first.columns is not None:
                builders[name] = ColumnsBuilder(first.msgtype, self.topics[name].message_count)
                builders[name].add(first.columns)
            else:
                messages[name] = []
        times: dict[str, list[NDArray[np.int64]]] = {name: [] for name in names}
        codes: list[NDArray[np.int16]] = []
        positions: list[NDArray[np.int64]] = []
        seen = np.zeros(len(names), dtype=np.int64)
        for block in self.blocks(names):
            for name in block.topics:
                decoded = self.decode(block, name)
                times[name].append(decoded.log_time_ns)
                if decoded.columns is not None:
                    builders[name].add(decoded.columns)
                else:
                    messages[name].extend(decoded.messages or ())
            order = block.order
            codes.append(order.topic)
            positions.append(order.position + seen[order.topic])
            seen += np.bincount(order.topic, minlength=len(names))
        result = {name: Decoded(
            name, self.topics[name].msgtype,
            np.concatenate(times[name]) if times[name] else np.zeros(0, np.int64),
            builders[name].build() if name in builders else None,
            tuple(messages[name]) if name in messages else None) for name in names}
        return BagRead(result, MessageOrder(
            names, np.concatenate(codes) if codes else np.zeros(0, np.int16),
            np.concatenate(positions) if positions else np.zeros(0, np.int64)))

    def raw_messages(self, topics: Collection[str]) -> Iterator[RawMessage]:
        """The stored messages of ``topics`` one by one, as ``BagReader.raw_messages``
        yields them (same order, log times and bytes): for tests and small reads."""
        for block in self.blocks(topics):
            names = block.order.names
            for code, i in zip(block.order.topic.tolist(), block.order.position.tolist(),
                               strict=True):
                m = block.topics[names[code]]
                yield RawMessage(m.topic, m.msgtype, int(m.log_time_ns[i]),
                                 block.payload(m.topic, i))

    def close(self) -> None:
        """Close the files (idempotent)."""
        fds, self._fds = self._fds, []
        self._index = []
        self._buffers = [np.zeros(0, dtype=np.uint8), np.zeros(0, dtype=np.uint8)]
        for fd in fds:
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> IndexedBag:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
