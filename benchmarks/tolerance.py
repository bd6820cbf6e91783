"""Throughput of the general tolerance engine's nonlinear Monte Carlo (issue: tolerance analysis
for any mechanism): samples per second on one core, for planar mechanisms of seed 004's size.

Mechanisms:
- ``examples/seed004_flap_variant.yaml``: seed 004's flap linkage as analysed (15 sources,
  2 closure equations h_y, h_θ for u1, u2; 11 + 10 vectors);
- *flap 3 × 3*: the same linkage as printed (14 sources, 10 + 10 vectors) with u3 turned
  perpendicular to u2 (angle −u1) so that h_x, h_y, h_θ fix u1, u2, u3, closed at Table 1's
  nominal by a constant ground vector and angle: 3 equations, 3 unknowns (built here);
- ``examples/four_bar.yaml`` for reference.

Measured, best of three, one thread: the whole Monte Carlo (draws from the laws + the kernel's
Newton closure + the assembly dimensions + T·x; :func:`~positioning_cell.tolerance.montecarlo.
monte_carlo`), the kernel alone on drawn samples, the draws alone, the linear model alone
(draws + T·x); and the baseline in the same run: the closure per sample with
``scipy.optimize.root`` (hybrd, exact Jacobian) over a few thousand samples, extrapolated. The
kernel's unknowns and assembly dimensions must match scipy's to 1e-9 (m or rad) on those
samples: the run exits 1 otherwise, never on speed.

Run: ``.venv/bin/python benchmarks/tolerance.py [samples] [baseline_samples]``. Target
(issue): >= 1 M samples/s for the whole nonlinear Monte Carlo. The machine is shared and its
speed drifts by tens of per cent.
"""

from __future__ import annotations

import os

for _var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')   # one core: BLAS (T·x) on one thread too

import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import TypeVar  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from positioning_cell.tolerance.loops import Form, linearise  # noqa: E402
from positioning_cell.tolerance.model import Mechanism, load_mechanism, parse_mechanism  # noqa: E402
from positioning_cell.tolerance.montecarlo import (  # noqa: E402
    KernelProblem,
    monte_carlo,
    solve_samples,
    solve_with_scipy,
)
from positioning_cell.tolerance.sampling import draw  # noqa: E402

R = TypeVar('R')
EXAMPLES = Path(__file__).resolve().parent.parent / 'examples'
TARGET = 1e6
AGREEMENT = 1e-9


def flap_three_by_three() -> Mechanism:
    """Seed 004's printed flap loop with u3 perpendicular to u2 and a ground closing it."""
    data = yaml.safe_load((EXAMPLES / 'seed004_flap.yaml').read_text())
    loop = data['closed_loops']['flap']
    for v in loop['vectors']:
        if v['length'] == 'u3':
            v['angle'] = '-u1'
    trial = parse_mechanism(data, 'flap 3 x 3')
    form = Form.from_mechanism(trial)
    h = form.evaluate(form.point())[:3]
    loop['vectors'] += [{'length': -float(h[0]) * 1e3, 'angle': '0 deg'},
                        {'length': -float(h[1]) * 1e3, 'angle': '90 deg'}]
    loop['equations']['theta'] += f' - {math.degrees(float(h[2]))!r} deg'
    data['name'] = 'seed 004 flap, 3 x 3 (u3 perpendicular to u2)'
    return parse_mechanism(data, 'flap 3 x 3')


def best(fn: Callable[[], R], runs: int = 3) -> tuple[R, float]:
    """The last result and the least wall time of ``runs`` calls."""
    times, out = [], None
    for _ in range(runs):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    assert out is not None
    return out, min(times)


def bench(name: str, mech: Mechanism, samples: int, baseline_samples: int) -> tuple[bool, float]:
    """Print the figures of one mechanism; (agreement ok, whole Monte Carlo rate)."""
    form = Form.from_mechanism(mech)
    lin = linearise(form)
    problem = KernelProblem.build(form, lin)
    monte_carlo(mech, 1000, np.random.default_rng(0), lin=lin)   # compiled (or cached) kernel
    print(f'{name}: {len(mech.sources)} sources, {form.n_closure} equations / unknowns, '
          f'{form.length.shape[0]} vectors, {problem.angle_ptr.size - 1} angle(s) with an '
          f'unknown, {problem.n_free} without')
    mc, t_mc = best(lambda: monte_carlo(mech, samples, np.random.default_rng(1), lin=lin))
    assert mc.unsolved == 0, f'{mc.unsolved} unsolved samples'
    x, t_draw = best(lambda: draw(mech.sources, samples, np.random.default_rng(1)))
    _, t_kernel = best(lambda: solve_samples(problem, x))
    _, t_lin = best(lambda: lin.T @ draw(mech.sources, samples, np.random.default_rng(1)))
    sub = draw(mech.sources, baseline_samples, np.random.default_rng(2))
    ref, t_ref = best(lambda: solve_with_scipy(form, lin, sub), runs=1)
    ours = solve_samples(problem, sub)
    du = float(np.abs(ours.unknowns - ref.unknowns).max())
    dg = float(np.abs(ours.outputs - ref.outputs).max())
    ok = bool(ref.converged.all() and ours.converged.all() and du <= AGREEMENT
              and dg <= AGREEMENT)
    rate = samples / t_mc
    scipy_rate = baseline_samples / t_ref
    for label, t, n in (('whole Monte Carlo (draws + closure + Gap + T.x)', t_mc, samples),
                        ('kernel alone (closure + Gap + T.x, drawn samples)', t_kernel, samples),
                        ('draws alone', t_draw, samples),
                        ('linear model (draws + T.x)', t_lin, samples),
                        ('baseline: scipy.optimize.root per sample', t_ref, baseline_samples)):
        print(f'  {label}: {n / t:>12,.0f} samples/s  ({n} samples, {t:.3f} s)')
    print(f'  ratio whole Monte Carlo / scipy baseline: {rate / scipy_rate:,.0f}x; Newton steps '
          f'per sample: mean {mc.iterations.mean():.2f}, max {mc.iterations.max()}')
    print(f'  agreement with scipy on {baseline_samples} samples: max |du| {du:.1e}, max |dGap| '
          f'{dg:.1e} (m or rad): {"ok" if ok else "WRONG"}; max |nonlinear - T.x| '
          f'{np.abs(mc.outputs - mc.linear).max():.2e}')
    return ok, rate


def main() -> int:
    samples = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    baseline_samples = int(sys.argv[2]) if len(sys.argv) > 2 else 2000
    print(f'machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} (shared); '
          'one thread')
    cases = {'seed 004 flap, analysable variant': load_mechanism(
        EXAMPLES / 'seed004_flap_variant.yaml'), 'seed 004 flap, 3 x 3': flap_three_by_three(),
        'four-bar': load_mechanism(EXAMPLES / 'four_bar.yaml')}
    results = {name: bench(name, replace(mech), samples, baseline_samples)
               for name, mech in cases.items()}
    for name, (_, rate) in results.items():
        print(f'target >= {TARGET:,.0f} samples/s, {name}: '
              f'{"met" if rate >= TARGET else "NOT met"} ({rate:,.0f}/s)')
    return 0 if all(ok for ok, _ in results.values()) else 1


if __name__ == '__main__':
    sys.exit(main())
