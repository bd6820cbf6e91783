"""The bag subpackage's exception types: BagError, and what the MCAP reader
(:class:`positioning_cell.bag.IndexedBag`) raises for a file it cannot read."""

from __future__ import annotations

from pathlib import Path

from positioning_cell.errors import PositioningError


class BagError(PositioningError):
    """A bag cannot be written, read or recovered: ``path`` names it, ``reason`` says why.

    Raised before anything is changed on disk whenever the problem is detectable up front
    (an existing output, a file that is not MCAP, a metadata.yaml that does not parse).
    """

    def __init__(self, path: str | Path, reason: str) -> None:
        super().__init__(f'{path}: {reason}')
        self.path = Path(path)
        self.reason = reason


class IndexedReadError(BagError):
    """The MCAP reader cannot read this storage file as it is (it is truncated or damaged,
    or uses what the reader does not handle); the slow path (verify, recover) can tell more.
    ``path`` is the storage file, ``reason`` what is wrong."""


class UnindexedBagError(IndexedReadError):
    """A storage file has no footer: a recording that did not end cleanly (its last record
    may be cut off; ``recover_bag`` rewrites its readable records)."""


class DamagedBagError(IndexedReadError):
    """A storage file is damaged: a chunk (``chunk``: its number in the file, in file order;
    ``offset``: byte offset of its record) that fails its CRC, does not decompress or does
    not match its index; a summary or data section that fails its CRC; an index that
    contradicts itself; records whose framing is broken. ``chunk`` / ``offset`` are None
    when no chunk is concerned."""

    def __init__(self, path: str | Path, reason: str, chunk: int | None = None,
                 offset: int | None = None) -> None:
        where = f'chunk {chunk} at byte {offset}: ' if chunk is not None else ''
        super().__init__(path, where + reason)
        self.chunk = chunk
        self.offset = offset


class UnsupportedBagError(IndexedReadError):
    """A storage file uses something this reader does not handle (an unknown chunk
    compression, a topic with channels of different types, chunks past 4 GiB)."""
