"""Verifying the storage files of a bag: is each ``.mcap`` an MCAP file, is every chunk intact,
is the data section's CRC right, and for a damaged file which chunks are corrupt and what they
covered (byte offset, log-time range, topics and message counts).

The MCAP format carries three CRC-32s; 0 means "not computed":

* ``uncompressed_crc`` of each Chunk record: its records before compression. A compressed chunk
  is decompressed first (a decompression failure, or a size other than the one the chunk states,
  is a corruption too).
* ``data_section_crc`` of the DataEnd record: every byte from the start of the file up to
  DataEnd. It also covers what lies outside the chunks' records (chunk headers, message
  indexes, the metadata record).
* ``summary_crc`` of the footer: the summary section (schemas, channels, chunk indexes,
  statistics). A summary that fails it is not used.

The cell's writer (:mod:`positioning_cell.bag.writer`) fills all three. rosbags' own MCAP writer
(used by ``rosbags.rosbag2.Writer``) writes 0 for all three; ``ros2 bag record`` (the C++ mcap
library) writes chunk and summary CRCs but no data-section CRC. Where a chunk carries no CRC its
structure is checked instead: every record inside must be a schema, channel or message whose
length fits, messages on known channels (when the summary lists them), with log times in the
chunk's range. Damage inside a message's payload in an uncompressed chunk without a CRC is then
not detectable (a compressed chunk almost always fails to decompress).

A chunk's log-time range and contents come from the summary's chunk index when the file has a
sound summary (also when the chunk header itself is damaged), else from the chunk record's header
and the message index records that follow it, and when those are unreadable too, from the
neighbouring chunks. Without a summary (a recording that did not end cleanly) the record stream
is walked from the start; after a record whose framing is broken the walk resumes at the next
indexed chunk, or at the next byte offset where a consistent chunk header starts.

A file is mapped into memory, never read whole; the CRCs are computed with ``zlib.crc32``
(a 280 MiB bag verifies in about a second). The records of the sound chunks
(:func:`sound_records`) are what :func:`positioning_cell.bag.recovery.recover_bag` rewrites.
"""

from __future__ import annotations

import mmap
import re
import struct
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from io import BytesIO
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    ChunkIndex,
    Header,
    McapRecord,
    Message,
    Metadata,
    Schema,
    Statistics,
)
from mcap.stream_reader import CRCValidationError, StreamReader, get_chunk_data_stream

MCAP_MAGIC = b'\x89MCAP0\r\n'
_MAGIC = len(MCAP_MAGIC)
_RECORD_HEADER = 1 + 8                        # opcode, length
_FOOTER = _RECORD_HEADER + 8 + 8 + 4          # summary_start, summary_offset_start, summary_crc
_DATA_END = _RECORD_HEADER + 4                # data_section_crc
_CHUNK_FIXED = 8 + 8 + 8 + 4 + 4 + 8          # times, size, crc, compression length, data length
_MESSAGE_FIXED = 2 + 4 + 8 + 8                # channel, sequence, log time, publish time
#: The smallest MCAP file: magic, a header record with empty strings, a footer record, magic.
MIN_MCAP_BYTES = 2 * _MAGIC + _RECORD_HEADER + 8 + _FOOTER
_COMPRESSIONS = (b'', b'zstd', b'lz4')
_DATA_OPCODES = frozenset({Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE, Opcode.CHUNK,
                           Opcode.MESSAGE_INDEX, Opcode.ATTACHMENT, Opcode.METADATA,
                           Opcode.DATA_END})
#: The mcap library's reader of each record kind checked here.
_READERS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.HEADER: Header.read, Opcode.ATTACHMENT: Attachment.read,
    Opcode.METADATA: Metadata.read, Opcode.SCHEMA: Schema.read, Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK: Chunk.read}
#: What parsing damaged bytes with the mcap records can raise.
_PARSE_ERRORS = (McapError, struct.error, ValueError, UnicodeDecodeError, EOFError, IndexError,
                 KeyError, OverflowError, MemoryError)
