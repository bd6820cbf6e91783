"""U (k = 2) of the ISO 9283 position figures AP_p and RP_l from the measurement's stated
covariances (positioning_cell.accuracy.figure_uncertainty): hand-worked limits, bad input, and
coverage on seeded simulated machines (issue 25's target: the figure from the true poses lies
within U of the figure from the measurements in ≥ 95 % of runs)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from positioning_cell.accuracy.figure_uncertainty import (
    BATCH,
    BATCH_ERRORS,
    MAX_BATCHES,
    adaptive_quantiles,
    distance_figure_uncertainty,
    drawn_errors,
    euler_rates_from_rotation,
    multidirectional_angle_uncertainty,
    multidirectional_uncertainty,
    orientation_figure_uncertainty,
    pose_figure_uncertainty,
)
from positioning_cell.accuracy.iso9283 import (
    approach_groups,
    distance_figures,
    iso9283,
    multidirectional_figures,
    orientation_angles,
)
from positioning_cell.errors import InputError

Q = np.array([0.0, 0.0, 0.0, 1.0])
C = np.array([0.1, -0.2, 0.9])


def rp_l_of(position: np.ndarray) -> float:
    """ISO 9283's RP_l of attained positions (n, 3) (iso9283's)."""
    figures = iso9283(C, Q, position, np.tile(Q, (len(position), 1)))
    assert figures.rp_l is not None
    return figures.rp_l


def test_far_from_zero_ap_p_has_the_linear_u_of_the_mean_covariance() -> None:
    """AP 50 µm along x, every visit measured with σ 3 µm along x only: the barycentre's σ
    is taken as 3 µm (the visits' errors fully correlated), so U = 2 · 3 µm (the norm's
    second-order term is zero: no variance across AP)."""
    n = 5
    x = np.tile(C + [50e-6, 0.0, 0.0], (n, 1))
    cov = np.tile(np.diag([9e-12, 0.0, 0.0]), (n, 1, 1))
    u = pose_figure_uncertainty(C, x, cov)
    assert u.ap_p == pytest.approx(6e-6, rel=1e-9)


def test_rp_l_of_exact_measurements_has_no_uncertainty_and_one_visit_none() -> None:
    x = C + np.random.default_rng(2).normal(0.0, 5e-6, (6, 3))
    u = pose_figure_uncertainty(C, x, np.zeros((6, 3, 3)))
    assert u.rp_l == pytest.approx(0.0, abs=1e-15) and u.ap_p == pytest.approx(0.0, abs=1e-15)
    single = pose_figure_uncertainty(C, x[:1], np.tile(np.eye(3) * 1e-12, (1, 1, 1)))
    assert math.isfinite(single.ap_p) and math.isnan(single.rp_l)


def test_rp_l_u_grows_with_the_stated_noise() -> None:
    x = C + np.random.default_rng(3).normal(0.0, 3e-6, (10, 3))
    small, large = (pose_figure_uncertainty(C, x, np.tile(np.eye(3) * s**2, (10, 1, 1))).rp_l
                    for s in (1e-6, 4e-6))
    assert 0.0 < small < large


def test_a_visit_without_a_covariance_states_none() -> None:
    cov = np.tile(np.eye(3) * 1e-12, (3, 1, 1))
    cov[1, 0, 0] = math.nan
    u = pose_figure_uncertainty(C, np.tile(C, (3, 1)), cov)
    assert math.isnan(u.ap_p) and math.isnan(u.rp_l)


@pytest.mark.parametrize(('position', 'covariance', 'k', 'words'), [
    (np.zeros((3, 3)), np.zeros((2, 3, 3)), 2.0, 'expected shape'),
    (np.full((2, 3), math.nan), np.zeros((2, 3, 3)), 2.0, 'finite'),
    (np.zeros((2, 3)), np.tile(np.diag([1.0, -1.0, 1.0]), (2, 1, 1)), 2.0, 'semi-definite'),
    (np.zeros((2, 3)), np.zeros((2, 3, 3)), 0.0, 'k must be > 0'),
])
def test_bad_input_is_refused(position: np.ndarray, covariance: np.ndarray, k: float,
                              words: str) -> None:
    with pytest.raises(InputError, match=words):
        pose_figure_uncertainty(C, position, covariance, k)


@pytest.mark.parametrize(('repeatability', 'common', 'noise'), [
    (2e-6, 4e-6, 3e-6),  # a registration error shared by every visit
    (2e-6, 0.0, 5e-6),  # the readings' noise only, larger than the machine's scatter
    (0.5e-6, 3e-6, 3e-6),  # a machine far more repeatable than its measurement
])
def test_the_true_figures_lie_within_u_of_the_measured_ones_in_95_percent_of_runs(
        repeatability: float, common: float, noise: float) -> None:
    """200 seeded machines: AP drawn ~30 µm per axis, each of 10 visits scattered by
    ``repeatability`` (σ per axis); measured with an error ``common`` to the run and
    ``noise`` per visit, each visit stated with covariance (common² + noise²)·I."""
    runs, n = 200, 10
    covered = np.zeros((runs, 2), dtype=bool)
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        true = C + rng.normal(0.0, 30e-6, 3) + rng.normal(0.0, repeatability, (n, 3))
        measured = true + rng.normal(0.0, common, 3) + rng.normal(0.0, noise, (n, 3))
        cov = np.tile(np.eye(3) * (common**2 + noise**2), (n, 1, 1))
        u = pose_figure_uncertainty(C, measured, cov, rng=np.random.default_rng(10_000 + seed))
        ap_true, ap_measured = (float(np.linalg.norm(x.mean(axis=0) - C))
                                for x in (true, measured))
        covered[seed] = (abs(ap_measured - ap_true) <= u.ap_p,
                         abs(float(rp_l_of(measured)) - float(rp_l_of(true))) <= u.rp_l)
    share = covered.mean(axis=0)
    print(f"AP_p, RP_l covered in {share[0]:.1%}, {share[1]:.1%} of {runs} runs")
    assert share[0] >= 0.95 and share[1] >= 0.95, share


def test_distance_figures_of_a_hand_worked_example() -> None:
    """Commanded 10 mm apart along x; attained 10.002, 9.999, 10.004 mm apart: D̄ 10.001667
    mm, AD_p 1.667 µm, S_D = √((0.333² + 2.667² + 2.333²)/2) µm = 2.517 µm, RD_p 7.550 µm.
    Each position measured with σ 3 µm per axis: u(D̄)² = 3 · 2σ² / 3² along x, U of AD_p =
    2σ√(2/3) = 4.899 µm."""
    c1, c2 = C, C + [0.010, 0.0, 0.0]
    first = np.tile(C, (3, 1)) + np.array([[0.0, 1e-6, 0.0], [0.0, -2e-6, 0.0],
                                           [0.0, 0.0, 3e-6]])
    second = first + np.array([[10.002e-3, 0.0, 0.0], [9.999e-3, 0.0, 0.0],
                               [10.004e-3, 0.0, 0.0]])
    figures = distance_figures(c1, c2, first, second)
    assert figures.commanded_distance == pytest.approx(0.010, abs=1e-15)
    assert figures.ad_p == pytest.approx(1.6667e-6, abs=1e-10)
    assert figures.s_d == pytest.approx(2.5166e-6, abs=1e-10)
    assert figures.rd_p == pytest.approx(7.5498e-6, abs=1e-9)
    cov = np.tile(np.eye(3) * 9e-12, (3, 1, 1))
    u = distance_figure_uncertainty(first, second, cov, cov)
    assert u.ad_p == pytest.approx(2 * 3e-6 * math.sqrt(2 / 3), rel=1e-6)
    assert u.rd_p > 0.0 and math.isnan(distance_figure_uncertainty(
        first[:1], second[:1], cov[:1], cov[:1]).rd_p)
    with pytest.raises(InputError, match='as many attained'):
        distance_figures(c1, c2, first, second[:2])


def test_the_true_distance_figures_lie_within_u_in_95_percent_of_runs() -> None:
    """200 seeded machines reaching two poses 11 mm apart 10 times each, scattered 2 µm and
    off by ~30 µm, measured with a common 4 µm and a per-visit 3 µm error."""
    runs, n = 200, 10
    covered = np.zeros((runs, 2), dtype=bool)
    c2 = C + [0.004, 0.004, -0.008]
    cov = np.tile(np.eye(3) * (4e-6**2 + 3e-6**2), (n, 1, 1))
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        true = [c + rng.normal(0.0, 30e-6, 3) + rng.normal(0.0, 2e-6, (n, 3)) for c in (C, c2)]
        common = rng.normal(0.0, 4e-6, 3)
        measured = [t + common + rng.normal(0.0, 3e-6, (n, 3)) for t in true]
        u = distance_figure_uncertainty(*measured, cov, cov,
                                        rng=np.random.default_rng(10_000 + seed))
        f_true, f_measured = (distance_figures(C, c2, *x) for x in (true, measured))
        assert f_true.rd_p is not None and f_measured.rd_p is not None
        covered[seed] = (abs(f_measured.ad_p - f_true.ad_p) <= u.ad_p,
                         abs(f_measured.rd_p - f_true.rd_p) <= u.rd_p)
    share = covered.mean(axis=0)
    print(f'AD_p, RD_p covered in {share[0]:.1%}, {share[1]:.1%} of {runs} runs')
    assert share[0] >= 0.95 and share[1] >= 0.95, share


def test_euler_rates_are_the_finite_differences_of_the_angles() -> None:
    rng = np.random.default_rng(5)
    q = Rotation.from_euler('xyz', rng.uniform(-1.0, 1.0, (6, 3))).as_quat()
    m = euler_rates_from_rotation(q)
    h = 1e-7
    for i in range(3):
        step = np.zeros(3)
        step[i] = h
        moved = (Rotation.from_rotvec(step) * Rotation.from_quat(q)).as_quat()
        rate = (orientation_angles(moved) - orientation_angles(q)) / h
        np.testing.assert_allclose(rate, m[:, :, i], atol=1e-6)


def test_orientation_u_at_the_home_orientation_is_2_sigma_per_angle() -> None:
    """At R = I the angles are the small rotations themselves: U of AP_a = 2σ_x etc."""
    sigma = np.array([1e-5, 2e-5, 3e-5])
    cov = np.tile(np.diag(sigma**2), (4, 1, 1))
    u = orientation_figure_uncertainty(np.tile(Q, (4, 1)), cov)
    np.testing.assert_allclose([u.ap_a, u.ap_b, u.ap_c], 2 * sigma, rtol=1e-9)
    assert 0.0 < u.rp_a < u.rp_b < u.rp_c
    single = orientation_figure_uncertainty(Q[None], cov[:1])
    assert math.isnan(single.rp_a) and single.ap_c == pytest.approx(6e-5)


def test_the_true_orientation_figures_lie_within_u_in_95_percent_of_runs() -> None:
    """200 seeded machines tilted ~0.2° (AP) and scattering 10 µrad per axis, measured with a
    common 20 µrad and a per-visit 15 µrad error about each base axis."""
    runs, n = 200, 10
    covered = np.zeros((runs, 6), dtype=bool)
    cov = np.tile(np.eye(3) * (20e-6**2 + 15e-6**2), (n, 1, 1))
    c = Rotation.from_euler('xyz', [0.02, -0.01, 0.3])
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        true = (Rotation.from_rotvec(rng.normal(0.0, 10e-6, (n, 3)))
                * Rotation.from_rotvec(rng.normal(0.0, 3.5e-3, 3)) * c)
        measured = (Rotation.from_rotvec(rng.normal(0.0, 15e-6, (n, 3)))
                    * Rotation.from_rotvec(rng.normal(0.0, 20e-6, 3)) * true)
        u = orientation_figure_uncertainty(measured.as_quat(), cov,
                                           rng=np.random.default_rng(10_000 + seed))
        f_true, f_measured = (iso9283(C, c.as_quat(), np.tile(C, (n, 1)), r.as_quat())
                              for r in (true, measured))
        for i, name in enumerate(('ap_a', 'ap_b', 'ap_c', 'rp_a', 'rp_b', 'rp_c')):
            covered[seed, i] = abs(getattr(f_measured, name) - getattr(f_true, name)) \
                <= getattr(u, name)
    share = covered.mean(axis=0)
    print('AP_a, AP_b, AP_c, RP_a, RP_b, RP_c covered in '
          + ', '.join(f'{v:.1%}' for v in share) + f' of {runs} runs')
    assert np.all(share >= 0.95), share


def test_multidirectional_figures_of_a_hand_worked_example() -> None:
    """Approached along +x twice (attained 10 and 12 µm along x) and along +y twice (10, 12
    µm along y, turned 20 µrad about z): barycentres (11, 0, 0) and (0, 11, 0) µm, vAP_p
    11·√2 µm, vAP_c 20 µrad; one direction: none."""
    position = C + 1e-6 * np.array([[10.0, 0, 0], [12.0, 0, 0], [0, 10.0, 0], [0, 12.0, 0]])
    turned = Rotation.from_rotvec([0.0, 0.0, 2e-5]).as_quat()
    quaternion = np.array([Q, Q, turned, turned])
    approach = np.array([[1.0, 0, 0], [2.0, 0.1, 0], [0, 1.0, 0], [0.1, 1.0, 0]])
    v = multidirectional_figures(Q, position, quaternion, approach)
    assert v is not None and v.directions == 2 and v.n == 4
    assert v.vap_p == pytest.approx(11e-6 * math.sqrt(2), rel=1e-9)
    assert v.vap_c == pytest.approx(2e-5, rel=1e-6) and v.vap_a == pytest.approx(0, abs=1e-12)
    assert v.approaches[1] == pytest.approx((0.0, 1.0, 0.0))
    assert multidirectional_figures(Q, position[:2], quaternion[:2], approach[:2]) is None
    with pytest.raises(InputError, match='zero vector'):
        approach_groups([[0.0, 0.0, 0.0]])


def test_the_true_vap_lies_within_u_in_95_percent_of_runs() -> None:
    """200 seeded machines whose pose lands 5-20 µm apart by the direction it came from (3
    directions, 4 visits each, 2 µm scatter), measured with a common 4 µm and a per-visit
    3 µm error."""
    runs, n = 200, 12
    direction = np.repeat([0, 1, 2], 4)
    cov = np.tile(np.eye(3) * (4e-6**2 + 3e-6**2), (n, 1, 1))
    covered = np.zeros(runs, dtype=bool)
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        offsets = rng.normal(0.0, 8e-6, (3, 3))
        true = C + offsets[direction] + rng.normal(0.0, 2e-6, (n, 3))
        measured = true + rng.normal(0.0, 4e-6, 3) + rng.normal(0.0, 3e-6, (n, 3))
        u = multidirectional_uncertainty(measured, cov, direction)
        vap = [max(np.linalg.norm(x[direction == h].mean(axis=0) - x[direction == j].mean(axis=0))
                   for h in range(3) for j in range(3)) for x in (true, measured)]
        covered[seed] = abs(vap[1] - vap[0]) <= u
    print(f'vAP_p covered in {covered.mean():.1%} of {runs} runs')
    assert covered.mean() >= 0.95
    assert math.isnan(multidirectional_uncertainty(C[None], cov[:1], [0]))


def test_vap_angles_u_of_a_hand_worked_example() -> None:
    """Two directions at the home orientation, 2 visits each, every visit's rotation
    variance σ² about each base axis (the angles' rates there are the identity): each
    direction's mean of variance σ², the difference below 2(σ² + σ²) = 4σ²: U = 2·2σ = 4σ
    away from zero; at vAP 0 the lower bound is clamped at 0, U is still 4σ."""
    sigma = 1e-5
    turned = Rotation.from_rotvec([0.0, 0.0, 2e-4]).as_quat()
    quaternion = np.array([Q, Q, turned, turned])
    cov = np.tile(np.eye(3) * sigma**2, (4, 1, 1))
    u = multidirectional_angle_uncertainty(quaternion, cov, [0, 0, 1, 1])
    np.testing.assert_allclose(u, [4 * sigma] * 3, rtol=1e-6)
    assert all(math.isnan(x) for x in multidirectional_angle_uncertainty(
        quaternion, cov, [0, 0, 0, 0]))


def test_the_true_vap_angles_lie_within_u_in_95_percent_of_runs() -> None:
    """200 seeded machines whose orientation lands 10-40 µrad apart by the direction it came
    from (3 directions, 4 visits each, 5 µrad scatter), measured with a common 8 µrad and a
    per-visit 6 µrad error about each axis."""
    runs, n = 200, 12
    direction = np.repeat([0, 1, 2], 4)
    cov = np.tile(np.eye(3) * (8e-6**2 + 6e-6**2), (n, 1, 1))
    covered = np.zeros((runs, 3), dtype=bool)
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        offsets = rng.normal(0.0, 2e-5, (3, 3))
        true = offsets[direction] + rng.normal(0.0, 5e-6, (n, 3))
        measured = true + rng.normal(0.0, 8e-6, 3) + rng.normal(0.0, 6e-6, (n, 3))
        quaternion = Rotation.from_rotvec(measured).as_quat()
        u = multidirectional_angle_uncertainty(quaternion, cov, direction)
        figures = [multidirectional_figures(Q, np.tile(C, (n, 1)),
                                            Rotation.from_rotvec(x).as_quat(),
                                            np.eye(3)[direction]) for x in (true, measured)]
        assert figures[0] is not None and figures[1] is not None
        for i, name in enumerate(('vap_a', 'vap_b', 'vap_c')):
            covered[seed, i] = abs(getattr(figures[1], name)
                                   - getattr(figures[0], name)) <= u[i]
    share = covered.mean(axis=0)
    print(f'vAP_a, vAP_b, vAP_c covered in {share[0]:.1%}, {share[1]:.1%}, {share[2]:.1%} of '
          f'{runs} runs')
    assert np.all(share >= 0.95), share


def test_the_adaptive_monte_carlo_stops_once_the_quantile_is_settled() -> None:
    """JCGM 101 §7.9: a narrow bound (many visits) settles after the least two batches, a
    wide one runs the most; either gives the quantile of all its draws (N(1, 1) at 95.45 %,
    the coverage probability of k = 2: 1 + Φ⁻¹(0.9545) = 2.69, within the Monte Carlo's own
    error)."""
    rng = np.random.default_rng(7)
    asked: list[int] = []

    def narrow(m: int) -> np.ndarray:
        asked.append(m)
        return rng.normal(10.0, 0.01, (m, 1))

    assert adaptive_quantiles(narrow, 2.0)[0] == pytest.approx(10.0, abs=0.05)
    assert asked == [BATCH, BATCH]
    asked.clear()

    def wide(m: int) -> np.ndarray:
        asked.append(m)
        return rng.normal(1.0, 1.0, (m, 2))

    q = adaptive_quantiles(wide, 2.0)
    assert len(asked) == MAX_BATCHES and q.shape == (2,)
    np.testing.assert_allclose(q, 1.0 + 1.6906, atol=0.1)
    # many visits a draw: smaller batches (the memory of one bounded), the same rule
    asked.clear()
    adaptive_quantiles(narrow, 2.0, visits=4 * BATCH_ERRORS // BATCH)
    assert asked == [BATCH // 4, BATCH // 4]


def test_drawn_errors_are_laid_out_by_visit_each_with_its_own_covariance() -> None:
    """drawn_errors (n, draws, d): row j's draws have covariance cov[j] (three different
    ones, one exact along an axis), and they are the generator's (draws, n, d) standard
    normals through each visit's square root, computed here a second way (einsum)."""
    a = np.array([[[2.0, 0.5, 0.0], [0.0, 1.0, 0.3], [0.0, 0.0, 0.7]],
                  [[1.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 0.0]],
                  [[0.5, -0.4, 0.2], [0.1, 0.8, 0.0], [0.3, 0.0, 1.5]]]) * 1e-5
    cov = a @ np.swapaxes(a, 1, 2)
    draws = 40_000
    errors = drawn_errors(cov, np.random.default_rng(5), draws)
    assert errors.shape == (3, draws, 3)
    for j in range(3):
        np.testing.assert_allclose(np.cov(errors[j].T), cov[j], rtol=0.0,
                                   atol=0.03 * np.abs(cov[j]).max())
    z = np.random.default_rng(5).standard_normal((draws, 3, 3))
    w, v = np.linalg.eigh(cov)
    root = v * np.sqrt(np.maximum(w, 0.0))[:, None, :]
    np.testing.assert_allclose(errors, np.einsum('jab,mjb->jma', root, z), rtol=1e-12,
                               atol=1e-12 * np.sqrt(np.abs(cov).max()))


