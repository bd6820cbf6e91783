"""The live view's cost and latency, and the terminal watch's time to its first table.

Starts live_view_node (config/cell.yaml, any free port) and, as the baseline, a bare rclpy node
as separate processes on a free ROS domain; this process plays the cell (the command latched,
the encoder estimate and the tracker at their configured rates, 50 and 20 Hz) and connects a
Foxglove WebSocket client (test/foxglove_ws.py: websockets, subprotocol foxglove.sdk.v1) subscribed
to every channel. Three windows of --seconds each: poses streaming before any client
connects, streaming to the client, and the client connected but no poses (idle).
For each: CPU seconds per wall second of live_view_node and of the bare node
(utime + stime of all threads, /proc/<pid>/stat) and the messages received per channel. In
the streaming window: the latency of each /live/deviation message, from the measurement's
header stamp (set when this process published it) to its arrival at the client (same clock).

Then, with tmux, ``cell watch`` (frame user) is started --trials times in a tmux pane against
the same poses (a stand-in positioner node serves the mechanism parameters) and timed from
the spawn to the first screen that shows the deviation table; baseline: ``cell --help`` (the
interpreter and the imports) timed the same way in the same run.

Run: .venv/bin/python benchmarks/live_view.py [--seconds S] [--trials N]
Targets (issue 14): live_view at 20 Hz adds <= 5 % of one core; median latency pose published
→ message received <= 50 ms; the watch shows the deviation within 2 s of its start. Prints
what it measured and whether each target is met; exits non-zero only if it could not measure.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from idle_cpu import BARE_NODE, cpu_seconds, standalone_environment

from positioning_cell import names
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import CellClient
from positioning_cell.ros.domains import free_domain
from positioning_cell.ros.messages import status_values
from positioning_cell.ros.processes import Processes, cell_environment, executable

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / 'test'))
from fake_cell import FakeCell, stand_in_positioner  # noqa: E402  (the tests' helpers)
from foxglove_ws import FoxgloveClient, Received  # noqa: E402
from tmux_pane import TmuxPane  # noqa: E402

CELL_YAML = config_path('cell.yaml')
CPU_TARGET = 0.05       # cores
LATENCY_TARGET = 0.050  # s, median
WATCH_TARGET = 2.0      # s
CHANNELS = [names.LIVE_SCENE, names.LIVE_TRANSFORMS, names.LIVE_DEVIATION, names.LIVE_STATUS]
MECH = Mechanism.default()
OFFSET = np.array([30e-6, -20e-6, 10e-6])


class Cell(FakeCell):
    """This process as the cell: the command, and from a thread (while ``streaming``) the
    estimate and the tracker at their configured rates."""

    def __init__(self, client: CellClient, tracker_rate: float, estimate_rate: float) -> None:
        super().__init__(client.node)
        self.tracker_rate, self.estimate_rate = tracker_rate, estimate_rate
        self.command(MECH.home_position)
        self.streaming = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        period = 1.0 / self.estimate_rate
        every = max(1, round(self.estimate_rate / self.tracker_rate))
        tick, next_t = 0, time.monotonic()
        while not self._stop.is_set():
            next_t += period
            time.sleep(max(0.0, next_t - time.monotonic()))
            if not self.streaming.is_set():
                continue
            self.estimated(MECH.home_position)
            tick += 1
            if tick % every == 0:
                self.measure(MECH.home_position + OFFSET)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)


class Reader:
    """The WebSocket client's messages, taken by a thread."""

    def __init__(self, ws: FoxgloveClient) -> None:
        self.ws, self.got = ws, []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            received = self.ws.receive(0.2)
            if received is not None:
                self.got.append(received)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)


def window(pids: dict[str, int], reader: Reader | None,
           seconds: float) -> tuple[dict[str, float], list[Received]]:
    """CPU s per wall s of each process and the messages received over ``seconds``."""
    cpu0 = {k: cpu_seconds(p) for k, p in pids.items()}
    first, t0 = len(reader.got) if reader else 0, time.monotonic()
    time.sleep(seconds)  # the measurement interval itself
    wall = time.monotonic() - t0
    return ({k: (cpu_seconds(p) - cpu0[k]) / wall for k, p in pids.items()},
            reader.got[first:] if reader else [])


def verdict(ok: bool) -> str:
    return 'met' if ok else 'NOT met'


def time_to_screen(socket: str, command: str, done: str, log_dir: Path, env: dict[str, str],
                   timeout: float = 60.0) -> float:
    """Seconds from spawning ``command`` in a tmux pane to a screen containing ``done``."""
    t0 = time.monotonic()
    with TmuxPane(socket, command, env, log_dir) as pane:
        while time.monotonic() - t0 < timeout:
            if done in (screen := pane.screen()):
                return time.monotonic() - t0
            time.sleep(0.01)
        print(f'{command!r}: {done!r} not on the screen within {timeout:g} s:\n{screen}',
              file=sys.stderr)
        return float('nan')


def time_watch(client: CellClient, domain: int, trials: int,
               log_dir: Path) -> tuple[list[float], list[float]]:
    """``cell watch`` (frame user) timed ``trials`` times in a tmux pane from its spawn to the
    first screen with the deviation table, against the poses this process streams (a
    :class:`Cell` streaming) and a stand-in positioner node (the mechanism parameters); and
    ``cell --help`` timed the same way, the baseline. Seconds of each start (NaN: not shown)."""
    positioner = stand_in_positioner(client.context)
    client.executor.add_node(positioner)
    env = cell_environment(domain)
    cli = shlex.quote(executable('cell'))
    watch, helps = [], []
    try:
        for k in range(trials):
            watch.append(time_to_screen(f'pc_bench_{domain}_{k}', f'{cli} watch --domain '
                                        f'{domain}', '|Δp|', log_dir, env))
            helps.append(time_to_screen(f'pc_bench_{domain}_h{k}', f'{cli} --help',
                                        'exit codes', log_dir, env))
    finally:
        client.executor.remove_node(positioner)
        positioner.destroy_node()
    return watch, helps


