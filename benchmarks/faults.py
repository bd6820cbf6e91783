"""Reaction times of the fault matrix (positioning_cell.procedures.fault_trials;
docs/reference/fault-matrix.md): --trials trials of each fault on one cell (the four nodes
and the recorder as processes on a free ROS domain, homed).

Per fault: the reaction time (injection → the positioner's status with the result code; the
driver's answer for a trajectory sent to it; the last reply of a flood), median and max, against
its bound; the time until every axis was at rest (from /sim/legs/true_joint_states), median and
max; how many trials gave the expected reaction; and whether any axis went beyond a limit.
The baseline, from the same cell: --baseline-trials trials of each with the positioner's
liveness rules as lax as their parameters allow (joint silence, answer timeout and freeze window
10 s, tracker silence 60 s, scatter limit 1000 sigma: what is left is the arrival and
measurement timeouts), its median reaction time and how many trials still gave the expected
reaction.

Then the probes only the driver's commander can send (positioning_cell.ros.driver_probes:
stamps 0.6 s in the past and 4 s ahead, 100 000 and 50 000 points), --driver-trials times each
on a driver bound to this benchmark: the time to the driver's answer and the largest interval
between two of its encoder publications around it, median and max; the baseline: the largest
interval over 60 publications while nothing is sent, from the same driver.

Run: .venv/bin/python benchmarks/faults.py [--trials 20] [--baseline-trials 3]
[--driver-trials 5] [fault ...]
Targets (issues 11, 21): every reaction within its bound, the expected code in every trial, no
motion beyond a limit in any trial; every driver probe answered as expected with no
publication interval above 0.1 s. Exits 1 if one is not met.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from positioning_cell.procedures.fault_trials import (
    FAULTS,
    Trial,
    fault,
    run_trial,
    set_liveness,
)
from positioning_cell.ros.driver_probes import PROBES, CommandedDriver, ProbeResult
from positioning_cell.ros.fault_cell import FaultCell

#: Largest interval between two encoder publications of the driver while it takes a command.
LARGEST_GAP_S = 0.1


def _stats(values: list[float]) -> str:
    return f'{np.median(values):6.3f} / {max(values):6.3f}' if values else '     — /      —'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--trials', type=int, default=20)
    parser.add_argument('--baseline-trials', type=int, default=3)
    parser.add_argument('--driver-trials', type=int, default=5)
    parser.add_argument('faults', nargs='*', help='names of rows (default: all)')
    args = parser.parse_args()
    chosen = [fault(n) for n in args.faults] or list(FAULTS)
    results: dict[str, list[Trial]] = {f.name: [] for f in chosen}
    baseline: dict[str, list[Trial]] = {f.name: [] for f in chosen}
    with tempfile.TemporaryDirectory(prefix='faults_bench_') as tmp, FaultCell(Path(tmp)) as cell:
        cell.start()
        for k in range(args.trials):
            for f in chosen:
                results[f.name].append(run_trial(cell, f))
            print(f'round {k + 1}/{args.trials} done', flush=True)
        set_liveness(cell, False)
        for k in range(args.baseline_trials):
            for f in chosen:
                baseline[f.name].append(run_trial(cell, f))
            print(f'baseline round {k + 1}/{args.baseline_trials} done', flush=True)
        set_liveness(cell, True)
    print(f'\n{"fault":26s} {"bound s":>7s} {"reaction s med / max":>22s} '
          f'{"at rest s med / max":>21s} {"expected":>9s} {"limits":>7s} '
          f'{"baseline: reaction med, expected":>33s}')
    met = True
    for f in chosen:
        trials = results[f.name]
        reaction = [t.reaction_s for t in trials]
        rest = [t.stopped_s for t in trials if t.stopped_s is not None]
        good = sum(t.ok for t in trials)
        limits = all(t.within_limits for t in trials)
        base = baseline[f.name]
        base_text = (f'{np.median([t.reaction_s for t in base]):8.3f} s, '
                     f'{sum(t.ok for t in base)}/{len(base)}') if base else '—'
        print(f'{f.name:26s} {f.bound_s:7g} {_stats(reaction):>22s} {_stats(rest):>21s} '
              f'{good:4d}/{len(trials):<4d} {"ok" if limits else "BEYOND":>7s} '
              f'{base_text:>33s}')
        for t in trials:
            if not t.ok:
                print(f'    {t.code} (injection took {t.inject_s:.3f} s): '
                      f'{"; ".join(t.problems)}')
        codes = sorted({t.code for t in trials})
        print(f'    codes seen: {", ".join(codes)}')
        met &= good == len(trials) and limits
    met &= _driver_probes(args.driver_trials)
    print(f'\ntargets (every reaction expected and in bound, no axis beyond a limit, every '
          f'driver probe answered as expected without a publication gap above '
          f'{LARGEST_GAP_S:g} s): {"met" if met else "NOT met"}')
    return 0 if met else 1


def _driver_probes(trials: int) -> bool:
    """The commander's probes, ``trials`` times each; True when every one was as expected."""
    results: dict[str, list[ProbeResult]] = {p.name: [] for p in PROBES}
    quiet: list[float] = []
    with tempfile.TemporaryDirectory(prefix='driver_probes_') as tmp:
        driver = CommandedDriver(Path(tmp))
        try:
            for _ in range(trials):
                quiet.append(driver.quiet_gap() * 1e3)
                for probe in PROBES:
                    results[probe.name].append(driver.probe(probe))
        finally:
            driver.close()
    print(f'\n{"driver probe":26s} {"answer ms med / max":>22s} '
          f'{"largest gap ms med / max":>26s} {"expected":>9s}')
    met = True
    for name, done in results.items():
        answer = [r.answer_s * 1e3 for r in done]
        gap = [r.largest_gap_s * 1e3 for r in done]
        good = sum(r.expected and r.largest_gap_s < LARGEST_GAP_S for r in done)
        print(f'{name:26s} {_stats(answer):>22s} {_stats(gap):>26s} {good:4d}/{len(done):<4d}')
        met &= good == len(done)
    print(f'{"baseline: nothing sent":26s} {"":>22s} {_stats(quiet):>26s}')
    return met


if __name__ == '__main__':
    sys.exit(main())
