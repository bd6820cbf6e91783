"""Opening a recorded bag for reading, whatever its storage: MCAP files (any layout) through
:class:`positioning_cell.bag.IndexedBag`, a rosbag2 bag stored otherwise (sqlite3) through
rosbags (:class:`positioning_cell.bag.BagReader`). Both give the same :class:`MessageSource`:
topics, log-time range, and the messages raw or decoded, in rosbags' order.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator
from pathlib import Path
from types import TracebackType
from typing import Protocol

from positioning_cell.bag.errors import BagError
from positioning_cell.bag.indexed import IndexedBag
from positioning_cell.bag.reader import BagMessage, BagReader, RawMessage, TopicInfo
from positioning_cell.bag.verify import storage_files


class MessageSource(Protocol):
    """An open bag: its path, topics, message count and log-time range (ns since the epoch;
    0 when empty), its messages (those of ``topics``, None: all, from log time ``start_ns``
    on) raw or decoded; a context manager."""

    path: Path
    topics: dict[str, TopicInfo]

    @property
    def message_count(self) -> int: ...

    @property
    def start_ns(self) -> int: ...

    @property
    def end_ns(self) -> int: ...

    def raw_messages(self, topics: Collection[str] | None = None,
                     start_ns: int | None = None) -> Iterator[RawMessage]: ...

    def messages(self, topics: Collection[str] | None = None,
                 start_ns: int | None = None) -> Iterator[BagMessage]: ...

    def close(self) -> None: ...

    def __enter__(self) -> MessageSource: ...

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...


def mcap_files(path: Path) -> list[Path] | None:
    """The ``.mcap`` storage files of the bag at ``path`` (a rosbag2 folder in split order,
    or one ``.mcap`` file); None when it is stored otherwise (no ``.mcap`` file in the
    folder, or a single file of another kind)."""
    files = storage_files(path) if path.is_dir() else [path]
    return files if files and all(f.suffix == '.mcap' for f in files) else None


def open_bag(path: str | Path) -> MessageSource:
    """The bag at ``path`` open for reading (module docstring). BagError if there is no such
    path, or it cannot be read as it is (not a bag; a recording that did not end cleanly or
    a damaged file: ``recover_bag`` rewrites what is readable)."""
    path = Path(path)
    if not path.exists():
        raise BagError(path, 'does not exist')
    return IndexedBag(path) if mcap_files(path) is not None else BagReader(path)