_INDEX = re.compile(r'_(\d+)\.mcap$')


def storage_files(bag: Path) -> list[Path]:
    """The ``.mcap`` files of a bag directory in split order (``name_0``, ``name_1``, ...)."""
    def key(p: Path) -> tuple[int, str]:
        m = _INDEX.search(p.name)
        return (int(m.group(1)) if m else -1, p.name)
    return sorted((p for p in bag.glob('*.mcap') if p.is_file()), key=key)


def utc(ns: int) -> str:
    """A log time (ns since the epoch) as ``YYYY-MM-DD HH:MM:SS.mmm`` UTC."""
    stamp = datetime.fromtimestamp(ns // 1_000_000 / 1e3, tz=timezone.utc)
    return stamp.strftime('%Y-%m-%d %H:%M:%S.%f')[:-3]


@dataclass(frozen=True)
class DamagedChunk:
    """A corrupt chunk: storage file name, its number in the file (0-based, file order), byte
    offset and length of the record (0: unknown), why it is corrupt, the log-time range it
    covered (ns since the epoch, inclusive; None when unknown) and the messages it held per
    topic (empty when unknown)."""

    file: str
    index: int
    offset: int
    length: int
    reason: str
    start_ns: int | None
    end_ns: int | None
    topic_counts: Mapping[str, int] = field(default_factory=dict)

    @property
    def message_count(self) -> int | None:
        """Messages the chunk held, when known."""
        return sum(self.topic_counts.values()) if self.topic_counts else None

    def describe(self, bag_start_ns: int | None = None) -> str:
        """One line: which chunk, why, and what was lost (UTC and seconds into the bag)."""
        size = f' ({self.length} bytes)' if self.length else ''
        text = (f'{self.file}: chunk {self.index} at byte {self.offset}{size} is corrupt '
                f'({self.reason})')
        if self.start_ns is None or self.end_ns is None:
            text += ': log times lost unknown'
        else:
            first, last = utc(self.start_ns), utc(self.end_ns)
            if first[:10] == last[:10]:
                last = last[11:]
            text += f': lost {first} .. {last} UTC'
            if bag_start_ns is not None:
                text += (f' ({(self.start_ns - bag_start_ns) * 1e-9:.3f} s .. '
                         f'{(self.end_ns - bag_start_ns) * 1e-9:.3f} s into the bag)')
        if self.topic_counts:
            counts = ', '.join(f'{t} {n}' for t, n in sorted(self.topic_counts.items()))
            text += f', {self.message_count} messages ({counts})'
        else:
            text += ', message count unknown'
        return text


@dataclass(frozen=True)
class FileCheck:
    """The verification of one storage file.

    ``kind``: ``mcap``, or why the file is no MCAP file at all (``empty``, ``too short``,
    ``not MCAP``: ``problems`` says it). ``complete``: it ends with a footer (else a recording
    that did not end cleanly: ``truncated_at`` is where its readable records end).
    ``chunks``: chunk records (or indexed chunks), ``crc_chunks`` how many carried a CRC;
    ``data_crc`` / ``summary_crc``: ``ok``, ``mismatch``, ``absent`` (0 in the file) or
    ``unchecked`` (no such record). ``damaged``: the corrupt chunks; ``problems``: damage outside
    the chunks (or the reason the file is unusable). ``start_ns`` / ``end_ns``: the log-time
    range of its chunks, damaged ones included, and of its messages outside chunks (None when
    unknown); ``message_count``: messages
    by the summary's statistics (None without a summary).
    """

    path: Path
    size: int
    kind: str
    complete: bool = False
    chunks: int = 0
    crc_chunks: int = 0
    data_crc: str = 'unchecked'
    summary_crc: str = 'unchecked'
    damaged: tuple[DamagedChunk, ...] = ()
    problems: tuple[str, ...] = ()
    truncated_at: int | None = None
    start_ns: int | None = None
    end_ns: int | None = None
    message_count: int | None = None

    @property
    def usable(self) -> bool:
        """An MCAP file (possibly damaged or truncated)."""
        return self.kind == 'mcap'

    @property
    def sound(self) -> bool:
        """Complete, and no damage found."""
        return self.usable and self.complete and not self.damaged and not self.problems

    def lines(self, bag_start_ns: int | None = None) -> list[str]:
        """What is wrong with the file, one line each (empty for a sound file)."""
        out = [f'{self.path.name}: {p}' for p in self.problems]
        out += [d.describe(bag_start_ns) for d in self.damaged]
        if self.usable and not self.complete:
            out.append(f'{self.path.name}: truncated at byte {self.truncated_at} of '
                       f'{self.size} (no footer: the recording did not end cleanly)')
        return out


@dataclass(frozen=True)
class BagCheck:
    """The verification of every storage file of a bag."""

    path: Path
    files: tuple[FileCheck, ...]

    @property
    def sound(self) -> bool:
        """Every file complete and undamaged."""
        return all(f.sound for f in self.files)

    @property
    def damaged(self) -> tuple[DamagedChunk, ...]:
        """Every corrupt chunk, in file order."""
        return tuple(d for f in self.files for d in f.damaged)

    @property
    def start_ns(self) -> int | None:
        """First log time of the bag's chunks (damaged ones included), None when unknown."""
        known = [f.start_ns for f in self.files if f.start_ns is not None]
        return min(known) if known else None

    def lines(self) -> list[str]:
        """What is wrong, one line per problem (empty for a sound bag)."""
        start = self.start_ns
        return [line for f in self.files for line in f.lines(start)]


# -- the walk over one file ----------------------------------------------------------------
class _DamageError(Exception):
    """A record that fails its check (internal)."""


@dataclass
class _Pending:
    """A damaged chunk while the walk goes on: its message indexes may still follow."""

    index: int
    offset: int
    length: int
    reason: str
    start_ns: int | None
    end_ns: int | None
    counts: dict[int, int] = field(default_factory=dict)
    counts_known: bool = False
    after: int | None = None  # number of the previous sound chunk (for neighbour times)


def _u64(data: bytes | mmap.mmap, at: int) -> int:
    return int(struct.unpack_from('<Q', data, at)[0])


class _ExactStream(ReadDataStream):
    """The mcap library's record stream, except that a read past the end of the record raises
    (the library returns what there is), so that a damaged length field is noticed."""

    def read(self, length: int) -> bytes:
        data = super().read(length)
        if len(data) != length:
            raise EndOfFile()
        return data


def _parse(op: int, body: bytes) -> McapRecord:
    """Parse a record body (opcode ``op``) with the mcap library's reader; _DamageError if it does
    not parse within its length."""
    stream = _ExactStream(BytesIO(body))
    name = Opcode(op).name.lower().replace('_', ' ')
    try:
        record = (Message.read(stream, len(body)) if op == Opcode.MESSAGE
                  else _READERS[op](stream))
    except _PARSE_ERRORS as err:
        raise _DamageError(f'{name} record does not parse ({err or type(err).__name__})') from err
    if stream.count > len(body):
        raise _DamageError(f'{name} record is longer than its length field')
    return record


def _index_counts(ci: ChunkIndex) -> dict[int, int]:
    """Messages per channel of an indexed chunk, from the message index offsets and lengths
    (each message index record is 15 + 16·n bytes, written one after the other); empty for a
    chunk without message indexes (not known)."""
    if not ci.message_index_offsets:
        return {}
    ends = sorted((offset, cid) for cid, offset in ci.message_index_offsets.items())
    limit = ci.chunk_start_offset + ci.chunk_length + ci.message_index_length
    bounds = [o for o, _ in ends[1:]] + [limit]
    return {cid: max(0, (end - offset - 15) // 16)
            for (offset, cid), end in zip(ends, bounds, strict=True)}


class _Walk:
    """One storage file walked record by record (see the module docstring)."""

    def __init__(self, path: Path, data: mmap.mmap) -> None:
        self.path = path
        self.data = data
        self.size = len(data)
        self.problems: list[str] = []
        self.pending: list[_Pending] = []
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.chunks = 0
        self.crc_chunks = 0
        self.times: list[tuple[int, int]] = []
        self.loose = 0  # messages outside chunks (an unchunked file)
        self.loose_times = (2**64, -1)  # their first and last log time
        self.truncated_at: int | None = None
        self.data_crc = 'unchecked'
        self.summary_crc = 'unchecked'
        self.message_count: int | None = None
        self.complete = False
        self.index: list[ChunkIndex] = []
        self.by_offset: dict[int, int] = {}
        self.summary_ok = False
        self.limit = self.size
        self.data_end_ok = False
        self._sound_times: dict[int, tuple[int, int]] = {}
        self._last_chunk: _Pending | None = None
        self._last_sound: int | None = None
        self._footer()

    # -- footer and summary --------------------------------------------------------------
    def _footer(self) -> None:
        data, size = self.data, self.size
        footer = size - _MAGIC - _FOOTER
        if data[size - _MAGIC:] != MCAP_MAGIC:
            return
        if data[footer:footer + 9] != struct.pack('<BQ', Opcode.FOOTER, 20):
            self.problems.append('the footer record is damaged (its summary is not used)')
            return
        self.complete = True
        summary_start = _u64(data, footer + 9)
        stored = int(struct.unpack_from('<I', data, footer + 25)[0])
        if summary_start and not _MAGIC < summary_start <= footer:
            self.problems.append(f'the footer is damaged (summary offset {summary_start} '
                                 f'outside the file)')
            return
        data_end = (summary_start or footer) - _DATA_END
        if data_end >= _MAGIC:
            self.limit = data_end
            self.data_end_ok = (data[data_end:data_end + 9]
                                == struct.pack('<BQ', Opcode.DATA_END, 4))
        start = summary_start or footer
        if stored:
            with memoryview(data) as view, view[start:footer + 25] as part:
                ok = zlib.crc32(part) == stored
            self.summary_crc = 'ok' if ok else 'mismatch'
            if not ok:
                self.problems.append('summary section CRC mismatch: the summary (chunk index, '
                                     'statistics) is damaged and not used')
                return
        else:
            self.summary_crc = 'absent'
        if summary_start:
            self._summary(summary_start)

    def _summary(self, start: int) -> None:
        index: list[ChunkIndex] = []
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        stats: Statistics | None = None
        try:
            for record in StreamReader(BytesIO(self.data[start:]), skip_magic=True).records:
                if isinstance(record, ChunkIndex):
                    index.append(record)
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Statistics):
                    stats = record
        except _PARSE_ERRORS as err:
            self.problems.append(f'the summary section does not parse ({err}): not used')
            return
        index.sort(key=lambda ci: ci.chunk_start_offset)
        end = _MAGIC
        for ci in index:
            if ci.chunk_start_offset < end or ci.chunk_length < _RECORD_HEADER + _CHUNK_FIXED \
                    or ci.chunk_start_offset + ci.chunk_length > self.limit:
                self.problems.append('the summary\'s chunk index is inconsistent: not used')
                return
            end = ci.chunk_start_offset + ci.chunk_length
        self.index = index
        self.by_offset = {ci.chunk_start_offset: i for i, ci in enumerate(index)}
        self.schemas.update(schemas)
        self.channels.update(channels)
        self.summary_ok = True
        if stats is not None:
            self.message_count = stats.message_count

    # -- the record walk -----------------------------------------------------------------
    def records(self, want: bool) -> Iterator[list[McapRecord]]:
        """Walk the data section; with ``want``, yield the schemas, channels, messages,
        attachments and metadata records of each sound part (the summary's schemas and
        channels first) as lists."""
        if want and (self.schemas or self.channels):
            yield [*self.schemas.values(), *self.channels.values()]
        data, limit = self.data, self.limit
        pos = _MAGIC
        header_seen = False
        while pos < limit:
            if limit - pos < _RECORD_HEADER:
                pos = self._broken(pos, 'a record header is cut off')
                continue
            op = data[pos]
            length = _u64(data, pos + 1)
            end = pos + _RECORD_HEADER + length
            if not header_seen:
                header_seen = True
                if op == Opcode.HEADER and end <= limit:
                    try:
                        _parse(op, data[pos + 9:end])
                    except _DamageError as err:
                        self.problems.append(f'the header record is damaged ({err})')
                    pos = end
                    continue
                self.problems.append('the file does not start with a header record')
            if op not in _DATA_OPCODES or end > limit:
                reason = (f'unknown record opcode 0x{op:02x}' if op not in _DATA_OPCODES
                          else f'record length {length} runs past the end of the data')
                pos = self._broken(pos, reason)
                continue
            if op == Opcode.DATA_END:
                self._data_end(pos, end)
                break
            if op == Opcode.CHUNK:
                found = self._chunk(pos, end, want)
                if found is None:  # the header is inconsistent: framing unknown
                    pos = self._broken(pos, 'the chunk record header is inconsistent')
                    continue
                if found:
                    yield found
            elif op == Opcode.MESSAGE_INDEX:
                self._message_index(pos, end)
            else:
                try:
                    record = _parse(op, data[pos + 9:end])
                except _DamageError as err:
                    self.problems.append(f'record at byte {pos} is damaged ({err})')
                    pos = end
                    continue
                kept = self._top_level(record)
                if want and kept is not None:
                    yield [kept]
            pos = end
        else:
            if self.complete and self.data_end_ok:
                self._data_end(limit, limit + _DATA_END)
            elif self.complete:
                self.problems.append(f'no DataEnd record at byte {limit}, before the summary')
        self._finish()

    def _top_level(self, record: McapRecord) -> McapRecord | None:
        if isinstance(record, Schema):
            self.schemas.setdefault(record.id, record)
            return record
        if isinstance(record, Channel):
            self.channels.setdefault(record.id, record)
            return record
        if isinstance(record, Message):
            self.loose += 1
            first, last = self.loose_times
            self.loose_times = (min(first, record.log_time), max(last, record.log_time))
            return record
        if isinstance(record, (Attachment, Metadata)):  # what the bag says of itself
            return record
        return None

    def _message_index(self, pos: int, end: int) -> None:
        """A message index record: its framing is checked (channel, then 16 bytes per message:
        log time, offset); its count goes to a damaged chunk it follows."""
        if end - pos < _RECORD_HEADER + 6:
            self.problems.append(f'the message index at byte {pos} is damaged (too short)')
            return
        channel, size = struct.unpack_from('<HI', self.data, pos + _RECORD_HEADER)
        if size != end - pos - _RECORD_HEADER - 6 or size % 16:
            self.problems.append(f'the message index at byte {pos} is damaged (its lengths '
                                 'disagree)')
            return
        last = self._last_chunk
        if last is not None and not last.counts_known:
            last.counts[channel] = last.counts.get(channel, 0) + size // 16

    def _data_end(self, pos: int, end: int) -> None:
        stored = int(struct.unpack_from('<I', self.data, end - 4)[0])
        if not stored:
            self.data_crc = 'absent'
            return
        with memoryview(self.data) as view, view[:pos] as part:
            computed = zlib.crc32(part)
        self.data_crc = 'ok' if computed == stored else 'mismatch'

    def _broken(self, pos: int, reason: str) -> int:
        """Framing lost at ``pos``: note the damage and return where the walk resumes."""
        later = [o for o in self.by_offset if o > pos]
        resume = min(later) if later else (self.limit if self.index else self._find_chunk(pos))
        if resume is None:  # nothing recognisable follows
            if not self.complete:
                self.truncated_at = pos
                return self.limit
            resume = self.limit
        if pos in self.by_offset or (not self.index and self.data[pos] == Opcode.CHUNK):
            self._damaged_chunk(pos, resume - pos if not self.index else 0,
                                f'its record header is damaged: {reason}', None)
        else:
            self.problems.append(f'bytes {pos} .. {resume - 1} do not parse as MCAP records '
                                 f'({reason})')
        return resume

    def _find_chunk(self, pos: int) -> int | None:
        """The next offset after ``pos`` where a consistent chunk record starts."""
        data, limit = self.data, self.limit
        at = pos
        while True:
            at = data.find(b'\x06', at + 1, limit)
            if at < 0:
                return None
            if self._chunk_header_ok(at):
                return at

    def _chunk_header_ok(self, at: int) -> bool:
        data, limit = self.data, self.limit
        body = at + _RECORD_HEADER
        if body + _CHUNK_FIXED > limit:
            return False
        length = _u64(data, at + 1)
        start, stop = struct.unpack_from('<QQ', data, body)
        clen = int(struct.unpack_from('<I', data, body + 28)[0])
        if clen > 4 or start > stop or body + _CHUNK_FIXED + clen > limit:
            return False
        if data[body + 32:body + 32 + clen] not in _COMPRESSIONS:
            return False
        dlen = _u64(data, body + 32 + clen)
        end = body + length
        return (length == _CHUNK_FIXED + clen + dlen and end <= limit
                and (end == limit or data[end] in _DATA_OPCODES))

    def _chunk(self, pos: int, end: int, want: bool) -> list[McapRecord] | None:
        """Check the chunk record at ``pos``: its records if sound (and wanted), [] if sound
        or damaged (noted), None if its header is inconsistent (framing lost)."""
        number = self.by_offset.get(pos, self.chunks)
        ci = self.index[number] if pos in self.by_offset else None
        if self.index and ci is None:
            self.problems.append(f'a chunk at byte {pos} is not in the summary\'s chunk index')
        try:
            chunk = _parse(Opcode.CHUNK, self.data[pos + 9:end])
        except _DamageError:
            return None
        assert isinstance(chunk, Chunk)
        if _CHUNK_FIXED + len(chunk.compression.encode()) + len(chunk.data) != end - pos - 9:
            return None
        self.chunks = max(self.chunks, number + 1)
        if chunk.uncompressed_crc:
            self.crc_chunks += 1
        if ci is not None and (ci.chunk_length != end - pos or ci.compression != chunk.compression
                               or ci.compressed_size != len(chunk.data)
                               or ci.uncompressed_size != chunk.uncompressed_size):
            self._damaged_chunk(pos, end - pos, 'its header disagrees with the summary\'s '
                                'chunk index', chunk, number)
            return []
        lo, hi = ((ci.message_start_time, ci.message_end_time) if ci is not None
                  else (chunk.message_start_time, chunk.message_end_time))
        try:
            records = self._contents(chunk, lo, hi, want)
        except _DamageError as err:
            self._damaged_chunk(pos, end - pos, str(err), chunk, number)
            return []
        if ci is not None and (chunk.message_start_time, chunk.message_end_time) != (lo, hi):
            self.problems.append(f'chunk {number} at byte {pos}: its header\'s log times '
                                 'disagree with the summary\'s chunk index (its messages are '
                                 'intact)')
        self._sound_times[number] = (lo, hi)
        self.times.append((lo, hi))
        self._last_chunk = None
        self._last_sound = number
        return records if want else []

    def _contents(self, chunk: Chunk, lo: int, hi: int, want: bool) -> list[McapRecord]:
        """Decompress and check the chunk's records (module docstring); its schemas, channels
        and messages when ``want``. A chunk whose CRC verified is parsed only when its records
        are wanted, or for its channels when there is no summary to list them."""
        try:
            stream, size = get_chunk_data_stream(chunk, validate_crc=True)
            raw = stream.read(size)
        except CRCValidationError as err:
            raise _DamageError(f'chunk CRC mismatch: stored {err.expected:08x}, computed '
                          f'{err.actual:08x}') from err
        except Exception as err:  # whatever a decompressor raises on a damaged stream
            raise _DamageError(f'does not decompress ({chunk.compression}: '
                          f'{err or type(err).__name__})') from err
        if size != chunk.uncompressed_size:
            raise _DamageError(f'decompresses to {size} bytes, not the {chunk.uncompressed_size} '
                          f'its header states')
        checked = bool(chunk.uncompressed_crc)
        if checked and not want and self.summary_ok:
            return []
        known = self.channels if self.summary_ok else None
        out: list[McapRecord] = []
        at = 0
        while at < size:
            if size - at < _RECORD_HEADER:
                raise _DamageError(f'a record header at byte {at} of its records is cut off')
            op = raw[at]
            end = at + _RECORD_HEADER + _u64(raw, at + 1)
            if end > size:
                raise _DamageError(f'the record at byte {at} of its records runs past its end')
            if op == Opcode.MESSAGE:
                if end - at - 9 < _MESSAGE_FIXED:
                    raise _DamageError(f'the message at byte {at} of its records is too short')
                cid, seq, log, pub = struct.unpack_from('<HIQQ', raw, at + 9)
                if not checked:
                    if known is not None and cid not in known:
                        raise _DamageError(f'a message on unknown channel {cid}')
                    if not lo <= log <= hi:
                        raise _DamageError(f'a message log time ({log}) outside the '
                                           f'chunk\'s range')
                if want:
                    out.append(Message(channel_id=cid, sequence=seq, log_time=log,
                                       publish_time=pub, data=raw[at + 9 + _MESSAGE_FIXED:end]))
            elif op in (Opcode.SCHEMA, Opcode.CHANNEL):
                record = _parse(op, raw[at + 9:end])
                if isinstance(record, Schema):
                    self.schemas.setdefault(record.id, record)
                elif isinstance(record, Channel):
                    self.channels.setdefault(record.id, record)
                if want:
                    out.append(record)
            else:
                raise _DamageError(f'unexpected record (opcode 0x{op:02x}) at byte {at} of its '
                              f'records')
            at = end
        return out

    def _damaged_chunk(self, pos: int, length: int, reason: str, chunk: Chunk | None,
                       number: int | None = None) -> None:
        if number is None:
            number = self.by_offset.get(pos, self.chunks)
        ci = self.index[number] if pos in self.by_offset else None
        self.chunks = max(self.chunks, number + 1)
        if ci is not None:
            item = _Pending(number, pos, ci.chunk_length, reason, ci.message_start_time,
                            ci.message_end_time, _index_counts(ci),
                            bool(ci.message_index_offsets))
        elif chunk is not None and chunk.message_start_time <= chunk.message_end_time:
            item = _Pending(number, pos, length, reason, chunk.message_start_time,
                            chunk.message_end_time)
        else:
            item = _Pending(number, pos, length, reason, None, None, after=self._last_sound)
        if item.start_ns is not None and item.end_ns is not None:
            self.times.append((item.start_ns, item.end_ns))
        self.pending.append(item)
        self._last_chunk = item

    def _finish(self) -> None:
        """Indexed chunks the walk never reached are damaged; times from the neighbours."""
        seen = {p.index for p in self.pending} | set(self._sound_times)
        for i, ci in enumerate(self.index):
            if i not in seen:
                self.pending.append(_Pending(i, ci.chunk_start_offset, ci.chunk_length,
                                             'no readable chunk record at its indexed offset',
                                             ci.message_start_time, ci.message_end_time,
                                             _index_counts(ci),
                                             bool(ci.message_index_offsets)))
                self.times.append((ci.message_start_time, ci.message_end_time))
        self.pending.sort(key=lambda p: p.offset)
        for p in self.pending:
            if p.start_ns is None:
                before = self._sound_times.get(p.after) if p.after is not None else None
                after = min((t for n, t in self._sound_times.items() if n > p.index),
                            default=None)
                if before is not None and after is not None:
                    p.start_ns, p.end_ns = before[1], after[0]
        if self.data_crc == 'mismatch' and not self.pending and not self.problems:
            self.problems.append(
                f'data section CRC mismatch: damage in the {self.loose} messages stored '
                'outside chunks (one may be corrupt; none is lost) or in chunk headers, '
                'message indexes or metadata' if self.loose else
                'data section CRC mismatch: damage outside the chunks\' records (chunk '
                'headers, message indexes or metadata); no message is lost')
        if self.loose:
            self.times.append(self.loose_times)

    def result(self) -> FileCheck:
        damaged = tuple(DamagedChunk(
            self.path.name, p.index, p.offset, p.length, p.reason, p.start_ns, p.end_ns,
            {self.channels[c].topic if c in self.channels else f'channel {c}': n
             for c, n in sorted(p.counts.items()) if n})
            for p in self.pending)
        return FileCheck(
            self.path, self.size, 'mcap', self.complete, max(self.chunks, len(self.index)),
            self.crc_chunks, self.data_crc, self.summary_crc, damaged,
            tuple(dict.fromkeys(self.problems)), None if self.complete else
            (self.truncated_at if self.truncated_at is not None else self.size),
            min((t[0] for t in self.times), default=None),
            max((t[1] for t in self.times), default=None), self.message_count)


def _unusable(path: Path) -> FileCheck | None:
    """The check of a file that is no MCAP file at all, else None."""
    size = path.stat().st_size
    if size == 0:
        return FileCheck(path, 0, 'empty', problems=('empty (0 bytes)',))
    if size < MIN_MCAP_BYTES:
        return FileCheck(path, size, 'too short',
                         problems=(f'{size} bytes: too short to be an MCAP file',))
    with path.open('rb') as stream:
        if stream.read(_MAGIC) != MCAP_MAGIC:
            return FileCheck(path, size, 'not MCAP',
                             problems=('not an MCAP file (wrong magic bytes)',))
    return None


def verify_file(path: str | Path) -> FileCheck:
    """Verify one ``.mcap`` file (see the module docstring). OSError if it cannot be read."""
    path = Path(path)
    bad = _unusable(path)
    if bad is not None:
        return bad
    with path.open('rb') as stream, mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) \
            as data:
        walk = _Walk(path, data)
        for _ in walk.records(want=False):
            pass
        return walk.result()


def sound_records(path: str | Path
                  ) -> Iterator[Schema | Channel | Message | Attachment | Metadata]:
    """The schemas, channels, messages, attachments and metadata records (the ``rosbag2``
    one included) of the sound part of an MCAP file in file order
    (the summary's schemas and channels first, when it has a sound summary): every corrupt
    chunk is skipped and the walk goes on with the next (module docstring). Nothing for a file
    that is no MCAP file."""
    path = Path(path)
    if _unusable(path) is not None:
        return
    with path.open('rb') as stream, mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) \
            as data:
        walk = _Walk(path, data)
        for part in walk.records(want=True):
            for record in part:
                if isinstance(record, (Schema, Channel, Message, Attachment, Metadata)):
                    yield record


def verify_bag(path: str | Path, files: Sequence[Path] | None = None) -> BagCheck:
    """Verify each storage file of the bag at ``path`` (a bag directory, or one ``.mcap``);
    ``files`` instead of the directory's ``.mcap`` files in split order."""
    path = Path(path)
    if files is None:
        files = storage_files(path) if path.is_dir() else [path]
    return BagCheck(path, tuple(verify_file(f) for f in files))
