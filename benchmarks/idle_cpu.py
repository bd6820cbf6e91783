"""CPU cost and memory of the cell's nodes at rest and while moving, and the leg driver's
publish rate.

Starts kinematics_node (positioner), leg_driver_node, pose_measurement_node and
accuracy_monitor_node as separate processes with config/cell.yaml on a free ROS domain, waits
until the cell is up, then measures two windows of --seconds each: at rest (the configuration
as shipped), and while the positioner moves back to back between poses within 4 mm of home
(compensation.mode set to 'none' first, to keep the moves short). For each window: CPU seconds
per wall second of each node (utime + stime of all its threads, /proc/<pid>/stat) and their
total, and the rate and p99 interval of /legs/joint_states from its header stamps (the driver's
own clock, so a slow subscriber is not blamed on the driver). After both windows: each
node's peak and current resident set (VmHWM, VmRSS of /proc/<pid>/status) and whether it
loaded numba (it runs compiled kernels: numba is loaded only by such a node, while it is
built; positioning_cell.core.compiled).

The same run measures a baseline: a bare rclpy node (parameter services, no callbacks of its
own) started the same way, the floor under every node's figure.

With --one-process, the same run then starts the same four nodes composed in one process
(cell_container, on a domain of its own, after the separate cell has stopped) and measures it
the same way, then compares the two: CPU at rest and moving, peak and current RSS, and the
proportional set (PSS, /proc/<pid>/smaps_rollup: the pages shared between the separate processes
counted once in all, which the sum of their RSS counts once per process), the driver's rate
and p99 interval.

Run: .venv/bin/python benchmarks/idle_cpu.py [--seconds S] [--one-process]
Targets (issue): the idle cell <= 0.4 core in total; the driver publishes at >= 95 % of its
nominal rate with a p99 interval <= 2 periods; memory (issue 24): each node's peak RSS <= 2x
the bare node's unless it runs compiled kernels (then <= 160 MB), the nodes together <= 700
MB. Prints what it measured and whether each target
is met; exits non-zero only if the cell did not come up or could not be measured.
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from sensor_msgs.msg import JointState

import positioning_cell
from positioning_cell import names
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.motion.settings import COMPENSATION_MODE
from positioning_cell.parameters import parse
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.domains import free_domain
from positioning_cell.ros.processes import Processes, cell_environment
from positioning_cell.ros.qos import STREAM_QOS
from positioning_cell.sim.drives import DriverSettings

CELL_YAML = config_path('cell.yaml')
#: Executable -> node name, in start order.
NODES = {node.executable: node.name for node in names.CELL_NODES}
#: The baseline's label, and the baseline: a bare node, started as a process like the others.
BARE = 'bare_node'
BARE_NODE = ('import rclpy, rclpy.node\n'
             'rclpy.init()\n'
             'node = rclpy.node.Node("bare_node")\n'
             'try:\n'
             '    rclpy.spin(node)\n'
             'except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):\n'
             '    pass\n')
IDLE_TARGET = 0.4        # cores, the idle cell in total
NODE_FACTOR_TARGET = 2.0  # a node that runs no compiled kernel: peak RSS <= this x a bare node's
KERNEL_NODE_TARGET_MB = 160.0  # MB, a node that runs compiled kernels
CELL_TARGET_MB = 700.0   # MB, the cell's nodes together
MIB_MB = 1.048576        # MB per MiB
RATE_TARGET = 0.95       # fraction of the nominal publish rate
P99_TARGET = 2.0         # periods
START_TIMEOUT = 90.0     # s, a first start compiles the numba kernels of the kernel nodes
MOVE_TIMEOUT = 30.0      # s, one move from command to settled
CENTRE = np.array([0.0, 0.0, 0.196])  # m, near home (0, 0, 0.19596)
OFFSETS = np.array([[4.0, 0.0, 0.0], [0.0, 4.0, -2.0], [-4.0, 0.0, 2.0], [0.0, -4.0, 0.0]]) * 1e-3
IDENTITY = (0.0, 0.0, 0.0, 1.0)
CLOCK_TICKS = os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid: int) -> float:
    """utime + stime of every thread of a process so far, s."""
    # Fields after the parenthesised command name: state is field 3, utime 14, stime 15.
    fields = Path(f'/proc/{pid}/stat').read_text().rpartition(')')[2].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


@dataclass(frozen=True)
class DriverRate:
    """/legs/joint_states in one window, from the header stamps."""

    messages: int
    rate: float          # Hz: intervals / stamp span
    p99: float           # s
    longest: float       # s
    repeated: int        # intervals <= 0 (a stamp equal to or before the previous one)

    @classmethod
    def from_stamps(cls, stamps_ns: list[int]) -> DriverRate:
        if len(stamps_ns) < 2:
            return cls(len(stamps_ns), float('nan'), float('nan'), float('nan'), 0)
        t = np.asarray(stamps_ns, dtype=np.int64)
        dt = np.diff(t) * 1e-9
        return cls(len(t), len(dt) / ((t[-1] - t[0]) * 1e-9), float(np.percentile(dt, 99)),
                   float(dt.max()), int(np.count_nonzero(dt <= 0)))


@dataclass(frozen=True)
class Window:
    """What one measurement window gave."""

    cpu: dict[str, float]    # node (and 'bare_node') -> CPU s per wall s
    own: float               # the benchmark process itself, CPU s per wall s
    driver: DriverRate
    moves: int = 0           # moves settled inside the window

    @property
    def total(self) -> float:
        """The cell: its four nodes, or the one process hosting them."""
        return sum(v for k, v in self.cpu.items() if k != BARE)

    @property
    def baseline(self) -> float:
        """The bare node."""
        return self.cpu[BARE]


class Mover:
    """Back-to-back moves between the goals, from a thread, until stopped."""

    def __init__(self, client: CellClient) -> None:
        self.client = client
        self.settled = 0
        self.refused = 0
        self.seconds = 0.0   # command-to-settled time of the settled moves
        self.error: Exception | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        try:
            for offset in itertools.cycle(OFFSETS):
                if self._stop.is_set():
                    return
                t0 = time.monotonic()
                if self.client.plan(names.MOVE_TO_POSE, CENTRE + offset, IDENTITY,
                                    timeout=MOVE_TIMEOUT):
                    self.settled += 1
                    self.seconds += time.monotonic() - t0
                else:
                    self.refused += 1
        except Exception as err:  # re-raised by stop()
            self.error = err

    def stop(self) -> None:
        """Stop after the current move; re-raise what failed in the thread."""
        self._stop.set()
        self._thread.join(timeout=MOVE_TIMEOUT + 5.0)
        if self.error is not None:
            raise RuntimeError(f'moves failed: {self.error}') from self.error


def check_alive(procs: Processes) -> None:
    """RuntimeError if a node has exited."""
    gone = {label: p.returncode for label, p in procs.procs.items() if p.poll() is not None}
    if gone:
        raise RuntimeError(f'node processes exited: {gone}')


def wait_for_cell(procs: Processes, client: CellClient) -> None:
    """Until the positioner publishes its pose, the tracker measures and the monitor answers."""
    seen: dict[str, list[Any]] = {'/positioner/pose': [], '/metrology/pose': []}
    subscriptions = [client.node.create_subscription(msg_type, topic, seen[topic].append,
                                                     STREAM_QOS)
                     for topic, msg_type in (('/positioner/pose', PoseStamped),
                                             ('/metrology/pose', PoseWithCovarianceStamped))]

    def up() -> bool:
        check_alive(procs)
        return all(seen.values())

    wait_until(up, START_TIMEOUT, '/positioner/pose and /metrology/pose')
    client.monitor_report()  # the monitor answers
    for subscription in subscriptions:  # not part of the measured load
        client.node.destroy_subscription(subscription)


def measure(procs: Processes, stamps: list[int], seconds: float,
            mover: Mover | None = None) -> Window:
    """CPU per node and the driver's stamps over ``seconds`` of wall time from now."""
    pids = {NODES.get(label, label): p.pid for label, p in procs.procs.items()}
    cpu0 = {node: cpu_seconds(pid) for node, pid in pids.items()}
    own0, first, moves0 = cpu_seconds(os.getpid()), len(stamps), mover.settled if mover else 0
    t0 = time.monotonic()
    time.sleep(seconds)  # the measurement interval itself
    cpu1 = {node: cpu_seconds(pid) for node, pid in pids.items()}
    own1, last, moves1 = cpu_seconds(os.getpid()), len(stamps), mover.settled if mover else 0
    wall = time.monotonic() - t0
    check_alive(procs)
    return Window({node: (cpu1[node] - cpu0[node]) / wall for node in pids}, (own1 - own0) / wall,
                  DriverRate.from_stamps(stamps[first:last]), moves1 - moves0)


