"""The rules that make ``measured`` mode quick (positioning_cell.moves.correction): what an
averaged tracker reading says of a goal tolerance beyond its uncertainty (``verdict``: the early
end of a reading rests on it, so WITHIN must imply the plain comparison holds and OUTSIDE that
it fails), and the correction a nearby goal starts with (``correction_offset``,
``offset_command``, ``predicted_offset``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from positioning_cell.errors import InputError
from positioning_cell.motion.settings import GoalTolerance
from positioning_cell.moves.correction import (
    Verdict,
    corrected_command,
    correction_offset,
    offset_command,
    predicted_offset,
    verdict,
)

TOL = GoalTolerance(position=1e-5, orientation=1e-4)
Z = 2.0
errors = st.lists(st.floats(-3e-5, 3e-5), min_size=3, max_size=3)
rotations = st.lists(st.floats(-3e-4, 3e-4), min_size=3, max_size=3)
sigmas = st.lists(st.floats(0.0, 1e-5), min_size=6, max_size=6)


@settings(max_examples=300)
@given(errors, rotations, sigmas)
def test_a_verdict_beyond_doubt_agrees_with_the_plain_comparison(
        e_p: list[float], e_r: list[float], sigma: list[float]) -> None:
    found = verdict(e_p, e_r, sigma, TOL.position, TOL.orientation, Z)
    if found is Verdict.WITHIN:
        assert TOL.holds(e_p, e_r)
    if found is Verdict.OUTSIDE:
        assert not TOL.holds(e_p, e_r)
    # a zero uncertainty decides every case, as the plain comparison does
    exact = verdict(e_p, e_r, np.zeros(6), TOL.position, TOL.orientation, Z)
    assert exact is (Verdict.WITHIN if TOL.holds(e_p, e_r) else Verdict.OUTSIDE)


def test_the_margin_is_significance_sigma_per_component() -> None:
    sigma = np.array([1e-6] * 3 + [1e-5] * 3)
    # 7 µm along x: within 10 µm even enlarged by 2 µm per component (norm 9.6 µm) ...
    assert verdict([7e-6, 0, 0], np.zeros(3), sigma, 1e-5, 1e-4, Z) is Verdict.WITHIN
    # ... 8 µm is not (norm 10.4 µm), nor beyond doubt outside: undecided
    assert verdict([8e-6, 0, 0], np.zeros(3), sigma, 1e-5, 1e-4, Z) is Verdict.UNDECIDED
    # 12.5 µm shrunk by 2 µm is still 10.5 µm: outside; 11.5 µm is not yet
    assert verdict([12.5e-6, 0, 0], np.zeros(3), sigma, 1e-5, 1e-4, Z) is Verdict.OUTSIDE
    assert verdict([11.5e-6, 0, 0], np.zeros(3), sigma, 1e-5, 1e-4, Z) is Verdict.UNDECIDED
    # the rotation alone can put it outside
    assert verdict(np.zeros(3), [0, 1.3e-4, 0], sigma, 1e-5, 1e-4, Z) is Verdict.OUTSIDE


@pytest.mark.parametrize(('e_p', 'sigma'), [
    ([np.nan, 0, 0], np.zeros(6)),
    ([0, 0, 0], [-1e-6] + [0.0] * 5),
    ([0, 0, 0], [np.inf] + [0.0] * 5),
])
def test_bad_input_is_refused(e_p: list[float], sigma: list[float]) -> None:
    with pytest.raises(InputError, match='finite, sigma >= 0'):
        verdict(e_p, np.zeros(3), sigma, 1e-5, 1e-4, Z)


def test_an_offset_applied_to_its_own_goal_is_the_corrected_command() -> None:
    rng = np.random.default_rng(5)
    goal_p, goal_q = np.array([0.01, -0.02, 0.2]), Rotation.from_rotvec([0.02, 0.0, -0.01])
    command_p = goal_p + rng.normal(0, 3e-4, 3)
    command_q = Rotation.from_rotvec(rng.normal(0, 5e-3, 3)) * goal_q
    measured_p = goal_p + rng.normal(0, 3e-4, 3)
    measured_q = Rotation.from_rotvec(rng.normal(0, 5e-3, 3)) * goal_q
    offset = correction_offset(command_p, command_q.as_quat(), measured_p, measured_q.as_quat())
    p, q = offset_command(goal_p, goal_q.as_quat(), offset)
    want_p, want_q = corrected_command(goal_p, goal_q.as_quat(), command_p, command_q.as_quat(),
                                       measured_p, measured_q.as_quat())
    np.testing.assert_allclose(p, want_p, atol=1e-15)
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(),
                               Rotation.from_quat(want_q).as_matrix(), atol=1e-12)


def test_a_predicted_offset_follows_an_affine_field_and_carries_one_move_as_it_is() -> None:
    rng = np.random.default_rng(7)
    a, slope = rng.normal(0, 1e-4, 6), rng.normal(0, 2e-3, (3, 6))  # offset per m of goal
    goals = 0.004 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    offsets = a + goals @ slope
    at = np.array([0.006, -0.003, 0.002])
    np.testing.assert_allclose(predicted_offset(goals, offsets, at, 0.01), a + at @ slope,
                               rtol=1e-9, atol=1e-15)
    # one move: its offset, wherever the goal
    np.testing.assert_allclose(predicted_offset(goals[:1], offsets[:1], at, 0.01), offsets[0],
                               atol=1e-15)
    # goals along x only: a slope along x, none across it
    line = np.zeros((4, 3))
    line[:, 0] = [-0.004, -0.001, 0.002, 0.005]
    along = a + line @ slope
    np.testing.assert_allclose(predicted_offset(line, along, [0.003, 0.004, 0.0], 0.01),
                               a + np.array([0.003, 0.0, 0.0]) @ slope, rtol=1e-9, atol=1e-15)
    # goals within 0.1 mm of each other (less than rcond of a 10 mm neighbourhood): no slope
    close = 1e-4 * rng.uniform(-1, 1, (5, 3))
    np.testing.assert_allclose(predicted_offset(close, a + close @ slope, at, 0.01),
                               (a + close @ slope).mean(axis=0), atol=1e-15)


@pytest.mark.parametrize(('goals', 'offsets', 'scale', 'words'), [
    (np.zeros((2, 3)), np.zeros((3, 6)), 0.01, r'expected shape \(2, 6\)'),
    (np.zeros((0, 3)), np.zeros((0, 6)), 0.01, 'at least one'),
    (np.zeros((1, 3)), np.zeros((1, 6)), 0.0, 'scale = 0.0'),
])
def test_a_prediction_from_bad_input_is_refused(goals: np.ndarray, offsets: np.ndarray,
                                                scale: float, words: str) -> None:
    with pytest.raises(InputError, match=words):
        predicted_offset(goals, offsets, np.zeros(3), scale)
