"""The mean of tracker readings and the covariance of that mean
(positioning_cell.moves.correction.mean_reading): a part common to every reading (the
tracker's registration) does not average down, an independent part does, and the readings'
own scatter tells them apart; the result is symmetric positive semi-definite and keeps the
stated correlations."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from workspace import MECH

from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import averaged_covariance
from positioning_cell.moves.correction import mean_pose, mean_reading, unread_sigma

K = 10  # readings per mean, as the positioner's default compensation.samples
R0 = Rotation.from_rotvec([0.02, -0.01, 0.03])
#: Per-axis σ of a reading: common (registration) and independent parts, m and rad.
COMMON_SIGMA = np.array([10e-6, 12e-6, 8e-6, 40e-6, 50e-6, 30e-6])
INDEPENDENT_SIGMA = np.array([1e-6, 1.5e-6, 1e-6, 5e-6, 4e-6, 5e-6])


def readings(common: np.ndarray, independent: np.ndarray,
             k: int = K) -> tuple[np.ndarray, np.ndarray]:
    """k readings of the pose (home, R0) off by ``common`` (6,) in all of them plus
    ``independent`` (k, 6) each (positions m; rotations rad about the base axes)."""
    off = common + independent
    q = (Rotation.from_rotvec(off[:, 3:]) * R0).as_quat()
    return MECH.home_position + off[:, :3], q


def test_a_common_error_is_not_averaged_down() -> None:
    """Readings sharing a large common error, with small independent noise: the mean's
    stated covariance stays at the common part (plus the independent part over k), not the
    mean stated covariance over k (what the readings taken as independent would say), and the
    mean's true error is within it."""
    rng = np.random.default_rng(11)
    stated = np.diag(COMMON_SIGMA**2 + INDEPENDENT_SIGMA**2)
    for _ in range(20):
        common = rng.standard_normal(6) * COMMON_SIGMA
        p, q = readings(common, rng.standard_normal((K, 6)) * INDEPENDENT_SIGMA)
        position, quaternion, cov = mean_reading(p, q, np.broadcast_to(stated, (K, 6, 6)))
        expected = COMMON_SIGMA**2 + INDEPENDENT_SIGMA**2 / K
        # the independent share is a few % of the stated variance: s² would need to exceed
        # 5 times its expectation to move the result by 5 %
        np.testing.assert_allclose(np.diag(cov), expected, rtol=0.05)
        assert np.all(np.diag(cov) > 5.0 * np.diag(stated) / K)
        e_r = (Rotation.from_quat(quaternion) * R0.inv()).as_rotvec()
        error = np.concatenate([position - MECH.home_position, e_r]) - common
        assert np.all(np.abs(error) < 4.0 * INDEPENDENT_SIGMA / np.sqrt(K))


def test_a_common_error_is_covered_over_many_poses() -> None:
    """Over 400 poses with a fresh common error each, the errors of the means normalised by
    their stated σ have a mean square near 1 per axis (readings taken as independent: ~9)."""
    rng = np.random.default_rng(12)
    stated = np.broadcast_to(np.diag(COMMON_SIGMA**2 + INDEPENDENT_SIGMA**2), (K, 6, 6))
    z = []
    for _ in range(400):
        common = rng.standard_normal(6) * COMMON_SIGMA
        p, q = readings(common, rng.standard_normal((K, 6)) * INDEPENDENT_SIGMA)
        position, quaternion, cov = mean_reading(p, q, stated)
        e_r = (Rotation.from_quat(quaternion) * R0.inv()).as_rotvec()
        z.append(np.concatenate([position - MECH.home_position, e_r]) / np.sqrt(np.diag(cov)))
    mean_square = np.mean(np.square(z), axis=0)
    # χ²(400)/400 per axis: 0.80 … 1.22 at ±3σ
    assert np.all((mean_square > 0.75) & (mean_square < 1.3)), mean_square