@dataclass(frozen=True)
class Memory:
    """One process's memory after the windows: peak and current resident set, its proportional
    set now (the pages it shares with other processes divided among them), MiB, and whether it
    has loaded numba (it ran a compiled kernel)."""

    peak: float
    resident: float
    proportional: float
    kernels: bool

    @classmethod
    def of(cls, pid: int) -> Memory:
        def kib(path: str, field: str) -> float:
            return next(int(line.split()[1]) for line in
                        Path(f'/proc/{pid}/{path}').read_text().splitlines()
                        if line.startswith(f'{field}:'))

        maps = Path(f'/proc/{pid}/maps').read_text()
        return cls(kib('status', 'VmHWM') / 1024, kib('status', 'VmRSS') / 1024,
                   kib('smaps_rollup', 'Pss') / 1024, '/numba/' in maps)


def memory(procs: Processes) -> dict[str, Memory]:
    """Node (or the container, and 'bare_node') -> its :class:`Memory` now."""
    return {NODES.get(label, label): Memory.of(p.pid) for label, p in procs.procs.items()}


def cell_memory(memory: dict[str, Memory]) -> Memory:
    """The cell's processes together (peaks summed: each process's own peak)."""
    cell = [m for label, m in memory.items() if label != BARE]
    return Memory(sum(m.peak for m in cell), sum(m.resident for m in cell),
                  sum(m.proportional for m in cell), any(m.kernels for m in cell))


