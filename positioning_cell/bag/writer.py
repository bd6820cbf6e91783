"""Writing rosbag2 MCAP bags from serialized (CDR) messages, in small chunks that reach the disk
on every :meth:`BagWriter.flush`, so a killed recorder loses at most what came after the last
flush (and :func:`positioning_cell.bag.recovery.recover_bag` restores the rest).

A bag is a directory ``<name>/`` holding ``<name>_0.mcap`` (``_1``, ``_2`` ... after splits,
rosbag2's naming) and ``metadata.yaml``. Each ``.mcap`` is written by rosbags' MCAP storage
writer (the ``ros2`` profile as rosbag2 writes it: one ``ros2msg`` schema per type with the full
definition from the rosbags Jazzy typestore, one ``cdr`` channel per topic carrying its
``offered_qos_profiles``, log time = receive time, a ``rosbag2`` metadata record, chunk and
message indexes). It is 3-4x faster than ``mcap.writer.Writer`` here (about 150k against 45k
small messages/s), which is what lets a recorder keep up at 20k messages/s; its 1 MiB chunk
buffer is bounded by closing the chunk at ``chunk_bytes`` and on every flush.

rosbags' writer leaves every CRC of the format at 0 ("not computed"); this one fills all three,
so that :mod:`positioning_cell.bag.verify` (and any MCAP reader that checks them) detects a
damaged file: each chunk's ``uncompressed_crc`` (CRC-32 of its records before compression), the
``data_section_crc`` of the DataEnd record (every byte from the start of the file to DataEnd,
kept as a running CRC of what reaches the file) and the footer's ``summary_crc``.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import struct
import zlib
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import TracebackType
from typing import Any

from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag2,
    MessageDefinition,
    MessageDefinitionFormat,
    Qos,
)
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.storage_mcap import (
    McapWriter,
    PendingChunk,
    write_record,
    write_string,
    write_uint16,
    write_uint32,
    write_uint64,
)
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from positioning_cell.bag.errors import BagError
from positioning_cell.bag.metadata import (
    METADATA_VERSION,
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
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4      # opcode, length, summary_start, summary_offset_start, crc
_DATA_END_BYTES = 1 + 8 + 4            # opcode, length, data_section_crc
_OP_CHUNK, _OP_DATA_END, _OP_FOOTER = 0x06, 0x0F, 0x02


class _CrcRaw(io.RawIOBase):
    """The raw file under the storage's buffered writer: what reaches the file also goes into
    a running CRC-32 (``crc``) of the file from its first byte."""

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

    def close(self) -> None:
        if not self.closed:
            self._raw.close()
        super().close()


class _CrcMcapWriter(McapWriter):
    """rosbags' MCAP storage writer with the chunk CRCs filled in and the file's running CRC
    kept (see :class:`_CrcRaw`); :meth:`seal` fills the data-section and summary CRCs."""

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        super().__init__(path, compression)
        self.bio.flush()  # magic and header record; they start the data-section CRC
        header = self.path.read_bytes()
        self.raw = _CrcRaw(self.bio.detach(), zlib.crc32(header), len(header))
        self.bio = io.BufferedWriter(self.raw)

    def close_chunk(self) -> None:
        """rosbags' ``McapWriter.close_chunk`` (0.11.9), with ``uncompressed_crc`` computed."""
        chunk = self.chunk
        records = chunk.bio.getbuffer()
        rec = io.BytesIO()
        write_uint64(rec, chunk.message_start_time)
        write_uint64(rec, chunk.message_end_time)
        write_uint64(rec, len(records))
        write_uint32(rec, zlib.crc32(records))
        compressed = self.compressor(bytes(records))
        del records  # release the chunk buffer
        write_string(rec, self.compression)
        write_uint64(rec, len(compressed))
        rec.write(compressed)

        chunk_start = self.bio.tell()
        write_record(self.bio, _OP_CHUNK, rec)
        chunk_end = self.bio.tell()

        offsets: list[tuple[int, int]] = []
        for cid, msgs in chunk.msgs.items():
            offsets.append((cid, self.bio.tell()))
            rec = io.BytesIO()
            write_uint16(rec, cid)
            write_uint32(rec, len(msgs) * 16)
            for ts, offset in msgs:
                write_uint64(rec, ts)
                write_uint64(rec, offset)
            write_record(self.bio, 0x07, rec)

        rec = io.BytesIO()
        write_uint64(rec, chunk.message_start_time)
        write_uint64(rec, chunk.message_end_time)
        write_uint64(rec, chunk_start)
        write_uint64(rec, chunk_end - chunk_start)
        write_uint32(rec, len(offsets) * 10)
        for cid, offset in offsets:
            write_uint16(rec, cid)
            write_uint64(rec, offset)
        write_uint64(rec, self.bio.tell() - chunk_end)
        write_string(rec, self.compression)
        write_uint64(rec, len(compressed))
        write_uint64(rec, chunk.bio.tell())
        self.chunks.append(rec)

        self.chunk = PendingChunk(2**63 - 1, 0, io.BytesIO(), defaultdict(list))

    def seal(self, mark: int, crc: int) -> None:
        """After :meth:`close`: write the DataEnd and footer CRCs into the file. ``crc`` is the
        running CRC of the file's first ``mark`` bytes (everything but the metadata record
        that :meth:`close` writes before DataEnd)."""
        with self.path.open('r+b') as f:
            size = f.seek(0, os.SEEK_END)
            footer = size - len(_MAGIC) - _FOOTER_BYTES
            f.seek(footer)
            tail = f.read()
            if tail[:9] != struct.pack('<BQ', _OP_FOOTER, 20) or tail[-8:] != _MAGIC:
                raise BagError(self.path, 'no MCAP footer after closing; CRCs not written')
            summary_start = struct.unpack_from('<Q', tail, 9)[0]
            data_end = (summary_start or footer) - _DATA_END_BYTES
            f.seek(mark)
            rest = f.read(data_end + 9 - mark)
            if rest[-9:] != struct.pack('<BQ', _OP_DATA_END, 4):
                raise BagError(self.path, 'no DataEnd record before the summary; CRCs not '
                                          'written')
            f.seek(summary_start or footer)
            summary = f.read(footer + 25 - (summary_start or footer))
            f.seek(data_end + 9)
            f.write(struct.pack('<I', zlib.crc32(rest[:-9], crc)))
            f.seek(footer + 25)
            f.write(struct.pack('<I', zlib.crc32(summary)))


