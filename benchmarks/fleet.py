"""analyze_bags throughput: 20 bags the size of a recorded run on a Dask LocalCluster of one and
of two worker processes, against the serial loop in one process (figures vary ±20-50 % on the
shared 2-core VMs; see platform.md).

The bags are synthetic cell runs (positioning_cell.testing.synthetic_run), each of about
``--messages`` (300 000) messages: the ISO cube's five poses under the three compensation
modes, the tracker at 20 Hz with the true pose at the same stamps, the program steps, the
positioner's mode and calibration diagnostics, a tracker registration, and /legs/joint_states
filler so that the analysed topics are the share of the messages they are in a recorded run
(~13 %, as benchmarks/analysis.py). ``--distinct`` (4) runs are written (each its own seed and
day, the third recalibrated), then copied until there are ``--bags`` (20): the analysis of a
copy costs what the original's does. Written once into a temporary folder, removed at the end.

Measured: the work of ``analyze_bags`` (:func:`positioning_cell.tools.analyze_bags.digest_bags`:
one task per bag, ``analyse_bag`` and the digest on a worker, the digest back), as bags per
second, on a LocalCluster of 1 and then of 2 single-threaded worker processes on 127.0.0.1.
Each cluster is started, and every worker has digested a small bag (imports, first-call
costs), before the clock starts: the figures are the steady rate, not the start-up (which is
printed apart). Baseline: the serial loop (``digest_bag`` over the bags in this process, warmed
up the same way); it may use more than one core (numpy's BLAS threads), where a Dask worker
is single-threaded (Dask starts it with OMP/OPENBLAS/MKL_NUM_THREADS=1), so one worker runs
below the serial loop. Target: 2 workers >= 1.6 x the 1-worker rate.

Run: ``.venv/bin/python benchmarks/fleet.py [--bags N] [--distinct N] [--messages N]`` (make
bench). Exits non-zero only if the analysis is wrong (a bag failed, a digest differs from the
serial one, a mode missing), never on speed.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

from positioning_cell.accuracy.monitor import MonitorSettings
from positioning_cell.analysis.fleet import BagFailure, RunDigest, digest_bag, trends
from positioning_cell.config import config_path
from positioning_cell.testing.synthetic_run import long_run, write_run_bag
from positioning_cell.tools.analyze_bags import dask_client, digest_bags

DAY = 86400.0
MODES = ('none', 'model', 'measured')


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


def timed(what: Callable[[], tuple[list[RunDigest], list[BagFailure]]], count: int,
          label: str) -> tuple[list[RunDigest], list[BagFailure], float]:
    """Run ``what`` (the digests and failures of ``count`` bags), print its rate; the digests,
    the failures and the bags/s."""
    start = time.perf_counter()
    digests, failures = what()
    took = time.perf_counter() - start
    print(f'{label}: {count} bags in {took:.1f} s = {count / took:.3f} bags/s', flush=True)
    return digests, failures, count / took


def quiet(line: str) -> None:
    """No progress lines while timing."""


def split(results: list[RunDigest | BagFailure]) -> tuple[list[RunDigest], list[BagFailure]]:
    """Digests and failures apart."""
    return ([r for r in results if isinstance(r, RunDigest)],
            [r for r in results if isinstance(r, BagFailure)])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--bags', type=int, default=20, help='bags analysed (default 20)')
    parser.add_argument('--distinct', type=int, default=4,
                        help='distinct runs written, the rest copies (default 4)')
    parser.add_argument('--messages', type=int, default=300_000,
                        help='messages per bag, about (default 300 000)')
    args = parser.parse_args()
    settings = MonitorSettings.from_file(config_path('cell.yaml'))
    work = Path(tempfile.mkdtemp(prefix='positioning_cell_bench_fleet_'))
    try:
        start = time.perf_counter()
        bags, written = write_bags(work, args.bags, args.distinct, args.messages)
        size = sum(f.stat().st_size for f in bags[0].iterdir()) / 2**20
        print(f'bags: {len(bags)} ({min(args.distinct, args.bags)} distinct runs, the rest '
              f'copies), {written:,} messages and {size:.0f} MiB each, written in '
              f'{time.perf_counter() - start:.0f} s: {work}', flush=True)
        small = work / 'warm_up'
        write_run_bag(small, long_run(2_000)[0])
        print(f'cores: {os.cpu_count()}; load average before: '
              f'{", ".join(f"{v:.1f}" for v in os.getloadavg())}', flush=True)

        digest_bag(small, settings)
        reference, failures, serial_rate = timed(
            lambda: split([digest_bag(b, settings) for b in bags]), len(bags),
            'serial loop in one process (baseline)')
        ok = not failures
        rates: dict[int, float] = {}
        for workers in (1, 2):
            start = time.perf_counter()
            with dask_client(None, workers) as client:
                client.run(digest_bag, str(small), settings)  # every worker warmed up
                print(f'LocalCluster of {workers} worker(s) started and warmed up in '
                      f'{time.perf_counter() - start:.1f} s (before the clock)', flush=True)
                digests, failures, rates[workers] = timed(
                    partial(digest_bags, client, bags, settings, say=quiet), len(bags),
                    f'LocalCluster, {workers} worker(s)')
            by_bag = {d.bag: d for d in digests}
            same = not failures and [by_bag.get(d.bag) for d in reference] == reference
            ok = ok and same
            if not same:
                print(f'WRONG: {len(failures)} bag(s) failed '
                      f'({"; ".join(f.reason for f in failures[:3])}) or digests differ from '
                      'the serial ones')
        ratio = rates[2] / rates[1]
        print(f'ratio 2 workers / 1 worker: {ratio:.2f} (target >= 1.6); 2 workers / serial: '
              f'{rates[2] / serial_rate:.2f}; 1 worker / serial: {rates[1] / serial_rate:.2f}')
        print(f'load average after: {", ".join(f"{v:.1f}" for v in os.getloadavg())}')
        result = trends(reference)
        ok = ok and result.modes == MODES and all(d.modes == MODES for d in reference)
        print('analysis ' + ('correct: every bag analysed, the same digests serially and on '
                             'each cluster, three modes' if ok else 'WRONG'))
        return 0 if ok else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == '__main__':
    sys.exit(main())
