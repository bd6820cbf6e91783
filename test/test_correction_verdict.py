"""What an averaged tracker reading says of a goal tolerance beyond its uncertainty
(positioning_cell.moves.correction.verdict): the early end of a reading in ``measured`` mode
rests on it, so WITHIN must imply the plain comparison holds and OUTSIDE that it fails."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from positioning_cell.errors import InputError
from positioning_cell.motion.settings import GoalTolerance
from positioning_cell.moves.correction import Verdict, verdict

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
