"""How long the one file reader (positioning_cell.files) takes on files at its size limits,
against the positioner's bound on a calibration file's load.

For each kind of file: a YAML document of numbers in short lists (the costliest plain content
per byte: one node per 4-8 bytes) just under the kind's limit, loaded with
``files.load_yaml``; the median and largest of --repeat loads. Then a real-sized calibration
file and the largest one accepted, loaded as the positioner does (calibration file checks and
the calibrated machine built: ``motion.calibrated.calibrated_machine``, in its worker thread).

Run: .venv/bin/python benchmarks/files.py [--repeat 5]
Target (issue 21): the largest calibration file accepted loads in under a third of
LOAD_TIMEOUT_S (1 s), so that a busy machine does not refuse a file the cell accepts. Exits 1
if not.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from positioning_cell import files
from positioning_cell.calibration import file as calfile
from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration.calibrated import LOAD_TIMEOUT_S, calibrated_machine
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.motion.settings import CALIBRATION_FILE, PositionerSettings
from positioning_cell.parameters import parse


def _numbers_document(max_bytes: int) -> str:
    """Rows of six numbers until just under ``max_bytes``."""
    row = yaml.safe_dump([[0.123456, -1.5e-05, 2.0, 3.25, -0.000125, 1.0]],
                         default_flow_style=None)
    return 'rows:\n' + row * ((max_bytes - 16) // len(row))


def _calibration(residuals: int) -> dict[str, Any]:
    mech = Mechanism.default()
    params = {n: {'value': 1e-5, 'sigma': 1e-6, 'unit': cp.UNITS[k], 'identified': True}
              for k, n in enumerate(cp.PARAMETER_NAMES)}
    a = np.random.default_rng(0).normal(0.0, 1e-9, (cp.COUNT, cp.COUNT))
    return {'calibration': {
        'format': calfile.FORMAT, 'mechanism_fingerprint': calfile.fingerprint(mech),
        'date': '2026-01-01T00:00:00+00:00', 'program': {'poses': 60, 'hold_out': 20},
        'seating_force': 1.0, 'parameters': params, 'covariance': (a @ a.T).tolist(),
        'residuals': {'chi2': 1.0, 'dof': 300,
                      'pose_position_um': [1.234567] * residuals}}}


def _largest_calibration(folder: Path) -> Path:
    """A valid calibration file just under the limit (its residuals list padded)."""
    path = folder / 'largest.yaml'
    low, high = 0, files.CALIBRATION_FILE.max_bytes // 4
    while low < high:  # the most residuals that fit
        mid = (low + high + 1) // 2
        calfile.write(path, _calibration(mid))
        if path.stat().st_size <= files.CALIBRATION_FILE.max_bytes:
            low = mid
        else:
            high = mid - 1
    calfile.write(path, _calibration(low))
    return path


def _times(load: Callable[[], Any], repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        start = time.perf_counter()
        load()
        out.append(time.perf_counter() - start)
    return out


def _line(what: str, size: int, times: list[float]) -> str:
    return (f'{what:<44} {files.size_text(size):>10}  median {statistics.median(times):7.3f} s'
            f'  max {max(times):7.3f} s')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeat', type=int, default=5)
    args = parser.parse_args()
    print(f'libyaml events: {files._EVENTS.__name__}')
    with tempfile.TemporaryDirectory(prefix='files_bench_') as tmp:
        folder = Path(tmp)
        for kind in (files.PARAMETER_FILE, files.MECHANISM_FILE, files.CALIBRATION_FILE,
                     files.COORDINATE_SYSTEMS_FILE):
            path = folder / f'{kind.name.replace(" ", "_")}.yaml'
            path.write_text(_numbers_document(kind.max_bytes))
            times = _times(lambda p=path, k=kind: files.load_yaml(p, k), args.repeat)
            print(_line(f'{kind.name}: numbers at the limit', path.stat().st_size, times))
        real = calfile.write(folder / 'real.yaml', _calibration(60))
        largest = _largest_calibration(folder)
        worst = 0.0
        for what, path in (('calibration file, real size, as the positioner', real),
                           ('calibration file, largest accepted, as above', largest)):
            settings = parse(PositionerSettings, {CALIBRATION_FILE: str(path)})
            times = _times(lambda s=settings: calibrated_machine(s), args.repeat)
            print(_line(what, path.stat().st_size, times))
            worst = max(worst, *times)
    target = LOAD_TIMEOUT_S / 3
    ok = worst < target
    print(f'largest calibration load {worst:.3f} s, target < {target:.3f} s '
          f'(LOAD_TIMEOUT_S / 3): {"met" if ok else "NOT met"}')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
