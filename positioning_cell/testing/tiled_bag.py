"""A recorded bag repeated end to end to a chosen number of messages: a long recorded run for
the analysis benchmark (benchmarks/analysis_recorded.py) and its tests.

Copy ``k`` (0, 1, ...) of the source bag's messages is shifted by ``k`` periods, the period
being the span of every time the copy holds (log times, the header stamps of its stamped
messages, the times in its JSON markers) plus ``gap_s``, so that copy ``k + 1`` starts after
copy ``k`` ends whatever time one looks at: the tiled bag reads as one long run of the same
program repeated, never as overlapping copies. Shifted in each message:

- the log and publish time (the cell's writer, :class:`positioning_cell.bag.BagWriter`, writes
  both as the receive time);
- the header stamp of every message whose type starts with a ``std_msgs/Header`` (poses,
  diagnostics, joint states and trajectories, ...): patched in the CDR bytes (little- or
  big-endian as the encapsulation says), the rest of the message left as it was recorded; a
  zero stamp (a trajectory to start at once) stays zero;
- in the JSON text of std_msgs/String markers (/cell/program, /cell/calibration,
  /cell/axis_test): the numbers under :data:`SECONDS_KEYS` (s since the epoch) and the UTC ISO
  8601 times under :data:`ISO_KEYS` (a calibration run's name is its start), so that each copy's
  calibration run is a run of its own.

Messages of other types (no header first: MarkerArray, DiagnosticStatus) keep their bytes.
The last copy is cut so that the bag holds exactly the number of messages asked for.
"""

from __future__ import annotations

import json
import math
import struct
from contextlib import suppress
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

from positioning_cell.bag import BagReader, BagWriter, RawMessage
from positioning_cell.bag.writer import jazzy_typestore

#: Keys of a JSON marker holding a time in s since the epoch.
SECONDS_KEYS = ('stamp', 'start', 'time')
#: Keys of a JSON marker holding a UTC ISO 8601 time.
ISO_KEYS = ('run',)
STRING = 'std_msgs/msg/String'
#: The header stamp's place in CDR: after the 4-byte encapsulation, sec int32, nanosec uint32.
STAMP_OFFSET = 4
NS = 1_000_000_000


@dataclass(frozen=True)
class TiledBag:
    """A tiled bag: its path, messages, copies of the source (the last one possibly cut),
    the source's message count and the period (ns) between copies."""

    path: Path
    message_count: int
    copies: int
    source_messages: int
    period_ns: int


def _stamp_format(data: bytes) -> str:
    """The struct format of a header stamp (sec, nanosec) in this CDR message."""
    return '<iI' if data[1] == 1 else '>iI'


def _header_first(store: Any, msgtype: str, sample: bytes) -> bool:
    """Whether messages of ``msgtype`` begin with a std_msgs/Header (checked on ``sample``:
    its decoded stamp must be the bytes at :data:`STAMP_OFFSET`)."""
    if msgtype == STRING:
        return False
    message = store.deserialize_cdr(sample, msgtype)
    header = getattr(message, 'header', None)
    if header is None or not hasattr(header, 'stamp'):
        return False
    sec, nanosec = struct.unpack_from(_stamp_format(sample), sample, STAMP_OFFSET)
    return bool(sec == header.stamp.sec and nanosec == header.stamp.nanosec)


def _header_ns(data: bytes) -> int:
    sec, nanosec = struct.unpack_from(_stamp_format(data), data, STAMP_OFFSET)
    return int(sec) * NS + int(nanosec)


def _with_stamp(data: bytes, stamp_ns: int) -> bytes:
    """``data`` with its header stamp set to ``stamp_ns``."""
    out = bytearray(data)
    struct.pack_into(_stamp_format(data), out, STAMP_OFFSET, *divmod(stamp_ns, NS))
    return bytes(out)


def _string_text(store: Any, data: bytes) -> str:
    return str(store.deserialize_cdr(data, STRING).data)


