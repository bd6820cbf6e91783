"""Writing rosbag2 MCAP bags from serialized (CDR) messages, in small chunks that reach the disk
on every :meth:`BagWriter.flush`, so a killed recorder loses at most what came after the last
flush (and :func:`positioning_cell.bag.recovery.recover_bag` restores the rest).

A bag is a directory ``<name>/`` holding ``<name>_0.mcap`` (``_1``, ``_2`` ... after splits,
rosbag2's naming) and ``metadata.yaml``. Each ``.mcap`` holds rosbags' MCAP storage records
(the ``ros2`` profile as rosbag2 writes it: one ``ros2msg`` schema per type with the full
definition from the rosbags Jazzy typestore, one ``cdr`` channel per topic carrying its
``offered_qos_profiles``, log time = receive time, a ``rosbag2`` metadata record, chunk and
message indexes): rosbags' writer builds the chunks in memory, 3-4x faster than
``mcap.writer.Writer`` here (about 150k against 45k small messages/s), which is what lets a
recorder keep up at 20k messages/s; its 1 MiB chunk buffer is bounded by closing the chunk at
``chunk_bytes`` and on every flush.

rosbags' writer leaves every CRC of the format at 0 ("not computed"); this one fills all three,
so that :mod:`positioning_cell.bag.verify` (and any MCAP reader that checks them) detects a
damaged file: each chunk's ``uncompressed_crc`` (CRC-32 of its records before compression), the
``data_section_crc`` of the DataEnd record (every byte from the start of the file to DataEnd,
kept as a running CRC of what reaches the file) and the footer's ``summary_crc``.

A failing disk (any OSError: ENOSPC, EFBIG, EIO ...) never leaves a torn bag behind when it can
be helped. The file is only ever extended by whole pieces (a chunk with its message indexes; the
summary section with the footer), each all or nothing: a failed write cuts the file back to the
end of the last complete piece, and the chunk being filled keeps its messages. The bag directory
holds a preallocated ``.close_reserve`` file, grown with the bag's index to what closing it needs
(twice the summary section and a full chunk, plus metadata.yaml), so that on a full disk its
space can be given back to close the bag. After a failure :class:`BagWriter` closes the bag with
what it has (:meth:`BagWriter.close`'s result: indexed files and metadata.yaml), moving what no
longer fits in a file (a per-file size limit: EFBIG) into one more file, and raises
:class:`BagWriteError` with the :class:`WriteFailure`: the errno, the file, what is in the bag and
what was lost.
"""

from __future__ import annotations

import contextlib
import errno
import io
import math
import os
import re
import shutil
import struct
import zlib
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from importlib.metadata import version
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

import zstandard
from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag2,
    MessageDefinition,
    MessageDefinitionFormat,
    Qos,
)
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.storage_mcap import (
    McapWriter,
    PendingChunk,
    decompress,
    write_channel,
    write_record,
    write_schema,
    write_string,
    write_uint16,
    write_uint32,
    write_uint64,
)
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from positioning_cell.bag.description import ROSBAG2_RECORD, Attachment, MetadataRecord
from positioning_cell.bag.errors import BagError
from positioning_cell.bag.metadata import (
    FileSummary,
    TopicMeta,
    bag_metadata,
    metadata_yaml,
    qos_yaml,
    write_metadata,
)

COMPRESSIONS = {'none': CompressionMode.NONE, 'zstd': CompressionMode.STORAGE}
#: Default chunk size: small, so that a periodic flush writes little and a kill loses little.
DEFAULT_CHUNK_BYTES = 64 * 1024
#: rosbags' storage closes a chunk past 1 MiB by itself; larger chunk sizes are not possible.
MAX_CHUNK_BYTES = 2**20
_TYPE_NAME = re.compile(r'^[A-Za-z]\w*/(msg|srv|action)/[A-Za-z]\w*$')
_SCHEMA_FORMATS = {'ros2msg': MessageDefinitionFormat.MSG, 'ros2idl': MessageDefinitionFormat.IDL}


@cache
def jazzy_typestore() -> Typestore:
    """The rosbags typestore of ROS 2 Jazzy's standard messages (built once)."""
    return get_typestore(Stores.ROS2_JAZZY)


def message_definition(msgtype: str, typestore: Typestore | None = None) -> tuple[str, str]:
    """Full ``ros2msg`` definition (dependencies appended, as rosbag2 stores it) and RIHS01
    hash of ``msgtype`` (``pkg/msg/Type``); BagError if the typestore does not know it."""
    store = typestore or jazzy_typestore()
    if not _TYPE_NAME.match(msgtype) or msgtype not in store.fielddefs:
        raise BagError(msgtype, 'message type unknown to the ROS 2 Jazzy typestore; cannot '
                                'store its definition')
    text, _ = store.generate_msgdef(msgtype, ros_version=2)
    return text, store.hash_rihs01(msgtype)


