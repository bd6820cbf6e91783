"""Reading chosen topics of an MCAP bag through its index: one sequential pass over each file
in blocks of whole chunks, only the wanted channels' message records touched, in bounded
memory, in exactly the order rosbags' ``AnyReader.messages`` yields them.

:class:`IndexedBag` opens a bag (its summaries; :mod:`positioning_cell.bag.file_index`);
:meth:`IndexedBag.blocks` streams the messages of chosen topics as :class:`Block` s (log times,
file keys, payload offsets into a reused buffer, the order across topics);
:meth:`IndexedBag.decode` decodes a topic of a block (vectorised with
:mod:`positioning_cell.bag.cdr` for fixed-layout types, else rosbags message by message);
:meth:`IndexedBag.read` does both for the whole bag. Every valid MCAP file is read: one whose
summary lacks what this read needs (no summary, no chunk index, chunks without message
indexes: rosbag2's ``fastwrite`` files, for one) was scanned once when it was opened, and is
then read the same way, from what the scan found instead of its message indexes (its runs of
unchunked records read as chunks stored as they are). What cannot be read as it is (a file
that did not end cleanly, damage, an unknown compression) raises an :class:`IndexedReadError`
so that the caller falls back to the slow path
(``positioning_cell.analysis.reading.with_recording``: verify, recover).

How (MCAP spec, https://mcap.dev/spec):

* **Chunks wanted.** A chunk (or scanned segment) is wanted when the index lists a message of
  a wanted channel in it. Chunks without a wanted channel are never parsed.
* **Blocks.** Each file is read front to back with ``os.preadv``, a block of whole chunks
  (with their message indexes and what lies between them) at a time: at most ``block_bytes``
  read and at most ``block_bytes`` decompressed, or a single chunk when it is larger. A worker
  thread reads one block ahead into the other of two reused buffers and feeds every byte from
  the file start to the DataEnd record to ``zlib.crc32`` (which releases the GIL), checked
  against DataEnd's ``data_section_crc`` once the file is read, when it is nonzero: it
  covers the chunks not parsed too. (A file without that CRC is read only where wanted
  chunks are; a scanned file's was checked by the scan.)
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
  file (for a file without chunk index rosbags keeps the file order, and refuses a file not
  in log-time order: the same order where it reads). A block emits its messages up to the
  earliest ``message_start_time`` of a wanted chunk not yet read; later ones (chunks
  overlapping in time) are copied aside and emitted with a later block, so the stream is
  globally in that order.
* **Completeness.** When the summary has Statistics, the messages indexed for each wanted
  channel must add up to its ``channel_message_counts`` at the end of the file.

A chunk without a CRC (rosbags' own writer) is checked through its index only: damage inside
a message's payload is then not detected (verify_bag has the same limit). Memory: two block
buffers, the files' index arrays (~1 MB per 4000 chunks; 32 bytes per message of a scanned
file) and the decoded output; bags whose chunks overlap in time hold back more (the messages
after the earliest start of an unread chunk wait until that chunk is read).
"""

from __future__ import annotations

import contextlib
import os
import zlib
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple, TypeVar

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
from positioning_cell.bag.errors import (
    BagError,
    DamagedBagError,
    IndexedReadError,
    UnindexedBagError,
    UnsupportedBagError,
)
from positioning_cell.bag.file_index import (
    CHUNK_FIXED,
    DEFAULT_BLOCK_BYTES,
    INDEX,
    MESSAGE,
    RECORD,
    TIME_LIMIT,
    U64,
    FileIndex,
    SchemaInfo,
    column,
    decompress,
    pread,
    read_index,
    rows,
    spread,
)
from positioning_cell.bag.metadata import METADATA_FILE, parse_qos_yaml
from positioning_cell.bag.reader import BagMessage, RawMessage, TopicInfo
from positioning_cell.bag.verify import storage_files
from positioning_cell.bag.writer import jazzy_typestore

__all__ = ['DEFAULT_BLOCK_BYTES', 'BagRead', 'Block', 'DamagedBagError', 'Decoded',
           'IndexedBag', 'IndexedReadError', 'MessageOrder', 'TopicMessages',
           'UnindexedBagError', 'UnsupportedBagError']

_T = TypeVar('_T')
_YAML_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)  # libyaml: 100x ruamel's speed


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
    index, _ = spread(offsets, lengths, 1)  # every byte of every payload
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
    """A file's wanted entries (K,): message index entries of an indexed file (``room``:
    the messages each leaves room for; ``log`` None), or messages of a scanned file (their
    ``log`` times and record offsets); wanted chunks (bool (C,)) and, per chunk, the
    earliest start time of a wanted chunk at or after it ((C + 1,), the last = no more)."""

    chunk: NDArray[np.int64]
    channel: NDArray[np.int64]
    topic: NDArray[np.int16]
    offset: NDArray[np.int64]
    room: NDArray[np.int64]
    log: NDArray[np.int64] | None
    chunks: NDArray[np.bool_]
    later_start: NDArray[np.int64]