def report_memory(memory: dict[str, Memory]) -> None:
    """The table: each process's peak RSS against the bare node's, and the targets (a node's
    own, or for the one process hosting the cell the cell's)."""
    bare = memory[BARE].peak
    print(row('memory, MiB', 'peak RSS', 'RSS now', 'PSS now', 'x bare', 'numba', 'target'))
    for label, m in memory.items():
        if label == BARE:
            continue
        if label == names.CONTAINER:
            limit, ok = f'<= {CELL_TARGET_MB / MIB_MB:.0f}', m.peak <= CELL_TARGET_MB / MIB_MB
        elif m.kernels:
            limit = f'<= {KERNEL_NODE_TARGET_MB / MIB_MB:.0f}'
            ok = m.peak <= KERNEL_NODE_TARGET_MB / MIB_MB
        else:
            limit, ok = f'<= {NODE_FACTOR_TARGET:g}x', m.peak <= NODE_FACTOR_TARGET * bare
        print(row(f'  {label}', f'{m.peak:.0f}', f'{m.resident:.0f}', f'{m.proportional:.0f}',
                  f'{m.peak / bare:.2f}', 'yes' if m.kernels else 'no',
                  f'  {limit} {verdict(ok)}'))
    total = cell_memory(memory).peak
    print(row('  baseline: a bare rclpy node', f'{bare:.0f}', f'{memory[BARE].resident:.0f}',
              f'{memory[BARE].proportional:.0f}'))
    print(f'target cell total <= {CELL_TARGET_MB:g} MB ({CELL_TARGET_MB / MIB_MB:.0f} MiB): '
          f'{verdict(total <= CELL_TARGET_MB / MIB_MB)} ({total:.0f} MiB)')


def set_parameter(client: CellClient, node: str, name: str, value: Any) -> None:
    result = client.set_parameter(node, name, value)
    if not result.successful:
        raise RuntimeError(f'{node}: setting {name} = {value!r} refused: {result.reason}')


def verdict(ok: bool) -> str:
    return 'met' if ok else 'NOT met'


def row(label: str, *cells: object) -> str:
    return f'{label:<34}' + ''.join(f'{cell!s:>14}' for cell in cells)