_MAGIC = b'\x89MCAP0\r\n'
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL = 0x01, 0x02, 0x03, 0x04
_OP_MESSAGE, _OP_CHUNK, _OP_MESSAGE_INDEX = 0x05, 0x06, 0x07
_OP_CHUNK_INDEX, _OP_STATISTICS, _OP_METADATA, _OP_METADATA_INDEX = 0x08, 0x0B, 0x0C, 0x0D
_OP_SUMMARY_OFFSET, _OP_DATA_END = 0x0E, 0x0F
_OP_ATTACHMENT, _OP_ATTACHMENT_INDEX = 0x09, 0x0A
_RECORD_HEADER = 1 + 8                 # opcode, length
_MESSAGE_FIXED = 2 + 4 + 8 + 8         # channel, sequence, log time, publish time
_NO_TIME = 2**63 - 1
#: The name of the preallocated file that keeps the space closing the bag needs.
RESERVE_FILE = '.close_reserve'
#: The reserve's smallest size, and the unit it grows in (bytes).
RESERVE_STEP = 64 * 1024
#: How much a file grows between two checks of the reserve when :meth:`BagWriter.flush` is not
#: called (bytes; a flush checks it too).
_RESERVE_CHECK_BYTES = 16 * 2**20


class StoredMessage(NamedTuple):
    """A message taken back out of a storage file (to go into another one): its topic, log
    time (ns since the epoch) and serialized data."""

    topic: str
    log_time_ns: int
    data: bytes


def _body(data: bytes) -> io.BytesIO:
    """``data`` as a record body for rosbags' ``write_record`` (which takes its length from
    the stream's position)."""
    rec = io.BytesIO()
    rec.write(data)
    return rec


def _metadata_body(name: str, values: Mapping[str, str]) -> io.BytesIO:
    """The body of an MCAP metadata record: its name and its string map (keys sorted)."""
    rec = io.BytesIO()
    write_string(rec, name)
    pairs = io.BytesIO()
    for key in sorted(values):
        write_string(pairs, key)
        write_string(pairs, values[key])
    write_uint32(rec, pairs.tell())
    rec.write(pairs.getvalue())
    return rec


def _messages_in(records: bytes, topics: Mapping[int, str]) -> list[StoredMessage]:
    """The Message records among a chunk's records, in order (schemas and channels skipped).
    Only the failure path of a recording reads chunks back: a plain loop."""
    out = []
    at, end = 0, len(records)
    while at < end:
        opcode = records[at]
        length = int.from_bytes(records[at + 1:at + _RECORD_HEADER], 'little')
        body = at + _RECORD_HEADER
        if opcode == _OP_MESSAGE:
            channel = int.from_bytes(records[body:body + 2], 'little')
            log_time = int.from_bytes(records[body + 6:body + 14], 'little')
            out.append(StoredMessage(topics[channel], log_time,
                                     records[body + _MESSAGE_FIXED:body + length]))
        at = body + length
    return out


class _Block(NamedTuple):
    """A chunk written to the file with its message indexes: where it starts, the file's running
    CRC there, its log-time range (ns) and its messages per channel id."""

    start: int
    crc: int
    start_time: int
    end_time: int
    counts: dict[int, int]


class _CrcRaw(io.RawIOBase):
    """The storage file: what reaches it also goes into a running CRC-32 (``crc``) of the file
    from its first byte; ``position`` is its length."""

    def __init__(self, raw: io.RawIOBase, crc: int, position: int) -> None:
        super().__init__()
        self._raw = raw
        self.crc = crc
        self.position = position

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return False

    def tell(self) -> int:
        return self.position

    def write(self, b: Any, /) -> int:  # a bytes-like object (typeshed's ReadableBuffer)
        n = self._raw.write(b) or 0
        with memoryview(b) as view, view.cast('B')[:n] as written:
            self.crc = zlib.crc32(written, self.crc)
        self.position += n
        return n

    def rewind(self, position: int, crc: int) -> None:
        """Cut the file back to its first ``position`` bytes, whose running CRC is ``crc``."""
        os.ftruncate(self._raw.fileno(), position)
        self._raw.seek(position)
        self.position, self.crc = position, crc

    def close(self) -> None:
        if not self.closed:
            self._raw.close()
        super().close()


