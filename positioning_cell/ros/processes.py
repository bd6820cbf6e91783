"""The cell's executables as processes: their environment (a private ROS domain, loopback
only), where they are installed, and a group of them started and stopped together. Plain
Python (subprocess); the rclpy client of the running cell is :mod:`positioning_cell.ros.client`.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import yaml

#: How long after its stop signal a process still running has its native stacks written beside
#: its log (:func:`native_stacks`, with gdb where it is installed): before the node's own stop
#: deadline (``positioning_cell.ros.entry.STOP_DEADLINE_S``, 10 s) ends it with its Python
#: stacks alone, which end at the call into the library where a stop hung (Fast DDS's
#: destruction: rclpy's ``destroy_node`` or a collection, twice in CI, December 2026).
NATIVE_STACKS_AFTER_S = 7.0

#: The ROS wheels' bootstrap marker: set in a Python process once its ``.pth`` has re-executed
#: it with the venv's library path (platform.md).
BOOTSTRAP_MARKER = '_ROS_WHEELS_BOOTSTRAP_COMPLETE'


def cell_environment(domain: int, base: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment of a cell process: ``base`` (default: this process's) on ROS domain
    ``domain``, on this machine's loopback only (:func:`loopback_only`). The wheels' bootstrap
    marker is removed so the child sets its own library path (platform.md); a child that is
    this interpreter's own is given it back by :func:`bootstrapped_as_this`."""
    env = dict(os.environ if base is None else base, ROS_DOMAIN_ID=str(domain),
               PYTHONUNBUFFERED='1')
    loopback_only(env)
    env.pop(BOOTSTRAP_MARKER, None)
    return env


def bootstrapped_as_this(env: Mapping[str, str], program: str) -> dict[str, str]:
    """``env`` for running ``program``: when it is one of this interpreter's own executables
    (beside ``sys.executable``: its venv's python or console scripts), this process was
    bootstrapped and ``env`` keeps its library path as it is, with this process's bootstrap
    marker, so that the child does not re-execute itself to compute the same path again (one
    interpreter start less: ~0.03 s and ~0.03 CPU-s of every node the cell starts, ad hoc).
    Anything else gets ``env`` unchanged: another Python that inherited the marker would run
    without its own libraries (platform.md), and a library path the caller changed is set up
    by the child's own bootstrap, as before."""
    out = dict(env)
    marker, path = os.environ.get(BOOTSTRAP_MARKER), os.environ.get('LD_LIBRARY_PATH')
    if (marker and path and env.get('LD_LIBRARY_PATH') == path
            and Path(program).parent == Path(sys.executable).parent):
        out[BOOTSTRAP_MARKER] = marker
    return out


def loopback_only(env: dict[str, str]) -> None:
    """Fast DDS on loopback only, unless ``env`` names its own Fast DDS profile.

    Without one: the shipped ``config/fastdds_loopback.xml`` (UDPv4 on 127.0.0.1 and shared
    memory, unicast discovery on 127.0.0.1) in FASTRTPS_DEFAULT_PROFILES_FILE, the variable Fast
    DDS 2.14 (Jazzy) reads, and discovery left to it: ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT,
    because with LOCALHOST Jazzy's rmw_fastrtps adds a UDP transport of its own that binds
    0.0.0.0 and every interface (ROS_LOCALHOST_ONLY=1 would mean LOCALHOST too). With the
    caller's own profile (a deliberate choice, e.g. a multi-machine cell), the caller's range,
    by default LOCALHOST."""
    from positioning_cell import files
    from positioning_cell.config import config_path
    from positioning_cell.errors import ConfigError

    shipped = config_path('fastdds_loopback.xml')
    own = env.get('FASTRTPS_DEFAULT_PROFILES_FILE', '')
    try:
        ours = not own or (files.read_bytes(own, files.FAST_DDS_PROFILE)
                           == files.read_bytes(shipped, files.FAST_DDS_PROFILE))
    except ConfigError:  # the caller's missing or odd file: theirs to fix (Fast DDS logs it)
        ours = False
    if not ours:
        env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        return
    env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(shipped)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SYSTEM_DEFAULT'
    env.pop('ROS_LOCALHOST_ONLY', None)


def use_loopback() -> None:
    """This process's own environment as the cell's processes get it (:func:`loopback_only`):
    for a command line's client, before its ROS context is initialised."""
    env = dict(os.environ)
    loopback_only(env)
    for key in set(os.environ) - set(env):
        del os.environ[key]
    os.environ.update(env)


#: How the cell starts each of its processes: in a process group of its own (a signal to the
#: group reaches the node and whatever it started; a terminal's Ctrl-C reaches only the command
#: that started them, which stops them in order), but in the starter's session. A session of
#: its own (``start_new_session``) is a scheduling group of its own where the kernel groups
#: processes by session (``kernel.sched_autogroup_enabled``, on by default). Measured on the
#: 2-core VM (Linux 6.18), `run_cell --cell config/three_positioners.yaml` with a session per
#: process: in each of six runs one set's container went 0.5-1.7 s without any CPU while its
#: threads were runnable and the other sets ran, its drives stopped for a positioner gone
#: silent, and moves failed. In one session (or with the autogroups off): no gap of 0.4 s in
#: two whole runs, all 15 moves done (docs/howto/coordinated.md). Python 3.10's subprocess
#: cannot start a child in a group of its own but by a ``preexec_fn`` (unsafe beside
#: threads): there, a session of its own, as before.
OWN_PROCESS_GROUP: dict[str, Any] = (
    {'process_group': 0} if sys.version_info >= (3, 11) else {'start_new_session': True})


