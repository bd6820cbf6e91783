"""The shipped coordinated cell end to end (issue 27): ``run_cell --cell
config/three_positioners.yaml`` (each positioner calibrated, the panel mounted and relaxed, the
cell calibrated from the panel's targets, relaxed again, the panel program's three cycles of
five poses, the analysis), as shipped and, in the same run, its BASELINE: the same with the load
corrections one for every pose (``relax.follow_pose: false``, config/coordinated.yaml otherwise
unchanged), what the cell did before the strain map.

For each: the wall time of run_cell, its exit code, the moves done and failed, and from its
panel report (the simulators' truth, judging only) the panel's test point from its goal (RMS and
largest, µm), the cell tracker's own error, and the largest attachment disagreement and
internal force while moving and at rest.

Targets (issue 27, on the default three-positioner cell): the run <= 6 min; the panel's pose
truth RMS <= 15 µm on the program's poses (hold-out: the cell was calibrated at others);
the attachments' disagreement <= 20 µm while moving (truth). Prints what it measured and
whether each target is met; exits non-zero only when a run gave no report.

Run: ``.venv/bin/python benchmarks/coordinated_run.py [--only shipped|baseline]`` (about 6
min a run; ``make bench``).
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

import numpy as np
import yaml

from positioning_cell.config import config_path

RUN_TARGET_S = 6 * 60.0
TRUTH_RMS_TARGET_UM = 15.0
MOVING_TARGET_UM = 20.0


def baseline_config(work: Path) -> Path:
    """config/coordinated.yaml with the coordinator's ``relax.follow_pose`` false."""
    params = yaml.safe_load(config_path('coordinated.yaml').read_text(encoding='utf-8'))
    section = params.setdefault('cell_coordinator', {}).setdefault('ros__parameters', {})
    section.setdefault('relax', {})['follow_pose'] = False
    path = work / 'coordinated_baseline.yaml'
    path.write_text(yaml.safe_dump(params), encoding='utf-8')
    return path


def run(work: Path, cell_config: Path | None) -> dict[str, Any]:
    """One run_cell --cell into ``work/runs``: its wall time, exit code and panel report."""
    command = [sys.executable, '-m', 'positioning_cell.tools.run_cell', '--cell',
               str(config_path('three_positioners.yaml')), '--runs', str(work / 'runs')]
    if cell_config is not None:
        command += ['--cell-config', str(cell_config)]
    start = time.perf_counter()
    ran = subprocess.run(command, check=False, env=dict(os.environ), capture_output=True,
                         text=True)
    seconds = time.perf_counter() - start
    reports = sorted((work / 'runs').glob('*/panel_report.json'))
    report = json.loads(reports[-1].read_text()) if reports else None
    relaxes = [line for line in ran.stdout.splitlines() if line.startswith('relax from')]
    return {'seconds': seconds, 'code': ran.returncode, 'report': report, 'relaxes': relaxes,
            'tail': ran.stdout.splitlines()[-5:] + ran.stderr.splitlines()[-5:]}


def figures(result: dict[str, Any]) -> dict[str, float]:
    """What the run's report says against the targets."""
    report = result['report']
    truth = np.asarray(report['true_error_um'], dtype=float)
    return {'seconds': result['seconds'], 'steps': report['steps'],
            'failed': len(report['failed']),
            'truth_rms_um': float(np.sqrt(np.mean(truth**2))),
            'truth_max_um': float(truth.max()),
            'tracker_rms_um': float(np.sqrt(np.mean(np.square(report['tracker_error_um'])))),
            'moving_um': report['moving']['largest_stretch_um'],
            'moving_n': report['moving']['largest_force_n'],
            'rest_um': report['at_rest']['largest_stretch_um'],
            'rest_n': report['at_rest']['largest_force_n']}


def main() -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or '').split('\n\n')[0])
    parser.add_argument('--only', choices=('shipped', 'baseline'),
                        help='one of the two runs only')
    args = parser.parse_args()
    results: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix='coordinated_run_') as tmp:
        work = Path(tmp)
        for name in ('baseline', 'shipped'):
            if args.only not in (None, name):
                continue
            where = work / name
            where.mkdir()
            config = baseline_config(where) if name == 'baseline' else None
            results[name] = run(where, config)
            print(f'{name}: exit {results[name]["code"]} in {results[name]["seconds"]:.0f} s',
                  flush=True)
            for line in results[name]['relaxes']:
                print(f'  {line[:160]}')
    missing = [n for n, r in results.items() if r['report'] is None]
    for name in missing:
        print(f'{name}: no panel report; its output ends:', *results[name]['tail'], sep='\n  ')
    rows = {n: figures(r) for n, r in results.items() if r['report'] is not None}
    print('\n| run | time | exit | moves (failed) | truth RMS (largest) | tracker RMS | '
          'moving: stretch, force | at rest |')
    print('| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |')
    for name, f in rows.items():
        minutes, rest = divmod(round(f['seconds']), 60)
        print(f'| {name} | {minutes}:{rest:02d} | '
              f'{results[name]["code"]} | {f["steps"]:.0f} ({f["failed"]:.0f}) | '
              f'{f["truth_rms_um"]:.1f} um ({f["truth_max_um"]:.1f}) | '
              f'{f["tracker_rms_um"]:.1f} um | {f["moving_um"]:.1f} um, {f["moving_n"]:.0f} N | '
              f'{f["rest_um"]:.1f} um, {f["rest_n"]:.0f} N |')
    if 'shipped' in rows:
        f = rows['shipped']
        for what, value, target, unit in (
                ('run time', f['seconds'], RUN_TARGET_S, 's'),
                ('panel truth RMS', f['truth_rms_um'], TRUTH_RMS_TARGET_UM, 'um'),
                ('disagreement while moving', f['moving_um'], MOVING_TARGET_UM, 'um')):
            verdict = 'met' if value <= target else 'NOT met'
            print(f'target {what} <= {target:g} {unit}: {value:.1f} {unit}, {verdict}')
    return 1 if missing else 0


if __name__ == '__main__':
    sys.exit(main())
