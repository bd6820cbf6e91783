"""The Monte Carlo with the nonlinear loop closure (positioning_cell.tolerance.montecarlo): the
kernel against a per-sample scipy solve (planar and spatial), against the linear model for
small tolerances (the difference is second order), unsolved samples flagged, the draws'
laws, and the yield with its interval."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.stats import kstest, truncnorm

from positioning_cell.tolerance.analysis import analyse
from positioning_cell.tolerance.expressions import LENGTH
from positioning_cell.tolerance.loops import Form, linearise
from positioning_cell.tolerance.model import Mechanism, Source, load_mechanism, parse_mechanism
from positioning_cell.tolerance.montecarlo import (
    KernelProblem,
    monte_carlo,
    solve_samples,
    solve_with_scipy,
    warm_up,
)
from positioning_cell.tolerance.sampling import draw

EXAMPLES = Path(__file__).resolve().parent.parent / 'examples'

SPATIAL: dict[str, Any] = {
    'units': {'length': 'mm'}, 'space': 'spatial',
    'sources': {'ox': {'nominal': 50, 'tolerance': 0.5}, 'oy': {'nominal': -20, 'tolerance': 0.5},
                'oz': {'nominal': 10, 'tolerance': 0.5}, 'tx': {'nominal': 250, 'tolerance': 1},
                'ty': {'nominal': 180, 'tolerance': 1}, 'tz': {'nominal': 140, 'tolerance': 1},
                'c': {'nominal': 40, 'tolerance': 0.5},
                'az': {'nominal': '30 deg', 'tolerance': '2 deg'},
                'el': {'nominal': '-15 deg', 'tolerance': '2 deg', 'distribution': 'uniform'}},
    'unknowns': {'L': 300, 'a': '40 deg', 'e': '25 deg'},
    'closed_loops': {'leg': {'vectors': [
        {'length': 'ox', 'direction': [1, 0, 0]}, {'length': 'oy', 'direction': [0, 1, 0]},
        {'length': 'oz', 'direction': [0, 0, 1]},
        {'length': 'L', 'azimuth': 'a', 'elevation': 'e'},
        {'length': 'c', 'azimuth': 'az + a', 'elevation': 'el - e'},
        {'length': '-tx', 'direction': [1, 0, 0]}, {'length': '-ty', 'direction': [0, 1, 0]},
        {'length': '-tz', 'direction': [0, 0, 1]}]}},
    'open_loops': {
        'leg_length': {'expression': 'L', 'requirement': {'tolerance': 1}},
        'knee_z': {'vectors': [{'length': 'oz', 'direction': [0, 0, 1]},
                               {'length': 'L', 'azimuth': 'a', 'elevation': 'e'}],
                   'component': 'z'},
        'knee_angle': {'expression': 'e - el'}}}


def mechanisms() -> dict[str, Mechanism]:
    return {name: load_mechanism(EXAMPLES / f'{name}.yaml')
            for name in ('seed004_flap_variant', 'four_bar', 'seed002_planar')} | {
        'spatial': parse_mechanism(SPATIAL, 'spatial')}


def scaled(mech: Mechanism, factor: float) -> Mechanism:
    return dataclasses.replace(mech, sources=tuple(
        dataclasses.replace(s, tolerance=s.tolerance * factor) for s in mech.sources))


@pytest.mark.parametrize('name', ['seed004_flap_variant', 'four_bar', 'seed002_planar',
                                  'spatial'])
def test_the_kernel_solves_as_scipy_does(name: str) -> None:
    mech = scaled(mechanisms()[name], 5.0)   # beyond the spec: a nonlinear closure
    form = Form.from_mechanism(mech)
    lin = linearise(form)
    deviations = draw(mech.sources, 60, np.random.default_rng(3))
    ours = solve_samples(KernelProblem.build(form, lin), deviations)
    ref = solve_with_scipy(form, lin, deviations)
    assert ours.converged.all() and ref.converged.all()
    np.testing.assert_allclose(ours.unknowns, ref.unknowns, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.outputs, ref.outputs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.linear, ref.linear, rtol=0, atol=1e-15)
    # ... and the loops are closed at the kernel's solution.
    points = form.point(lin.x0 + deviations.T, lin.u0 + ours.unknowns)
    assert np.abs(form.evaluate(points)[:, :form.n_closure]).max() < 1e-11
    assert np.abs(ours.outputs - ref.linear).max() > 1e-9   # the closure is not linear


@pytest.mark.parametrize('name', ['seed004_flap_variant', 'four_bar', 'spatial'])
def test_small_tolerances_follow_the_linear_model_to_second_order(name: str) -> None:
    base = mechanisms()[name]
    gaps = []
    for factor in (1e-1, 1e-2):
        mc = monte_carlo(scaled(base, factor), 4000, np.random.default_rng(5))
        assert mc.unsolved == 0
        spread = np.abs(mc.linear).max(axis=0)
        gaps.append(np.abs(mc.outputs - mc.linear).max(axis=0) / np.maximum(spread, 1e-300))
        assert (gaps[-1][spread > 0] < 20 * factor).all()
    ratio = gaps[0] / np.maximum(gaps[1], 1e-300)
    moving = gaps[0] > 1e-9
    assert ((ratio[moving] > 5) & (ratio[moving] < 20)).all(), ratio   # ~10: second order


def test_unassemblable_samples_are_flagged_and_counted_outside() -> None:
    """r3 = 90 ± 80 mm: the crank pin lies 87.2 mm from O4, so r3 outside [17.2, 157.2] mm
    cannot close the loop (12.5 % of a uniform law)."""
    mech = load_mechanism(EXAMPLES / 'four_bar.yaml')
    wide = dataclasses.replace(mech, sources=tuple(
        dataclasses.replace(s, tolerance=0.08, distribution='uniform') if s.name == 'r3' else s
        for s in mech.sources))
    result = analyse(wide, samples=5000, seed=2)
    mc, samples = result.monte_carlo, result.samples
    assert mc is not None and samples is not None
    assert 0 < mc.unsolved < 5000
    bad = ~samples.converged
    assert np.isnan(samples.outputs[bad]).all() and np.isnan(samples.unknowns[bad]).all()
    assert np.isfinite(samples.linear).all()
    rocker = result.dimensions[0].yield_nonlinear
    assert rocker is not None and rocker.inside <= 5000 - mc.unsolved


def test_draws_follow_the_laws() -> None:
    sources = [Source('n', LENGTH, 0.0, 0.3), Source('m', LENGTH, 0.0, 0.2, sigmas=2.0),
               Source('u', LENGTH, 0.0, 0.1, 'uniform'), Source('z', LENGTH, 0.0, 0.0)]
    x = draw(sources, 40_000, np.random.default_rng(11))
    assert x.shape == (4, 40_000) and x.flags.c_contiguous
    for row, src in zip(x, sources, strict=True):
        assert np.abs(row).max() <= src.tolerance
        assert row.std() == pytest.approx(src.std, rel=0.02, abs=1e-15)
    assert kstest(x[0] / 0.1, truncnorm(-3, 3).cdf).pvalue > 1e-3
    assert kstest(x[1] / 0.1, truncnorm(-2, 2).cdf).pvalue > 1e-3
    assert kstest(x[2], 'uniform', args=(-0.1, 0.2)).pvalue > 1e-3
    assert not x[3].any()


def test_the_yield_and_its_interval() -> None:
    """Gap = x1 + x2 with x1, x2 uniform on ± 1 mm: triangular, P(|Gap| ≤ 1 mm) = 3/4."""
    data = {'units': {'length': 'mm'},
            'sources': {'x1': {'nominal': 10, 'tolerance': 1, 'distribution': 'uniform'},
                        'x2': {'nominal': 5, 'tolerance': 1, 'distribution': 'uniform'}},
            'unknowns': {'u': 15},
            'closed_loops': {'stack': {'vectors': [
                {'length': 'x1', 'angle': '0 deg'}, {'length': 'x2', 'angle': '0 deg'},
                {'length': '-u', 'angle': '0 deg'}], 'components': ['x']}},
            'open_loops': {'gap': {'expression': 'u', 'requirement': {'nominal': 15,
                                                                      'tolerance': 1}}}}
    result = analyse(parse_mechanism(data, 'stack'), samples=100_000, seed=7, confidence=0.999)
    gap = result.dimensions[0]
    y = gap.yield_nonlinear
    assert y is not None and y.trials == 100_000 and y.confidence == 0.999
    assert y.low < 0.75 < y.high and y.high - y.low < 0.01
    assert gap.worst_case == pytest.approx(2e-3) and gap.rss == pytest.approx(math.sqrt(2) * 1e-3)
    assert gap.linear_std == pytest.approx(math.sqrt(2 / 3) * 1e-3)
    assert result.monte_carlo is not None and result.monte_carlo.joint_yield == y


def test_monte_carlo_is_reproducible_and_warm_up_runs() -> None:
    warm_up()
    mech = load_mechanism(EXAMPLES / 'seed004_flap_variant.yaml')
    a = monte_carlo(mech, 3000, np.random.default_rng(9))
    b = monte_carlo(mech, 3000, np.random.default_rng(9))
    np.testing.assert_array_equal(a.outputs, b.outputs)
    assert (a.iterations <= 2).all() and a.converged.all()