class _CrcMcapWriter(McapWriter):
    """rosbags' MCAP storage writer (its schema, channel and message records, gathered in the
    chunk being filled) with every CRC filled in, writing to the file only through
    :meth:`_append`: a chunk with its message indexes (:meth:`close_chunk`), and the metadata
    record, summary section and footer (:meth:`finish`), each all or nothing. After a failed
    write the file ends after the last complete piece again (``torn`` if even cutting it back
    failed) and the chunk being filled still holds its messages."""

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        # rosbags' own __init__ writes the same header through a buffered <dir>/<dir>.mcap; this
        # one writes it to ``path`` directly (an OSError leaves nothing behind).
        self.path = path
        self.schemas = []
        self.channels = []
        self.chunks = []
        self.chunk = PendingChunk(_NO_TIME, 0, io.BytesIO(), defaultdict(list))
        # zstd at level 3, the level rosbags' own storage writer compresses with.
        self.compressor = (zstandard.ZstdCompressor(level=3).compress
                           if compression == CompressionMode.STORAGE else bytes)
        self.compression = 'zstd' if compression == CompressionMode.STORAGE else ''
        self.message_start_time = _NO_TIME
        self.message_end_time = 0
        self.channel_stats = {}
        self.blocks: list[_Block] = []
        self.index_bytes = 0  # the chunk index records of the summary section
        #: The metadata and attachment records written: (index opcode, file offset, index body)
        self.described: list[tuple[int, int, bytes]] = []
        self.torn = False
        rec = io.BytesIO()
        write_string(rec, 'ros2')
        write_string(rec, f'rosbags-{version("rosbags")}')
        header = io.BytesIO()
        header.write(_MAGIC)
        write_record(header, _OP_HEADER, rec)
        self.raw = _CrcRaw(path.open('xb', buffering=0), 0, 0)
        try:
            self._append(header.getvalue())
        except OSError:
            self.raw.close()
            path.unlink(missing_ok=True)
            raise

    def _append(self, data: bytes) -> None:
        """Write ``data`` at the end of the file, all or nothing: after an OSError (naming the
        file) the file is cut back to where it ended."""
        raw = self.raw
        start, crc = raw.position, raw.crc
        view = memoryview(data)
        try:
            while view:
                n = raw.write(view)
                if not n:
                    raise OSError(errno.EIO, 'the file took no bytes')
                view = view[n:]
        except OSError as err:
            err.filename = err.filename or str(self.path)
            try:
                raw.rewind(start, crc)
            except OSError:
                self.torn = True
            raise

    def close_chunk(self) -> None:
        """rosbags' ``McapWriter.close_chunk`` (0.11.9), with ``uncompressed_crc`` computed and
        the chunk and its message indexes written in one piece; an OSError keeps the chunk."""
        chunk = self.chunk
        with chunk.bio.getbuffer() as records:
            size, crc = len(records), zlib.crc32(records)
            compressed = self.compressor(bytes(records))
        rec = io.BytesIO()
        write_uint64(rec, chunk.message_start_time)
        write_uint64(rec, chunk.message_end_time)
        write_uint64(rec, size)
        write_uint32(rec, crc)
        write_string(rec, self.compression)
        write_uint64(rec, len(compressed))
        rec.write(compressed)

        start = self.raw.position
        block = io.BytesIO()
        write_record(block, _OP_CHUNK, rec)
        chunk_end = start + block.tell()
        offsets: list[tuple[int, int]] = []
        for cid, msgs in chunk.msgs.items():
            offsets.append((cid, start + block.tell()))
            rec = io.BytesIO()
            write_uint16(rec, cid)
            write_uint32(rec, len(msgs) * 16)
            for ts, offset in msgs:
                write_uint64(rec, ts)
                write_uint64(rec, offset)
            write_record(block, _OP_MESSAGE_INDEX, rec)

        index = io.BytesIO()
        write_uint64(index, chunk.message_start_time)
        write_uint64(index, chunk.message_end_time)
        write_uint64(index, start)
        write_uint64(index, chunk_end - start)
        write_uint32(index, len(offsets) * 10)
        for cid, offset in offsets:
            write_uint16(index, cid)
            write_uint64(index, offset)
        write_uint64(index, start + block.tell() - chunk_end)
        write_string(index, self.compression)
        write_uint64(index, len(compressed))
        write_uint64(index, size)

        crc_before = self.raw.crc
        self._append(block.getvalue())
        self.chunks.append(index)
        self.index_bytes += _RECORD_HEADER + index.tell()
        self.blocks.append(_Block(start, crc_before, chunk.message_start_time,
                                  chunk.message_end_time,
                                  {cid: len(msgs) for cid, msgs in chunk.msgs.items()}))
        self.chunk = PendingChunk(_NO_TIME, 0, io.BytesIO(), defaultdict(list))

    def describe(self, records: Sequence[MetadataRecord],
                 attachments: Sequence[Attachment]) -> None:
        """Write metadata and attachment records (after the chunk being filled, so that they
        are top-level records of the data section) in one piece, and keep their index entries
        for the summary section; an OSError writes none of them."""
        if self.chunk.msgs:
            self.close_chunk()
        start = self.raw.position
        block = io.BytesIO()
        entries: list[tuple[int, int, bytes]] = []
        for record in records:
            at = start + block.tell()
            write_record(block, _OP_METADATA, _metadata_body(record.name, record.values))
            index = io.BytesIO()
            write_uint64(index, at)
            write_uint64(index, start + block.tell() - at)
            write_string(index, record.name)
            entries.append((_OP_METADATA_INDEX, at, index.getvalue()))
        for item in attachments:
            at = start + block.tell()
            rec = io.BytesIO()
            write_uint64(rec, item.log_time_ns)
            write_uint64(rec, item.log_time_ns)  # create time: when it came into the recording
            write_string(rec, item.name)
            write_string(rec, item.media_type)
            write_uint64(rec, len(item.data))
            rec.write(item.data)
            write_uint32(rec, zlib.crc32(rec.getvalue()))
            write_record(block, _OP_ATTACHMENT, rec)
            index = io.BytesIO()
            write_uint64(index, at)
            write_uint64(index, start + block.tell() - at)
            write_uint64(index, item.log_time_ns)
            write_uint64(index, item.log_time_ns)
            write_uint64(index, len(item.data))
            write_string(index, item.name)
            write_string(index, item.media_type)
            entries.append((_OP_ATTACHMENT_INDEX, at, index.getvalue()))
        self._append(block.getvalue())
        self.described += entries
        self.index_bytes += sum(_RECORD_HEADER + len(body) for _, _, body in entries)

    def finish(self, metadata: str) -> None:
        """Write the chunk being filled, then the ``rosbag2`` metadata record, DataEnd with the
        data section's CRC, the summary section (rosbags' ``McapWriter.close``, 0.11.9) and the
        footer with the summary CRC; close the file. After an OSError the file is still open
        and ends after its last chunk."""
        chunk = self.chunk
        if chunk.msgs:
            self.close_chunk()
        elif chunk.bio.tell():
            chunk.bio.seek(0)  # schemas and channels only: repeated in the summary
            chunk.bio.truncate()
        base = self.raw.position
        tail = io.BytesIO()

        write_record(tail, _OP_METADATA,
                     _metadata_body(ROSBAG2_RECORD, {'serialized_metadata': metadata}))
        metadata_end = base + tail.tell()
        rec = io.BytesIO()
        write_uint32(rec, zlib.crc32(tail.getvalue(), self.raw.crc))
        write_record(tail, _OP_DATA_END, rec)

        summary = tail.tell()
        schema_start = base + tail.tell()
        for schema in self.schemas:
            write_schema(tail, schema)
        channel_start = base + tail.tell()
        for channel in self.channels:
            write_channel(tail, channel, self.schemas)
        chunk_start = base + tail.tell()
        for index in self.chunks:
            write_record(tail, _OP_CHUNK_INDEX, index)
        attachment_index_start = base + tail.tell()
        for opcode, _, body in self.described:
            if opcode == _OP_ATTACHMENT_INDEX:
                write_record(tail, opcode, _body(body))
        metadata_index_start = base + tail.tell()
        for opcode, _, body in self.described:
            if opcode == _OP_METADATA_INDEX:
                write_record(tail, opcode, _body(body))
        rec = io.BytesIO()
        write_uint64(rec, base)
        write_uint64(rec, metadata_end - base)
        write_string(rec, ROSBAG2_RECORD)
        write_record(tail, _OP_METADATA_INDEX, rec)

        statistics_start = base + tail.tell()
        rec = io.BytesIO()
        write_uint64(rec, sum(self.channel_stats.values()))
        write_uint16(rec, len(self.schemas))
        write_uint32(rec, len(self.channels))
        kinds = [opcode for opcode, _, _ in self.described]
        write_uint32(rec, kinds.count(_OP_ATTACHMENT_INDEX))
        write_uint32(rec, 1 + kinds.count(_OP_METADATA_INDEX))  # and rosbag2's own
        write_uint32(rec, len(self.chunks))
        write_uint64(rec, self.message_start_time)
        write_uint64(rec, self.message_end_time)
        write_uint32(rec, len(self.channel_stats) * 10)
        for cid, count in sorted(self.channel_stats.items()):
            write_uint16(rec, cid)
            write_uint64(rec, count)
        write_record(tail, _OP_STATISTICS, rec)

        summary_offset_start = base + tail.tell()
        for opcode, begin, end in ((_OP_SCHEMA, schema_start, channel_start),
                                   (_OP_CHANNEL, channel_start, chunk_start),
                                   (_OP_CHUNK_INDEX, chunk_start, attachment_index_start),
                                   (_OP_ATTACHMENT_INDEX, attachment_index_start,
                                    metadata_index_start),
                                   (_OP_METADATA_INDEX, metadata_index_start, statistics_start),
                                   (_OP_STATISTICS, statistics_start, summary_offset_start)):
            if begin != end or opcode in (_OP_METADATA_INDEX, _OP_STATISTICS):
                rec = io.BytesIO()
                rec.write(bytes([opcode]))
                write_uint64(rec, begin)
                write_uint64(rec, end - begin)
                write_record(tail, _OP_SUMMARY_OFFSET, rec)

        footer = struct.pack('<BQQQ', _OP_FOOTER, 20, schema_start, summary_offset_start)
        summary_crc = zlib.crc32(footer, zlib.crc32(tail.getbuffer()[summary:]))
        tail.write(footer)
        tail.write(struct.pack('<I', summary_crc))
        tail.write(_MAGIC)
        self._append(tail.getvalue())
        self.raw.close()

    def _times(self) -> None:
        """The file's log-time range again from its chunks and the chunk being filled."""
        starts = [b.start_time for b in self.blocks]
        ends = [b.end_time for b in self.blocks]
        if self.chunk.msgs:
            starts.append(self.chunk.message_start_time)
            ends.append(self.chunk.message_end_time)
        self.message_start_time = min(starts, default=_NO_TIME)
        self.message_end_time = max(ends, default=0)

    def _topics(self) -> dict[int, str]:
        return {channel.id: channel.topic for channel in self.channels}

    def take_pending(self) -> list[StoredMessage]:
        """The messages of the chunk being filled, taken out of this file."""
        chunk = self.chunk
        taken = _messages_in(chunk.bio.getvalue(), self._topics())
        for cid, msgs in chunk.msgs.items():
            self.channel_stats[cid] -= len(msgs)
        self.chunk = PendingChunk(_NO_TIME, 0, io.BytesIO(), defaultdict(list))
        self._times()
        return taken

    def pop_block(self) -> list[StoredMessage]:
        """The messages of the last chunk written, read back and cut off the file."""
        block = self.blocks[-1]
        with self.path.open('rb') as f:
            f.seek(block.start)
            head = f.read(_RECORD_HEADER)
            body = f.read(int.from_bytes(head[1:], 'little'))
        if len(head) != _RECORD_HEADER or head[0] != _OP_CHUNK:
            raise OSError(errno.EIO, f'no chunk record at byte {block.start} to read back',
                          str(self.path))
        size, crc = struct.unpack_from('<QI', body, 16)
        name_length = int.from_bytes(body[28:32], 'little')
        compression = body[32:32 + name_length].decode()
        data_at = 32 + name_length + 8
        try:
            records = decompress(body[data_at:], compression, size, crc)
        except ReaderError as err:
            raise OSError(errno.EIO, f'the chunk at byte {block.start} reads back damaged: '
                                     f'{err}', str(self.path)) from err
        messages = _messages_in(records, self._topics())
        try:
            self.raw.rewind(block.start, block.crc)
        except OSError:
            self.torn = True
            raise
        self.blocks.pop()
        cut = [e for e in self.described if e[1] >= block.start]  # written after that chunk
        self.described = [e for e in self.described if e[1] < block.start]
        self.index_bytes -= sum(_RECORD_HEADER + len(body) for _, _, body in cut)
        index = self.chunks.pop()
        self.index_bytes -= _RECORD_HEADER + index.tell()
        for cid, n in block.counts.items():
            self.channel_stats[cid] -= n
        self._times()
        return messages