def run(seconds: float, trials: int, log_dir: Path) -> int:
    cell_yaml = load_parameter_file(CELL_YAML)
    tracker_rate = float(node_parameters(cell_yaml, names.NODE_MEASUREMENT)['rate_hz'])
    estimate_rate = float(node_parameters(cell_yaml, names.NODE_POSITIONER)['pose_rate_hz'])
    with free_domain() as domain, Processes(cell_environment(domain), log_dir) as procs, \
            CellClient(domain, 'live_view_benchmark') as client:
        print(f'domain {domain}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}; '
              f'tracker {tracker_rate:g} Hz, estimate {estimate_rate:g} Hz, windows of '
              f'{seconds:g} s')
        statuses = client.statuses(names.STATUS_LIVE_VIEW)
        procs.start('live_view_node', params=[CELL_YAML],
                    overrides={names.NODE_LIVE_VIEW: {'port': 0}})
        procs.start('python', label='bare_node', extra_args=('-c', BARE_NODE))
        try:
            status = wait_until(lambda: statuses[-1] if statuses else None, 90.0,
                                'the live view status')
        except TimeoutError as err:
            print(f'{err}\n{procs.log("live_view_node")[-2000:]}', file=sys.stderr)
            return 1
        url = status_values(status)['url']
        cell = Cell(client, tracker_rate, estimate_rate)
        pids = {'live_view_node': procs.procs['live_view_node'].pid,
                'bare_node': procs.procs['bare_node'].pid}
        cell.streaming.set()
        time.sleep(1.0)  # the first messages through, then measure
        alone, _ = window(pids, None, seconds)
        with FoxgloveClient(url) as ws:
            ws.wait_channels(CHANNELS, 30.0)
            ws.subscribe(CHANNELS)
            reader = Reader(ws)
            try:
                time.sleep(1.0)
                cpu, msgs = window(pids, reader, seconds)
                cell.streaming.clear()
                time.sleep(1.0)
                idle_cpu, idle_msgs = window(pids, reader, seconds)
            finally:
                reader.close()
        print(f'live view {url}, channels: ' + ', '.join(
            f'{t} ({ws.channels[t]["schemaName"]}, {ws.channels[t]["encoding"]})'
            for t in CHANNELS))
        print(f'{"CPU s per wall s":<36}{"idle":>10}{"no client":>12}{"streaming":>12}')
        for name in pids:
            print(f'  {name:<34}{idle_cpu[name]:>10.4f}{alone[name]:>12.4f}{cpu[name]:>12.4f}')
        for topic in CHANNELS:
            n_idle = sum(m.topic == topic for m in idle_msgs)
            n = sum(m.topic == topic for m in msgs)
            print(f'  {topic + " msgs/s":<34}{n_idle / seconds:>10.1f}{"":>12}'
                  f'{n / seconds:>12.1f}')
        added = cpu['live_view_node']
        print(f'target live_view at {tracker_rate:g} Hz <= {CPU_TARGET * 100:g} % of one core: '
              f'{verdict(added <= CPU_TARGET)} ({added * 100:.2f} % streaming; idle '
              f'{idle_cpu["live_view_node"] * 100:.2f} %, bare rclpy node '
              f'{cpu["bare_node"] * 100:.2f} %)')
        latency = np.array([m.received - m.message['stamp'] for m in msgs
                            if m.topic == names.LIVE_DEVIATION])
        if latency.size == 0:
            print('no /live/deviation message received while streaming', file=sys.stderr)
            return 1
        med = float(np.median(latency))
        print(f'latency measurement stamp → /live/deviation at the client, {latency.size} '
              f'messages: median {med * 1e3:.2f} ms, p95 {np.percentile(latency, 95) * 1e3:.2f}'
              f' ms, max {latency.max() * 1e3:.2f} ms')
        print(f'target median <= {LATENCY_TARGET * 1e3:g} ms: {verdict(med <= LATENCY_TARGET)}')
        codes = procs.stop()
        print('nodes stopped, exit codes: ' + ', '.join(f'{k} {v}' for k, v in codes.items()))
        if shutil.which('tmux') is None:
            print('tmux not found: the watch window was not timed')
            cell.close()
            return 0
        cell.streaming.set()  # the watch needs measurements
        watch, helps = time_watch(client, domain, trials, log_dir)
        cell.close()
        print(f'cell watch (frame user) to its first deviation table, {trials} starts: median '
              f'{np.median(watch):.2f} s (each {", ".join(f"{t:.2f}" for t in watch)}); '
              f'baseline cell --help {np.median(helps):.2f} s')
        print(f'target <= {WATCH_TARGET:g} s: {verdict(float(np.median(watch)) <= WATCH_TARGET)}')
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=10.0,
                        help='length of each measurement window, s (default 10)')
    parser.add_argument('--trials', type=int, default=5,
                        help='starts of cell watch timed (default 5)')
    args = parser.parse_args(argv)
    standalone_environment('liveview')
    with tempfile.TemporaryDirectory(prefix='live_view_') as log_dir:
        return run(args.seconds, args.trials, Path(log_dir))


if __name__ == '__main__':
    sys.exit(main())