def _marker_times_ns(text: str) -> list[int]:
    """The times (ns) a JSON marker holds under :data:`SECONDS_KEYS` and :data:`ISO_KEYS`."""
    try:
        doc = json.loads(text)
    except ValueError:
        return []
    if not isinstance(doc, dict):
        return []
    out = [round(float(doc[k]) * NS) for k in SECONDS_KEYS
           if isinstance(doc.get(k), (int, float))]
    for key in ISO_KEYS:
        with suppress(KeyError, ValueError):
            out.append(round(datetime.fromisoformat(str(doc[key])).timestamp() * NS))
    return out


def shift_marker(text: str, shift_ns: int) -> str:
    """A JSON marker with its times (:data:`SECONDS_KEYS`, s; :data:`ISO_KEYS`, ISO 8601)
    moved by ``shift_ns``; text that is not a JSON object is returned as it is."""
    try:
        doc = json.loads(text)
    except ValueError:
        return text
    if not isinstance(doc, dict):
        return text
    for key in SECONDS_KEYS:
        if isinstance(doc.get(key), (int, float)) and not isinstance(doc[key], bool):
            doc[key] = doc[key] + shift_ns / NS
    for key in ISO_KEYS:
        try:
            when = datetime.fromisoformat(str(doc[key]))
        except (KeyError, ValueError):
            continue
        doc[key] = (when + timedelta(microseconds=shift_ns // 1000)).isoformat(
            timespec='milliseconds')
    return json.dumps(doc)


class _Source:
    """The source bag in memory: its messages in log-time order, which topics carry a header
    stamp first, the QoS of each topic, and the span (ns) of every time it holds."""

    def __init__(self, path: Path) -> None:
        self.store = jazzy_typestore()
        with BagReader(path) as reader:
            self.topics = {t.name: t for t in reader.topics.values()}
            self.messages: list[RawMessage] = list(reader.raw_messages())
        if not self.messages:
            raise ValueError(f'{path}: the bag holds no message to tile')
        self.stamped: set[str] = set()
        checked: set[str] = set()
        times: list[int] = [self.messages[0].log_time_ns, self.messages[-1].log_time_ns]
        for m in self.messages:
            if m.topic not in checked:
                checked.add(m.topic)
                if _header_first(self.store, m.msgtype, m.data):
                    self.stamped.add(m.topic)
            if m.topic in self.stamped:
                times.append(_header_ns(m.data) or times[0])
            elif m.msgtype == STRING:
                times += _marker_times_ns(_string_text(self.store, m.data))
        self.span_ns = max(times) - min(times)

    def shifted(self, message: RawMessage, shift_ns: int) -> bytes:
        """The message's bytes with its header stamp or marker times moved by ``shift_ns``."""
        if shift_ns == 0:
            return message.data
        if message.topic in self.stamped:
            stamp = _header_ns(message.data)
            return _with_stamp(message.data, stamp + shift_ns) if stamp else message.data
        if message.msgtype == STRING:
            text = _string_text(self.store, message.data)
            moved = shift_marker(text, shift_ns)
            if moved != text:
                string = self.store.types[STRING]
                return bytes(self.store.serialize_cdr(string(data=moved), STRING))
        return message.data


def tile_bag(source: str | Path, target: str | Path, messages: int, *,
             gap_s: float = 1.0) -> TiledBag:
    """Write at ``target`` (a bag folder that must not exist) the bag at ``source`` repeated
    to exactly ``messages`` messages (module docstring), with the cell's writer and each
    topic's recorded QoS; copies ``gap_s`` s apart. ValueError when ``messages`` < 1 or the
    source holds no message; BagError from the reader or the writer."""
    if messages < 1:
        raise ValueError(f'messages = {messages}: must be at least 1')
    bag = _Source(Path(source))
    period_ns = bag.span_ns + round(gap_s * NS)
    copies = math.ceil(messages / len(bag.messages))
    target = Path(target)
    with BagWriter(target) as writer:
        for info in bag.topics.values():
            writer.add_topic(info.name, info.msgtype, info.qos)
        left = messages
        for k in range(copies):
            shift = k * period_ns
            for m in bag.messages[:left]:
                writer.write(m.topic, m.msgtype, bag.shifted(m, shift), m.log_time_ns + shift)
            left -= len(bag.messages)
        written = writer.message_count
    return TiledBag(target, written, copies, len(bag.messages), period_ns)
