"""ROS_DOMAIN_ID allocation on one machine: a domain no other run or test holds, locked with
flock on a file per domain, released when the block ends or the process dies."""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from pathlib import Path

from positioning_cell.errors import PositioningError

#: Usable domain IDs with Fast DDS (0-101 and 215-232); 0 is everyone's default, so skipped.
DOMAINS = (*range(1, 102), *range(215, 233))
LOCK_DIR = Path('/tmp/positioning_cell_domains')


class DomainError(PositioningError):
    """Every usable domain ID is held by another process."""


@contextlib.contextmanager
def free_domain(lock_dir: Path = LOCK_DIR) -> Iterator[int]:
    """A ROS_DOMAIN_ID that no other holder on this machine has while the block runs."""
    lock_dir.mkdir(exist_ok=True)
    start = os.getpid() % len(DOMAINS)
    for k in range(len(DOMAINS)):
        domain = DOMAINS[(start + k) % len(DOMAINS)]
        fd = os.open(lock_dir / f'{domain}.lock', os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        try:
            yield domain
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)
        return
    raise DomainError(f'no free ROS domain id (all locked in {lock_dir})')
