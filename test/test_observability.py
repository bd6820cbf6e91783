"""Observability of the calibration program (positioning_cell.calibration.observability) and
its choice by D, I or G criterion (positioning_cell.calibration.program): the indices against
hand-computed values and their invariances, the I and G criteria against a second path (the
identification's own pose uncertainty, an explicit loop, Monte Carlo), the greedy step's
update against a direct recomputation, the chosen program against random ones, and the
refusal of bad settings."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from positioning_cell.calibration import identify as idf
from positioning_cell.calibration import observability as obs
from positioning_cell.calibration import parameters as cp
from positioning_cell.calibration import program as prog
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.pose_grid import PoseGrid, grid_poses
from positioning_cell.errors import ConfigError
from positioning_cell.parameters import ParameterError, parse
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings

SETTINGS = parse(PoseMeasurementSettings,
                 node_parameters(load_parameter_file(config_path()), 'pose_measurement'))
MECH, PAYLOAD, STRUCTURE = SETTINGS.mechanism, SETTINGS.payload, SETTINGS.structure
POSE_COV = np.diag([3e-6**2] * 3 + [2e-5**2] * 3)
JOINT_SIGMA = np.r_[[4e-7] * 3, [3e-6] * 3]
SMALL = prog.ProgramSettings(poses=10, hold_out=3, candidates=300)


@pytest.fixture(scope='module')
def candidates() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p, q = prog.candidates(MECH, SMALL)
    return p, q, idf.information_rows(MECH, PAYLOAD, STRUCTURE, p, q, POSE_COV, JOINT_SIGMA)


@pytest.fixture(scope='module')
def production() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p, q = prog.production_poses(MECH, SMALL)
    return p, q, obs.pose_sensitivity(MECH, PAYLOAD, STRUCTURE, p, q)


def test_indices_of_a_diagonal_matrix_are_the_hand_computed_ones() -> None:
    j = np.zeros((5, 3))
    j[[0, 1, 2], [0, 1, 2]] = (1.0, 4.0, 2.0)  # singular values 4, 2, 1 of 5 rows
    ind = obs.observability(j)
    assert (ind.rows, ind.columns) == (5, 3)
    assert_allclose([ind.sigma_max, ind.sigma_min, ind.condition], [4.0, 1.0, 4.0])
    assert_allclose(ind.o1, 8.0 ** (1 / 3) / np.sqrt(5.0))
    assert_allclose([ind.o2, ind.o3, ind.o4], [0.25, 1.0, 0.25])
    # per-pose rows (N, k, n) are stacked
    assert_allclose(obs.observability(np.vstack([j, np.zeros((1, 3))]).reshape(3, 2, 3)).o1,
                    8.0 ** (1 / 3) / np.sqrt(6.0))


def test_a_rank_deficient_jacobian_has_no_observability() -> None:
    ind = obs.observability(np.diag([3.0, 1.0, 0.0]))
    assert ind.sigma_min == 0.0 and ind.o1 == 0.0 and ind.o2 == 0.0 and ind.o4 == 0.0
    assert ind.condition == np.inf
    fewer_rows = obs.observability(np.ones((2, 3)))  # 2 measurements of 3 parameters
    assert (fewer_rows.columns, fewer_rows.sigma_min, fewer_rows.o1) == (3, 0.0, 0.0)
    assert_allclose(fewer_rows.sigma_max, np.sqrt(6.0))
    with pytest.raises(ValueError, match='singular values'):
        obs.indices_of_singular_values([1.0, -1.0], 4)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 45))
def test_indices_do_not_depend_on_row_order_or_an_orthogonal_map_of_rows(
        seed: int, columns: int) -> None:
    """Any number of columns (the parameter vector may grow); O1..O4 are functions of JᵀJ."""
    rng = np.random.default_rng(seed)
    j = rng.normal(size=(columns + 7, columns)) * rng.uniform(0.1, 10.0, columns)
    ind = obs.observability(j)
    assert ind.columns == columns
    q, _ = np.linalg.qr(rng.normal(size=(j.shape[0], j.shape[0])))
    for other in (obs.observability(j[rng.permutation(j.shape[0])]), obs.observability(q @ j)):
        assert_allclose(other[2:], ind[2:], rtol=1e-8)
    # O1 is the geometric mean of the singular values over sqrt(m): sqrt(det JᵀJ)^(1/n)/sqrt(m)
    log_det = np.linalg.slogdet(j.T @ j)[1]
    assert_allclose(ind.o1, np.exp(log_det / (2 * columns)) / np.sqrt(j.shape[0]), rtol=1e-8)


def test_the_criteria_match_the_identifications_pose_uncertainty(
        candidates: tuple[np.ndarray, np.ndarray, np.ndarray],
        production: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """I and G through S_P M⁻¹ S_Pᵀ against pose_uncertainty of the parameters' covariance in
    their own units (an explicit loop over the poses)."""
    _, _, rows = candidates
    p, q, sens = production
    info = obs.information(rows[:12])
    scale = cp.scales(MECH)
    cov = np.linalg.inv(info) * np.outer(scale, scale)
    x0 = np.zeros(scale.size)
    x0[cp.R_A], x0[cp.R_B] = scale[cp.R_A], scale[cp.R_B]
    w = obs.pose_weights(MECH)
    variance = [np.trace(np.diag(w) @ c @ np.diag(w)) for c in
                idf.pose_uncertainty(x0, cov, MECH, PAYLOAD, STRUCTURE, p, q)]
    assert_allclose(obs.predicted_variance(info, sens), variance, rtol=1e-8)
    assert_allclose(obs.criterion_value('I', info, sens), np.mean(variance), rtol=1e-8)
    assert_allclose(obs.criterion_value('G', info, sens), np.max(variance), rtol=1e-8)
    assert_allclose(obs.criterion_value('D', info, sens), -np.linalg.slogdet(info)[1])


def test_the_i_criterion_is_the_mean_squared_pose_error_of_drawn_parameters(
        candidates: tuple[np.ndarray, np.ndarray, np.ndarray],
        production: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """Monte Carlo: parameters drawn from N(0, M⁻¹), their pose errors S_P δ, squared."""
    _, _, rows = candidates
    sens = production[2]
    info = obs.information(rows[:12])
    draws = np.random.default_rng(4).multivariate_normal(np.zeros(info.shape[0]),
                                                         np.linalg.inv(info), 40000)
    errors = np.einsum('qai,si->sqa', sens, draws)
    assert_allclose(np.mean(np.sum(errors**2, axis=2)), obs.criterion_value('I', info, sens),
                    rtol=0.03)


@pytest.mark.parametrize('criterion', obs.CRITERIA)
def test_a_greedy_steps_gain_is_the_change_of_the_criterion(
        criterion: str, candidates: tuple[np.ndarray, np.ndarray, np.ndarray],
        production: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    """The vectorised update (Woodbury) against the criterion recomputed with each pose."""
    _, _, rows = candidates
    sens = production[2]
    info = obs.information(rows[:8])
    gains = prog._gains(criterion, info, rows[20:40], sens)
    before = obs.criterion_value(criterion, info, sens)
    direct = [before - obs.criterion_value(criterion, info + r.T @ r, sens) for r in rows[20:40]]
    assert_allclose(gains, direct, rtol=1e-6, atol=1e-9 * abs(before))


def test_the_chosen_program_beats_random_programs_of_its_size_at_production(
        candidates: tuple[np.ndarray, np.ndarray, np.ndarray],
        production: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    p, _, rows = candidates
    sens = production[2]
    chosen = prog.choose(MECH, PAYLOAD, STRUCTURE, replace(SMALL, criterion='I'), POSE_COV,
                         JOINT_SIGMA, production[:2])
    chosen_rows = idf.information_rows(MECH, PAYLOAD, STRUCTURE, chosen.position,
                                       chosen.quaternion, POSE_COV, JOINT_SIGMA)
    value = obs.criterion_value('I', obs.information(chosen_rows), sens)
    assert_allclose(chosen.values[-1], value, rtol=1e-9)
    rng = np.random.default_rng(7)
    randoms = [obs.criterion_value('I', obs.information(rows[rng.choice(len(p), SMALL.poses,
                                                                         replace=False)]), sens)
               for _ in range(20)]
    assert value <= min(randoms)
    # the program states its predicted sigma at production and its indices
    assert chosen.production_sigma is not None and chosen.indices is not None
    assert_allclose(np.mean(chosen.production_sigma**2), value, rtol=1e-9)
    # its indices are those of the columns poses alone excite (thermal, reversal: 0 here)
    posed = np.any(chosen_rows != 0.0, axis=(0, 1))
    assert not posed[cp.THERMAL].any() and not posed[cp.REVERSAL].any() and posed[:26].all()
    assert_allclose(chosen.indices.o1, obs.observability(chosen_rows[:, :, posed]).o1,
                    rtol=1e-9)
    assert chosen.indices.sigma_min > 0.0


def test_exchange_never_makes_the_greedy_program_worse(
        candidates: tuple[np.ndarray, np.ndarray, np.ndarray],
        production: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    rows, sens = candidates[2], production[2]
    for criterion in obs.CRITERIA:
        greedy = prog.select(rows, sens, 10, criterion, exchange_passes=0)
        exchanged = prog.select(rows, sens, 10, criterion, exchange_passes=2)
        assert exchanged[1][-1] <= greedy[1][-1] + 1e-12 * abs(greedy[1][-1])
        assert len(set(exchanged[0].tolist())) == 10


def test_the_shipped_production_poses_are_the_iso_cube_grid() -> None:
    p, q = prog.production_poses(MECH, prog.ProgramSettings())
    assert p.shape == (27, 3)
    assert_allclose(p.mean(axis=0), (0.0, 0.0, 0.196), atol=1e-12)
    assert_allclose(np.ptp(p, axis=0), (0.01, 0.01, 0.01))
    assert_allclose(q, np.tile((0.0, 0.0, 0.0, 1.0), (27, 1)))
    tilted = grid_poses(MECH, PoseGrid(points=1, tilt=0.05))
    assert tilted[0].shape == (5, 3)


def test_a_bad_criterion_is_refused_naming_the_key() -> None:
    with pytest.raises(ParameterError, match='criterion'):
        prog.ProgramSettings(criterion='E')
    with pytest.raises(ParameterError, match='criterion'):
        parse(prog.ProgramSettings, {'criterion': 'A-optimal'})
    with pytest.raises(ValueError, match='criterion'):
        obs.criterion_value('X', np.eye(2), np.zeros((1, 6, 2)))


@pytest.mark.parametrize(('block', 'key'), [
    ('{points: 0}', 'production.points'),
    ('{size: 3}', 'production.size'),
    ('{half_widths: [0.01, -0.01, 0.0]}', 'production.half_widths'),
    ('{centre: [0.0, 0.0, 0.5]}', 'production: no pose of the grid'),
])
def test_a_bad_production_block_is_refused_naming_the_key(tmp_path: Path, block: str,
                                                          key: str) -> None:
    path = tmp_path / 'program.yaml'
    path.write_text(f'production: {block}\n')
    with pytest.raises(ConfigError, match=key):
        prog.production_poses(MECH, replace(SMALL, production=str(path)))
