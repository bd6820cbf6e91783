"""A node whose stop hangs is ended at the stop's deadline (positioning_cell.ros.entry): its
threads' stacks in its stderr, where it hung named, exit status 1. A stop that completes in
time keeps its own exit status and prints no stacks."""

from __future__ import annotations

import signal
import subprocess
import sys

#: The child: the node entry's stop handling with a given deadline, then a main thread that
#: never returns (``hang_here``) or one that ends the process once the stop flag is up.
CHILD = """
import threading, time
from positioning_cell.ros import entry
entry.STOP_DEADLINE_S = {deadline}
entry.hold_stops()
def hang_here():
    threading.Event().wait()
def end_at_stop():
    while not entry.stop_requested():
        time.sleep(0.01)
    entry.end_process(0)
print('ready', flush=True)
{call}()
"""


def _stopped(call: str, deadline_s: float) -> subprocess.CompletedProcess[str]:
    """Run the child, SIGINT it once it is ready, wait for its end (a hang fails at 60 s)."""
    proc = subprocess.Popen([sys.executable, '-c', CHILD.format(call=call, deadline=deadline_s)],
                            text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline() == 'ready\n'
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def test_a_stop_that_hangs_is_ended_with_the_stacks_at_its_deadline() -> None:
    result = _stopped('hang_here', 0.5)
    assert result.returncode == 1, result
    assert 'Timeout' in result.stderr and 'hang_here' in result.stderr, result.stderr


def test_a_stop_that_ends_in_time_keeps_its_status_and_prints_no_stacks() -> None:
    result = _stopped('end_at_stop', 30.0)
    assert result.returncode == 0, result
    assert 'Timeout' not in result.stderr, result.stderr
