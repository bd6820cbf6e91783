"""The loop equations as arrays (positioning_cell.tolerance.loops): exact derivatives against
central differences and the trigonometric normal form against the vectors, over random planar
and spatial mechanisms (hypothesis); the nominal solve; T = C − D·U⁻¹·A; the refusals."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from positioning_cell.errors import ConvergenceError
from positioning_cell.tolerance.analysis import analyse
from positioning_cell.tolerance.expressions import ANGLE, LENGTH, Affine
from positioning_cell.tolerance.linear import SingularLoopsError, sensitivity
from positioning_cell.tolerance.loops import (
    Form,
    TrigForm,
    check_derivatives,
    linearise,
    solve_nominal,
)
from positioning_cell.tolerance.model import (
    ClosedLoop,
    Equation,
    Input,
    Mechanism,
    OpenLoop,
    Source,
    Unknown,
    Vector,
    parse_mechanism,
)

COEFS = (-2.0, -1.0, -0.5, 0.5, 1.0, 2.0)


def random_mechanism(seed: int, spatial: bool) -> Mechanism:
    """A mechanism of random vectors (lengths and angles affine in random symbols; in space,
    elevations too), one or two closed loops with scalar equations, and open loops: the
    Python objects, no file."""
    rng = np.random.default_rng(seed)
    sources = [Source(f'L{i}', LENGTH, float(rng.uniform(0.05, 0.5)), 1e-4)
               for i in range(int(rng.integers(1, 4)))]
    sources += [Source(f'A{i}', ANGLE, float(rng.uniform(-math.pi, math.pi)), 1e-3)
                for i in range(int(rng.integers(1, 3)))]
    unknowns = [Unknown(f'u{i}', LENGTH, float(rng.uniform(0.05, 0.5)))
                for i in range(int(rng.integers(0, 3)))]
    unknowns += [Unknown(f'w{i}', ANGLE, float(rng.uniform(-math.pi, math.pi)))
                 for i in range(int(rng.integers(1, 3)))]
    inputs = [Input('th', ANGLE, float(rng.uniform(-math.pi, math.pi))),
              Input('h', LENGTH, float(rng.uniform(0.0, 0.2)))]
    declared = [(s.name, s.dimension) for s in sources] + [
        (u.name, u.dimension) for u in unknowns] + [(i.name, i.dimension) for i in inputs]
    names = {dim: [n for n, d in declared if d == dim] for dim in (LENGTH, ANGLE)}

    def affine(dim: str) -> Affine:
        pool = names[dim]
        chosen = rng.choice(pool, size=int(rng.integers(0, min(3, len(pool)) + 1)),
                            replace=False)
        terms = tuple((str(n), float(rng.choice(COEFS))) for n in chosen)
        scale = 0.3 if dim == LENGTH else math.pi
        return Affine(terms, float(rng.uniform(-scale, scale)), dim)

    def vectors() -> tuple[Vector, ...]:
        out = []
        for k in range(int(rng.integers(1, 6))):
            if spatial and rng.random() < 0.6:
                elevation = affine(ANGLE)
            elif spatial:
                elevation = Affine((), float(rng.uniform(-1.0, 1.0)), ANGLE)
            else:
                elevation = Affine.zero(ANGLE)
            out.append(Vector(affine(LENGTH), affine(ANGLE), elevation, f'v{k}'))
        return tuple(out)

    comps = ('x', 'y', 'z') if spatial else ('x', 'y')
    closed = tuple(ClosedLoop(f'loop{i}', vectors(), comps,
                              tuple(Equation(f'e{j}', affine(str(rng.choice([LENGTH, ANGLE]))))
                                    for j in range(int(rng.integers(0, 2)))))
                   for i in range(int(rng.integers(1, 3))))
    opened = (OpenLoop('chain', LENGTH, vectors(), str(rng.choice(comps)), affine(LENGTH), None),
              OpenLoop('angle', ANGLE, (), None, affine(ANGLE), None))
    return Mechanism('random', '', 'm', 'spatial' if spatial else 'planar', tuple(inputs),
                     tuple(sources), tuple(unknowns), (), closed, opened)


@settings(max_examples=60)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_exact_derivatives_match_central_differences(seed: int, spatial: bool) -> None:
    mech = random_mechanism(seed, spatial)
    form = Form.from_mechanism(mech)
    rng = np.random.default_rng(seed + 1)
    point = form.point() + rng.normal(size=len(form.symbols)) * 0.01
    exact, approx = form.jacobian(point), form.jacobian_fd(point)
    np.testing.assert_allclose(exact, approx, rtol=1e-6, atol=1e-7)
    check = check_derivatives(form, point)
    assert check.max_abs < 1e-7


@settings(max_examples=60)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_the_normal_form_equals_the_vector_sums(seed: int, spatial: bool) -> None:
    """TrigForm (what the kernel interprets) and Form (the vectors) are the same rows."""
    mech = random_mechanism(seed, spatial)
    form = Form.from_mechanism(mech)
    trig = TrigForm.from_form(form)
    rng = np.random.default_rng(seed + 2)
    points = form.point() + rng.normal(size=(5, len(form.symbols)))
    np.testing.assert_allclose(trig.evaluate(points), form.evaluate(points), rtol=0,
                               atol=1e-12)
    # No two angles of the normal form are the same direction of variation (up to sign).
    keys = {tuple(row) for row in trig.angles} | {tuple(-row) for row in trig.angles}
    assert len(keys) == 2 * trig.angles.shape[0]


FOUR_BAR: dict[str, Any] = {
    'units': {'length': 'mm'}, 'inputs': {'t2': '60 deg'},
    'sources': {'r1': {'nominal': 100, 'tolerance': 0.05},
                'r2': {'nominal': 40, 'tolerance': 0.05},
                'r3': {'nominal': 90, 'tolerance': 0.05},
                'r4': {'nominal': 70, 'tolerance': 0.05}},
    'unknowns': {'t3': '20 deg', 't4': '80 deg'},
    'closed_loops': {'loop': {'vectors': [
        {'length': 'r2', 'angle': 't2'}, {'length': 'r3', 'angle': 't3'},
        {'length': '-r4', 'angle': 't4'}, {'length': '-r1', 'angle': '0 deg'}]}},
    'open_loops': {'t4': {'expression': 't4'},
                   'py': {'vectors': [{'length': 'r2', 'angle': 't2'},
                                      {'length': 'r3 / 2', 'angle': 't3 + 10 deg'}],
                          'component': 'y'}}}


def test_linearise_solves_the_nominal_and_builds_t() -> None:
    mech = parse_mechanism(FOUR_BAR, 'four-bar')
    form = Form.from_mechanism(mech)
    lin = linearise(mech)
    assert lin.iterations >= 2 and np.abs(form.evaluate(form.point(u=lin.u0))[:2]).max() < 1e-11
    assert np.abs(lin.guess_residual).max() > 1e-3   # the guess did not close
    np.testing.assert_allclose(lin.T, lin.C - lin.D @ np.linalg.solve(lin.U, lin.A), atol=1e-12)
    np.testing.assert_array_equal(lin.T, sensitivity(lin.A, lin.U, lin.C, lin.D))
    fd = linearise(mech, method='fd')
    np.testing.assert_allclose(fd.T, lin.T, rtol=1e-6, atol=1e-8)
    assert lin.equations == ('loop: x', 'loop: y') and lin.open_loops == ('t4', 'py')
    # The loop closed at the solution stays closed after a small source change to 1st order.
    dx = np.array([1e-7, -2e-7, 1.5e-7, 0.5e-7])
    u1, _ = solve_nominal(Form.from_mechanism(mech), tolerance=1e-13)
    assert np.allclose(u1, lin.u0)
    shifted = form.evaluate(form.point(lin.x0 + dx, lin.u0 + lin.first_order @ dx))[:2]
    assert np.abs(shifted).max() < 1e-12


def test_a_singular_u_names_the_dependent_loops_and_unknowns() -> None:
    data = {
        'units': {'length': 'mm'},
        'sources': {'a': {'nominal': 100, 'tolerance': 0.1},
                    'b': {'nominal': 50, 'tolerance': 0.1}},
        'unknowns': {'u1': 30, 'u2': 20, 'w': '10 deg'},
        'closed_loops': {
            'left': {'vectors': [{'length': 'u1', 'angle': 'w'}, {'length': 'u2', 'angle': 'w'},
                                 {'length': '-a', 'angle': '0 deg'}]},
            'right': {'vectors': [{'length': 'b', 'angle': '90 deg'},
                                  {'length': '-b', 'angle': '90 deg'}],
                      'components': ['x']}},
        'open_loops': {'g': {'expression': 'u1'}}}
    mech = parse_mechanism(data, 'dep.yaml')
    with pytest.raises(SingularLoopsError) as info:
        linearise(mech)
    message = str(info.value)
    assert 'unknowns u1, u2 enter only in a fixed combination' in message
    assert 'right: x' in message and 'condition number' in message
    refusal = analyse(mech, samples=0)
    assert refusal.refused and refusal.refusal == message
    assert refusal.at_guess.U.shape == (3, 3) and not refusal.dimensions


def test_loops_that_cannot_close_are_refused() -> None:
    data = {**FOUR_BAR, 'sources': {**FOUR_BAR['sources'],
                                    'r3': {'nominal': 300, 'tolerance': 0.05}}}
    mech = parse_mechanism(data, 'open.yaml')
    with pytest.raises((ConvergenceError, SingularLoopsError)):
        linearise(mech)
    result = analyse(mech, samples=0)
    assert result.refused and result.linearisation is None