def report(rest: Window, moving: Window, nominal: float) -> None:
    """The table: CPU per node and total, driver rate, targets."""
    windows = (rest, moving)
    print(row('CPU s per wall s', 'at rest', 'moving'))
    cell = [label for label in rest.cpu if label != BARE]
    for label in cell:
        print(row(f'  {label}', *(f'{w.cpu[label]:.3f}' for w in windows)))
    print(row(f'  total ({len(cell)} process{"es" if len(cell) > 1 else ""})',
              *(f'{w.total:.3f}' for w in windows)))
    print(row('  baseline: a bare rclpy node', *(f'{w.baseline:.3f}' for w in windows)))
    print(row('  benchmark client (not in total)', *(f'{w.own:.3f}' for w in windows)))
    print(f'target idle total <= {IDLE_TARGET} core: {verdict(rest.total <= IDLE_TARGET)} '
          f'({rest.total:.3f})')
    print()
    period = 1.0 / nominal
    rates = [w.driver for w in windows]
    print(row(f'driver /legs/joint_states, {nominal:g} Hz', 'at rest', 'moving'))
    print(row('  messages', *(d.messages for d in rates)))
    print(row('  rate from stamps, Hz', *(f'{d.rate:.1f}' for d in rates)))
    print(row('  % of nominal', *(f'{100 * d.rate / nominal:.1f} %' for d in rates)))
    print(row('  p99 interval, ms (periods)',
              *(f'{d.p99 * 1e3:.1f} ({d.p99 / period:.2f})' for d in rates)))
    print(row('  longest interval, ms', *(f'{d.longest * 1e3:.1f}' for d in rates)))
    print(row('  repeated or earlier stamps', *(d.repeated for d in rates)))
    print(row(f'  target rate >= {RATE_TARGET * 100:g} % of nominal',
              *(verdict(d.rate >= RATE_TARGET * nominal) for d in rates)))
    print(row(f'  target p99 <= {P99_TARGET:g} periods',
              *(verdict(d.p99 <= P99_TARGET * period) for d in rates)))


@dataclass(frozen=True)
class Cell:
    """One way of running the cell, measured: its two windows and its memory."""

    rest: Window
    moving: Window
    memory: dict[str, Memory]


def measure_cell(seconds: float, log_dir: Path, one_process: bool,
                 nominal: float) -> Cell | None:
    """Start the cell (its four nodes as processes, or ``cell_container`` hosting them) and a
    bare node on a free domain, measure both windows and the memory, print them, stop it.
    None if the cell did not come up (its logs printed)."""
    start = (names.CONTAINER,) if one_process else tuple(NODES)
    log_dir.mkdir(parents=True, exist_ok=True)
    with free_domain() as domain, Processes(cell_environment(domain), log_dir) as procs, \
            CellClient(domain, 'idle_cpu_benchmark') as client:
        print(f'domain {domain}, {os.cpu_count()} CPUs, load average '
              f'{os.getloadavg()[0]:.2f} before start, windows of {seconds:g} s')
        stamps: list[int] = []
        client.node.create_subscription(
            JointState, '/legs/joint_states',
            lambda m: stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec),
            STREAM_QOS)
        t0 = time.monotonic()
        for exe in start:
            procs.start(exe, params=[CELL_YAML])
        procs.start('python', label=BARE, extra_args=('-c', BARE_NODE))
        try:
            wait_for_cell(procs, client)
        except (TimeoutError, RuntimeError) as err:
            print(f'the cell did not come up: {err}', file=sys.stderr)
            for exe in start:
                print(f'--- {exe} log (tail) ---\n{procs.log(exe)[-1500:]}', file=sys.stderr)
            return None
        print(f'cell up after {time.monotonic() - t0:.1f} s')
        homed, message = client.trigger(names.HOME)  # references the drives
        if not homed:
            raise RuntimeError(f'homing failed: {message}')
        rest = measure(procs, stamps, seconds)
        set_parameter(client, 'positioner', COMPENSATION_MODE, 'none')
        mover = Mover(client)
        mover.start()
        try:
            wait_until(lambda: mover.settled or mover.error, MOVE_TIMEOUT, 'the first move')
            moving = measure(procs, stamps, seconds, mover)
        finally:
            mover.stop()
        mean = mover.seconds / mover.settled if mover.settled else float('nan')
        print(f'moving window: compensation.mode none, {moving.moves} moves settled in it '
              f'(mean {mean:.2f} s command to settled), {mover.refused} refused in all')
        print()
        report(rest, moving, nominal)
        print()
        used = memory(procs)
        report_memory(used)
        codes = procs.stop()
        print('\nstopped, exit codes: '
              + ', '.join(f'{NODES.get(exe, exe)} {code}' for exe, code in codes.items()))
    return Cell(rest, moving, used)


