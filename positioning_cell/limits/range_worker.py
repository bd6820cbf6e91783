"""The live axis-range search (:mod:`.axis_ranges`) in a process of its own, for a node.

The search is a compiled kernel (~1 ms; some 1.6 s as its Python source), and numba costs a
process ~125 MB and half a second to load: the positioner would break its start-up and memory
bounds, and loading numba in one of its threads would hold the interpreter long enough to
starve its heartbeat during a move. So the node starts this worker (``python -m
positioning_cell.limits.range_worker``), which lowers its own priority (nice 10), loads
numba and the kernel from the disk cache, says it is ready and answers searches, one at a
time, over its standard input and output: length-prefixed pickles of (number, model fields,
start pose) → (number, bounds, bindings, margins). It ends when its input closes or its
parent goes, however the node ends (a SIGKILL of the node included); the node's close kills
it.

:meth:`RangeWorker.ranges` starts the worker on its first call (a node that is never asked
for ranges never starts it), never waits for it to load, and waits at most ``answer_timeout``
s for an answer; until the worker is ready (``pending``), when it is late, or when it has
ended, the answer is no ranges and why. A late
answer is recognised by its number and dropped. Started again at most once per
:data:`RESTART_PERIOD_S` after it ends.
"""

from __future__ import annotations

import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from typing import IO, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.limits.axis_ranges import (
    AxisRanges,
    RangeModel,
    assemble,
    search,
    start_pose,
)

FloatArray = NDArray[np.float64]

#: The worker's niceness: its searches and its start yield to the cell's nodes.
NICE = 10
#: Shortest time between two starts of the worker (s).
RESTART_PERIOD_S = 10.0
#: What the worker says once it can answer.
READY = 'ready'
_HEADER = struct.Struct('<I')
_LARGEST_FRAME = 1 << 20


class WorkerError(RuntimeError):
    """The worker's pipe broke, ended, or carried something that is not a frame."""


def _write_frame(stream: IO[bytes], value: object) -> None:
    data = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)) + data)
    stream.flush()


def _read_exact(fd: int, n: int, deadline: float | None) -> bytes:
    """``n`` bytes from the file descriptor ``fd``; TimeoutError at ``deadline`` (monotonic s,
    None: no bound), WorkerError at the end of the stream."""
    out = bytearray()
    while len(out) < n:
        if deadline is not None:
            remaining = max(deadline - time.monotonic(), 0.0)
            if not select.select([fd], [], [], remaining)[0]:
                raise TimeoutError
        chunk = os.read(fd, n - len(out))
        if not chunk:
            raise WorkerError('the stream ended')
        out += chunk
    return bytes(out)


def _read_frame(fd: int, deadline: float | None) -> Any:
    (size,) = _HEADER.unpack(_read_exact(fd, _HEADER.size, deadline))
    if size > _LARGEST_FRAME:
        raise WorkerError(f'a frame of {size} bytes: not this protocol')
    # The worker is this package's own child, over a pipe only the two hold.
    return pickle.loads(_read_exact(fd, size, None))


#: How the answer of a search that came too late, or of a call that found another holding the
#: worker too long, begins: no ranges this time, the worker still searching (a load on the
#: machine; a later call may be answered in time).
LATE_REASON = 'the range search did not answer within'
BUSY_REASON = 'the range search is busy with another request'


