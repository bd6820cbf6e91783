"""Recovering a bag whose recorder was killed, or whose files are damaged: every sound chunk
of a truncated or damaged ``.mcap`` is rewritten into a valid, indexed file and
``metadata.yaml`` is rebuilt from the files.

A recording killed with SIGKILL leaves ``.mcap`` files without their summary section (and the
last one cut in the middle of a record) and no ``metadata.yaml``. The MCAP record stream is
self-describing (schemas and channels precede the messages that use them), so walking it from
the start yields the readable prefix. A file damaged on disk (a corrupt chunk: its CRC,
compression or records fail, see :mod:`positioning_cell.bag.verify`) is rewritten from its
sound chunks: the walk skips each corrupt chunk and goes on with the next, and what each one
covered is reported (:attr:`FileRecovery.lost`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mcap.records import Attachment as McapAttachment
from mcap.records import Channel, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE
from rosbags.rosbag2.errors import ReaderError
from ruamel.yaml import YAML
from ruamel.yaml.error import YAMLError

from positioning_cell.bag.description import ROSBAG2_RECORD, Attachment, MetadataRecord
from positioning_cell.bag.errors import BagError
from positioning_cell.bag.file_index import summarise
from positioning_cell.bag.metadata import (
    METADATA_FILE,
    FileSummary,
    TopicMeta,
    topic_meta,
    write_metadata,
)
from positioning_cell.bag.verify import (
    MCAP_MAGIC,
    DamagedChunk,
    FileCheck,
    sound_records,
    storage_files,
    verify_file,
)
from positioning_cell.bag.writer import McapFile

__all__ = ['MCAP_MAGIC', 'FileRecovery', 'RecoveryReport', 'recover_bag', 'storage_files']

RECOVER_CHUNK_BYTES = 1024 * 1024
#: Suffix of the kept original, by status.
BACKUP_SUFFIX = {'recovered': '.truncated', 'repaired': '.damaged'}


@dataclass(frozen=True)
class FileRecovery:
    """What happened to one storage file: ``complete`` (sound, untouched), ``recovered``
    (truncated: rewritten from its readable records), ``repaired`` (complete but damaged:
    rewritten from its sound chunks); a rewritten file's original is kept as ``backup``.
    ``lost``: the corrupt chunks left out (what each covered); ``problems``: damage found
    outside the chunks."""

    path: Path
    status: str
    message_count: int
    backup: Path | None = None
    lost: tuple[DamagedChunk, ...] = ()
    problems: tuple[str, ...] = ()


@dataclass(frozen=True)
class RecoveryReport:
    """Outcome of :func:`recover_bag`: the bag directory, each file, whether metadata.yaml was
    (re)written."""

    bag: Path
    files: tuple[FileRecovery, ...]
    metadata_written: bool

    @property
    def message_count(self) -> int:
        """Messages in the bag after recovery."""
        return sum(f.message_count for f in self.files)

    @property
    def changed(self) -> bool:
        """True when anything on disk was rewritten."""
        return self.metadata_written or any(f.status != 'complete' for f in self.files)


@dataclass(frozen=True)
class _Inspection:
    path: Path
    complete: bool
    topics: tuple[TopicMeta, ...] = ()
    summary: FileSummary | None = None
    check: FileCheck | None = None

    @property
    def status(self) -> str:
        """What recovery does with the file (see FileRecovery)."""
        if self.complete:
            return 'complete'
        return 'repaired' if self.check is not None and self.check.complete else 'recovered'


def _topic(channel: Channel, schema: Schema | None, path: Path) -> TopicMeta:
    return topic_meta(channel.topic, schema.name if schema is not None else '',
                      channel.message_encoding, channel.metadata, path)


def _inspect(path: Path, check: FileCheck | None) -> _Inspection:
    """Is ``path`` an MCAP file (else BagError), and is it complete (a footer) and sound
    (:func:`verify_file`, unless ``check`` is its verification already) and readable as it
    is (:func:`positioning_cell.bag.file_index.summarise`: any valid layout, indexed or not)?
    For such a file, its topics and counts."""
    size = path.stat().st_size
    with path.open('rb') as stream:
        head = stream.read(MAGIC_SIZE)
        if size and head != MCAP_MAGIC[:len(head)]:
            raise BagError(path, 'not an MCAP file (wrong magic bytes); nothing changed')
    check = check or verify_file(path)
    if not check.usable:
        return _Inspection(path, False)
    if not check.sound:
        return _Inspection(path, False, check=check)
    try:
        summary, topics = summarise(path)
    except BagError:  # sound by its CRCs and framing, yet not readable as it is
        return _Inspection(path, False, check=check)
    return _Inspection(path, True, topics, summary)


def _rewrite(path: Path, compression: str) -> tuple[FileSummary, tuple[TopicMeta, ...]]:
    """Write the sound records of ``path`` (:func:`sound_records`: every readable chunk, corrupt
    ones skipped; the description records and attachments too) to ``path.recovering``; its
    summary and topics."""
    target = path.with_name(path.name + '.recovering')
    target.unlink(missing_ok=True)
    out = McapFile(target, compression, RECOVER_CHUNK_BYTES)
    schemas: dict[int, Schema] = {}
    topics: dict[int, TopicMeta] = {}
    try:
        for record in sound_records(path):
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                schema = schemas.get(record.schema_id)
                if schema is None or record.id in topics:
                    continue
                topics[record.id] = _topic(record, schema, path)
                out.add_topic(topics[record.id], schema.data.decode('utf-8', 'replace'),
                              schema.encoding)
            elif isinstance(record, Metadata):
                if record.name != ROSBAG2_RECORD:  # close() writes rosbag2's anew
                    out.describe([MetadataRecord(record.name, record.metadata)])
            elif isinstance(record, McapAttachment):
                out.describe(attachments=[Attachment(record.name, record.media_type,
                                                     bytes(record.data), record.log_time)])
            elif record.channel_id in topics:
                out.write(topics[record.channel_id].name, record.data, record.log_time)
        summary = out.close(list(topics.values()))
    except BaseException:
        target.unlink(missing_ok=True)
        raise
    return FileSummary(path.name, summary.start_ns, summary.end_ns, summary.message_count,
                       summary.topic_counts), tuple(topics.values())


def _listed_files(bag: Path) -> list[str] | None:
    """``relative_file_paths`` of an existing, parseable metadata.yaml, else None."""
    try:
        data = YAML(typ='safe').load((bag / METADATA_FILE).read_text(encoding='utf-8'))
        return [Path(p).name for p in data['rosbag2_bagfile_information']['relative_file_paths']]
    except (OSError, YAMLError, KeyError, TypeError, ReaderError):
        return None


def recover_bag(path: str | Path, compression: str = 'zstd', *,
                checked: Sequence[FileCheck] = ()) -> RecoveryReport:
    """Make the bag at ``path`` (its directory, or one of its ``.mcap`` files) valid again.

    Every file is verified (:func:`positioning_cell.bag.verify.verify_file`; ``checked``: files
    verified already, matched by file name). Sound, complete files are left as they are; each
    truncated one is rewritten from its readable records, each damaged one from its sound
    chunks (``compression``: ``zstd`` or ``none``), the original kept beside it as
    ``<name>.mcap.truncated`` or ``<name>.mcap.damaged``; metadata.yaml is rebuilt when missing,
    stale or after any rewrite. A sound bag is not touched. Input that is not a bag (missing
    path, no ``.mcap``, a file that is not MCAP) raises BagError before anything is changed.
    """
    path = Path(path)
    bag = path.parent if path.suffix == '.mcap' and path.is_file() else path
    if not bag.is_dir():
        raise BagError(path, 'does not exist or is not a bag directory')
    files = storage_files(bag)
    if not files:
        raise BagError(bag, 'no .mcap storage files: not an MCAP rosbag2 bag')
    known = {c.path.name: c for c in checked}
    inspections = [_inspect(f, known.get(f.name)) for f in files]  # raises before any change

    results: list[FileRecovery] = []
    summaries: list[FileSummary] = []
    topics: dict[str, TopicMeta] = {}
    for item in inspections:
        if item.complete and item.summary is not None:
            summary, found = item.summary, item.topics
            results.append(FileRecovery(item.path, 'complete', summary.message_count))
        else:
            summary, found = _rewrite(item.path, compression)
            status = item.status
            backup = item.path.with_name(item.path.name + BACKUP_SUFFIX[status])
            os.replace(item.path, backup)
            os.replace(item.path.with_name(item.path.name + '.recovering'), item.path)
            check = item.check
            results.append(FileRecovery(
                item.path, status, summary.message_count, backup,
                check.damaged if check is not None else (),
                check.problems if check is not None else ()))
        summaries.append(summary)
        for topic in found:
            topics.setdefault(topic.name, topic)

    rewritten = any(r.status != 'complete' for r in results)
    stale = _listed_files(bag) != [f.name for f in files]
    if rewritten or stale:
        write_metadata(bag, list(topics.values()), summaries)
    return RecoveryReport(bag, tuple(results), rewritten or stale)