@pytest.mark.parametrize('k', [3, 10])
def test_a_known_common_part_is_stated_exactly_and_covered(k: int) -> None:
    """With the common part known (the tracker's published registration), the mean of k
    readings (3: a reading ended early) states common + (C̄ − common)/k whatever the readings'
    scatter, and over 400 poses with a fresh common error each its normalised errors have a
    mean square near 1 per axis: honest, not merely safe."""
    rng = np.random.default_rng(15)
    own = 2.0 * COMMON_SIGMA  # a reading's own noise, the larger share as on the tracker
    common_cov = np.diag(COMMON_SIGMA**2)
    stated = np.broadcast_to(common_cov + np.diag(own**2), (k, 6, 6))
    expected = common_cov + np.diag(own**2) / k
    z = []
    for _ in range(400):
        common = rng.standard_normal(6) * COMMON_SIGMA
        p, q = readings(common, rng.standard_normal((k, 6)) * own, k=k)
        position, quaternion, cov = mean_reading(p, q, stated, common_cov)
        np.testing.assert_allclose(cov, expected, rtol=1e-12, atol=0)
        e_r = (Rotation.from_quat(quaternion) * R0.inv()).as_rotvec()
        z.append(np.concatenate([position - MECH.home_position, e_r]) / np.sqrt(np.diag(cov)))
    mean_square = np.mean(np.square(z), axis=0)
    # χ²(400)/400 per axis: 0.80 … 1.22 at ±3σ
    assert np.all((mean_square > 0.75) & (mean_square < 1.3)), mean_square


def test_a_bad_common_part_or_count_is_refused() -> None:
    p, q = readings(np.zeros(6), np.zeros((K, 6)))
    stated = np.broadcast_to(np.diag(COMMON_SIGMA**2), (K, 6, 6))
    with pytest.raises(InputError, match='common covariance: expected a finite 6 x 6'):
        mean_reading(p, q, stated, np.zeros((3, 3)))
    with pytest.raises(InputError, match='common covariance: expected a finite 6 x 6'):
        mean_reading(p, q, stated, np.full((6, 6), np.nan))
    with pytest.raises(InputError, match='samples: expected at least 1'):
        averaged_covariance(stated[0], stated[0], 0)


@pytest.mark.parametrize('scale', [1.0, 2.0])
def test_independent_readings_average_down(scale: float) -> None:
    """Readings that scatter exactly as stated (scale 1) or more (scale 2, the share capped),
    with stated covariances differing between readings: the covariance of their plain mean
    is the mean stated covariance over k, correlations and all (the information sum
    inv(Σ C_i⁻¹) would be smaller)."""
    rng = np.random.default_rng(13)
    scales = np.linspace(0.5, 2.0, K)  # each reading's covariance a multiple of a base one
    base = np.diag(INDEPENDENT_SIGMA**2)
    base[0, 3] = base[3, 0] = 0.5 * INDEPENDENT_SIGMA[0] * INDEPENDENT_SIGMA[3]
    covariances = scales[:, None, None] * base
    mean_cov = covariances.mean(axis=0)
    draws = rng.standard_normal((K, 6))
    draws = (draws - draws.mean(axis=0)) / draws.std(axis=0, ddof=1)  # sample variance 1
    p, q = readings(np.zeros(6), draws * np.sqrt(scale * np.diag(mean_cov)))
    _, _, cov = mean_reading(p, q, covariances)
    np.testing.assert_allclose(cov, mean_cov / K, rtol=1e-3, atol=1e-30)


def test_independent_readings_are_stated_below_one_reading_and_covered() -> None:
    """Purely independent noise at 10 readings a mean, over 400 draws: the stated variance of
    the mean always lies between the mean stated variance over k and the stated variance
    itself, on average well below the latter (the scatter of 10 readings only estimates the
    independent share, so it stays above 1/k), and covers the true error of the mean."""
    rng = np.random.default_rng(14)
    sigma = COMMON_SIGMA  # a reading's σ, all of it independent now
    stated = np.broadcast_to(np.diag(sigma**2), (K, 6, 6))
    ratios, z = [], []
    for _ in range(400):
        p, q = readings(np.zeros(6), rng.standard_normal((K, 6)) * sigma)
        position, quaternion, cov = mean_reading(p, q, stated)
        ratios.append(np.diag(cov) / sigma**2)
        e_r = (Rotation.from_quat(quaternion) * R0.inv()).as_rotvec()
        z.append(np.concatenate([position - MECH.home_position, e_r]) / np.sqrt(np.diag(cov)))
    ratio = np.array(ratios)
    assert np.all(ratio >= 1.0 / K * (1 - 1e-9)) and np.all(ratio <= 1.0 + 1e-9)
    # E[ratio] ≈ 0.27 for k = 10 (1 − f·(1 − 1/k), f = min(χ²₉/9, 1)); over 400 draws ± 0.01
    assert np.all(ratio.mean(axis=0) < 0.4) and np.all(ratio.mean(axis=0) > 0.15)
    assert np.all(np.mean(np.square(z), axis=0) < 1.3)


