"""The axis-range search in its own process (positioning_cell.limits.range_worker): the same
ranges as the search in this process, no ranges (and why) while it starts or after it has
ended, started again, and gone with its parent however the parent ends."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator

import numpy as np
import pytest

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.limits import range_worker
from positioning_cell.limits.axis_ranges import RangeModel
from positioning_cell.limits.boxes import LimitLayers
from positioning_cell.limits.range_worker import RangeWorker
from positioning_cell.polling import wait_until

pytestmark = pytest.mark.slow

MECH = Mechanism.default()
MODEL = RangeModel.of(MECH, LimitLayers.for_mechanism(MECH), CoordinateSystems())
#: Long enough for the worker to load numba on a loaded machine, and bounded.
READY_TIMEOUT_S = 60.0


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (ended, not yet reaped by its new parent) counts as gone
    with open(f'/proc/{pid}/stat') as stat:
        return stat.read().split(') ')[-1][0] != 'Z'


@pytest.fixture
def worker() -> Iterator[RangeWorker]:
    started = RangeWorker(answer_timeout=2.0)
    yield started
    started.close()


def test_the_worker_answers_what_the_search_here_finds(worker: RangeWorker) -> None:
    assert worker._proc is None  # started by the first search, not before
    first = worker.ranges(MODEL, np.zeros(6))
    assert first.valid or (first.pending and 'starting' in first.reason), first
    wait_until(lambda: worker.ranges(MODEL, np.zeros(6)).valid, READY_TIMEOUT_S,
               'the worker to answer')
    rng = np.random.default_rng(5)
    poses = [np.zeros(6), *(rng.uniform(-1.0, 1.0, 6) * [0.01, 0.01, 0.008, 0.05, 0.05, 0.1]
                            for _ in range(12)),
             np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])]  # outside the stroke: no ranges
    for pose in poses:
        assert worker.ranges(MODEL, pose) == MODEL.ranges(pose), pose
    with pytest.raises(InputError, match='finite'):
        worker.ranges(MODEL, [0.0, np.nan, 0.0, 0.0, 0.0, 0.0])


def test_an_ended_worker_is_said_and_started_again(worker: RangeWorker,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    wait_until(lambda: worker.ranges(MODEL, np.zeros(6)).valid, READY_TIMEOUT_S,
               'the worker to answer')
    proc = worker._proc
    assert proc is not None
    proc.kill()
    proc.wait()
    monkeypatch.setattr(range_worker, 'RESTART_PERIOD_S', 3600.0)
    ended = worker.ranges(MODEL, np.zeros(6))
    assert not ended.valid and not ended.pending, ended
    assert 'ended (exit code -9)' in ended.reason, ended
    assert not worker.ranges(MODEL, np.zeros(6)).valid  # not restarted within the period
    monkeypatch.setattr(range_worker, 'RESTART_PERIOD_S', 0.0)
    wait_until(lambda: worker.ranges(MODEL, np.zeros(6)).valid, READY_TIMEOUT_S,
               'the restarted worker to answer')
    assert worker._proc is not None and worker._proc.pid != proc.pid


@pytest.mark.parametrize('ready', [False, True])
def test_the_worker_ends_with_its_parent_even_while_it_loads(ready: bool) -> None:
    """A parent SIGKILLed (no close, no atexit) takes the worker with it, also before the worker
    has loaded numba (when it reads nothing)."""
    script = textwrap.dedent(f"""
        import sys, numpy as np
        from positioning_cell.core.mechanism import Mechanism
        from positioning_cell.frames.systems import CoordinateSystems
        from positioning_cell.limits.axis_ranges import RangeModel
        from positioning_cell.limits.boxes import LimitLayers
        from positioning_cell.limits.range_worker import RangeWorker
        from positioning_cell.polling import wait_until
        m = Mechanism.default()
        model = RangeModel.of(m, LimitLayers.for_mechanism(m), CoordinateSystems())
        w = RangeWorker(answer_timeout=1.0)
        w.start()
        if {ready}:
            wait_until(lambda: w.ranges(model, np.zeros(6)).valid, 60.0, 'ready')
        print(w._proc.pid, flush=True)
        sys.stdin.read()
    """)
    parent = subprocess.Popen([sys.executable, '-c', script], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        pid = int(parent.stdout.readline())
        assert _alive(pid)
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
    wait_until(lambda: not _alive(pid), 10.0, f'the worker {pid} to end with its parent')


def test_a_parent_gone_before_the_worker_starts_is_seen() -> None:
    """The race behind stop 53's CI failure: the parent killed before the worker's interpreter
    reached ``main``. The worker checks the pid its starter passed, not whichever process has
    adopted it by then, so it ends at its first check instead of loading numba for nobody and
    waiting on an input nobody closes (it did, with ``os.getppid()`` taken in ``main``)."""
    gone = subprocess.Popen([sys.executable, '-c', 'pass'])
    gone.wait()
    worker = subprocess.Popen([sys.executable, '-m', range_worker.__name__, str(gone.pid)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert worker.wait(timeout=READY_TIMEOUT_S) == 0
        assert worker.stdout is not None and worker.stdout.read() == b''  # never said READY
    finally:
        worker.kill()
        worker.wait()
        for stream in (worker.stdin, worker.stdout):
            assert stream is not None
            stream.close()


def test_a_sigint_ends_the_worker_without_a_traceback() -> None:
    """The node's stop (SIGINT to its process group) ends the worker quietly: it printed a
    KeyboardInterrupt traceback into the node's log."""
    worker = subprocess.Popen([sys.executable, '-m', range_worker.__name__, str(os.getpid())],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE)
    try:
        assert worker.stdout is not None
        assert worker.stdout.read(1)  # its READY frame has begun: it waits for requests
        worker.send_signal(signal.SIGINT)
        _, err = worker.communicate(timeout=READY_TIMEOUT_S)
        assert worker.returncode == -signal.SIGINT
        assert b'Traceback' not in err, err.decode(errors='replace')
    finally:
        worker.kill()
        worker.communicate()


def test_a_caller_never_waits_longer_than_the_answer_timeout() -> None:
    """Another request holding the worker: the call gives up at its timeout and says so."""
    worker = RangeWorker(answer_timeout=0.05)
    try:
        with worker._lock:
            t0 = time.monotonic()
            busy = worker.ranges(MODEL, np.zeros(6))
            waited = time.monotonic() - t0
        assert not busy.valid and not busy.pending and 'busy' in busy.reason, busy
        assert waited < 1.0  # bounded (0.05 s asked; generous for a loaded machine)
        assert worker._proc is None  # nothing started for a call that gave up
    finally:
        worker.close()
