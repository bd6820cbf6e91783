"""Reading a recorded bag for analysis: decoded messages of chosen topics in recorded order,
including from a bag whose recording did not end cleanly or whose files are damaged.

Every storage file is verified first (:func:`positioning_cell.bag.verify_bag`: MCAP magic, each
chunk's CRC or structure, the data-section CRC). A file that is no MCAP file at all (empty,
too short, wrong magic) holds nothing to analyse: when no file is left, BagError says what
each one is. A sound bag is read with :class:`positioning_cell.bag.BagReader`. A bag with
damage (corrupt chunks, a truncated file), or one the reader refuses (no metadata.yaml because
the recorder was killed), is linked into a temporary folder and repaired there with
:func:`positioning_cell.bag.recover_bag` (the sound chunks of every file, the readable records
of a truncated one; the original is left as it is); :attr:`BagContents.problems` names each
corrupt chunk with the time range lost (UTC and seconds into the bag) and the messages lost
when the index says. This is the one place that reads bags for the analysis.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from positioning_cell.bag import (
    BagError,
    BagMessage,
    BagReader,
    FileCheck,
    FileRecovery,
    recover_bag,
)
from positioning_cell.bag.verify import BagCheck, storage_files, verify_bag


@dataclass(frozen=True)
class BagContents:
    """What was read: the wanted messages in recorded (log time) order, every topic of the bag
    with its ROS type and count, the total message count, the problems found (empty for a
    sound bag) and the verification of its storage files (None when the bag has none to
    verify)."""

    path: Path
    messages: tuple[BagMessage, ...]
    topics: dict[str, tuple[str, int]]
    message_count: int
    problems: tuple[str, ...]
    check: BagCheck | None = None


def _read(path: Path, topics: Collection[str]) -> BagContents:
    with BagReader(path) as reader:
        present = [t for t in topics if t in reader.topics]
        messages = tuple(reader.messages(present)) if present else ()
        info = {t.name: (t.msgtype, t.message_count) for t in reader.topics.values()}
        return BagContents(path, messages, info, reader.message_count, ())


def _place(source: Path, target: Path) -> None:
    """``target`` names ``source`` (a symbolic link; a copy where links are not possible).
    Recovery only ever replaces the names of the folder it repairs, never the files' bytes."""
    try:
        os.symlink(source.resolve(), target)
    except OSError:
        shutil.copyfile(source, target)


def _unusable(path: Path, files: Sequence[FileCheck]) -> BagError:
    what = '; '.join('; '.join(f.problems) if f.path == path
                     else f'{f.path.name}: {"; ".join(f.problems)}' for f in files)
    return BagError(path, f'{what}: nothing to analyse')


def _problems(check: BagCheck, first: str | None, kept: int,
              rewritten: Sequence[FileRecovery]) -> tuple[str, ...]:
    """The problems of a bag read from a repaired copy: what was wrong, what was lost."""
    out: list[str] = []
    damaged = check.damaged
    if damaged or any(f.usable and f.problems for f in check.files):
        counts = [d.message_count for d in damaged]
        lost = (f', {sum(n or 0 for n in counts)} in corrupt chunks lost'
                if damaged and None not in counts else '')
        what = (f'{len(damaged)} corrupt chunk{"s" if len(damaged) > 1 else ""} ('
                + ', '.join(f'{d.file} chunk {d.index}' for d in damaged) + ')'
                if damaged else 'damage outside the chunks')
        out.append(f'the bag is damaged: {what}; analysed its sound part ({kept} messages'
                   f'{lost}) from a repaired copy')
    if first is not None or any(f.usable and not f.complete for f in check.files):
        reason = f' ({first})' if first is not None else ''
        out.append(f'the bag is not complete{reason}; analysed its readable part ({kept} '
                   'messages) from a repaired copy')
    out += [f'{line}: not analysed' if not f.usable else line
            for f in check.files for line in f.lines(check.start_ns)]
    for r in rewritten:
        what = 'truncated' if r.status == 'recovered' else 'repaired'
        out.append(f'{r.path.name}: {what}, {r.message_count} messages readable')
    return tuple(out)


def read_bag(path: str | Path, topics: Collection[str]) -> BagContents:
    """The messages of ``topics`` (those the bag has) from the bag at ``path`` (a rosbag2
    folder or an ``.mcap`` file). Raises BagError when nothing readable is there (no bag, or
    no storage file that is an MCAP file)."""
    path = Path(path)
    if not path.exists():
        raise BagError(path, 'no such file or folder')
    files = storage_files(path) if path.is_dir() else [path]
    mcap = bool(files) and all(f.suffix == '.mcap' for f in files)
    check = verify_bag(path, files) if mcap else None
    usable = [f for f in check.files if f.usable] if check is not None else []
    if check is not None and not usable:
        raise _unusable(path, check.files)
    first: str | None = None
    if check is None or check.sound:
        try:
            contents = _read(path, topics)
        except BagError as err:
            first = err.reason
        else:
            return BagContents(path, contents.messages, contents.topics,
                               contents.message_count, (), check)
        if not mcap:
            raise BagError(path, f'not a bag ({first})')
    assert check is not None
    with tempfile.TemporaryDirectory(prefix='analyze_bag_') as tmp:
        copy = Path(tmp) / 'bag'
        copy.mkdir()
        for f in usable:
            _place(f.path, copy / f.path.name)
        try:
            report = recover_bag(copy, checked=[replace(f, path=copy / f.path.name)
                                                for f in usable])
            contents = _read(copy, topics)
        except BagError as err:  # name the user's bag, not the copy
            raise BagError(path, f'not a readable bag: {err.reason}'
                                 f'{f" ({first})" if first else ""}') from err
    problems = _problems(check, first, contents.message_count,
                         [r for r in report.files if r.status != 'complete'])
    return BagContents(path, contents.messages, contents.topics, contents.message_count,
                       problems, check)
