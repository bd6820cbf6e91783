"""rosbag2 bag metadata: topic descriptions, per-file summaries, QoS, and metadata.yaml.

The layout is the one rosbag2 Jazzy writes (metadata version 9, storage ``mcap``): the field
names and types are rosbags' ``Metadata`` TypedDict (the schema its reader checks) and the QoS
profiles are serialised by rosbags' own ``dump_qos_v9``, so the file this module writes, the
channel metadata in each ``.mcap`` and what rosbags parses back agree field for field.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.metadata import Metadata, dump_qos_v9, parse_qos

from positioning_cell.bag.errors import BagError

#: rosbag2 metadata version of ROS 2 Jazzy.
METADATA_VERSION = 9
#: ``ros_distro`` written to metadata.yaml: the cell runs on ROS 2 Jazzy.
ROS_DISTRO = 'jazzy'
METADATA_FILE = 'metadata.yaml'


@dataclass(frozen=True)
class TopicMeta:
    """One recorded topic: name, ROS type (``pkg/msg/Type``), the QoS its publishers offered,
    the RIHS01 type hash and the serialization format (always ``cdr`` here)."""

    name: str
    msgtype: str
    qos: tuple[Qos, ...] = ()
    type_hash: str = ''
    serialization_format: str = 'cdr'


@dataclass(frozen=True)
class FileSummary:
    """One storage file of a bag: its name relative to the bag directory, first and last
    log (receive) times in ns since the epoch (0, 0 when empty), and message counts."""

    path: str
    start_ns: int
    end_ns: int
    message_count: int
    topic_counts: Mapping[str, int] = field(default_factory=dict)


# -- QoS ---------------------------------------------------------------------------------------
def make_qos(history: QosHistory, depth: int, reliability: QosReliability,
             durability: QosDurability) -> Qos:
    """A rosbags Qos with the given policies and system-default timing and liveliness."""
    zero = QosTime(0, 0)
    return Qos(history, depth, reliability, durability, zero, zero,
               QosLiveliness.SYSTEM_DEFAULT, zero, False)


def _adapted(offered: Sequence[Qos]) -> tuple[QosReliability, QosDurability]:
    """rosbag2's adaptive choice: reliable unless a publisher is best effort (a reliable reader
    would not match it), transient-local only when every publisher is."""
    best_effort = any(q.reliability == QosReliability.BEST_EFFORT for q in offered)
    latched = bool(offered) and all(q.durability == QosDurability.TRANSIENT_LOCAL
                                    for q in offered)
    return (QosReliability.BEST_EFFORT if best_effort else QosReliability.RELIABLE,
            QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE)


def recording_qos(offered: Sequence[Qos], depth: int) -> Qos:
    """QoS of a recorder subscription matching every publisher in ``offered``: reliable and
    transient-local where the publishers are (see ``_adapted``); ``depth`` 0 means keep all."""
    reliability, durability = _adapted(offered)
    if depth <= 0:
        return make_qos(QosHistory.KEEP_ALL, 0, reliability, durability)
    return make_qos(QosHistory.KEEP_LAST, depth, reliability, durability)


def playback_qos(offered: Sequence[Qos], depth: int) -> Qos:
    """QoS of a player publisher re-offering what was recorded: the recorded reliability and
    durability; a latched topic keeps the depth it was offered with (its last value(s) for late
    joiners), a stream gets ``depth``."""
    reliability, durability = _adapted(offered)
    if durability == QosDurability.TRANSIENT_LOCAL:
        depth = max([q.depth for q in offered if q.history == QosHistory.KEEP_LAST] or [1])
    return make_qos(QosHistory.KEEP_LAST, max(depth, 1), reliability, durability)


def qos_yaml(qos: Sequence[Qos]) -> str:
    """The ``offered_qos_profiles`` string stored in an MCAP channel's metadata (rosbag2 v9)."""
    if not qos:
        return ''
    return yaml.safe_dump(dump_qos_v9(list(qos)), default_flow_style=False,
                          sort_keys=False).strip()


