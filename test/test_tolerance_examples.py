"""The shipped examples (examples/*.yaml): the four-bar against its closed form (the
Freudenstein equation differentiated by hand, independently of the engine), seed 004's flap as
printed (refused) and its variant, seed 002's planar mechanism against the circle
intersection, and the check of seed 004's printed numbers."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from positioning_cell.errors import ConfigError
from positioning_cell.mechanics.planar_parallel import PlanarParallel, forward_hanging
from positioning_cell.tolerance import seed004
from positioning_cell.tolerance.analysis import analyse
from positioning_cell.tolerance.linear import SingularLoopsError
from positioning_cell.tolerance.loops import linearise
from positioning_cell.tolerance.model import load_mechanism, parse_mechanism
from positioning_cell.tolerance.report import matrix_in_file_units

EXAMPLES = Path(__file__).resolve().parent.parent / 'examples'
MM = 1e-3


def four_bar_closed_form(r1: float, r2: float, r3: float, r4: float, t2: float,
                         p: float, beta: float, branch_t4: float) -> dict[str, np.ndarray]:
    """Positions and sensitivities of the four-bar from the Freudenstein equation
    F = r1² + r2² − r3² + r4² + 2 r1 r4 cos θ4 − 2 r1 r2 cos θ2 − 2 r2 r4 cos(θ2 − θ4) = 0
    (|r3·e^{iθ3}|² with r3·e^{iθ3} = r1 + r4·e^{iθ4} − r2·e^{iθ2}): θ4 from A cos θ4 +
    B sin θ4 + C = 0 (the branch nearest ``branch_t4``), dθ4/dr_k = −F_rk / F_θ4, θ3 = arg Z and
    dθ3 = Im(dZ / Z); the coupler point's y = r2 sin θ2 + p sin(θ3 + β). Sensitivities over
    (r1, r2, r3, r4, p, β)."""
    a = 2 * r1 * r4 - 2 * r2 * r4 * math.cos(t2)
    b = -2 * r2 * r4 * math.sin(t2)
    c = r1**2 + r2**2 - r3**2 + r4**2 - 2 * r1 * r2 * math.cos(t2)
    base, spread = math.atan2(b, a), math.acos(-c / math.hypot(a, b))
    t4 = min((base + spread, base - spread),
             key=lambda t: abs(math.remainder(t - branch_t4, 2 * math.pi)))
    f_t4 = -2 * r1 * r4 * math.sin(t4) - 2 * r2 * r4 * math.sin(t2 - t4)
    f_r = np.array([2 * r1 + 2 * r4 * math.cos(t4) - 2 * r2 * math.cos(t2),
                    2 * r2 - 2 * r1 * math.cos(t2) - 2 * r4 * math.cos(t2 - t4),
                    -2 * r3,
                    2 * r4 + 2 * r1 * math.cos(t4) - 2 * r2 * math.cos(t2 - t4)])
    dt4 = np.concatenate([-f_r / f_t4, [0.0, 0.0]])
    z = r1 + r4 * complex(math.cos(t4), math.sin(t4)) - r2 * complex(math.cos(t2), math.sin(t2))
    t3 = math.atan2(z.imag, z.real)
    e4, e2 = complex(math.cos(t4), math.sin(t4)), complex(math.cos(t2), math.sin(t2))
    dz = np.array([1.0, -e2, 0.0, e4, 0.0, 0.0]) + 1j * r4 * e4 * dt4
    dt3 = (dz / z).imag
    y = r2 * math.sin(t2) + p * math.sin(t3 + beta)
    dy = p * math.cos(t3 + beta) * dt3 + np.array(
        [0.0, math.sin(t2), 0.0, 0.0, math.sin(t3 + beta), p * math.cos(t3 + beta)])
    return {'t3': np.array(t3), 't4': np.array(t4), 'dt3': dt3, 'dt4': dt4, 'y': np.array(y),
            'dy': dy}


@pytest.mark.parametrize('theta2', [60.0, 20.0, 135.0, 250.0])
def test_four_bar_sensitivities_match_the_closed_form(theta2: float) -> None:
    mech = load_mechanism(EXAMPLES / 'four_bar.yaml').with_inputs(theta2=math.radians(theta2))
    lin = linearise(mech)
    x = dict(zip(lin.sources, lin.x0, strict=True))
    t3, t4 = lin.u0
    ref = four_bar_closed_form(x['r1'], x['r2'], x['r3'], x['r4'], math.radians(theta2),
                               x['p'], x['beta'], t4)
    assert t4 == pytest.approx(float(ref['t4']), abs=1e-12)
    assert math.remainder(t3 - float(ref['t3']), 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
    cols = [lin.sources.index(n) for n in ('r1', 'r2', 'r3', 'r4', 'p', 'beta')]
    rows = {n: i for i, n in enumerate(lin.open_loops)}
    # In the file's units (rad per mm, mm per mm, mm per rad): to 1e-9.
    per_mm = np.array([MM, MM, MM, MM, MM, 1.0])
    np.testing.assert_allclose(lin.T[rows['rocker_angle'], cols] * per_mm, ref['dt4'] * per_mm,
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(lin.T[rows['coupler_angle'], cols] * per_mm,
                               ref['dt3'] * per_mm, rtol=0, atol=1e-9)
    np.testing.assert_allclose(lin.T[rows['coupler_point_y'], cols] * per_mm / MM,
                               ref['dy'] * per_mm / MM, rtol=0, atol=1e-9)
    assert lin.gap0[rows['coupler_point_y']] == pytest.approx(float(ref['y']), abs=1e-14)
    # The ground tilt γ turns the whole linkage: θ3 and θ4 by exactly γ.
    gamma = lin.sources.index('gamma')
    np.testing.assert_allclose(lin.T[[rows['rocker_angle'], rows['coupler_angle']], gamma],
                               1.0, atol=1e-12)


def test_the_flap_as_printed_is_refused_naming_the_dependent_loop() -> None:
    mech = load_mechanism(EXAMPLES / 'seed004_flap.yaml')
    assert mech.source_names == seed004.SOURCES
    with pytest.raises(SingularLoopsError) as info:
        linearise(mech)
    message = str(info.value)
    assert 'unknowns u2, u3 enter only in a fixed combination' in message
    assert 'equations flap: x, flap: y, flap: theta are dependent' in message
    assert info.value.condition > 1e15
    result = analyse(mech, samples=0)
    assert result.refused and result.refusal == message
    # At the printed nominal the loop does not close; the engine's A, U, C, D there match the
    # printed ones where the paper's own derivatives are right (mm and rad).
    np.testing.assert_allclose(result.guess_residual[:2] / MM, [1621.842, 268.006], atol=1e-3)
    assert math.degrees(result.guess_residual[2]) == pytest.approx(75.0)
    form = result.form
    u = matrix_in_file_units(mech, result.at_guess.U, form.row_dimensions[:3],
                             form.dimensions[len(mech.sources):])
    np.testing.assert_array_equal(u[:, 1], u[:, 2])                 # identical columns
    np.testing.assert_allclose(u, seed004.PRINTED.U, atol=0.6)
    c = result.at_guess.C[0] * np.array([1.0 if n not in ('a8', 'b') else 1 / MM
                                         for n in mech.source_names])
    agree = [n for n in seed004.SOURCES if n not in ('a2', 'a7', 'a8', 'r23')]
    idx = [seed004.SOURCES.index(n) for n in agree]
    np.testing.assert_allclose(c[idx], seed004.PRINTED.C[idx], atol=6e-4)
    # The misprints: ∂Gap/∂a7 = sin a8, not 34.476; a2 and r23 swapped (θ = 60°).
    assert c[6] == pytest.approx(math.sin(math.radians(9.0)))
    assert (c[1], c[11]) == pytest.approx((seed004.PRINTED.C[11], seed004.PRINTED.C[1]), abs=1e-3)


def test_the_flap_variant_is_analysed() -> None:
    mech = load_mechanism(EXAMPLES / 'seed004_flap_variant.yaml')
    result = analyse(mech, samples=200_000, seed=1)
    lin = result.linearisation
    assert lin is not None and not result.refused
    assert math.degrees(lin.u0[0]) == pytest.approx(84.0, abs=1e-7)     # Table 1's nominal
    assert lin.u0[1] / MM == pytest.approx(400.0, abs=1e-7)
    gap = result.dimensions[0]
    assert gap.nominal / MM == pytest.approx(285.0, abs=1e-7)
    assert gap.worst_case / MM == pytest.approx(6.318, abs=1e-3)
    t = dict(zip(lin.sources, lin.T[0], strict=True))
    # The engine's T against the printed one where the paper's matrices are right (rounding of
    # the printed U and A: about 1 %); a7 (misprinted C) and a2/r23 (swapped) differ.
    for name in ('a1', 'a5', 'a6', 'r12', 'r56', 'a3', 'a9'):
        printed = seed004.PRINTED.T[seed004.SOURCES.index(name)]
        assert t[name] == pytest.approx(printed, abs=0.011)
    for name in ('a8', 'b'):
        printed = seed004.PRINTED.T[seed004.SOURCES.index(name)]
        assert t[name] / MM == pytest.approx(printed, rel=0.04)
    assert abs(t['a7']) < 1e-12 and t['a2'] == pytest.approx(math.sqrt(3) / 2)
    y = gap.yield_nonlinear
    assert y is not None and y.probability > 0.9999 and y.low > 0.999
    assert result.monte_carlo is not None and result.monte_carlo.unsolved == 0
    # The alternative closure (h_x, h_y) of the seed004 module: b then has no effect.
    alternative = linearise(seed004.position_closure_variant(mech))
    assert math.degrees(alternative.u0[0]) == pytest.approx(84.0, abs=1e-7)
    assert alternative.T[0, alternative.sources.index('b')] == pytest.approx(0.0, abs=1e-12)


def test_the_printed_numbers_of_seed_004() -> None:
    closure = seed004.printed_closure()
    assert closure.determinant == pytest.approx(0.0, abs=1e-12)
    assert 'u2, u3' in closure.refusal
    best = seed004.reproduce_t()[0]
    assert (best.equations, best.unknowns) == (('h_y', 'h_θ'), ('u1', 'u2'))
    assert best.max_difference < 0.25
    assert np.delete(best.differences, seed004.SOURCES.index('a8')).max() < 0.03
    wc = seed004.worst_case_subsets()
    assert wc.all_sources == pytest.approx(16.647, abs=1e-3)
    assert wc.without_a7 == pytest.approx(6.351, abs=1e-3)
    assert wc.hits and all('a7' in names for _, names in wc.hits)
    for hypothesis in seed004.yield_hypotheses(samples=100_000):
        for printed in (seed004.PRINTED_YIELD, seed004.PRINTED_YIELD_WITHOUT_CLEARANCE):
            assert not hypothesis.low <= printed <= hypothesis.high, hypothesis
    assert seed004.sigma_for(seed004.PRINTED_YIELD) == pytest.approx(3.379, abs=1e-3)
    text = seed004.report()
    assert '(h_y, h_θ)' in text and '6.24' in text


def test_seed_002_nominal_is_the_forward_kinematics() -> None:
    mech = load_mechanism(EXAMPLES / 'seed002_planar.yaml')
    lin = linearise(mech)
    u = dict(zip(lin.unknowns, lin.u0, strict=True))
    depth = math.sqrt(600.0**2 - 400.0**2)
    assert (u['x'] / MM, u['y'] / MM) == pytest.approx((0.0, -depth), abs=1e-9)
    assert math.degrees(u['alpha1']) == pytest.approx(math.degrees(math.atan2(-depth, 400)),
                                                      abs=1e-9)
    assert math.degrees(u['alpha4']) == pytest.approx(math.degrees(math.atan2(-depth, -400)),
                                                      abs=1e-9)
    assert u['phi'] == pytest.approx(0.0, abs=1e-12) and u['d4'] == pytest.approx(0, abs=1e-12)
    # Other inputs: the platform centre is the lower intersection (hanging branch) of the
    # circles of radius L about B1 − A1 and B3 − A3.
    for s1, s2 in ((0.0, 100.0 * MM), (-60.0 * MM, 30.0 * MM)):
        moved = linearise(mech.with_inputs(s1=s1, s2=s2))
        um = dict(zip(moved.unknowns, moved.u0, strict=True))
        c1, c2 = np.array([-0.5 + 0.1, s1]), np.array([0.5 - 0.1, s2])
        d = np.linalg.norm(c2 - c1)
        normal = np.array([-(c2 - c1)[1], (c2 - c1)[0]]) / d
        centre = (c1 + c2) / 2 - normal * math.sqrt(0.6**2 - (d / 2) ** 2)
        assert (um['x'], um['y']) == pytest.approx(tuple(centre), abs=1e-12)
        assert um['phi'] == pytest.approx(0.0, abs=1e-12)
        # and the closed-form kinematics of positioning_cell.mechanics.planar_parallel (the
        # same assumed machine, its hanging branch) agree
        fk = forward_hanging(PlanarParallel(), (s1, s2))
        assert (um['x'], um['y']) == pytest.approx(tuple(fk), abs=1e-12)


def test_seed_002_four_rigid_links_are_over_constrained() -> None:
    data = yaml.safe_load((EXAMPLES / 'seed002_planar.yaml').read_text())
    del data['unknowns']['d4']
    data['closed_loops']['link4']['vectors'][-1]['length'] = '-L4'
    del data['open_loops']['link4_misfit']
    with pytest.raises(ConfigError, match=r'8 closure equations .* for 7 unknowns'):
        parse_mechanism(data, 'seed002')
