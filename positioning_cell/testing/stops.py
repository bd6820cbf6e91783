"""Stopping executables at chosen moments of their start and judging the stop: exit 0, no
traceback or C++ abort in what they printed, and how long the stop took. Used by
test/test_shutdown.py and benchmarks/shutdown.py (plain subprocess and /proc; no rclpy).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from positioning_cell import names
from positioning_cell.config import config_path
from positioning_cell.ros.processes import (
    OWN_PROCESS_GROUP,
    executable,
    stacks_path,
    wait_writing_stacks,
    written_stacks,
)
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag

#: What an unclean stop prints.
CRASH_SIGNS = ('Traceback', 'terminate called', 'Segmentation fault', 'Aborted', 'core dumped',
               '[FATAL]', 'Error occurred at', 'context is invalid')


def catches_signal(pid: int, sig: int) -> bool:
    """Whether process ``pid`` has a handler installed for ``sig`` (``SigCgt`` of
    /proc/<pid>/status; False once it has exited). A node started through
    :mod:`positioning_cell.ros.entry` catches SIGTERM from its first import on."""
    try:
        text = Path(f'/proc/{pid}/status').read_text()
    except OSError:
        return False
    caught = next((line.split()[1] for line in text.splitlines()
                   if line.startswith('SigCgt:')), '0')
    return bool(int(caught, 16) >> (sig - 1) & 1)


def stop_commands(run_dir: Path) -> dict[str, list[str]]:
    """{executable: argv} of every node executable of the package with config/cell.yaml and
    an override in ``run_dir``: the recorder records into ``run_dir/bag``, the player loops a
    one-pose synthetic bag (written there) without waiting for subscribers."""
    run_dir.mkdir(parents=True, exist_ok=True)
    source = run_dir / 'source_bag'
    write_run_bag(source, synthetic_run([[0.0, 0.0, 0.196]], [[0.0, 0.0, 0.0, 1.0]],
                                        modes=('none',), cycles=1))
    override = run_dir / 'stops.yaml'
    override.write_text(
        f'{names.NODE_RECORDER}:\n  ros__parameters:\n    output: {run_dir / "bag"}\n'
        f'{names.NODE_PLAYER}:\n  ros__parameters:\n    bag: {source}\n    loop: true\n'
        '    wait_for_subscribers_s: 0.0\n'
        f'{names.NODE_LIVE_VIEW}:\n  ros__parameters:\n    port: 0\n')  # any free port
    return {node.executable: [executable(node.executable), '--ros-args', '--params-file',
                              str(config_path('cell.yaml')), '--params-file', str(override)]
            for node in names.NODE_EXECUTABLES}


@dataclass(frozen=True)
class Stop:
    """How one process took a signal: ``clean`` (exit 0, nothing of :data:`CRASH_SIGNS`
    printed), the seconds from the signal to its exit, what was wrong, and its native
    stacks when it was still stopping
    :data:`~positioning_cell.ros.processes.NATIVE_STACKS_AFTER_S` after the signal ('' else
    or without gdb)."""

    label: str
    clean: bool
    seconds: float
    problem: str
    stacks: str = ''

    def describe(self) -> str:
        """One line, and the native stacks below it when they were written."""
        line = (f'{self.label}: ' + ('clean' if self.clean else self.problem)
                + f' ({self.seconds:.2f} s)')
        return line + (f'\n{self.stacks}' if self.stacks else '')


def stop_after(commands: Mapping[str, Sequence[str]], env: Mapping[str, str], log_dir: Path,
               sig: int, delay: float, ready: Callable[[str, subprocess.Popen[bytes]], bool]
               | None = None, timeout: float = 30.0) -> list[Stop]:
    """Start every command ({label: argv}) in its own process group, wait for each until it
    catches SIGTERM (its entry point runs) and then ``ready(label, proc)`` if given, then
    ``delay`` s more (the moment of the stop is what the caller varies), send ``sig`` and
    judge the stop. A process still there ``timeout`` s after the signal is killed and
    counted unclean; one still there
    :data:`~positioning_cell.ros.processes.NATIVE_STACKS_AFTER_S` after it has its native
    stacks written to ``log_dir/<label>.stacks.txt`` first, and in its :class:`Stop`."""
    log_dir.mkdir(parents=True, exist_ok=True)
    procs: dict[str, subprocess.Popen[bytes]] = {}
    for label, argv in commands.items():
        with (log_dir / f'{label}.log').open('wb') as log:
            procs[label] = subprocess.Popen(list(argv), stdout=log, stderr=subprocess.STDOUT,
                                            env=dict(env), **OWN_PROCESS_GROUP)
    stops: dict[str, Stop] = {}

    def stop(label: str, proc: subprocess.Popen[bytes]) -> None:
        try:
            deadline = time.monotonic() + 120.0
            while not catches_signal(proc.pid, signal.SIGTERM) and proc.poll() is None:
                if time.monotonic() > deadline:
                    raise TimeoutError(f'{label} never installed its signal handlers')
                time.sleep(0.005)
            while ready is not None and proc.poll() is None and not ready(label, proc):
                if time.monotonic() > deadline:
                    raise TimeoutError(f'{label} never became ready')
                time.sleep(0.02)
            if proc.poll() is not None:
                stops[label] = Stop(label, False, 0.0, f'exited by itself ({proc.returncode})')
                return
            time.sleep(delay)
            sent = time.monotonic()
            os.killpg(proc.pid, sig)
            try:
                code = wait_writing_stacks(proc, sent, timeout, stacks_path(log_dir, label))
                problem = '' if code == 0 else f'exit {code}'
            except subprocess.TimeoutExpired:
                problem = f'still running {timeout:.0f} s after {signal.Signals(sig).name}'
            stops[label] = Stop(label, not problem, time.monotonic() - sent, problem)
        except Exception as err:
            stops[label] = Stop(label, False, 0.0, f'{type(err).__name__}: {err}')
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)  # leftovers of the group

    threads = [threading.Thread(target=stop, args=item) for item in procs.items()]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    out = []
    for label in commands:
        result = stops[label]
        text = (log_dir / f'{label}.log').read_text(errors='replace')
        signs = [s for s in CRASH_SIGNS if s in text]
        if signs:
            problem = ', '.join(filter(None, [result.problem, f'printed {", ".join(signs)}']))
            result = Stop(label, False, result.seconds, problem)
        out.append(dataclasses.replace(
            result, stacks=written_stacks(stacks_path(log_dir, label))))
    return out