class McapFile:
    """One ``.mcap`` storage file being written (not thread-safe: one writer thread).

    ``compression`` is ``none`` or ``zstd`` (whole chunks, which every MCAP reader decodes);
    a chunk is written out once it holds ``chunk_bytes`` and on every :meth:`flush`. An OSError
    from :meth:`write`, :meth:`flush` or :meth:`close` leaves the file ending after its last
    complete chunk and every message of the chunk being filled kept: :meth:`close` can be tried
    again, and :meth:`salvage` finishes it with what fits.
    """

    def __init__(self, path: Path, compression: str = 'none',
                 chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> None:
        if path.exists():
            raise BagError(path, 'exists already; a storage file is never overwritten')
        try:
            self._storage = _CrcMcapWriter(path, COMPRESSIONS[compression])
        except OSError as err:
            raise BagError(path, f'cannot create storage file: {err.strerror or err}') from err
        self.path = path
        self._chunk_bytes = min(chunk_bytes, MAX_CHUNK_BYTES)
        self._types: set[str] = set()
        self._static_bytes = 0  # schema and channel records of the summary, about
        self.connections: dict[str, Connection] = {}

    def add_topic(self, topic: TopicMeta, schema_data: str,
                  schema_encoding: str = 'ros2msg') -> None:
        """Register ``topic`` (and its type's schema once); idempotent."""
        if topic.name in self.connections:
            return
        if schema_encoding not in _SCHEMA_FORMATS:
            raise BagError(self.path, f'{topic.name}: schema encoding {schema_encoding!r} is '
                                      f'not one of {", ".join(_SCHEMA_FORMATS)}')
        conn = Connection(
            id=len(self.connections) + 1, topic=topic.name, msgtype=topic.msgtype,
            msgdef=MessageDefinition(_SCHEMA_FORMATS[schema_encoding], schema_data),
            digest=topic.type_hash, msgcount=0,
            ext=ConnectionExtRosbag2(topic.serialization_format, list(topic.qos)), owner=None)
        qos = qos_yaml(topic.qos)
        if topic.msgtype not in self._types:
            self._storage.add_msgtype(conn)
            self._types.add(topic.msgtype)
            self._static_bytes += 64 + len(topic.msgtype) + len(schema_data.encode())
        self._storage.add_connection(conn, qos)
        self._static_bytes += 128 + 2 * len(topic.name) + len(topic.msgtype) + len(qos)
        self.connections[topic.name] = conn

    def describe(self, records: Sequence[MetadataRecord] = (),
                 attachments: Sequence[Attachment] = ()) -> None:
        """Write metadata and attachment records (:mod:`positioning_cell.bag.description`)
        after the messages so far; indexed in the summary section."""
        if records or attachments:
            self._storage.describe(records, attachments)

    def write(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Append one message of a registered ``topic`` (log time in ns since the epoch)."""
        storage = self._storage
        storage.write(self.connections[topic], log_time_ns, data)
        if storage.chunk.bio.tell() >= self._chunk_bytes:
            storage.close_chunk()

    def keep(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Add one message to the chunk being filled without writing anything to the file
        (a message that must not be lost while the file is failing)."""
        self._storage.write(self.connections[topic], log_time_ns, data)

    @property
    def message_count(self) -> int:
        """Messages written to this file."""
        return sum(self._storage.channel_stats.values())

    @property
    def start_ns(self) -> int:
        """Log time of the first message (meaningless while empty)."""
        return self._storage.message_start_time

    def size(self) -> int:
        """Bytes written to the file so far (the chunk being filled is not counted)."""
        return self._storage.raw.position

    def flush(self) -> None:
        """Write the chunk being filled to the file: handed to the OS, so that it survives a
        killed process (not an fsync)."""
        if self._storage.chunk.msgs:
            self._storage.close_chunk()

    def close_bytes(self) -> int:
        """At most how many more bytes :meth:`close` writes if the chunk being filled grows to
        a full chunk (bytes): that chunk with its message indexes (16 bytes per message of at
        least 31), the metadata record and the summary section."""
        storage = self._storage
        chunk = max(self._chunk_bytes, storage.chunk.bio.tell())
        chunk_with_indexes = chunk + chunk * 16 // 31 + 256 + 16 * len(self.connections)
        metadata = 2048 + 1024 * len(self.connections)
        statistics = 64 + 10 * len(self.connections)
        return (chunk_with_indexes + metadata + self._static_bytes + storage.index_bytes
                + statistics + 512)

    def summary(self) -> FileSummary:
        """This file's entry in metadata.yaml."""
        stats = self._storage.channel_stats
        count = sum(stats.values())
        return FileSummary(self.path.name, self._storage.message_start_time if count else 0,
                           self._storage.message_end_time if count else 0, count,
                           {name: stats[c.id] for name, c in self.connections.items()})

    def on_disk(self) -> int:
        """Messages in the chunks written to the file so far."""
        return sum(sum(b.counts.values()) for b in self._storage.blocks)

    def close(self, topics: Sequence[TopicMeta]) -> FileSummary:
        """Write the ``rosbag2`` metadata record, the summary section and index, then close."""
        summary = self.summary()
        info = bag_metadata([t for t in topics if t.name in self.connections], [summary])
        self._storage.finish(metadata_yaml(info, inner=True))
        return summary

    def salvage(self, topics: Sequence[TopicMeta]) -> tuple[FileSummary | None,
                                                              list[StoredMessage]]:
        """Close a failing file with as much as it takes: :meth:`close`; while that fails, the
        chunk being filled is taken out of it, and at a file size limit (EFBIG) the last
        chunks on disk one by one (read back, then cut off) to make room for the summary.
        Returns its summary (None: it could not be finished; its complete chunks stay on disk
        for ``recover_bag``) and the messages taken out, in order (for another file)."""
        storage = self._storage
        moved: list[StoredMessage] = []
        try:
            while not storage.torn:
                try:
                    return self.close(topics), moved
                except OSError as err:
                    if storage.chunk.msgs:
                        moved = storage.take_pending() + moved
                    elif storage.blocks and err.errno == errno.EFBIG:
                        moved = storage.pop_block() + moved
                    else:
                        break
        except OSError:  # a chunk could not be read back or cut off: the file stays as it is
            pass
        with contextlib.suppress(OSError):
            storage.raw.close()
        return None, moved

    def abandon(self) -> None:
        """Close and delete a file that could not be finished (nothing of it is kept)."""
        with contextlib.suppress(OSError):
            self._storage.raw.close()
        with contextlib.suppress(OSError):
            self.path.unlink()


@dataclass(frozen=True)
class WriteFailure:
    """A bag whose writing failed, and what is in it: the ``operation`` that failed
    (``write``, ``flush``, ``split``, ``describe``, ``close`` or ``reserve``), the OSError's
    ``errno`` and ``reason`` (strerror) and the ``file`` it came from; the ``bag``, whether it was
    ``closed`` cleanly (indexed files and metadata.yaml: readable as it is; else
    ``recover_bag`` restores the ``messages`` on disk), the ``messages`` in it and the
    messages ``lost`` (accepted by :meth:`BagWriter.write` but not in the bag)."""

    operation: str
    errno: int | None
    reason: str
    file: Path
    bag: Path
    closed: bool
    messages: int
    lost: int

    @property
    def error(self) -> str:
        """The errno's symbolic name (``ENOSPC``), or ``OSError`` without one."""
        return errno.errorcode.get(self.errno or 0, 'OSError')

    def line(self) -> str:
        """One line: the error, the file and what is in the bag."""
        kept = (f'bag closed with {self.messages} messages' if self.closed else
                f'bag NOT closed: recover_bag {self.bag} restores {self.messages} messages')
        return (f'{self.error} ({self.reason}) on {self.operation} of {self.file}; {kept}, '
                f'{self.lost} lost')


class BagWriteError(BagError):
    """Writing the bag failed (an OSError); it was closed with what it had: ``failure``."""

    def __init__(self, failure: WriteFailure) -> None:
        super().__init__(failure.bag, failure.line())
        self.failure = failure


@dataclass
class _Topic:
    meta: TopicMeta
    schema: str


class BagWriter:
    """A rosbag2 MCAP bag being recorded: a context manager whose :meth:`close` is idempotent.

    ``path`` is the bag directory (must not exist; its parents are created).
    ``split_max_bytes`` (a file may exceed it by one chunk plus its summary section) and
    ``split_max_duration_s`` (receive-time span of one file) start a new ``.mcap`` when
    reached; 0 disables either. Messages are written with :meth:`write`; :meth:`flush` bounds
    what a crash can lose; :meth:`close` finishes the index of the last file and writes
    ``metadata.yaml``. ``reserve`` keeps the space closing the bag needs in
    :data:`RESERVE_FILE` (checked at each flush and every 16 MiB written).

    Any OSError from the disk in :meth:`write`, :meth:`flush` or :meth:`close` (a full disk, a
    file size limit, an I/O error) closes the bag with what it has and raises
    :class:`BagWriteError`; ``failure`` keeps the :class:`WriteFailure` and the writer is closed.
    """

    def __init__(self, path: str | Path, *, compression: str = 'none',
                 chunk_bytes: int = DEFAULT_CHUNK_BYTES, split_max_bytes: int = 0,
                 split_max_duration_s: float = 0.0, typestore: Typestore | None = None,
                 custom_data: Mapping[str, str] | None = None, reserve: bool = True) -> None:
        path = Path(path)
        if compression not in COMPRESSIONS:
            raise BagError(path, f'compression {compression!r}: expected one of '
                                 f'{", ".join(COMPRESSIONS)}')
        if not 1024 <= chunk_bytes <= MAX_CHUNK_BYTES:
            raise BagError(path, f'chunk_bytes = {chunk_bytes}: must be within 1024 .. '
                                 f'{MAX_CHUNK_BYTES}')
        if split_max_bytes < 0 or split_max_duration_s < 0:
            raise BagError(path, 'split limits must be >= 0 (0 = no split), got '
                                 f'{split_max_bytes} bytes, {split_max_duration_s} s')
        if path.exists():
            raise BagError(path, 'exists already; a bag is never overwritten')
        try:
            path.mkdir(parents=True)
        except OSError as err:
            raise BagError(path, f'cannot create the bag directory: {err.strerror or err}') \
                from err
        self.path = path
        self._options = (compression, chunk_bytes)
        self._max_bytes = split_max_bytes
        self._max_span_ns = round(split_max_duration_s * 1e9)
        self._typestore = typestore
        self._custom = dict(custom_data or {})
        self._records: list[MetadataRecord] = []
        self._attachments: list[Attachment] = []
        self._topics: dict[str, _Topic] = {}
        self._done: list[FileSummary] = []
        self._created = 0
        self.failure: WriteFailure | None = None
        self.reserve_bytes = 0
        self._reserve = path / RESERVE_FILE if reserve else None
        self._reserve_check_at = 0
        try:
            self._file: McapFile | None = self._open_file()
            self._keep_reserve()
        except OSError as err:  # nothing recorded yet: the new directory goes again
            shutil.rmtree(path, ignore_errors=True)
            raise BagError(err.filename or path, f'cannot start the bag: '
                                                 f'{err.strerror or err}') from err

    # -- topics and messages -----------------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> None:
        """Declare ``topic`` of ``msgtype`` with the QoS its publishers offered (recorded in the
        bag so that a player re-offers it). Idempotent; another type on a known topic, or a
        type the typestore does not know, raises BagError and changes nothing."""
        known = self._topics.get(topic)
        if known is not None:
            if known.meta.msgtype != msgtype:
                raise BagError(self.path, f'topic {topic} already recorded as '
                                          f'{known.meta.msgtype}, not {msgtype}')
            return
        current = self._active()
        definition, type_hash = message_definition(msgtype, self._typestore)
        entry = _Topic(TopicMeta(topic, msgtype, tuple(qos), type_hash), definition)
        self._topics[topic] = entry
        current.add_topic(entry.meta, entry.schema)

    def write(self, topic: str, msgtype: str, data: bytes, receive_time_ns: int) -> None:
        """Append one serialized (CDR) message received at ``receive_time_ns`` (ns since the
        epoch; the MCAP log and publish time). A topic not declared yet is declared with no QoS
        information. BagWriteError when the disk fails (the message is in the bag if it could
        be kept)."""
        entry = self._topics.get(topic)
        if entry is None or entry.meta.msgtype != msgtype:
            self.add_topic(topic, msgtype)
        current = self._active()
        operation = 'write'
        try:
            if (self._max_span_ns or self._max_bytes) and current.message_count and (
                    (self._max_span_ns
                     and receive_time_ns - current.start_ns >= self._max_span_ns)
                    or (self._max_bytes and current.size() >= self._max_bytes)):
                operation = 'split'
                current = self._split()
                operation = 'write'
            current.write(topic, data, receive_time_ns)
            if current.size() >= self._reserve_check_at:
                operation = 'reserve'
                self._keep_reserve()
        except OSError as err:
            unwritten = (topic, data, receive_time_ns) if operation == 'split' else None
            raise self._fail(operation, err, unwritten) from err

    def describe(self, records: Sequence[MetadataRecord] = (),
                 attachments: Sequence[Attachment] = ()) -> None:
        """Store metadata and attachment records (what the bag says of itself,
        :mod:`positioning_cell.bag.description`) in the file being written, after its
        messages so far, and again at the start of every later file of a split, so that each
        file describes itself. BagWriteError when the disk fails."""
        current = self._active()
        try:
            current.describe(records, attachments)
        except OSError as err:
            raise self._fail('describe', err) from err
        self._records += records
        self._attachments += attachments

    def flush(self) -> None:
        """Write the chunk being filled to the file (bounds the loss of a killed process) and
        grow the reserve if the bag's index needs it. BagWriteError when the disk fails."""
        if self._file is None:
            return
        operation = 'flush'
        try:
            self._file.flush()
            operation = 'reserve'
            self._keep_reserve()
        except OSError as err:
            raise self._fail(operation, err) from err

    # -- state -------------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran (or a failure closed the bag)."""
        return self._file is None

    @property
    def message_count(self) -> int:
        """Messages written so far, all files."""
        live = self._file.message_count if self._file is not None else 0
        return sum(f.message_count for f in self._done) + live

    @property
    def topic_counts(self) -> dict[str, int]:
        """Messages written so far per topic."""
        counts = {name: 0 for name in self._topics}
        summaries = [*self._done, *([self._file.summary()] if self._file is not None else [])]
        for summary in summaries:
            for name, n in summary.topic_counts.items():
                counts[name] += n
        return counts

    @property
    def files(self) -> list[Path]:
        """The storage files, in order (the last one is being written until closed)."""
        names = [f.path for f in self._done]
        if self._file is not None:
            names.append(self._file.path.name)
        return [self.path / n for n in names]

    def close(self) -> Path:
        """Finish the last file and write ``metadata.yaml``; returns the bag directory. A second
        call does nothing. BagWriteError when the disk fails (the bag is then closed with what
        fitted)."""
        if self._file is not None:
            self._release_reserve()
            try:
                self._done.append(self._file.close(self._metas()))
                self._file = None
                write_metadata(self.path, self._metas(), self._done, self._custom)
            except OSError as err:
                raise self._fail('close', err) from err
        return self.path

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        # Even after an error, what was written is kept: close, never abort.
        with contextlib.suppress(BagWriteError) if exc_type is not None else \
                contextlib.nullcontext():
            self.close()

    # -- internals ---------------------------------------------------------------------------
    def _metas(self) -> list[TopicMeta]:
        return [t.meta for t in self._topics.values()]

    def _active(self) -> McapFile:
        if self._file is None:
            raise BagError(self.path, 'the bag is closed')
        return self._file

    def _open_file(self) -> McapFile:
        """The next storage file with every topic declared; OSError when it cannot be made."""
        compression, chunk_bytes = self._options
        path = self.path / f'{self.path.name}_{self._created}.mcap'
        try:
            new = McapFile(path, compression, chunk_bytes)
        except BagError as err:
            if isinstance(err.__cause__, OSError):
                raise err.__cause__ from None
            raise
        self._created += 1
        for entry in self._topics.values():
            new.add_topic(entry.meta, entry.schema)
        try:
            new.describe(self._records, self._attachments)
        except OSError:
            new.abandon()
            raise
        return new

    def _split(self) -> McapFile:
        current = self._active()
        self._done.append(current.close(self._metas()))
        self._file = None
        self._file = self._open_file()
        return self._file

    def _keep_reserve(self) -> None:
        """Grow the reserve to what closing the bag needs now: twice what the current file's
        close may write, plus metadata.yaml (OSError when the disk has not that much)."""
        current = self._file
        if self._reserve is None or current is None:
            return
        self._reserve_check_at = current.size() + _RESERVE_CHECK_BYTES
        metadata = 4096 + 1024 * len(self._topics) + 512 * (len(self._done) + 1)
        needed = 2 * current.close_bytes() + metadata
        if needed <= self.reserve_bytes:
            return
        size = RESERVE_STEP * math.ceil(1.25 * needed / RESERVE_STEP)
        try:
            fd = os.open(self._reserve, os.O_WRONLY | os.O_CREAT, 0o644)
            try:
                os.posix_fallocate(fd, 0, size)
            finally:
                os.close(fd)
        except OSError as err:
            err.filename = err.filename or str(self._reserve)
            raise
        self.reserve_bytes = size

    def _release_reserve(self) -> None:
        """Give the reserve's space back (to close the bag)."""
        if self._reserve is not None:
            with contextlib.suppress(OSError):
                self._reserve.unlink(missing_ok=True)
            self._reserve = None
            self.reserve_bytes = 0

    def _fail(self, operation: str, err: OSError,
              unwritten: tuple[str, bytes, int] | None = None) -> BagWriteError:
        """After ``err``: give the reserve back, close the current file with as much as fits
        (:meth:`McapFile.salvage`; ``unwritten``, a message not in any file yet, is kept in it),
        move what did not fit into one more file, write metadata.yaml; the failure."""
        accepted = self.message_count + (unwritten is not None)
        self._release_reserve()
        current, self._file = self._file, None
        closed, on_disk = True, 0
        if current is not None:
            if unwritten is not None:
                current.keep(*unwritten)
            summary, moved = current.salvage(self._metas())
            if summary is None:
                closed, on_disk = False, current.on_disk()
            else:
                self._done.append(summary)
            if moved:
                self._done.extend(self._move(moved))
        if closed:
            try:
                write_metadata(self.path, self._metas(), self._done, self._custom)
            except OSError:
                closed = False
        in_files = sum(f.message_count for f in self._done)
        self.failure = WriteFailure(
            operation, err.errno, err.strerror or str(err) or type(err).__name__,
            Path(err.filename) if isinstance(err.filename, str) else self.path, self.path,
            closed, in_files + on_disk, accepted - in_files - on_disk)
        return BagWriteError(self.failure)

    def _move(self, messages: list[StoredMessage]) -> list[FileSummary]:
        """``messages`` into one more file, closed; [] (they are lost) if the disk refuses."""
        try:
            extra = self._open_file()
        except OSError:
            return []
        try:
            for m in messages:
                extra.write(m.topic, m.data, m.log_time_ns)
            return [extra.close(self._metas())]
        except OSError:
            extra.abandon()
            return []