def parse_qos_yaml(text: str, path: str | Path) -> tuple[Qos, ...]:
    """Inverse of :func:`qos_yaml` (BagError naming ``path`` if it does not parse)."""
    try:
        return tuple(parse_qos(text))
    except (ReaderError, KeyError, TypeError, ValueError) as err:
        raise BagError(path, f'unreadable offered_qos_profiles in channel metadata: {err}') \
            from err


def topic_meta(topic: str, msgtype: str, encoding: str, metadata: Mapping[str, str],
               path: str | Path) -> TopicMeta:
    """The TopicMeta of an MCAP channel: its topic, its schema's type name, its message
    encoding and metadata (``offered_qos_profiles``, ``topic_type_hash``, as rosbag2 stores
    them); BagError naming ``path`` if the QoS does not parse."""
    return TopicMeta(topic, msgtype, parse_qos_yaml(metadata.get('offered_qos_profiles', ''),
                                                    path),
                     metadata.get('topic_type_hash', ''), encoding)


# -- metadata.yaml -----------------------------------------------------------------------------
def bag_metadata(topics: Sequence[TopicMeta], files: Sequence[FileSummary],
                 custom_data: Mapping[str, str] | None = None) -> dict[str, Metadata]:
    """The ``rosbag2_bagfile_information`` mapping of a bag made of ``files`` (in order).

    Times are log (receive) times in ns; duration = last − first, as rosbag2 computes it.
    Chunk compression inside MCAP is storage-level, so compression_format/mode stay empty.
    """
    counts: dict[str, int] = {t.name: 0 for t in topics}
    for f in files:
        for name, n in f.topic_counts.items():
            counts[name] = counts.get(name, 0) + n
    used = [f for f in files if f.message_count]
    start = min((f.start_ns for f in used), default=0)
    end = max((f.end_ns for f in used), default=0)
    info: Metadata = {
        'version': METADATA_VERSION,
        'storage_identifier': 'mcap',
        'relative_file_paths': [f.path for f in files],
        'duration': {'nanoseconds': end - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(f.message_count for f in files),
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msgtype,
                                'serialization_format': t.serialization_format,
                                'offered_qos_profiles': dump_qos_v9(list(t.qos)),
                                'type_description_hash': t.type_hash},
             'message_count': counts.get(t.name, 0)}
            for t in topics],
        'compression_format': '',
        'compression_mode': '',
        'files': [{'path': f.path,
                   'starting_time': {'nanoseconds_since_epoch': f.start_ns},
                   'duration': {'nanoseconds': f.end_ns - f.start_ns},
                   'message_count': f.message_count} for f in files],
        'custom_data': dict(custom_data or {}),
        'ros_distro': ROS_DISTRO,
    }
    return {'rosbag2_bagfile_information': info}


def metadata_yaml(metadata: Mapping[str, Any], *, inner: bool = False) -> str:
    """YAML text of :func:`bag_metadata`'s result (``inner``: without the top-level key, the
    form rosbag2 stores in an MCAP ``rosbag2`` metadata record)."""
    data = metadata['rosbag2_bagfile_information'] if inner else metadata
    return yaml.safe_dump(data, default_flow_style=False, sort_keys=False)


def write_metadata(bag_dir: Path, topics: Sequence[TopicMeta], files: Sequence[FileSummary],
                   custom_data: Mapping[str, str] | None = None) -> Path:
    """Write ``bag_dir/metadata.yaml`` atomically (temporary file, then rename; an OSError
    leaves no part of it behind)."""
    path = bag_dir / METADATA_FILE
    tmp = path.with_suffix('.yaml.tmp')
    try:
        tmp.write_text(metadata_yaml(bag_metadata(topics, files, custom_data)), encoding='utf-8')
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    return path