class RangeWorker:
    """The search in a child process (module docstring). Thread-safe; :meth:`close` ends it."""

    def __init__(self, answer_timeout: float = 0.1) -> None:
        self.answer_timeout = answer_timeout
        self._lock = threading.Lock()
        self._proc: subprocess.Popen[bytes] | None = None
        self._ready = False
        self._started = -float('inf')
        self._number = 0
        self._status = 'the range search is not started'

    def start(self) -> None:
        """Start the worker if it is not running (and was not started within
        :data:`RESTART_PERIOD_S`); returns at once, the worker loads in the background."""
        with self._lock:
            self._start_locked()

    def _start_locked(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            return
        if time.monotonic() - self._started < RESTART_PERIOD_S:
            return
        self._started = time.monotonic()
        self._ready = False
        self._proc = subprocess.Popen(
            [sys.executable, '-m', __name__, str(os.getpid())], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, bufsize=0, close_fds=True)
        self._status = 'the range search is starting (its process loads the compiled kernel)'

    def ranges(self, model: RangeModel, user_pose6: ArrayLike) -> AxisRanges:
        """The axis ranges of one user pose6 (6,) m, rad, searched by the worker; none, with the
        reason, while it starts, when another request holds it or its answer comes later than
        ``answer_timeout`` s after this call (the whole call is bounded by it: a node's service
        thread never waits longer), or when it has ended. InputError for a pose that is not 6
        finite numbers."""
        start = start_pose(user_pose6)
        deadline = time.monotonic() + self.answer_timeout
        if not self._lock.acquire(timeout=self.answer_timeout):  # a caller never queues long
            return AxisRanges.unknown(f'{BUSY_REASON} for longer than '
                                      f'{self.answer_timeout:g} s')
        try:
            return self._ranges_locked(model, start, deadline)
        finally:
            self._lock.release()

    def _ranges_locked(self, model: RangeModel, start: FloatArray,
                       deadline: float) -> AxisRanges:
        """:meth:`ranges` with the lock held, the answer awaited until ``deadline``."""
        self._start_locked()
        proc = self._proc
        if proc is None or proc.stdin is None or proc.stdout is None:
            return AxisRanges.unknown(self._status, pending=self._pending())
        try:
            if not self._ready:  # said yet? (not waited for: a caller never waits on the load)
                if _read_frame(proc.stdout.fileno(), time.monotonic()) != READY:
                    raise WorkerError('it did not say it was ready')
                self._ready = True
            self._number += 1
            _write_frame(proc.stdin, (self._number, model.fields(), start))
            while True:
                number, *found = _read_frame(proc.stdout.fileno(), deadline)
                if number == self._number:
                    return assemble(start, *found)
        except TimeoutError:
            if not self._ready:
                return AxisRanges.unknown(self._status, pending=True)
            return AxisRanges.unknown(f'{LATE_REASON} {self.answer_timeout:g} s')
        except (WorkerError, OSError, pickle.UnpicklingError, ValueError) as err:
            code = proc.poll()
            self._status = (f'the range search process ended (exit code {code})'
                            if code is not None else f'the range search failed: {err}')
            proc.kill()
            return AxisRanges.unknown(self._status)

    def _pending(self) -> bool:
        return self._proc is not None and self._proc.poll() is None and not self._ready

    def close(self) -> None:
        """End the worker now (it holds nothing to save: killed, and waited for)."""
        with self._lock:
            proc, self._proc = self._proc, None
        if proc is None:
            return
        proc.kill()
        proc.wait()
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                stream.close()


def _end_with_parent(parent: int) -> None:
    """End this process once its parent ``parent`` (the pid its starter passed) has gone
    (reparented), also while it loads numba and reads nothing: checked every 0.2 s. The pid comes
    from the starter, not from ``os.getppid()`` here: a parent killed before this interpreter got
    as far would otherwise be missed, and the worker would load numba for nobody."""
    while os.getppid() == parent:
        time.sleep(0.2)
    os._exit(0)


def main() -> int:
    """The worker: nice, the kernel loaded, READY, then one answer per request until its input
    ends. Its standard output carries only frames (anything printed goes to standard error)."""
    # a SIGINT to the node's process group (its stop) ends the worker at once, without the
    # KeyboardInterrupt traceback it printed into the node's log while it loaded numba
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    parent = int(sys.argv[1]) if len(sys.argv) > 1 else os.getppid()
    threading.Thread(target=_end_with_parent, args=(parent,), daemon=True).start()
    os.nice(NICE)
    answers = os.fdopen(os.dup(sys.stdout.fileno()), 'wb')
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    from positioning_cell.limits import axis_ranges

    axis_ranges.warm_up()
    _write_frame(answers, READY)
    requests = sys.stdin.fileno()
    while True:
        try:
            number, fields, start = _read_frame(requests, None)
        except WorkerError:
            # The input ended: the parent closed it or is gone. End now, skipping the
            # interpreter's finalization (numba and llvmlite torn down, nothing of ours to
            # flush: each answer is flushed as written), which at this process's niceness on a
            # loaded machine took 8.6-9.0 s after a parent's SIGKILL (ad hoc, six busy loops
            # beside it), while the watch of the parent cannot end a finalizing interpreter.
            os._exit(0)
        _write_frame(answers, (number, *search(tuple(np.asarray(f) for f in fields), start)))


if __name__ == '__main__':
    raise SystemExit(main())
