"""analyze_bags scaling: 2, 4 and 8 bags the size of a recorded run on a Dask LocalCluster of one
and of two worker processes against the serial loop in one process, from the same run,
repeated (medians); Dask's own metrics for the per-bag cost and the overhead; and a 16-core
figure EXTRAPOLATED from them (not measured).

The bags are synthetic cell runs (positioning_cell.testing.synthetic_run), each of about
``--messages`` (300 000) messages: the ISO cube's five poses under the three compensation
modes, the tracker at 20 Hz with the true pose at the same stamps, the program steps, the
positioner's mode and calibration diagnostics, a tracker registration, and /legs/joint_states
filler so that the analysed topics are the share of the messages they are in a recorded run
(~13 %, as benchmarks/analysis.py). ``--distinct`` (4) runs are written (each its own seed and
day, the third recalibrated), then copied until there are as many bags as the largest count.

Measured, for each bag count (``--counts`` 2,4,8) and each of ``--repeats`` (3) rounds, the
three in a rotating order so that a change of the machine's load falls on each alike:

- the serial loop: ``digest_bag`` over the bags in this process;
- the work of ``analyze_bags`` on a LocalCluster of 1 and of 2 single-threaded worker
  processes (:func:`positioning_cell.tools.analyze_bags.digest_bags`: one task per bag, the
  path out, a ~6 kB digest back). Both clusters are started, and every worker has digested
  a small bag (imports, first calls), before the first clock: their start-up is printed
  apart, as is the serial tail of ``analyze_bags`` (trends, plots and report in the client:
  :func:`positioning_cell.tools.analyze_bags.report_fleet`). Neither is in the rates.

From Dask (distributed's fine performance metrics and task stream): per run the CPU seconds
of the tasks (``thread-cpu``) and their wall seconds not on a CPU (``thread-noncpu``: waiting
for a core the other processes hold, or I/O); the *cores obtained* (task CPU s / wall s: at
most 1 per worker; below it the machine was shared); the per-task overhead of the 1-worker
cluster (the wall time its worker was not computing, per task: dispatch, the digest's
transfer, the client's loop); and, from an untimed pass of the largest count's bags on a
third cluster of 2 workers with Dask's statistical profiler on (off on analyze_bags' local
clusters: it costs a task about a tenth of its CPU), where the tasks spent their time, by
function.

The extrapolation to 16 cores assumes 16 uncontended cores, each bag costing the median
per-task CPU seconds measured here plus the measured per-task overhead, the tasks spread
as Dask's largest-first order does (ceil(N/16) rounds), plus the measured serial tail; not
modelled: memory bandwidth, disk (the rate the bags must be read at is printed), a cluster's
start-up. It is printed as an extrapolation.

Target: 2 workers >= 1.6 x the 1-worker rate from 4 bags up. On a shared machine the wall
ratio follows the cores obtained; it is printed beside them. With Linux's autogroup
scheduling (printed when on), a busy machine gives this benchmark's session one share of
the CPU, however many workers it starts: 2 workers then obtain no more CPU than 1.

Run: ``.venv/bin/python benchmarks/fleet.py [--counts 2,4,8] [--repeats 3] [--messages N]``
(make bench). Exits non-zero only if the analysis is wrong (a bag failed, a digest differs
from the serial one beyond rounding, a mode missing), never on speed.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from positioning_cell.accuracy.monitor import MonitorSettings
from positioning_cell.analysis.fleet import BagFailure, RunDigest, digest_bag
from positioning_cell.config import config_path
from positioning_cell.testing.nested import assert_nested_close
from positioning_cell.testing.synthetic_run import long_run, write_run_bag
from positioning_cell.tools.analyze_bags import dask_client, digest_bags, report_fleet

DAY = 86400.0
MODES = ('none', 'model', 'measured')
#: The extrapolation's core count and bag counts.
EXTRAPOLATED_CORES = 16
EXTRAPOLATED_BAGS = (16, 64, 256)
#: The metric keys of distributed's fine performance metrics for a task's execution.
THREAD_CPU, THREAD_NONCPU = 'thread-cpu', 'thread-noncpu'


def write_bags(work: Path, count: int, distinct: int, messages: int) -> tuple[list[Path], int]:
    """``distinct`` runs of about ``messages`` messages, copied until there are ``count``
    bags; the bags and the messages of the first."""
    bags: list[Path] = []
    written = 0
    for k in range(min(distinct, count)):
        run, filler_rate = long_run(messages, start=1.77e9 + k * DAY, seed=k)
        bags.append(work / f'run{k:02d}' / 'bag')
        n = write_run_bag(bags[-1], run, joint_state_rate=filler_rate,
                          calibration='cal_B.yaml' if k >= 2 else 'cal_A.yaml',
                          calibration_run='recalibration' if k == 2 else None,
                          registration_um=(4.0 + k, 6.0, 5.0))
        written = written or n
    for k in range(len(bags), count):
        bags.append(work / f'run{k:02d}' / 'bag')
        shutil.copytree(bags[k % distinct], bags[-1])
    return bags, written


@dataclass
class Run:
    """One timed run: wall seconds, the digests and failures, and (for a cluster) the tasks'
    CPU and non-CPU seconds and the wall seconds the workers computed, from Dask."""

    wall: float
    digests: list[RunDigest]
    failures: list[BagFailure]
    cpu: float
    noncpu: float = math.nan
    computing: float = math.nan
    workers_cpu: float = math.nan
    client_cpu: float = math.nan

    @property
    def cores(self) -> float:
        """Cores obtained: CPU seconds per wall second."""
        return self.cpu / self.wall


def quiet(line: str) -> None:
    """No progress lines while timing."""


def split(results: list[RunDigest | BagFailure]) -> tuple[list[RunDigest], list[BagFailure]]:
    """Digests and failures apart."""
    return ([r for r in results if isinstance(r, RunDigest)],
            [r for r in results if isinstance(r, BagFailure)])


def serial(bags: list[Path], settings: MonitorSettings) -> Run:
    """The serial loop in this process; its CPU seconds those of this thread, as Dask's
    thread-cpu of a task (the idle clusters' threads in this process left out)."""
    cpu, start = time.thread_time(), time.perf_counter()
    digests, failures = split([digest_bag(b, settings) for b in bags])
    return Run(time.perf_counter() - start, digests, failures, time.thread_time() - cpu)


async def _heartbeat(dask_worker: Any) -> None:
    """Send the worker's heartbeat now (run on each worker): its metrics go with it."""
    await dask_worker.heartbeat()


def _task_metrics(client: Any) -> dict[str, float]:
    """Dask's cumulative execute metrics of the digest_bag tasks (s), by metric, with every
    worker's metrics sent (they travel with the heartbeats, every second or so)."""
    client.run(_heartbeat)
    def read(dask_scheduler: Any) -> dict[str, float]:
        out: dict[str, float] = {}
        for key, value in dask_scheduler.cumulative_worker_metrics.items():
            if isinstance(key, tuple) and len(key) == 4 and key[0] == 'execute' \
                    and key[1] == digest_bag.__name__ and key[3] == 'seconds':
                out[key[2]] = out.get(key[2], 0.0) + float(value)
        return out
    metrics: dict[str, float] = client.run_on_scheduler(read)
    return metrics


def _process_cpu() -> float:
    """The CPU seconds of this process, all its threads (run on each worker)."""
    return time.process_time()


def on_cluster(client: Any, bags: list[Path], settings: MonitorSettings) -> Run:
    """The bags on the cluster of ``client`` (:func:`digest_bags`), with Dask's metrics and
    the CPU seconds of the worker processes and of this one (the scheduler, the client)."""
    from dask.distributed import get_task_stream

    before = _task_metrics(client)
    workers_before = sum(client.run(_process_cpu).values())
    with get_task_stream(client) as stream:
        start, client_cpu = time.perf_counter(), time.process_time()
        digests, failures = digest_bags(client, bags, settings, say=quiet)
        wall, client_cpu = time.perf_counter() - start, time.process_time() - client_cpu
    workers_cpu = sum(client.run(_process_cpu).values()) - workers_before
    after = _task_metrics(client)
    computing = sum(s['stop'] - s['start'] for task in stream.data
                    for s in task['startstops'] if s['action'] == 'compute')
    return Run(wall, digests, failures, after.get(THREAD_CPU, 0.0) - before.get(THREAD_CPU, 0.0),
               after.get(THREAD_NONCPU, 0.0) - before.get(THREAD_NONCPU, 0.0), computing,
               workers_cpu, client_cpu)


def same(run: Run, reference: list[RunDigest]) -> bool:
    """Every bag digested, each within rounding of the serial loop's (figures to 1e-12
    relative; every count, name and time as it is)."""
    by_bag = {d.bag: d for d in run.digests}
    if run.failures or set(by_bag) != {d.bag for d in reference}:
        return False
    try:
        assert_nested_close([by_bag[d.bag].to_dict() for d in reference],
                            [d.to_dict() for d in reference], rtol=1e-12, atol=1e-15)
    except AssertionError as err:
        print(f'WRONG: {err}')
        return False
    return True


def _profile_counts(node: dict[str, Any], cumulative: dict[str, int],
                    own: dict[str, int], above: frozenset[str]) -> None:
    """Samples per function in Dask's profile tree: ``cumulative`` (on the stack, each
    sample once) and ``own`` (the innermost frame)."""
    d = node.get('description', {})
    name = f"{Path(d.get('filename', '?')).name}:{d.get('name', '?')}" if d else 'root'
    count = int(node['count'])
    if name not in above:
        cumulative[name] = cumulative.get(name, 0) + count
    children = node.get('children', {}).values()
    own[name] = own.get(name, 0) + count - sum(int(c['count']) for c in children)
    for child in children:
        _profile_counts(child, cumulative, own, above | {name})


def print_profile(profile: dict[str, Any], top: int = 8) -> None:
    """The functions the tasks spent most samples in (Dask's worker profile)."""
    cumulative: dict[str, int] = {}
    own: dict[str, int] = {}
    _profile_counts(profile, cumulative, own, frozenset())
    total = max(int(profile['count']), 1)
    print(f"Dask's worker profile of an untimed 2-worker pass ({total} samples): on the "
          'stack')
    tasks = cumulative.get(f'fleet.py:{digest_bag.__name__}', 0)
    for name, count in sorted(cumulative.items(), key=lambda kv: -kv[1])[:top * 2]:
        if name != 'root' and count <= tasks:
            print(f'  {count / total:6.1%}  {name}')
    print('  innermost: ' + ', '.join(f'{name} {count / total:.1%}' for name, count in
                                      sorted(own.items(), key=lambda kv: -kv[1])[:top]))


def autogroup() -> bool:
    """Whether the Linux scheduler shares the CPU between sessions rather than threads."""
    try:
        return Path('/proc/sys/kernel/sched_autogroup_enabled').read_text().strip() == '1'
    except OSError:
        return False


def median(values: list[float]) -> float:
    return statistics.median(values) if values else math.nan


@contextlib.contextmanager
def clusters(small: Path, settings: MonitorSettings) -> Iterator[dict[int, Any]]:
    """A client of a LocalCluster of 1 and one of 2 worker processes, every worker warmed
    up (start-up printed)."""
    with contextlib.ExitStack() as stack:
        out = {}
        for workers in (1, 2):
            start = time.perf_counter()
            out[workers] = stack.enter_context(dask_client(None, workers))
            out[workers].run(digest_bag, str(small), settings)
            print(f'LocalCluster of {workers} worker(s) started and warmed up in '
                  f'{time.perf_counter() - start:.1f} s (not in the rates)', flush=True)
        yield out


def extrapolate(cpu_per_bag: float, overhead: float, tail_per_bag: float, tail_fixed: float,
                bag_mib: float) -> None:
    """Print the EXTRAPOLATED rate on 16 uncontended cores (module docstring)."""
    task = cpu_per_bag + overhead
    print(f'\nEXTRAPOLATION to {EXTRAPOLATED_CORES} cores (not measured): a task = '
          f'{cpu_per_bag:.2f} s CPU per bag (median of Dask\'s thread-cpu per task) + '
          f'{overhead * 1e3:.0f} ms overhead per task (measured on 1 worker); serial tail '
          f'(trends, plots, report) {tail_fixed:.2f} s + {tail_per_bag * 1e3:.1f} ms CPU per '
          f'bag (measured); {EXTRAPOLATED_CORES} uncontended cores assumed, disk and memory '
          'bandwidth not modelled')
    for n in EXTRAPOLATED_BAGS:
        tail = tail_fixed + tail_per_bag * n
        one = n * task + tail
        many = math.ceil(n / EXTRAPOLATED_CORES) * task + tail
        print(f'  {n:4d} bags: 1 core {one:7.1f} s, {EXTRAPOLATED_CORES} cores {many:6.1f} s '
              f'= {n / many:.2f} bags/s, speed-up {one / many:.1f} x (Amdahl: serial share '
              f'{tail / one:.1%} of the 1-core time)')
    print(f'  needs the bags read at {EXTRAPOLATED_CORES * bag_mib / cpu_per_bag:.0f} MiB/s '
          f'({bag_mib:.0f} MiB a bag; the file reads are of the analysed topics\' chunks only, '
          'so this is an upper bound)')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--counts', default='2,4,8',
                        help='bag counts measured, comma-separated (default 2,4,8)')
    parser.add_argument('--repeats', type=int, default=3, help='rounds (default 3; medians)')
    parser.add_argument('--distinct', type=int, default=4,
                        help='distinct runs written, the rest copies (default 4)')
    parser.add_argument('--messages', type=int, default=300_000,
                        help='messages per bag, about (default 300 000)')
    args = parser.parse_args()
    counts = sorted({int(c) for c in args.counts.split(',')})
    settings = MonitorSettings.from_file(config_path('cell.yaml'))
    work = Path(tempfile.mkdtemp(prefix='positioning_cell_bench_fleet_'))
    try:
        start = time.perf_counter()
        bags, written = write_bags(work, max(counts), args.distinct, args.messages)
        bag_mib = sum(f.stat().st_size for f in bags[0].iterdir()) / 2**20
        print(f'bags: {len(bags)} ({min(args.distinct, len(bags))} distinct runs, the rest '
              f'copies), {written:,} messages and {bag_mib:.0f} MiB each, written in '
              f'{time.perf_counter() - start:.0f} s: {work}', flush=True)
        small = work / 'warm_up'
        write_run_bag(small, long_run(2_000)[0])
        print(f'cores: {os.cpu_count()}; load average before: '
              f'{", ".join(f"{v:.1f}" for v in os.getloadavg())}', flush=True)
        if autogroup():
            print('the kernel shares the CPU between sessions (sched_autogroup_enabled): '
                  'all processes of this benchmark, workers included, get one session\'s '
                  'share of a busy machine however many workers there are', flush=True)
        digest_bag(small, settings)

        runs: dict[tuple[int, str], list[Run]] = {}
        tails: dict[int, float] = {}
        ok = True
        labels = ('serial', '1 worker', '2 workers')
        with clusters(small, settings) as client:
            for r in range(args.repeats):
                for n in counts:
                    got: dict[str, Run] = {}
                    for k in range(3):
                        label = labels[(k + r + n) % 3]
                        got[label] = (serial(bags[:n], settings) if label == 'serial' else
                                      on_cluster(client[1 if label == '1 worker' else 2],
                                                 bags[:n], settings))
                    reference = got['serial'].digests
                    ok = ok and not got['serial'].failures and all(
                        d.modes == MODES for d in reference)
                    ok = ok and same(got['1 worker'], reference) and same(got['2 workers'],
                                                                           reference)
                    for label, run in got.items():
                        runs.setdefault((n, label), []).append(run)
                    print(f'round {r + 1}, {n} bags: ' + ', '.join(
                        f'{label} {run.wall:.1f} s ({run.cores:.2f} cores, '
                        f'{run.cpu / n:.2f} s CPU per bag)'
                        for label, run in got.items()) + '; load average '
                        f'{os.getloadavg()[0]:.1f}', flush=True)
                    if r == 0:
                        with tempfile.TemporaryDirectory() as out:
                            t, cpu = time.perf_counter(), time.process_time()
                            report_fleet(reference, [], out)
                            tails[n] = time.process_time() - cpu
                            print(f'serial tail of {n} bags (trends, plots, report): '
                                  f'{time.perf_counter() - t:.1f} s, {tails[n]:.2f} s CPU',
                                  flush=True)
        with dask_client(None, 2, profile=True) as profiled:
            digest_bags(profiled, bags[:counts[-1]], settings, say=quiet)
            print_profile(profiled.profile())

        print(f'\nmedians of {args.repeats} rounds (wall s; cores obtained = task CPU s / '
              'wall s; noncpu = Dask\'s thread-noncpu, the tasks\' wall time off a CPU):')
        print('bags | serial s | 1 worker s | 2 workers s | 2w/1w | 2w/serial | cores 1w | '
              'cores 2w | noncpu/cpu 2w')
        for n in counts:
            wall = {label: median([x.wall for x in runs[n, label]]) for label in labels}
            two = runs[n, '2 workers']
            print(f'{n:4d} | {wall["serial"]:8.1f} | {wall["1 worker"]:10.1f} | '
                  f'{wall["2 workers"]:11.1f} | {wall["1 worker"] / wall["2 workers"]:5.2f} | '
                  f'{wall["serial"] / wall["2 workers"]:9.2f} | '
                  f'{median([x.cores for x in runs[n, "1 worker"]]):8.2f} | '
                  f'{median([x.cores for x in two]):8.2f} | '
                  f'{median([x.noncpu / x.cpu for x in two]):13.2f}')
        print('target: 2w/1w >= 1.6 from 4 bags up (on a machine shared with other work, '
              'compare with cores 2w / cores 1w)')

        def per_bag(label: str, value: Any) -> float:
            return median([value(x) / n for n in counts for x in runs[n, label]])

        cpu_per_bag = median([x.cpu / n for n in counts for label in labels[1:]
                              for x in runs[n, label]])
        overhead = per_bag('1 worker', lambda x: x.wall - x.computing)
        print(f'per bag (Dask\'s metrics): {cpu_per_bag:.2f} s CPU (median thread-cpu per '
              f'task, both clusters); on 1 worker {per_bag("1 worker", lambda x: x.computing):.2f}'
              f' s computing (wall) and {overhead * 1e3:.0f} ms overhead (wall not computing) '
              f'per task. The serial loop: {per_bag("serial", lambda x: x.cpu):.2f} s CPU per '
              'bag (its thread)')
        both = [x for n in counts for label in labels[1:] for x in runs[n, label]]
        extra = median([x.workers_cpu / x.cpu - 1 for x in both])
        scheduler = median([x.client_cpu / x.cpu for x in both])
        print('CPU besides the tasks, as a share of the tasks\' CPU (medians over the cluster '
              f'runs): the worker processes {extra:.1%} (heartbeats, comms, memory monitor), '
              f'this process (scheduler, client) {scheduler:.1%}')
        big, low = counts[-1], counts[0]
        tail_per_bag = (tails[big] - tails[low]) / (big - low) if big > low else 0.0
        extrapolate(cpu_per_bag, max(overhead, 0.0), max(tail_per_bag, 0.0),
                    tails[low] - tail_per_bag * low, bag_mib)
        print(f'load average after: {", ".join(f"{v:.1f}" for v in os.getloadavg())}')
        print('analysis ' + ('correct: every bag analysed, the same digests serially and on '
                             'each cluster, three modes' if ok else 'WRONG'))
        return 0 if ok else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == '__main__':
    sys.exit(main())