def test_a_single_reading_is_its_own_covariance() -> None:
    cov = np.diag(COMMON_SIGMA**2)[None]
    p, q = readings(np.zeros(6), np.zeros((1, 6)), k=1)
    position, quaternion, out = mean_reading(p, q, cov)
    np.testing.assert_allclose(out, cov[0], rtol=1e-12)
    np.testing.assert_allclose(position, p[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(quaternion, R0.as_quat(canonical=True), rtol=0, atol=1e-15)


@pytest.mark.parametrize(('covariances', 'words'), [
    (np.zeros((K, 3, 3)), r'covariances: expected shape \(10, 6, 6\)'),
    (np.zeros((K - 1, 6, 6)), r'covariances: expected shape \(10, 6, 6\)'),
    (np.full((K, 6, 6), np.nan), 'covariances: not finite'),
])
def test_bad_covariances_are_refused(covariances: np.ndarray, words: str) -> None:
    p, q = readings(np.zeros(6), np.zeros((K, 6)))
    with pytest.raises(InputError, match=words):
        mean_reading(p, q, covariances)


def spd(raw: np.ndarray, units: np.ndarray) -> np.ndarray:
    """Symmetric positive semi-definite (..., 6, 6) from raw (..., 6, 6) numbers, scaled to
    ``units`` (6,) per axis."""
    a = raw * units[:, None]
    return np.asarray(a @ np.swapaxes(a, -1, -2))


UNITS = np.array([1e-5] * 3 + [1e-4] * 3)


@settings(max_examples=60, deadline=None)
@given(k=st.integers(1, 30), seed=st.integers(0, 2**32 - 1),
       scatter=st.floats(0.0, 3.0), common=st.floats(0.0, 1e-4))
def test_the_covariance_of_the_mean_is_honest_psd_and_keeps_correlations(
        k: int, seed: int, scatter: float, common: float) -> None:
    """Any readings, any positive semi-definite stated covariances: the result is symmetric
    PSD, every variance between the mean stated one over k and the mean stated one, the
    correlations those of the mean stated covariance, and the mean that of mean_pose."""
    rng = np.random.default_rng(seed)
    covariances = spd(rng.standard_normal((k, 6, 6)), UNITS)
    shift = np.full(6, common)
    p, q = readings(shift, rng.standard_normal((k, 6)) * UNITS * scatter, k=k)
    position, quaternion, cov = mean_reading(p, q, covariances)
    mean_cov = covariances.mean(axis=0)
    np.testing.assert_allclose(cov, cov.T, rtol=0, atol=0)
    eig = np.linalg.eigvalsh(cov)
    assert eig.min() >= -1e-12 * eig.max()
    variance, stated = np.diag(cov), np.diag(mean_cov)
    assert np.all(variance >= stated / k * (1 - 1e-9)) and np.all(variance <= stated * (1 + 1e-9))
    np.testing.assert_allclose(cov / np.sqrt(np.outer(variance, variance)),
                               mean_cov / np.sqrt(np.outer(stated, stated)), atol=1e-9)
    mp, mq = mean_pose(p, q)
    np.testing.assert_allclose(position, mp, rtol=0, atol=1e-15)
    np.testing.assert_allclose(quaternion, mq, rtol=0, atol=1e-15)
    if scatter == 0.0:  # identical readings: all of it common
        np.testing.assert_allclose(cov, mean_cov, rtol=1e-9, atol=1e-30)


def test_unread_sigma_is_how_far_the_readings_to_come_can_move_the_mean() -> None:
    """Monte Carlo over readings with a common error and independent noise: the spread of
    mean_K − mean_k is unread_sigma of the first k readings' stated covariances with the
    common part given (within 3 % over 20 000 draws); without it, it overstates; at k = K
    nothing is left; a malformed input is refused."""
    rng = np.random.default_rng(11)
    stated = np.diag(COMMON_SIGMA**2 + INDEPENDENT_SIGMA**2)
    common = np.diag(COMMON_SIGMA**2)
    draws = 20_000
    for k in (3, 6):
        x = rng.normal(0.0, COMMON_SIGMA, (draws, 1, 6)) + rng.normal(
            0.0, INDEPENDENT_SIGMA, (draws, K, 6))
        spread = (x.mean(axis=1) - x[:, :k].mean(axis=1)).std(axis=0)
        covariances = np.repeat(stated[None], k, axis=0)
        predicted = unread_sigma(covariances, common, K)
        np.testing.assert_allclose(spread, predicted, rtol=0.03)
        assert np.all(unread_sigma(covariances, None, K) > predicted)
    assert not np.any(unread_sigma(np.repeat(stated[None], K, axis=0), common, K))
    with pytest.raises(InputError, match='covariances'):
        unread_sigma(np.zeros((3, 6)), None, K)