def test_seeded_draws_are_the_same_in_every_call_read_only_bounded_and_thread_safe(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """SeededDraws: block b of shape s is the same standard normals in every call (the same
    inputs give the same U), whether kept or drawn again; kept blocks are read-only and their
    bytes stay within KEPT_BYTES (the least recently used dropped); threads drawing at once
    get the same blocks and leave the cache consistent."""
    from concurrent.futures import ThreadPoolExecutor

    from positioning_cell.accuracy import figure_uncertainty as fu
    monkeypatch.setattr(fu.SeededDraws, '_kept', fu.OrderedDict())
    monkeypatch.setattr(fu.SeededDraws, '_kept_bytes', 0)
    monkeypatch.setattr(fu, 'KEPT_BYTES', 4 * 8 * 1000)  # four blocks of 1000 numbers
    first = fu.SeededDraws()
    blocks = [first.standard_normal((100, 10)) for _ in range(6)]
    assert not blocks[0].flags.writeable
    assert fu.SeededDraws._kept_bytes <= fu.KEPT_BYTES and len(fu.SeededDraws._kept) == 4
    again = fu.SeededDraws()  # blocks 0 and 1 were dropped: drawn again, the same numbers
    for b in blocks:
        np.testing.assert_array_equal(again.standard_normal((100, 10)), b)
    assert not np.array_equal(blocks[0], blocks[1])
    np.testing.assert_array_equal(  # another shape: other numbers
        fu.SeededDraws().standard_normal((10, 100)).ravel()[:5] == blocks[0].ravel()[:5],
        np.zeros(5, dtype=bool))

    def draw(_: int) -> list[np.ndarray]:
        source = fu.SeededDraws()
        return [source.standard_normal((50, 20)) for _ in range(8)]

    with ThreadPoolExecutor(8) as pool:
        results = list(pool.map(draw, range(32)))
    for r in results[1:]:
        for a, b in zip(r, results[0], strict=True):
            np.testing.assert_array_equal(a, b)
    kept = fu.SeededDraws._kept
    assert fu.SeededDraws._kept_bytes == sum(v.nbytes for v in kept.values()) <= fu.KEPT_BYTES