class McapFile:
    """One ``.mcap`` storage file being written (not thread-safe: one writer thread).

    ``compression`` is ``none`` or ``zstd`` (whole chunks, which every MCAP reader decodes);
    a chunk is written out once it holds ``chunk_bytes`` and on every :meth:`flush`.
    """

    def __init__(self, path: Path, compression: str = 'none',
                 chunk_bytes: int = DEFAULT_CHUNK_BYTES) -> None:
        if path.exists():
            raise BagError(path, 'exists already; a storage file is never overwritten')
        # rosbags' storage names its file <dir>/<dir>.mcap: create it in a scratch directory
        # and move it to ``path`` at once (the open handle stays valid on POSIX).
        scratch = path.with_name(f'.{path.stem}.new')
        try:
            scratch.mkdir()
            try:
                self._storage = _CrcMcapWriter(scratch, COMPRESSIONS[compression])
                os.replace(self._storage.path, path)
            finally:
                with contextlib.suppress(OSError):
                    scratch.rmdir()
        except OSError as err:
            raise BagError(path, f'cannot create storage file: {err.strerror or err}') from err
        self._storage.path = path  # the header is on disk at once: a killed recording is MCAP
        self.path = path
        self._chunk_bytes = min(chunk_bytes, MAX_CHUNK_BYTES)
        self._types: set[str] = set()
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
        if topic.msgtype not in self._types:
            self._storage.add_msgtype(conn)
            self._types.add(topic.msgtype)
        self._storage.add_connection(conn, qos_yaml(topic.qos))
        self.connections[topic.name] = conn

    def write(self, topic: str, data: bytes, log_time_ns: int) -> None:
        """Append one message of a registered ``topic`` (log time in ns since the epoch)."""
        storage = self._storage
        storage.write(self.connections[topic], log_time_ns, data)
        if storage.chunk.bio.tell() >= self._chunk_bytes:
            storage.close_chunk()

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
        return self._storage.bio.tell()

    def flush(self) -> None:
        """Close the chunk being filled and hand everything to the OS (survives a killed
        process; not an fsync)."""
        if self._storage.chunk.msgs:
            self._storage.close_chunk()
        self._storage.bio.flush()

    def summary(self) -> FileSummary:
        """This file's entry in metadata.yaml."""
        stats = self._storage.channel_stats
        count = sum(stats.values())
        return FileSummary(self.path.name, self._storage.message_start_time if count else 0,
                           self._storage.message_end_time if count else 0, count,
                           {name: stats[c.id] for name, c in self.connections.items()})

    def close(self, topics: Sequence[TopicMeta]) -> FileSummary:
        """Write the ``rosbag2`` metadata record, the summary section and index, then close."""
        summary = self.summary()
        storage = self._storage
        if storage.chunk.msgs:
            storage.close_chunk()
        elif storage.chunk.bio.tell():
            storage.chunk.bio.seek(0)  # schemas and channels only: repeated in summary
            storage.chunk.bio.truncate()
        storage.bio.flush()
        mark, crc = storage.raw.position, storage.raw.crc
        info = bag_metadata([t for t in topics if t.name in self.connections], [summary])
        storage.close(METADATA_VERSION, metadata_yaml(info, inner=True))
        storage.seal(mark, crc)
        return summary


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
    ``metadata.yaml``.
    """

    def __init__(self, path: str | Path, *, compression: str = 'none',
                 chunk_bytes: int = DEFAULT_CHUNK_BYTES, split_max_bytes: int = 0,
                 split_max_duration_s: float = 0.0, typestore: Typestore | None = None,
                 custom_data: Mapping[str, str] | None = None) -> None:
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
        self._topics: dict[str, _Topic] = {}
        self._done: list[FileSummary] = []
        self._file: McapFile | None = self._open_file()

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
        definition, type_hash = message_definition(msgtype, self._typestore)
        entry = _Topic(TopicMeta(topic, msgtype, tuple(qos), type_hash), definition)
        self._topics[topic] = entry
        self._active().add_topic(entry.meta, entry.schema)

    def write(self, topic: str, msgtype: str, data: bytes, receive_time_ns: int) -> None:
        """Append one serialized (CDR) message received at ``receive_time_ns`` (ns since the
        epoch; the MCAP log and publish time). A topic not declared yet is declared with no QoS
        information."""
        entry = self._topics.get(topic)
        if entry is None or entry.meta.msgtype != msgtype:
            self.add_topic(topic, msgtype)
        current = self._active()
        if (self._max_span_ns or self._max_bytes) and current.message_count and (
                (self._max_span_ns and receive_time_ns - current.start_ns >= self._max_span_ns)
                or (self._max_bytes and current.size() >= self._max_bytes)):
            current = self._split()
        current.write(topic, data, receive_time_ns)

    def flush(self) -> None:
        """Write the chunk being filled to the file (bounds the loss of a killed process)."""
        if self._file is not None:
            self._file.flush()

    # -- state -------------------------------------------------------------------------------
    @property
    def closed(self) -> bool:
        """True once :meth:`close` ran."""
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
        call does nothing."""
        if self._file is not None:
            current, self._file = self._file, None
            self._done.append(current.close(self._metas()))
            write_metadata(self.path, self._metas(), self._done, self._custom)
        return self.path

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        # Even after an error, what was written is kept: close, never abort.
        with contextlib.suppress(OSError) if exc_type is not None else contextlib.nullcontext():
            self.close()

    # -- internals ---------------------------------------------------------------------------
    def _metas(self) -> list[TopicMeta]:
        return [t.meta for t in self._topics.values()]

    def _active(self) -> McapFile:
        if self._file is None:
            raise BagError(self.path, 'the bag is closed')
        return self._file

    def _open_file(self) -> McapFile:
        compression, chunk_bytes = self._options
        index = len(self._done)
        new = McapFile(self.path / f'{self.path.name}_{index}.mcap', compression, chunk_bytes)
        for entry in self._topics.values():
            new.add_topic(entry.meta, entry.schema)
        return new

    def _split(self) -> McapFile:
        current = self._active()
        self._done.append(current.close(self._metas()))
        self._file = self._open_file()
        return self._file
