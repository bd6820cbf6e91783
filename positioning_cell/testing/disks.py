"""Failing disks for the recorder's tests: for real, a small tmpfs that fills up (ENOSPC; needs
the right to mount, as root in CI) and a file size limit (RLIMIT_FSIZE: EFBIG past it, for any
user) on a child process; and injected, :class:`FaultyDisk` under the bag writer's files (any
errno at any byte, a per-file limit, a disk that cannot even cut a file back).

``python -m positioning_cell.testing.disks BYTES COMMAND [ARG...]`` runs COMMAND (same process,
``execv``) with every file it writes limited to BYTES and SIGXFSZ ignored, so that a write past
the limit fails with EFBIG instead of killing the process (Python ignores SIGXFSZ anyway).
"""

from __future__ import annotations

import contextlib
import errno
import os
import resource
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from positioning_cell.bag.writer import _CrcRaw


class Patcher(Protocol):
    """What :class:`FaultyDisk` needs of a patcher that undoes itself (pytest's
    ``monkeypatch``; the library does not depend on pytest)."""

    def setattr(self, target: Any, name: str, value: Any) -> None: ...


class MountError(RuntimeError):
    """This process may not mount a filesystem (not root, no CAP_SYS_ADMIN, no ``mount``)."""


@contextlib.contextmanager
def small_filesystem(path: Path, size_bytes: int) -> Iterator[Path]:
    """A tmpfs of ``size_bytes`` mounted at ``path`` (created) while the block runs, unmounted
    after; MountError with the system's reason when it cannot be mounted."""
    path.mkdir(parents=True, exist_ok=True)
    try:
        done = subprocess.run(['mount', '-t', 'tmpfs', '-o', f'size={size_bytes},mode=0755',
                               'tmpfs', str(path)], capture_output=True, text=True,
                              timeout=30, check=False)
    except OSError as err:
        raise MountError(f'cannot run mount: {err}') from err
    if done.returncode != 0:
        raise MountError(f'cannot mount a tmpfs at {path}: '
                         f'{done.stderr.strip() or done.returncode}')
    try:
        yield path
    finally:
        subprocess.run(['umount', '--lazy', str(path)], capture_output=True, timeout=30,
                       check=False)


class FaultyDisk:
    """The disk under the writer's storage files, failing as told (a pytest ``monkeypatch``
    undoes it). Every byte of them goes through ``_CrcRaw.write`` and every cut-back through
    ``_CrcRaw.rewind``; both are patched.
    ``fail(code, after, once)``: the write that would pass ``after`` more bytes (from now, over
    all files) writes up to them (a torn record) and the next one raises ``code``, once (a
    transient fault) or for good; ``limit(size)``: no file grows past ``size`` bytes (EFBIG,
    as RLIMIT_FSIZE does it); ``cut_fails``: cutting a file back fails too (EIO)."""

    def __init__(self, monkeypatch: Patcher) -> None:
        self.budget: int | None = None
        self.code = errno.EIO
        self.once = True
        self.size_limit: int | None = None
        self.cut_fails = False
        self.failures = 0
        from positioning_cell.bag.writer import _CrcRaw  # the wrapper (main) stays light

        real_write, real_rewind = _CrcRaw.write, _CrcRaw.rewind

        def write(raw: _CrcRaw, b: Any, /) -> int:
            size = memoryview(b).nbytes
            room = size
            if self.budget is not None:
                room = min(room, self.budget)
            if self.size_limit is not None:
                room = min(room, self.size_limit - raw.position)
            if room <= 0 < size:
                self.failures += 1
                if self.once and self.budget is not None:
                    self.budget = None
                code = self.code if self.size_limit is None else errno.EFBIG
                raise OSError(code, os.strerror(code))
            n = real_write(raw, memoryview(b).cast('B')[:room])
            if self.budget is not None:
                self.budget -= n
            return n

        def rewind(raw: _CrcRaw, position: int, crc: int) -> None:
            if self.cut_fails:
                raise OSError(errno.EIO, os.strerror(errno.EIO))
            real_rewind(raw, position, crc)

        monkeypatch.setattr(_CrcRaw, 'write', write)
        monkeypatch.setattr(_CrcRaw, 'rewind', rewind)

    def fail(self, code: int, after: int = 0, once: bool = True) -> None:
        """The write past ``after`` more bytes fails with errno ``code`` (``once``: only
        that write)."""
        self.code, self.budget, self.once = code, after, once

    def limit(self, size: int) -> None:
        """No storage file grows past ``size`` bytes (EFBIG)."""
        self.size_limit = size


def limit_file_size(size_bytes: int) -> Callable[[], None]:
    """A ``preexec_fn`` for :class:`subprocess.Popen`: the child's files limited to
    ``size_bytes`` (soft and hard RLIMIT_FSIZE), SIGXFSZ ignored."""
    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (size_bytes, size_bytes))
    return limit


def file_size_limited(size_bytes: int, command: list[str]) -> list[str]:
    """``command`` run with its files limited to ``size_bytes`` (this module's ``__main__``)."""
    return [sys.executable, '-m', __name__, str(size_bytes), *command]


def main(argv: list[str]) -> None:
    """``BYTES COMMAND [ARG...]``: exec COMMAND with its files limited to BYTES."""
    if len(argv) < 2 or not argv[0].isdigit():
        sys.exit('usage: python -m positioning_cell.testing.disks BYTES COMMAND [ARG...]')
    limit_file_size(int(argv[0]))()
    os.execv(argv[1], argv[1:])


if __name__ == '__main__':
    main(sys.argv[1:])
