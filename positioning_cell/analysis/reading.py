"""Reading a recorded bag for analysis: decoded messages of chosen topics in recorded order,
including from a bag whose recording did not end cleanly.

A readable bag is read with :class:`positioning_cell.bag.BagReader`. A bag it refuses or that
breaks while being read (no metadata.yaml because the recorder was killed, an ``.mcap`` cut
short) is copied to a temporary folder and repaired there with
:func:`positioning_cell.bag.recover_bag` (the readable prefix of every file; the original is
left as it is); :attr:`BagContents.problems` says so. This is the one place that reads bags
for the analysis.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

from positioning_cell.bag import BagError, BagMessage, BagReader, recover_bag
from positioning_cell.bag.recovery import storage_files


@dataclass(frozen=True)
class BagContents:
    """What was read: the wanted messages in recorded (log time) order, every topic of the bag
    with its ROS type and count, the total message count, and the problems found (empty for a
    sound bag)."""

    path: Path
    messages: tuple[BagMessage, ...]
    topics: dict[str, tuple[str, int]]
    message_count: int
    problems: tuple[str, ...]


def _read(path: Path, topics: Collection[str]) -> BagContents:
    with BagReader(path) as reader:
        present = [t for t in topics if t in reader.topics]
        messages = tuple(reader.messages(present)) if present else ()
        info = {t.name: (t.msgtype, t.message_count) for t in reader.topics.values()}
        return BagContents(path, messages, info, reader.message_count, ())


def read_bag(path: str | Path, topics: Collection[str]) -> BagContents:
    """The messages of ``topics`` (those the bag has) from the bag at ``path`` (a rosbag2
    folder or an ``.mcap`` file). Raises BagError when nothing readable is there."""
    path = Path(path)
    if not path.exists():
        raise BagError(path, 'no such file or folder')
    try:
        return _read(path, topics)
    except BagError as err:
        first = err.reason
    files = storage_files(path) if path.is_dir() else [path]
    if not files or any(f.suffix != '.mcap' for f in files):
        raise BagError(path, f'not a bag ({first})')
    with tempfile.TemporaryDirectory(prefix='analyze_bag_') as tmp:
        copy = Path(tmp) / 'bag'
        copy.mkdir()
        for f in files:
            shutil.copyfile(f, copy / f.name)
        try:
            report = recover_bag(copy)
            contents = _read(copy, topics)
        except BagError as err:  # name the user's bag, not the copy
            raise BagError(path, f'not a readable bag: {err.reason} ({first})') from err
    lost = [f'{r.path.name}: truncated, {r.message_count} messages readable'
            for r in report.files if r.status == 'recovered']
    problems = (f'the bag is not complete ({first}); analysed its readable part '
                f'({contents.message_count} messages) from a repaired copy',
                *lost)
    return BagContents(path, contents.messages, contents.topics, contents.message_count,
                       problems)
