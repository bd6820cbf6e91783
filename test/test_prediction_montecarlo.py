"""Monte Carlo with the nonlinear closure model: per-sample agreement with forward kinematics,
yield against an independent brute-force count, and the bound of the first-order worst case."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.prediction.montecarlo import (
    _rotation_from_rotvec,
    _sin_cos_small,
    compare,
    estimate_yield,
    inside_requirement,
    monte_carlo,
    per_sample_deviations,
    solve_closure,
)
from positioning_cell.prediction.sensitivity import linearise
from positioning_cell.prediction.sources import (
    Requirement,
    ToleranceSpec,
    draw_sources,
    load_tolerance_spec,
)
from positioning_cell.tools.predict_accuracy import shipped_config

MECH = Mechanism.default()
P = np.array([0.01, 0.015, MECH.home_height - 0.004])
Q = np.array([0.02, -0.01, 0.0, 1.0]) / np.linalg.norm([0.02, -0.01, 0.0, 1.0])


def shipped_spec() -> ToleranceSpec:
    return load_tolerance_spec(shipped_config('tolerances.yaml'), MECH)


def brute_force_deviations(spec: ToleranceSpec, x: np.ndarray) -> np.ndarray:
    """One kinematics.forward per sample on mech.with_offsets: slow and independent."""
    return per_sample_deviations(MECH, spec, P, Q, x)


def test_closure_solve_agrees_with_forward_kinematics_sample_by_sample() -> None:
    spec = shipped_spec()
    x = draw_sources(spec, 200, np.random.default_rng(11))
    lin = linearise(MECH, spec, P, Q)
    dev, converged = solve_closure(MECH, lin, x @ lin.source_map[0].T)
    assert converged.all()
    np.testing.assert_allclose(dev, brute_force_deviations(spec, x), rtol=0, atol=1e-10)


def test_yield_equals_an_independent_brute_force_count() -> None:
    spec = shipped_spec()
    n = 300
    result = monte_carlo(MECH, spec, P, Q, n, np.random.default_rng(5), chunk=128)
    # Requirement near the median so that the count is informative (neither 0 nor n).
    brute = brute_force_deviations(spec, _same_draws(spec, n, 5, 128))  # same random stream
    pos = np.linalg.norm(brute[:, :3], axis=1)
    ang = np.linalg.norm(brute[:, 3:], axis=1)
    req = Requirement(float(np.median(pos)) * 1.2, float(np.median(ang)) * 1.2)
    count = 0
    for k in range(n):  # the brute-force count, written out
        if pos[k] <= req.position and ang[k] <= req.orientation:
            count += 1
    estimate = estimate_yield(inside_requirement(result.deviations, req))
    assert 0 < count < n
    assert estimate.inside == count
    assert estimate.trials == n
    assert estimate.low < estimate.probability < estimate.high
    exact = stats.binomtest(count, n).proportion_ci(0.95, method='wilson')
    assert (estimate.low, estimate.high) == pytest.approx((exact.low, exact.high))


def _same_draws(spec: ToleranceSpec, n: int, seed: int, chunk: int) -> np.ndarray:
    """The samples monte_carlo draws: chunk k from the k-th generator spawned from the seed."""
    starts = range(0, n, chunk)
    streams = np.random.default_rng(seed).spawn(len(starts))
    return np.concatenate([draw_sources(spec, min(chunk, n - s), rng)
                           for s, rng in zip(starts, streams, strict=True)])


def test_monte_carlo_stays_within_worst_case_and_matches_linear_sigma() -> None:
    spec = shipped_spec()
    lin = linearise(MECH, spec, P, Q)
    result = monte_carlo(MECH, spec, P, Q, 40_000, np.random.default_rng(2))
    assert result.converged.all()
    c = compare(lin, spec, result)
    total = float(spec.bounds[[s.unit == 'm' for s in spec.sources]].sum())
    slack = np.array([total**2 / MECH.platform_radius] * 3
                     + [total**2 / MECH.platform_radius**2] * 3)
    assert np.all(c.mc_max <= c.worst_case + slack)
    assert np.all(c.mc_max > c.rss * 0.5)  # the samples do explore the tolerance box
    # 3σ from the samples vs the linear model (σ of a σ estimate with 40 000 samples: 0.4 %)
    np.testing.assert_allclose(c.mc_3sigma, c.linear_3sigma, rtol=0.03)
    # the nonlinearity is second order: tiny against the deviations
    gap = np.abs(result.deviations - result.linear).max(axis=0)
    assert np.all(gap <= slack)
    assert np.all(gap < 0.02 * c.worst_case)


def test_bad_inputs_are_refused() -> None:
    spec = shipped_spec()
    with pytest.raises(InputError, match='n_samples'):
        monte_carlo(MECH, spec, P, Q, 0, np.random.default_rng(0))
    with pytest.raises(InputError, match='workers'):
        monte_carlo(MECH, spec, P, Q, 10, np.random.default_rng(0), workers=0)
    with pytest.raises(InputError, match='no samples'):
        estimate_yield(np.zeros(0, dtype=bool))
    with pytest.raises(InputError, match='confidence'):
        estimate_yield(np.ones(3, dtype=bool), confidence=1.5)


def test_result_depends_on_the_generator_and_chunk_never_on_the_threads() -> None:
    spec = shipped_spec()
    runs = [monte_carlo(MECH, spec, P, Q, 3000, np.random.default_rng(9), chunk=256,
                        workers=w) for w in (1, 3)]
    np.testing.assert_array_equal(runs[0].deviations, runs[1].deviations)
    np.testing.assert_array_equal(runs[0].linear, runs[1].linear)
    other = monte_carlo(MECH, spec, P, Q, 3000, np.random.default_rng(10), chunk=256)
    assert not np.array_equal(other.deviations, runs[0].deviations)


def test_linear_part_is_the_sensitivity_matrix_times_the_draws() -> None:
    spec = shipped_spec()
    result = monte_carlo(MECH, spec, P, Q, 500, np.random.default_rng(6), chunk=200)
    x = _same_draws(spec, 500, 6, 200)
    matrix = linearise(MECH, spec, P, Q).matrix[0]
    np.testing.assert_allclose(result.linear, x @ matrix.T, rtol=0, atol=1e-15)


def test_compiled_rotation_from_rotation_vector_matches_scipy() -> None:
    """Rodrigues' formula in the kernel, across its small-angle series and the libm branch."""
    rng = np.random.default_rng(12)
    axes = rng.normal(size=(9, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.array([0.0, 1e-12, 1e-6, 1e-3, 0.049999, 0.050001, 0.3, 2.0, 3.1])
    out = np.empty((3, 3))
    for w in axes * angles[:, None]:
        _rotation_from_rotvec(w[0], w[1], w[2], out)
        np.testing.assert_allclose(out, Rotation.from_rotvec(w).as_matrix(), rtol=0, atol=1e-15)


def test_compiled_small_angle_sine_and_cosine_match_libm() -> None:
    for d in np.concatenate([np.linspace(-0.2, 0.2, 4001), [-0.05, 0.05, 1e-300, 0.0]]):
        sin_d, cos_d = _sin_cos_small(d)
        assert abs(sin_d - np.sin(d)) <= 2e-17 + 1e-16 * abs(d)
        assert abs(cos_d - np.cos(d)) <= 2.3e-16