def compare(separate: Cell, composed: Cell, nominal: float) -> None:
    """The table: the cell as separate processes against the cell in one process."""
    period = 1.0 / nominal
    apart, one = cell_memory(separate.memory), cell_memory(composed.memory)
    print(row('the cell, separate vs one process', 'separate', 'one process', 'ratio'))
    lines: list[tuple[str, float, float, str]] = [
        ('  CPU at rest, core', separate.rest.total, composed.rest.total, '.3f'),
        ('  CPU moving, core', separate.moving.total, composed.moving.total, '.3f'),
        ('  moves settled in the window', separate.moving.moves, composed.moving.moves, '.0f'),
        ('  peak RSS, MiB (sum)', apart.peak, one.peak, '.0f'),
        ('  RSS now, MiB (sum)', apart.resident, one.resident, '.0f'),
        ('  PSS now, MiB (sum)', apart.proportional, one.proportional, '.0f'),
        ('  driver rate at rest, Hz', separate.rest.driver.rate, composed.rest.driver.rate, '.1f'),
        ('  driver rate moving, Hz', separate.moving.driver.rate, composed.moving.driver.rate,
         '.1f'),
        ('  driver p99 at rest, periods', separate.rest.driver.p99 / period,
         composed.rest.driver.p99 / period, '.2f'),
        ('  driver p99 moving, periods', separate.moving.driver.p99 / period,
         composed.moving.driver.p99 / period, '.2f')]
    for label, a, b, fmt in lines:
        print(row(label, format(a, fmt), format(b, fmt), f'{b / a:.2f}' if a else '-'))


def run(seconds: float, log_dir: Path, one_process: bool) -> int:
    driver = parse(DriverSettings, node_parameters(load_parameter_file(CELL_YAML),
                                                   names.NODE_DRIVER))
    nominal = driver.publish_rate
    print(f'package {Path(positioning_cell.__file__).parent}, config {CELL_YAML}')
    print('\n== the cell as separate processes ==')
    separate = measure_cell(seconds, log_dir / 'separate', False, nominal)
    if separate is None:
        return 1
    if not one_process:
        return 0
    print(f'\n== the cell in one process ({names.CONTAINER}) ==')
    composed = measure_cell(seconds, log_dir / 'one_process', True, nominal)
    if composed is None:
        return 1
    print()
    compare(separate, composed, nominal)
    return 0


def standalone_environment(name: str) -> None:
    """This process's environment for a benchmark run by hand: nothing depends on the
    caller's ROS environment (the same settings as make bench), logs under the temp folder."""
    tmp = Path(tempfile.gettempdir())
    os.environ.setdefault('ROS_LOG_DIR', str(tmp / f'{name}_ros_log'))
    os.environ.setdefault('ROS_HOME', str(tmp / f'{name}_ros_home'))
    os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
    os.environ.update(cell_environment(0))  # loopback only, as the cell (the domain is set later)
    os.environ.pop('RMW_IMPLEMENTATION', None)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=20.0,
                        help='length of each measurement window, s (default 20)')
    parser.add_argument('--one-process', action='store_true',
                        help=f'then the same cell in one process ({names.CONTAINER}), compared')
    args = parser.parse_args(argv)
    standalone_environment('idlecpu')
    with tempfile.TemporaryDirectory(prefix='idle_cpu_') as log_dir:
        try:
            return run(args.seconds, Path(log_dir), args.one_process)
        except (TimeoutError, RuntimeError) as err:
            print(f'benchmark failed: {err}', file=sys.stderr)
            return 1


if __name__ == '__main__':
    raise SystemExit(main())