class _FileRead:
    """One storage file read block by block (see the module docstring)."""

    def __init__(self, bag: IndexedBag, index: FileIndex, fd: int, names: Sequence[str],
                 pool: ThreadPoolExecutor | None) -> None:
        self.bag = bag
        self.index = index
        self.fd = fd
        self.path = index.path
        self.names = tuple(names)
        self.pool = pool
        self.crc = 0  # the data section's running CRC-32, updated by the reading task only
        # 0: the writer did not compute it; a scanned file's was checked by the scan
        self.check_crc = bool(index.data_crc) and index.scanned is None
        self.carry = _no_carry()
        self.counts: dict[int, int] = {}
        self.wanted = self._wanted(names)
        c = index.chunks
        self.name_len = np.array([len(x.encode()) for x in c.compression], dtype=np.int64)
        self.packed = self.name_len > 0
        self.unpacked = np.where(self.wanted.chunks & self.packed, c.uncompressed, 0)

    def _wanted(self, names: Sequence[str]) -> _Wanted:
        c, scanned = self.index.chunks, self.index.scanned
        if scanned is None:
            chunk, channel, offset, room = c.mi_chunk, c.mi_channel, c.mi_offset, c.mi_count
        else:
            chunk, channel, offset = scanned.segment, scanned.channel, scanned.offset
            room = np.ones(chunk.shape[0], dtype=np.int64)
        code = {name: k for k, name in enumerate(names)}
        top = max(max(self.index.channels, default=0), int(channel.max(initial=0)))
        topic_of = np.full(top + 1, -1, dtype=np.int16)  # channel id -> topic code
        for cid, ch in self.index.channels.items():
            if ch.topic in code:
                topic_of[cid] = code[ch.topic]
        keep = (topic_of[channel] >= 0) & (room > 0)
        chunks = np.zeros(c.offset.shape[0], dtype=bool)
        chunks[chunk[keep]] = True
        starts = np.where(chunks, c.start, TIME_LIMIT - 1)
        later = np.minimum.accumulate(np.append(starts, TIME_LIMIT - 1)[::-1])[::-1]
        return _Wanted(chunk[keep], channel[keep], topic_of[channel[keep]], offset[keep],
                       room[keep], scanned.log[keep] if scanned is not None else None, chunks,
                       later)

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
        pread(self.fd, self.path, view, start)
        if self.check_crc:
            self.crc = zlib.crc32(view, self.crc)
        return buf

    def stream(self, start: int, stop: int, budget: int, slot: int = 0) -> None:
        """File bytes ``start`` .. ``stop`` through the data-section CRC only (not read when
        the file has no data-section CRC)."""
        while self.check_crc and start < stop:
            n = min(stop - start, budget)
            view = memoryview(self.bag._buffer(n, slot))[:n]  # type: ignore[arg-type]
            pread(self.fd, self.path, view, start)
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
        uint32, compression string, records bytes with a uint64 length. A run of top-level
        records of a scanned file is its own records."""
        c = self.index.chunks
        base = np.zeros(c.offset.shape[0], dtype=np.int64)
        runs = chunks[c.plain[chunks]]
        base[runs] = c.offset[runs] - start
        chunks = chunks[~c.plain[chunks]]
        rel = c.offset[chunks] - start
        head = rows(buf, rel, RECORD + CHUNK_FIXED)
        name_len = self.name_len[chunks]
        self.fail(head[:, 0] != Opcode.CHUNK, chunks, 'no chunk record at the offset the '
                  'summary\'s chunk index gives')
        self.fail((column(head, 1, U64) != c.length[chunks] - RECORD)
                  | (column(head, 9, U64) != c.start[chunks])
                  | (column(head, 17, U64) != c.end[chunks])
                  | (column(head, 25, U64) != c.uncompressed[chunks])
                  | (column(head, 37, np.dtype('<u4')) != name_len), chunks,
                  'its header (length, log times, size or compression) disagrees with the '
                  'summary\'s chunk index')
        at = rel + RECORD + CHUNK_FIXED + name_len
        self.fail(column(rows(buf, at, 8), 0, U64) != c.compressed[chunks], chunks,
                  'its compressed size disagrees with the summary\'s chunk index')
        at = at + 8
        self.fail(at + c.compressed[chunks] != rel + c.length[chunks], chunks,
                  'its records do not end with the record')
        for name in {c.compression[i] for i in chunks.tolist()} - {''}:
            sel = np.flatnonzero(np.array([c.compression[i] == name for i in chunks.tolist()]))
            code = np.frombuffer(name.encode(), dtype=np.uint8)
            stored = rows(buf, at[sel] - 8 - code.shape[0], code.shape[0])
            self.fail((stored != code).any(axis=1), chunks[sel], 'its compression disagrees '
                      'with the summary\'s chunk index')
        crcs = column(head, 33, np.dtype('<u4'))
        size = c.uncompressed[chunks]
        as_is = ~self.packed[chunks]
        base[chunks[as_is]] = at[as_is]
        out = raw
        for k in np.flatnonzero(~as_is).tolist():  # decompressed after the raw bytes
            i, n = int(chunks[k]), int(size[k])
            records = decompress(self.path, i, int(c.offset[i]), c.compression[i],
                                 view[int(at[k]):int(at[k]) + int(c.compressed[i])], n,
                                 self.bag._zstd)
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

    def messages(self, buf: NDArray[np.uint8], base: NDArray[np.int64], first: int, last: int,
                 start: int) -> _Found:
        """The messages of the wanted channels in chunks ``first`` .. ``last - 1`` (as
        their message indexes list them, or as the scan found them), checked against their
        records: log times, file keys, topic codes, payload offsets in ``buf`` and lengths."""
        c, w = self.index.chunks, self.wanted
        lo, hi = (int(k) for k in np.searchsorted(w.chunk, [first, last]))
        if w.log is None:
            chunk, channel, code, log, offset = self.indexed(buf, start, lo, hi)
        else:
            chunk, channel, code = w.chunk[lo:hi], w.channel[lo:hi], w.topic[lo:hi]
            log, offset = w.log[lo:hi], w.offset[lo:hi]
        size = c.uncompressed[chunk]
        self.fail((offset < 0) | (offset + MESSAGE > size), chunk, 'its message index '
                  'points past its records (byte {0})', offset)
        pos = base[chunk] + offset
        rec = rows(buf, pos, MESSAGE)
        length = column(rec, 1, U64)
        self.fail(rec[:, 0] != Opcode.MESSAGE, chunk, 'no message record at byte {0} of its '
                  'records, where its message index points', offset)
        self.fail((length < MESSAGE - RECORD) | (offset + RECORD + length > size), chunk,
                  'the message record at byte {0} of its records runs past them', offset)
        self.fail(column(rec, 9, np.dtype('<u2')) != channel, chunk, 'the message record at '
                  'byte {0} of its records is on channel {1}, its index says {2}', offset,
                  column(rec, 9, np.dtype('<u2')), channel)
        self.fail(column(rec, 15, U64) != log, chunk, 'the message record at byte {0} of '
                  'its records has log time {1}, its index says {2}', offset,
                  column(rec, 15, U64), log)
        self.fail((log < c.start[chunk]) | (log > c.end[chunk]), chunk, 'the message at byte '
                  '{0} of its records has log time {1}, outside the chunk\'s range', offset, log)
        order = np.lexsort((offset, chunk))
        ends = (offset + RECORD + length)[order]
        overlap = np.zeros(order.shape[0], dtype=bool)
        overlap[1:] = (chunk[order][1:] == chunk[order][:-1]) & (offset[order][1:] < ends[:-1])
        self.fail(overlap, chunk[order], 'two indexed message records overlap at byte {0} of '
                  'its records', offset[order])
        ids, counts = np.unique(channel, return_counts=True)
        for cid, n in zip(ids.tolist(), counts.tolist(), strict=True):
            self.counts[cid] = self.counts.get(cid, 0) + n
        return _Found(log, chunk << 32 | offset, code, pos + MESSAGE,
                      length - (MESSAGE - RECORD))

    def indexed(self, buf: NDArray[np.uint8], start: int, lo: int, hi: int,
                ) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int16],
                           NDArray[np.int64], NDArray[np.int64]]:
        """Wanted message index entries ``lo`` .. ``hi - 1`` read from their records in
        ``buf`` (file offset ``start``), checked: per message its chunk, channel, topic
        code, log time and record offset in the chunk's records."""
        w = self.wanted
        chunk, channel, code = w.chunk[lo:hi], w.channel[lo:hi], w.topic[lo:hi]
        rel = w.offset[lo:hi] - start
        head = rows(buf, rel, INDEX)
        length = column(head, 1, U64)
        nbytes = column(head, 11, np.dtype('<u4'))
        self.fail((head[:, 0] != Opcode.MESSAGE_INDEX) | (column(head, 9, np.dtype('<u2'))
                                                          != channel), chunk,
                  'no message index record of channel {0} at byte {1}, where the chunk index '
                  'places it', channel, rel + start)
        self.fail((length != nbytes + 6) | (nbytes % 16 != 0)
                  | (nbytes // 16 > w.room[lo:hi]), chunk,
                  'the message index of channel {0} at byte {1} is damaged (its lengths '
                  'disagree)', channel, rel + start)
        at, group = spread(rel + INDEX, nbytes // 16, 16)
        pairs = rows(buf, at, 16)
        return (chunk[group], channel[group], code[group], column(pairs, 0, U64),
                column(pairs, 8, U64))

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
def _bag_typestore(path: Path, schemas: Sequence[SchemaInfo]) -> Typestore:
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

    Opening reads each file's summary, or scans a file whose summary does not say where its
    messages are (:mod:`positioning_cell.bag.file_index`; :attr:`scans` names those and
    why): :attr:`topics` (type, message count from the statistics or the scan, QoS offered
    from metadata.yaml when there is one, else from the channels). :meth:`blocks` streams
    the messages of chosen topics; :meth:`decode` decodes a topic of a block; :meth:`read`
    does both for a whole bag; :meth:`raw_messages` and :meth:`messages` yield what
    ``BagReader.raw_messages`` / ``messages`` do. A missing path or a file that is no MCAP
    file raises BagError; a file that cannot be read as it is raises an
    :class:`IndexedReadError` (:class:`UnindexedBagError`: no footer, the recording did not
    end; :class:`DamagedBagError`; :class:`UnsupportedBagError`), on opening or while
    reading: the caller falls back to the slow path (verify, recover:
    ``positioning_cell.analysis.reading.with_recording``). ``block_bytes`` bounds each
    block's read and decompressed bytes; ``crc_thread``: the data-section CRC in a worker
    thread.
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
        self._index: list[FileIndex] = []
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
                self._index.append(read_index(path, file, number, fd, block_bytes))
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
            by_channel = index.counts()
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
    def scans(self) -> dict[str, str]:
        """The storage files (by name) read from a scan of their records, and why (the others
        are read through their message indexes)."""
        return {i.path.name: i.scanned.reason for i in self._index if i.scanned is not None}

    @property
    def start_ns(self) -> int:
        """Log time of the first message (ns since the epoch: the chunk indexes' earliest
        ``message_start_time``, or the earliest a scan found; 0 for a bag without messages),
        as ``BagReader.start_ns``."""
        ranges = [r for r in (i.log_range for i in self._index) if r is not None]
        return min((r[0] for r in ranges), default=0)

    @property
    def end_ns(self) -> int:
        """Log time of the last message (ns since the epoch: the latest
        ``message_end_time``, or the latest a scan found; 0 for a bag without messages), as
        ``BagReader.end_ns``."""
        ranges = [r for r in (i.log_range for i in self._index) if r is not None]
        return max((r[1] for r in ranges), default=0)

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

    def _make_block(self, index: FileIndex, buf: NDArray[np.uint8], names: tuple[str, ...],
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

    def raw_messages(self, topics: Collection[str] | None = None,
                     start_ns: int | None = None) -> Iterator[RawMessage]:
        """The stored messages of ``topics`` (None: every topic; topics the bag does not
        have are ignored) from log time ``start_ns`` on, one by one, as
        ``BagReader.raw_messages`` yields them (same order, log times and bytes)."""
        for block in self.blocks(list(self.topics) if topics is None else topics):
            order = block.order
            for code, i in zip(order.topic.tolist(), order.position.tolist(), strict=True):
                m = block.topics[order.names[code]]
                log = int(m.log_time_ns[i])
                if start_ns is None or log >= start_ns:
                    yield RawMessage(m.topic, m.msgtype, log, block.payload(m.topic, i))

    def messages(self, topics: Collection[str] | None = None,
                 start_ns: int | None = None) -> Iterator[BagMessage]:
        """Like :meth:`raw_messages`, each message decoded (rosbags, with the definitions
        stored in the bag), as ``BagReader.messages`` yields them."""
        store = self.typestore
        for raw in self.raw_messages(topics, start_ns):
            try:
                message = store.deserialize_cdr(raw.data, raw.msgtype)
            except (SerdeError, KeyError, ValueError) as err:
                raise BagError(self.path, f'message on {raw.topic} at {raw.log_time_ns} ns does '
                                          f'not decode as {raw.msgtype}: {err}') from err
            yield BagMessage(raw.topic, raw.msgtype, raw.log_time_ns, message)

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
