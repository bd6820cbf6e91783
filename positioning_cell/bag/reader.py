"""Reading a recorded bag back, through rosbags (decoder independent of the writer's mcap
library): raw CDR for replay, decoded messages and numpy arrays for analysis.

rosbags checks a chunk's CRC when it reads the chunk; :meth:`BagReader.verify` checks every
chunk and the data-section CRC up front (:mod:`positioning_cell.bag.verify`), and a read that
fails on damaged storage says which chunks are corrupt and what they covered.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Connection, ConnectionExtRosbag2, Qos
from rosbags.rosbag2.errors import ReaderError
from rosbags.serde import SerdeError

from positioning_cell.bag.errors import BagError
from positioning_cell.bag.metadata import METADATA_FILE
from positioning_cell.bag.verify import BagCheck, verify_bag

_READ_ERRORS = (AnyReaderError, ReaderError, SerdeError, OSError, KeyError, ValueError,
                AssertionError, EOFError)


class RawMessage(NamedTuple):
    """One stored message: topic, ROS type, log (receive) time in ns, CDR bytes."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes


class BagMessage(NamedTuple):
    """One decoded message: topic, ROS type, log (receive) time in ns, the message (a rosbags
    dataclass with the ROS field names; header stamps as recorded)."""

    topic: str
    msgtype: str
    log_time_ns: int
    message: Any


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a bag: ROS type, number of messages, QoS its publishers offered."""

    name: str
    msgtype: str
    message_count: int
    qos: tuple[Qos, ...]


def _damage(path: Path) -> str:
    """``; <what verification finds wrong>`` for an error message ('' if nothing)."""
    try:
        lines = verify_bag(path).lines() if path.is_dir() or path.suffix == '.mcap' else []
    except OSError:
        return ''
    return ''.join(f'; {line}' for line in lines)


class BagReader:
    """An open bag (a rosbag2 directory, or a single ``.mcap``): a context manager.

    Every message is yielded in log-time order across topics and files. Problems (missing
    path, no metadata.yaml, unreadable or corrupt storage, unknown topics) raise BagError; on
    unreadable or corrupt storage its reason names the damage :meth:`verify` finds.
    """

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        if not path.exists():
            raise BagError(path, 'does not exist')
        if path.is_dir() and not (path / METADATA_FILE).is_file():
            raise BagError(path, f'no {METADATA_FILE}: not a rosbag2 bag, or an interrupted '
                                 'recording (run recover_bag on it)')
        self.path = path
        try:
            self._reader = AnyReader([path])
            self._reader.open()
        except _READ_ERRORS as err:
            raise BagError(path, f'not a readable bag: {err}{_damage(path)}') from err
        self.topics: dict[str, TopicInfo] = {}
        for name, info in self._reader.topics.items():
            qos: list[Qos] = []
            for conn in info.connections:
                if isinstance(conn.ext, ConnectionExtRosbag2):
                    qos.extend(q for q in conn.ext.offered_qos_profiles if q not in qos)
            self.topics[name] = TopicInfo(name, info.msgtype or '', info.msgcount, tuple(qos))

    @property
    def message_count(self) -> int:
        """Number of messages in the bag."""
        return sum(t.message_count for t in self.topics.values())

    @property
    def start_ns(self) -> int:
        """Log time of the first message (ns since the epoch; 0 for an empty bag)."""
        return int(self._reader.start_time) if self.message_count else 0

    @property
    def end_ns(self) -> int:
        """Log time of the last message (ns since the epoch; 0 for an empty bag)."""
        return int(self._reader.end_time) - 1 if self.message_count else 0

    def _connections(self, topics: Collection[str] | None) -> list[Connection]:
        if topics is None:
            return list(self._reader.connections)
        unknown = sorted(set(topics) - set(self.topics))
        if unknown:
            raise BagError(self.path, f'no topic {", ".join(unknown)} in the bag (it has: '
                                      f'{", ".join(sorted(self.topics)) or "none"})')
        return [c for c in self._reader.connections if c.topic in topics]

    def raw_messages(self, topics: Collection[str] | None = None,
                     start_ns: int | None = None) -> Iterator[RawMessage]:
        """Stored messages of ``topics`` (None: all) from log time ``start_ns`` on, as CDR."""
        connections = self._connections(topics)
        if not connections:
            return
        try:
            for conn, t_ns, data in self._reader.messages(connections, start=start_ns):
                yield RawMessage(conn.topic, conn.msgtype, t_ns, bytes(data))
        except _READ_ERRORS as err:
            raise BagError(self.path, f'corrupt storage: {err}{_damage(self.path)}') from err

    def messages(self, topics: Collection[str] | None = None,
                 start_ns: int | None = None) -> Iterator[BagMessage]:
        """Like :meth:`raw_messages`, each message decoded with the definitions stored in the
        bag."""
        for raw in self.raw_messages(topics, start_ns):
            try:
                message = self._reader.deserialize(raw.data, raw.msgtype)
            except _READ_ERRORS as err:
                raise BagError(self.path, f'message on {raw.topic} at {raw.log_time_ns} ns does '
                                          f'not decode as {raw.msgtype}: {err}') from err
            yield BagMessage(raw.topic, raw.msgtype, raw.log_time_ns, message)

    def arrays(self, topic: str, extract: Callable[[Any], Sequence[float]]
               ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """One topic as arrays: log times (N,) ns and ``extract(message)`` stacked (N, k).

        ``extract`` maps a decoded message to k numbers, e.g. ``lambda m: (m.pose.position.x,
        m.pose.position.y, m.pose.position.z)``; every message must give the same k.
        """
        times: list[int] = []
        rows: list[Sequence[float]] = []
        for item in self.messages([topic]):
            times.append(item.log_time_ns)
            rows.append(extract(item.message))
        values = np.asarray(rows, dtype=float)
        if values.ndim == 1:
            values = values.reshape(len(times), -1)
        return np.asarray(times, dtype=np.int64), values

    def verify(self) -> BagCheck:
        """Verify the bag's storage files: every chunk's CRC (or structure) and the
        data-section CRC (:func:`positioning_cell.bag.verify.verify_bag`)."""
        return verify_bag(self.path)

    def close(self) -> None:
        """Release the files (idempotent)."""
        if self._reader.stack is not None:
            self._reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
