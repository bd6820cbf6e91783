"""The whole acceptance program on the cell (``run_cell --program config/acceptance.yaml``:
the calibration, five cycles of the ISO 9283 poses in two modes, the static compliance test)
and the analysis of its bag (issue 25).

Measured in the same run:
- the cell time: the wall time of ``run_cell`` from its start to the end of its own analysis
  (the cell started, calibrated, the program and the compliance test driven, stopped);
- the analysis: ``analyze`` of the recorded bag with the program's acceptance limits (the
  report, the acceptance record, the plots) in a fresh process, ``--repeat`` times, the fastest
  kept; BASELINE: rosbags (``AnyReader``) reading and deserialising every message of the topics
  the analysis reads (positioning_cell.analysis.summary.READ_TOPICS), in a fresh process, as
  many times.

``--bag PATH`` analyses a bag recorded before (no cell time then).

Targets (issue 25): the acceptance program <= 15 min of cell time; its analysis <= 10 s.
Prints what it measured, whether each target is met, and the record's decision per mode and
its §9, §10 figures; exits non-zero only when the record lacks a characteristic the program
measures (a clause of ISO 9283 that applies missing), never on time.

Run: ``.venv/bin/python benchmarks/acceptance_run.py [--bag PATH] [--repeat N]`` (make bench).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from analysis import peak_rss_mib, rosbags_decoded

from positioning_cell.analysis.summary import READ_TOPICS
from positioning_cell.config import config_path
from positioning_cell.tools.analyze_bag import ANALYSIS_ENVIRONMENT

CELL_TARGET_S = 15 * 60.0
ANALYSIS_TARGET_S = 10.0
#: The ISO 9283 clauses the shipped acceptance program gives a figure for.
CLAUSES = ('7.2.1', '7.2.2', '7.2.3', '7.3.1', '7.3.2', '7.4', '7.5', '7.6', '8.2', '8.6', '9',
           '10')


def child(which: str, bag: Path, out: Path) -> None:
    """One measurement in this process; prints JSON: seconds, peak RSS and what was found."""
    start = time.perf_counter()
    if which == 'baseline':
        found: dict[str, Any] = {'decoded': rosbags_decoded(bag, READ_TOPICS)}
    else:
        from positioning_cell.tools.analyze_bag import analyze
        output = analyze(bag, out, program=config_path('acceptance.yaml'))
        found = {'plots': len(output.plots), 'problems': list(output.analysis.problems)}
    print(json.dumps({'seconds': time.perf_counter() - start, 'rss_mib': peak_rss_mib(),
                      **found}))


def fresh(which: str, bag: Path, out: Path) -> dict[str, Any]:
    """:func:`child` in a new process with the analyze_bag command's environment."""
    result = subprocess.run([sys.executable, __file__, '--child', which, str(bag), str(out)],
                            capture_output=True, text=True, check=True,
                            env={**os.environ, **ANALYSIS_ENVIRONMENT})
    doc: dict[str, Any] = json.loads(result.stdout.strip().splitlines()[-1])
    return doc


def run_program(work: Path) -> tuple[Path, float]:
    """run_cell with the shipped acceptance program into ``work/runs``: its bag and wall
    time."""
    start = time.perf_counter()
    subprocess.run([sys.executable, '-m', 'positioning_cell.tools.run_cell', '--program',
                    str(config_path('acceptance.yaml')), '--runs', str(work / 'runs')],
                   check=False, env=dict(os.environ))
    seconds = time.perf_counter() - start
    bags = sorted((work / 'runs').glob('*/bag'))
    if not bags:
        raise SystemExit(f'run_cell recorded no bag under {work / "runs"}')
    return bags[-1], seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--bag', type=Path, help='analyse this acceptance bag (no cell run)')
    parser.add_argument('--repeat', type=int, default=2, help='analyses of each kind (2)')
    parser.add_argument('--child', nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], Path(args.child[1]), Path(args.child[2]))
        return 0
    with tempfile.TemporaryDirectory(prefix='acceptance_run_') as tmp:
        work = Path(tmp)
        cell_s = None
        bag = args.bag
        if bag is None:
            bag, cell_s = run_program(work)
        runs: dict[str, list[dict[str, Any]]] = {'baseline': [], 'analyze': []}
        for k in range(args.repeat):
            for which, taken in runs.items():
                taken.append(fresh(which, bag, work / f'out{k}'))
        best = {w: min(r, key=lambda d: float(d['seconds'])) for w, r in runs.items()}
        record = json.loads((work / 'out0' / 'acceptance.json').read_text())
    print(f'bag {bag}' + ('' if args.bag else ' (recorded now, removed after)'))
    if cell_s is not None:
        print(f'cell time (run_cell: start, calibration, program, compliance test, stop, its '
              f'analysis): {cell_s / 60:.2f} min; target <= {CELL_TARGET_S / 60:.0f} min: '
              f'{"met" if cell_s <= CELL_TARGET_S else "NOT met"}')
    a, b = best['analyze'], best['baseline']
    print(f'BASELINE rosbags read + deserialise of the analysed topics ({b["decoded"]} '
          f'messages): {b["seconds"]:.2f} s, peak RSS {b["rss_mib"]:.0f} MiB')
    print(f'analyze with the acceptance limits and the plots: {a["seconds"]:.2f} s '
          f'({a["seconds"] / b["seconds"]:.2f} x the baseline), peak RSS {a["rss_mib"]:.0f} '
          f'MiB; target <= {ANALYSIS_TARGET_S:.0f} s: '
          f'{"met" if a["seconds"] <= ANALYSIS_TARGET_S else "NOT met"}')
    print('decision per mode: ' + ', '.join(f'{m} {d}' for m, d in record['modes'].items()))
    found = record['characteristics']
    for c in found:
        if c['clause'] in ('9', '10') and c['mode'] in ('machine', 'model'):
            unit = 'um/N' if c['unit'] == 'm/N' else c['unit']
            scale = 1e6 if c['unit'] == 'm/N' else 1.0
            u = '?' if c['uncertainty'] is None else f'{c["uncertainty"] * scale:.3f}'
            print(f'  §{c["clause"]} {c["mode"]} {c["subject"]}: {c["value"] * scale:.3f} '
                  f'± {u} {unit}, {c["decision"]}')
    missing = [k for k in CLAUSES if k not in {c['clause'] for c in found}]
    if missing or a['problems']:
        print(f'WRONG: the record lacks ISO 9283 {", ".join(missing) or "nothing"}; problems: '
              f'{a["problems"]}')
        return 1
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
