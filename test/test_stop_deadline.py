"""A node whose stop hangs is ended at the stop's deadline (positioning_cell.ros.entry): its
threads' stacks in its stderr, where it hung named, exit status 1. A stop that completes in
time keeps its own exit status and prints no stacks. And a process a stop waits for long has
its native stacks written first (positioning_cell.ros.processes, and the shutdown sweep's
positioning_cell.testing.stops)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from positioning_cell.ros import processes
from positioning_cell.testing.stops import stop_after

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


#: A process asleep in the C library whose SIGINT is ignored (it ends by itself, exit 0,
#: ``seconds`` later) or, with no seconds, ends it at once (Python's default action: an
#: xdist worker leaves SIGINT ignored in its children).
STOPPED_BY_SIGINT = """
import signal, time
signal.signal(signal.SIGINT, signal.SIG_IGN if {seconds} else signal.SIG_DFL)
print('ready', flush=True)
time.sleep({seconds} or 60)
"""


@pytest.mark.skipif(shutil.which('gdb') is None, reason='needs gdb')
def test_a_process_still_stopping_has_its_native_stacks_written_before_its_deadline(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Processes.stop: a process running NATIVE_STACKS_AFTER_S after the signal has its
    native stacks beside its log (where a stop hung inside a library), then is waited for as
    before; one that stops at once has none written."""
    monkeypatch.setattr(processes, 'NATIVE_STACKS_AFTER_S', 0.5)
    procs = processes.Processes({}, tmp_path)
    for label, seconds in (('slow', 4.0), ('prompt', 0.0)):
        procs.procs[label] = subprocess.Popen(
            [sys.executable, '-c', STOPPED_BY_SIGINT.format(seconds=seconds)],
            stdout=subprocess.PIPE, text=True, **processes.OWN_PROCESS_GROUP)
        stdout = procs.procs[label].stdout
        assert stdout is not None and stdout.readline() == 'ready\n'
    codes = procs.stop(grace=30.0)
    assert codes == {'slow': 0, 'prompt': -signal.SIGINT}, codes
    stacks = procs.stacks('slow')
    assert 'Thread 1' in stacks and 'sleep' in stacks, stacks
    assert procs.stacks('prompt') == ''


#: A process that catches SIGTERM (as a node's entry point does): with ``seconds``, it lets the
#: signal pass and ends by itself (exit 0) that long after its start; with none, it ends at once,
#: exit 0.
TERM_CAUGHT = """
import signal, sys, time
signal.signal(signal.SIGTERM, (lambda *_: None) if {seconds} else (lambda *_: sys.exit(0)))
time.sleep({seconds} or 60)
"""


@pytest.mark.skipif(shutil.which('gdb') is None, reason='needs gdb')
def test_a_stop_sweep_reports_the_native_stacks_of_a_process_still_stopping(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """stops.stop_after (test_shutdown's sweep) as Processes.stop: a process running
    NATIVE_STACKS_AFTER_S after the signal has its native stacks written beside its log and
    in its Stop, so that a failed stop says where it hung; one that stops at once has none."""
    monkeypatch.setattr(processes, 'NATIVE_STACKS_AFTER_S', 0.5)
    commands = {label: [sys.executable, '-c', TERM_CAUGHT.format(seconds=seconds)]
                for label, seconds in (('slow', 5.0), ('prompt', 0.0))}
    stops = {s.label: s for s in stop_after(commands, os.environ, tmp_path, signal.SIGTERM, 0.0,
                                            timeout=30.0)}
    assert stops['slow'].clean and stops['prompt'].clean, stops
    assert 'Thread 1' in stops['slow'].stacks and 'sleep' in stops['slow'].stacks, stops
    assert stops['slow'].stacks in stops['slow'].describe()
    assert (tmp_path / 'slow.stacks.txt').read_text() == stops['slow'].stacks
    assert stops['prompt'].stacks == '' and not (tmp_path / 'prompt.stacks.txt').exists()
