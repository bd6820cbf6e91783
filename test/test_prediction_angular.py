"""Seed 003: the platform-normal angle, its fits, and the stacked-stage model with its three
strategies, checked against the paper's two examples."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from positioning_cell.errors import InputError
from positioning_cell.prediction.angular import (
    PAPER_EXAMPLES,
    PAPER_HOLES,
    PAPER_PARTS,
    PAPER_RUNS,
    Strategy,
    assembly_angles,
    draw_part_tilts,
    fit_angle_distribution,
    normal_angles,
    rice_law,
    tilts_from_rotvecs,
)


def test_single_part_angle_is_eq_4_and_tilts_round_trip() -> None:
    rng = np.random.default_rng(0)
    ab = rng.normal(0.0, 2e-3, size=(500, 2))
    rot = Rotation.from_euler('XY', ab)  # R_X(Δα)·R_Y(Δβ), seed 003 eq. (1)
    np.testing.assert_allclose(tilts_from_rotvecs(rot.as_rotvec()), ab, atol=1e-15)
    np.testing.assert_allclose(normal_angles(rot), np.hypot(ab[:, 0], ab[:, 1]), rtol=1e-5)


def test_fit_recovers_known_rice_and_gev_laws() -> None:
    rng = np.random.default_rng(1)
    rice = rice_law(3e-3, 1e-3).rvs(size=8000, random_state=rng)
    fits = fit_angle_distribution(rice)
    assert fits.rice_nu_sigma == pytest.approx((3e-3, 1e-3), rel=0.05)
    assert fits.rice.ks_pvalue > 0.01
    gev = stats.genextreme(0.2, loc=2e-3, scale=5e-4).rvs(size=8000, random_state=rng)
    c, loc, scale = fit_angle_distribution(gev).gev.params
    assert (c, loc, scale) == pytest.approx((0.2, 2e-3, 5e-4), rel=0.1)
    with pytest.raises(InputError):
        fit_angle_distribution(np.array([1e-3, -1e-3] * 10))


@pytest.mark.parametrize('example', list(PAPER_EXAMPLES))
def test_direct_assembly_follows_the_papers_rice_law(example: int) -> None:
    mean, std = PAPER_EXAMPLES[example]
    tilts = draw_part_tilts(PAPER_RUNS, PAPER_PARTS, mean, std, np.random.default_rng(example))
    angles = assembly_angles(tilts, PAPER_HOLES, Strategy.DIRECT)
    for n in (1, 4, PAPER_PARTS):
        law = rice_law(np.sqrt(2.0) * n * mean, np.sqrt(n) * std)  # Rice(√2·n·μ, √n·σ)
        assert stats.kstest(angles[:, n - 1], law.cdf).pvalue > 0.01
        assert angles[:, n - 1].mean() == pytest.approx(law.mean(), rel=0.02)
        assert angles[:, n - 1].std() == pytest.approx(law.std(), rel=0.03)
    nu, sigma = fit_angle_distribution(angles[:, -1]).rice_nu_sigma
    assert sigma == pytest.approx(np.sqrt(PAPER_PARTS) * std, rel=0.06)
    if example == 2:  # ν is identifiable only where ν/σ is large (example 1: 0.4)
        assert nu == pytest.approx(np.sqrt(2.0) * PAPER_PARTS * mean, rel=0.02)


@pytest.mark.parametrize('example', list(PAPER_EXAMPLES))
def test_stage_by_stage_is_flat_and_global_falls_toward_zero(example: int) -> None:
    mean, std = PAPER_EXAMPLES[example]
    tilts = draw_part_tilts(PAPER_RUNS, PAPER_PARTS, mean, std, np.random.default_rng(example))
    direct = assembly_angles(tilts, PAPER_HOLES, Strategy.DIRECT).mean(axis=0)
    stage = assembly_angles(tilts, PAPER_HOLES, Strategy.STAGE_BY_STAGE).mean(axis=0)
    best = assembly_angles(tilts[:60, :7], PAPER_HOLES, Strategy.GLOBAL).mean(axis=0)
    # stage by stage: roughly flat with n from the second part on, below direct assembly
    assert stage[1:].max() < 1.6 * stage[1:].min()
    assert stage[-1] < 0.3 * direct[-1]
    assert stage[-1] < direct[0]
    # global: never worse than stage by stage, strictly falling, toward 0
    assert np.all(best <= stage[:7] * 1.25)
    assert np.all(np.diff(best[1:]) < 0.0)
    assert best[-1] < 0.05 * best[0]


def test_global_search_equals_exhaustive_enumeration() -> None:
    tilts = draw_part_tilts(40, 4, 1e-3, 0.5e-3, np.random.default_rng(9))
    found = assembly_angles(tilts, 5, Strategy.GLOBAL)[:, -1]
    parts = Rotation.from_euler('XY', tilts.reshape(-1, 2)).as_matrix().reshape(40, 4, 3, 3)
    best = np.full(40, np.inf)
    for psi in itertools.product(range(5), repeat=4):  # every clocking, ψ_1 included
        stack = np.broadcast_to(np.eye(3), (40, 3, 3))
        for j in range(4):
            stack = stack @ Rotation.from_euler('z', 2 * np.pi * psi[j] / 5).as_matrix() @ parts[
                :, j]
        best = np.minimum(best, normal_angles(Rotation.from_matrix(stack)))
    np.testing.assert_allclose(found, best, rtol=1e-9, atol=1e-15)
    stage = assembly_angles(tilts, 5, Strategy.STAGE_BY_STAGE)[:, -1]
    assert np.all(found <= stage + 1e-15)


def test_bad_stack_inputs_are_refused() -> None:
    with pytest.raises(InputError, match='std'):
        draw_part_tilts(10, 3, 0.0, -1.0, np.random.default_rng(0))
    with pytest.raises(InputError, match='tilts'):
        assembly_angles(np.zeros((4, 3)), 6, Strategy.DIRECT)