def native_stacks(pid: int, timeout: float = 20.0) -> str | None:
    """Every thread's native stack of process ``pid`` as gdb prints it (``thread apply all
    bt``, attached and detached again), or None without gdb or when it could not attach."""
    gdb = shutil.which('gdb')
    if gdb is None:
        return None
    try:
        ran = subprocess.run([gdb, '-p', str(pid), '-batch', '-nx', '-ex', 'thread apply all bt'],
                             capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return ran.stdout if 'Thread ' in ran.stdout else None


def stacks_path(log_dir: Path, label: str) -> Path:
    """Where :func:`wait_writing_stacks` writes the native stacks of process ``label``: beside
    its log ``log_dir/<label>.log``."""
    return log_dir / f'{label}.stacks.txt'


def written_stacks(path: Path) -> str:
    """The native stacks written to ``path`` (:func:`wait_writing_stacks`), or ''."""
    return path.read_text(errors='replace') if path.exists() else ''


def wait_writing_stacks(proc: subprocess.Popen[bytes], signalled: float, grace: float,
                        path: Path) -> int:
    """``proc``'s exit code once it ends within ``grace`` s of ``signalled`` (a
    ``time.monotonic()``), TimeoutExpired if it does not. Still running
    :data:`NATIVE_STACKS_AFTER_S` after ``signalled`` (when that is within ``grace``), it has
    its native stacks (:func:`native_stacks`) written to ``path`` first."""
    end = signalled + grace
    stacks_at = signalled + NATIVE_STACKS_AFTER_S
    if stacks_at < end:
        try:
            return proc.wait(timeout=max(stacks_at - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            stacks = native_stacks(proc.pid)
            if stacks is not None:
                path.write_text(stacks)
    return proc.wait(timeout=max(end - time.monotonic(), 0.0))


def executable(name: str) -> str:
    """Path of one of the package's console scripts: beside this interpreter first (a venv),
    else on PATH; FileNotFoundError if it is not installed."""
    found = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if found is None:
        raise FileNotFoundError(f'{name} is not installed (run `make setup`)')
    return found


class Processes:
    """Processes started in environment ``env``, each in its own process group, output in
    ``log_dir/<label>.log``; :meth:`stop` ends them (SIGINT, SIGKILL after a grace period)."""

    def __init__(self, env: Mapping[str, str], log_dir: Path) -> None:
        self.env = dict(env)
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self._logs: dict[str, IO[bytes]] = {}

    def start(self, exe: str, *ros_args: str, params: Sequence[Path] = (),
              overrides: Mapping[str, Mapping[str, Any]] | None = None,
              label: str | None = None,
              extra_args: Sequence[str] = ()) -> subprocess.Popen[bytes]:
        """Start ``exe extra_args --ros-args --params-file P ... ros_args``. ``overrides``
        ({node name: {nested params}}) go in one more params file after ``params`` (a later
        file beats an earlier one, and a node's section beats a plain ``-p``)."""
        label = label or exe
        program = executable(exe)
        args = [program, *extra_args, '--ros-args']
        files = list(params)
        if overrides:
            extra = self.log_dir / f'{label}.overrides.yaml'
            extra.write_text(yaml.safe_dump(
                {node: {'ros__parameters': dict(v)} for node, v in overrides.items()}))
            files.append(extra)
        for path in files:
            args += ['--params-file', str(path)]
        args += list(ros_args)
        log = (self.log_dir / f'{label}.log').open('wb')
        self._logs[label] = log
        self.procs[label] = subprocess.Popen(
            args, stdout=log, stderr=subprocess.STDOUT,
            env=bootstrapped_as_this(self.env, program), **OWN_PROCESS_GROUP)
        return self.procs[label]

    def log(self, label: str) -> str:
        """What a process printed so far."""
        path = self.log_dir / f'{label}.log'
        return path.read_text(errors='replace') if path.exists() else ''

    def dead(self) -> list[str]:
        """Labels of the processes that have exited."""
        return [label for label, p in self.procs.items() if p.poll() is not None]

    def stop(self, label: str | None = None, sig: int = signal.SIGINT,
             grace: float = 20.0) -> dict[str, int]:
        """Send ``sig`` to the process group of ``label`` (default: all), wait up to ``grace``
        s, SIGKILL what is left; the exit codes. A process still running
        :data:`NATIVE_STACKS_AFTER_S` after the signal has its native stacks written to
        ``<label>.stacks.txt`` beside its log (:meth:`stacks`) first."""
        labels = [label] if label else list(self.procs)
        for name in labels:
            proc = self.procs[name]
            if proc.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, sig)
        signalled = time.monotonic()
        codes = {}
        for name in labels:
            proc = self.procs[name]
            try:
                codes[name] = self._wait(name, proc, signalled, grace)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                codes[name] = proc.wait()
            with contextlib.suppress(ProcessLookupError):  # leftovers of the group
                os.killpg(proc.pid, signal.SIGKILL)
            log = self._logs.pop(name, None)
            if log is not None:
                log.close()
        return codes

    def _wait(self, label: str, proc: subprocess.Popen[bytes], signalled: float,
              grace: float) -> int:
        """``proc``'s exit code (:func:`wait_writing_stacks` to ``<label>.stacks.txt``)."""
        return wait_writing_stacks(proc, signalled, grace, stacks_path(self.log_dir, label))

    def stacks(self, label: str) -> str:
        """The native stacks written of ``label`` as it did not stop (:meth:`stop`), or ''."""
        return written_stacks(stacks_path(self.log_dir, label))

    def __enter__(self) -> Processes:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
