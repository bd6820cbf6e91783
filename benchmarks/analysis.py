"""analyze_bag throughput on a bag of >= 1 000 000 messages (figures vary ±20-50 % on the shared
2-core VMs; see platform.md).

The bag is a long synthetic cell run written with rosbags' writer
(positioning_cell.testing.synthetic_run): the ISO cube's five poses visited under the three
compensation modes, a move every 2.5 s, the tracker at 20 Hz with the true pose at the same
stamps, the program steps and the positioner's mode diagnostics, and /legs/joint_states
filler so that the analysed topics are the share of the messages they are in a recorded run
of the cell (~13 %: 5 100 of 43 900 in a `make run` bag). Measured: the whole of
``analyze`` (read, replay through the monitor's rules, per mode/pose figures, report, plots),
and reading alone; reported as messages of the bag per second and as analysed (decoded and
replayed) messages per second.

Run: ``.venv/bin/python benchmarks/analysis.py [--messages N]`` (make bench). Exits non-zero
only if the analysis is wrong (a move did not settle, a mode is missing), never on speed.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from positioning_cell.analysis.reading import read_bag
from positioning_cell.analysis.replay import OPTIONAL_TOPICS, REQUIRED_TOPICS
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag
from positioning_cell.tools.analyze_bag import analyze

POSITIONS = np.array([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2], [-0.004, -0.004, 0.2],
                      [-0.004, -0.004, 0.192], [0.004, 0.004, 0.192]])
QUATERNIONS = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
RATE = 20.0                 # tracker, Hz (truth at the same stamps)
PERIOD = 2.5                # s per move
FILLER_SHARE = 0.87         # of all messages: /legs/joint_states (the rest is analysed)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--messages', type=int, default=1_000_000,
                        help='messages in the bag (at least this many; default 1 000 000)')
    args = parser.parse_args()
    analysed_rate = 2 * RATE + 2.0 / PERIOD  # measurement + truth + program + diagnostics
    filler_rate = analysed_rate * FILLER_SHARE / (1.0 - FILLER_SHARE)
    duration = args.messages / (analysed_rate + filler_rate) * 1.01
    cycles = max(2, int(np.ceil(duration / PERIOD / 3 / len(POSITIONS))))
    work = Path(tempfile.gettempdir()) / 'positioning_cell_bench' / 'analysis'
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    bag = work / 'bag'
    start = time.perf_counter()
    run = synthetic_run(POSITIONS, QUATERNIONS, cycles=cycles, rate=RATE, move_time=1.0,
                        dwell_time=PERIOD - 1.0)
    written = write_run_bag(bag, run, joint_state_rate=filler_rate)
    moves = run.target_time.size
    size = sum(f.stat().st_size for f in bag.iterdir()) / 2**20
    print(f'bag: {written:,} messages ({moves} moves, {cycles} cycles x 3 modes x 5 poses, '
          f'{run.time[-1] - run.time[0]:.0f} s of run), {size:.0f} MiB, written in '
          f'{time.perf_counter() - start:.0f} s: {bag}')

    start = time.perf_counter()
    contents = read_bag(bag, (*REQUIRED_TOPICS, *OPTIONAL_TOPICS))
    read_s = time.perf_counter() - start
    analysed = len(contents.messages)
    del contents
    print(f'read + decode the analysed topics: {read_s:.1f} s = {written / read_s:,.0f} bag '
          f'msgs/s ({analysed:,} decoded = {analysed / read_s:,.0f} msgs/s)')

    start = time.perf_counter()
    output = analyze(bag, work / 'out')
    total_s = time.perf_counter() - start
    a = output.analysis
    print(f'analyze (read, replay, figures, report, {len(output.plots)} plots): {total_s:.1f} s '
          f'= {written / total_s:,.0f} bag msgs/s, {analysed / total_s:,.0f} analysed msgs/s '
          f'({a.replay.measured.count:,} measurements + {a.replay.truth.count:,} true poses '
          f'through the monitor rules)')
    ok = (len(a.replay.visits) == moves and [m.mode for m in a.modes] ==
          ['none', 'model', 'measured'] and written >= args.messages)
    print('analysis ' + ('correct: every move settled, three modes' if ok else
                         f'WRONG: {len(a.replay.visits)} visits for {moves} moves'))
    shutil.rmtree(work, ignore_errors=True)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
