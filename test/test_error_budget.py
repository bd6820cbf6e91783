"""The error budget (positioning_cell.analysis.error_budget): on synthetic visits whose
contributions are known, each line finds its own; the window statistics equal a direct
computation however the samples are grouped; a bag without the truth says so; the budget of a
synthetic recorded run finds the tracker's noise it was made with."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from positioning_cell.accuracy import MonitorSettings
from positioning_cell.analysis import error_budget as eb
from positioning_cell.analysis.report import write_report
from positioning_cell.analysis.summary import analyse_bag
from positioning_cell.config import config_path
from positioning_cell.core import kinematics
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.testing.synthetic_run import synthetic_run, write_run_bag

N = 4000  # visits: the sample RMS within ~2 % of the RMS it is drawn with
SETTINGS = MonitorSettings.from_file(config_path('cell.yaml'))


def _jacobians(rng: np.random.Generator) -> np.ndarray:
    """Sensitivities of the nominal mechanism at poses around home."""
    mech = Mechanism()
    p = mech.home_position + rng.uniform(-3e-3, 3e-3, (N, 3))
    q = np.tile(mech.home_quaternion, (N, 1))
    jac: np.ndarray = kinematics.jacobian(mech, p, q).matrix[:, :3, :]
    return jac


def _known(mode: str, seed: int = 1) -> tuple[eb.ErrorBudget, dict[str, float]]:
    """Visits whose true error is the sum of a servo error, a quantisation error (uniform
    within ±r/2 per joint), in ``measured`` mode the tracker's error (a bias and the noise of
    its mean), and an unmodelled part; each drawn with a known RMS."""
    rng = np.random.default_rng(seed)
    jac = _jacobians(rng)
    r = np.array([2e-6] * 3 + [5e-5] * 3)
    dq = rng.normal(0.0, [3e-6] * 3 + [2e-5] * 3, (N, 6))
    quant = rng.uniform(-0.5, 0.5, (N, 6)) * r
    bias = np.array([2e-6, -1e-6, 2e-6])
    var_mean = np.full((N, 3), (1.5e-6) ** 2)  # the variance of the tracker's window mean
    noise = rng.normal(0.0, 1.5e-6, (N, 3))
    tracker = bias + noise
    unmodelled = rng.normal(0.0, 4e-6, (N, 3))
    e = (np.einsum('nij,nj->ni', jac, dq + quant) + unmodelled
         + (tracker if mode == 'measured' else 0.0))
    budget = eb.error_budget(mode, e, dq, jac, r, var_mean, tracker, N)
    expected = {
        eb.SERVO: math.sqrt(np.mean(np.einsum('nij,nj->ni', jac, dq) ** 2) * 3),
        eb.QUANTISATION: math.sqrt(np.mean(np.einsum('nij,j,nij->n', jac, r ** 2 / 12, jac))),
        eb.TRACKER_NOISE: 1.5e-6 * math.sqrt(3),
        eb.TRACKER_SYSTEMATICS: float(np.linalg.norm(bias)),
        eb.RESIDUAL: 4e-6 * math.sqrt(3),
    }
    return budget, expected


@pytest.mark.parametrize('mode', ['model', 'measured'])
def test_each_line_finds_the_contribution_it_was_made_with(mode: str) -> None:
    budget, expected = _known(mode)
    assert budget.visits == N and budget.truth_rms is not None
    for name in (eb.SERVO, eb.QUANTISATION, eb.TRACKER_NOISE):
        assert budget.contribution(name).rms == pytest.approx(expected[name], rel=0.03), name
    systematics = budget.contribution(eb.TRACKER_SYSTEMATICS).rms
    assert systematics == pytest.approx(expected[eb.TRACKER_SYSTEMATICS], rel=0.1)
    # The residual: what the servo, the quantisation and (measured) the tracker leave.
    assert budget.contribution(eb.RESIDUAL).rms == pytest.approx(expected[eb.RESIDUAL],
                                                                 rel=0.08)
    closed = mode == 'measured'
    assert budget.contribution(eb.TRACKER_NOISE).in_chain is closed
    assert (budget.contribution(eb.TRACKER_NOISE).share is None) is not closed
    # Root-sum-square shares of the in-chain lines and the residual add up to one.
    shares = [c.share for c in budget.contributions if c.in_chain]
    assert all(s is not None for s in shares)
    assert sum(s for s in shares if s is not None) == pytest.approx(1.0, abs=1e-12)
    total = math.sqrt(sum(expected[n] ** 2 for n in expected
                          if closed or n not in (eb.TRACKER_NOISE, eb.TRACKER_SYSTEMATICS)))
    assert budget.truth_rms == pytest.approx(total, rel=0.05)


def test_without_the_truth_the_budget_says_so_and_guesses_nothing() -> None:
    rng = np.random.default_rng(2)
    jac = _jacobians(rng)[:10]
    budget = eb.error_budget('measured', None, np.zeros((10, 6)), jac, np.full(6, 1e-6),
                             np.full((10, 3), 1e-12), None, 10)
    assert budget.truth_rms is None and eb.NO_TRUTH in budget.notes
    assert budget.contribution(eb.RESIDUAL).rms is None
    assert budget.contribution(eb.TRACKER_SYSTEMATICS).rms is None
    assert all(c.share is None for c in budget.contributions)
    assert budget.contribution(eb.QUANTISATION).rms is not None
    assert budget.contribution(eb.SERVO).rms == 0.0  # recorded, and zero
    nothing = eb.error_budget('model', None, None, None, None, None, None, 10)
    assert all((c.rms is None and c.note.startswith('not recorded')) or c.name == eb.RESIDUAL
               for c in nothing.contributions)
    with pytest.raises(InputError, match='servo_joint_error'):
        eb.error_budget('model', None, np.zeros((3, 6)), None, None, None, None, 10)


def test_more_than_the_truth_error_is_said() -> None:
    e = np.full((5, 3), 1e-7)
    jac = np.tile(np.eye(3, 6), (5, 1, 1))
    budget = eb.error_budget('model', e, np.full((5, 6), 1e-5), jac, None, None, None, 5)
    assert budget.contribution(eb.RESIDUAL).rms == 0.0
    assert any('exceed the truth error' in n for n in budget.notes)


def test_window_statistics_equal_a_direct_computation_however_grouped() -> None:
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 10.0, 2000))
    x = 0.2 + rng.normal(0.0, 3e-6, (t.size, 3))
    starts, stops = np.array([1.0, 4.0, 7.5]), np.array([1.5, 4.2, 9.0])
    whole = eb.WindowStats(starts, stops, np.full((3, 3), 0.2))
    whole.add(t, x)
    parts = eb.WindowStats(starts, stops, np.full((3, 3), 0.2))
    for chunk in np.array_split(np.arange(t.size), 17):
        parts.add(t[chunk], x[chunk])
    for v in range(3):
        inside = (t >= starts[v]) & (t <= stops[v])
        assert whole.count[v] == parts.count[v] == inside.sum()
        np.testing.assert_allclose(whole.mean()[v], x[inside].mean(axis=0), rtol=0, atol=1e-15)
        np.testing.assert_allclose(whole.variance_of_mean()[v],
                                   x[inside].var(axis=0, ddof=1) / inside.sum(), rtol=1e-6)
    np.testing.assert_allclose(parts.mean(), whole.mean(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(parts.variance_of_mean(), whole.variance_of_mean(), rtol=1e-9)
    found = eb.last_before([1.0, 2.0, 3.0], [[1.0], [2.0], [3.0]], [0.5, 2.0, 2.5, 9.0])
    np.testing.assert_array_equal(found[1:, 0], [2.0, 2.0, 3.0])
    assert math.isnan(found[0, 0])


def test_the_budget_of_a_recorded_run(tmp_path: Path) -> None:
    """A synthetic run (tracker noise 8 µm per axis, no bias; no trajectories recorded): the
    budget finds the noise of the window mean, no systematics, and says the servo was not
    recorded; without the truth, the report says the truth is needed."""
    noise = 8e-6
    run = synthetic_run([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2]], [[0, 0, 0, 1]] * 2,
                        modes=('model', 'measured'), cycles=3, noise=noise, seed=4)
    bag = tmp_path / 'bag'
    write_run_bag(bag, run)
    analysis = analyse_bag(bag, SETTINGS)
    budgets = {b.mode: b for b in analysis.budgets}
    assert sorted(budgets) == ['measured', 'model']
    k = np.mean([v.visit.samples for v in analysis.replay.visits])
    for budget in budgets.values():
        assert budget.contribution(eb.TRACKER_NOISE).rms == pytest.approx(
            noise * math.sqrt(3.0 / k), rel=0.3)
        assert budget.contribution(eb.TRACKER_SYSTEMATICS).rms < noise * math.sqrt(3.0 / k)
        assert budget.contribution(eb.SERVO).note.startswith('not recorded')
        truth = [v for v in analysis.replay.truth_visits if v.mode == budget.mode]
        assert budget.truth_rms == pytest.approx(
            math.sqrt(np.mean([v.verdict.position_error ** 2 for v in truth])), rel=0.05)
    write_report(analysis, tmp_path / 'out')
    text = (tmp_path / 'out' / 'report.md').read_text()
    assert '## Error budget' in text and 'servo steady state: not recorded' in text
    blind = tmp_path / 'blind'
    write_run_bag(blind, run, truth=False)
    write_report(analyse_bag(blind, SETTINGS), tmp_path / 'out_blind')
    assert eb.NO_TRUTH in (tmp_path / 'out_blind' / 'report.md').read_text()
