"""The tolerance engine on the assembled loops (positioning_cell.coordinated.panel_tolerance,
issue 27 item 6): the sensitivities of the panel's test point, its turn and its internal
forces to each positioner's error, checked against finite differences of the panel
simulator's nonlinear panel (sim.panel.PanelTruth), a hand-derived pair of clamps, and a Monte
Carlo of the positioners' errors through the simulator; the stack-ups against their own
definitions."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from positioning_cell.config import config_path
from positioning_cell.coordinated import cell_file
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.panel_motion import bases, platform_goals
from positioning_cell.coordinated.panel_tolerance import (
    by_positioner,
    panel_sensitivity,
    panel_stackup,
    sampled_errors,
    stackup_lines,
)
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.sim.panel import PanelTruth

MECH = Mechanism.default()
CELL = cell_file.load(config_path('three_positioners.yaml'))
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
TRUTH = PanelTruth(CELL, MECH)


def _panel_moved(cell: CellFile, displacements: np.ndarray, truth: PanelTruth = TRUTH
                 ) -> tuple[np.ndarray, np.ndarray, dict[tuple[str, ...], float]]:
    """The simulator's panel (``truth``, of ``cell``) with each positioner's attachment
    displaced by ``displacements`` (N, 3) m (cell frame; its platform translated): the test
    point's and the turn's change from the undisplaced panel (its weight's sag taken away),
    and each pair's internal force."""
    goals = platform_goals(cell, MECH, np.zeros(3), IDENTITY)
    rest = truth.state(goals)
    moved = truth.state([(p + base.R.T @ d, q) for (p, q), base, d in
                         zip(goals, bases(cell), displacements, strict=True)])
    c = cell.test_point(MECH)
    turn = moved.panel.R @ rest.panel.R.T
    rotvec = 0.5 * np.array([turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0],
                             turn[1, 0] - turn[0, 1]])
    return moved.panel.apply(c) - rest.panel.apply(c), rotvec, dict(moved.pairs)


def test_the_sensitivities_are_the_simulators_panel_differentiated() -> None:
    """Each translation source of the shipped cell (three balls) moved by 1 µm: the simulator's
    nonlinear panel moves its test point and turns as T's column says, and loads each pair as
    much as the column's coefficient (within 0.1 %)."""
    sens = panel_sensitivity(CELL, MECH)
    assert sens.sources[:3] == ('p1.x', 'p1.y', 'p1.z') and len(sens.sources) == 9
    assert sens.outputs[:6] == ('test_point.x', 'test_point.y', 'test_point.z', 'panel.rx',
                                'panel.ry', 'panel.rz')
    step = 1e-6
    for k, source in enumerate(sens.sources):
        d = np.zeros((3, 3))
        d[k // 3, k % 3] = step
        dp, dtheta, pairs = _panel_moved(CELL, d)
        column = sens.matrix[:, k]
        np.testing.assert_allclose(dp, column[:3] * step, rtol=1e-3, atol=1e-4 * step,
                                   err_msg=source)
        np.testing.assert_allclose(dtheta, column[3:6] * step, rtol=1e-3, atol=1e-4 * step,
                                   err_msg=source)
        for name, coefficient in zip(sens.outputs[6:], column[6:], strict=True):
            pair = tuple(name.removeprefix('force ').split('-'))
            assert pairs[pair] == pytest.approx(abs(coefficient) * step, rel=1e-3, abs=1e-4)


def test_two_clamps_share_a_misfit_along_their_line_as_springs_in_series() -> None:
    """Hand-derived: two clamps 1.2 m apart on x, each k; p2 off by δ along x stretches the two
    springs in series: k·δ/2 between them, and the midpoint (the test point) moves δ/2."""
    two = replace(CELL, positioners=tuple(
        replace(e, name=n, base_position=(1.2 * k, 0.0, 0.0), kind='clamp')
        for k, (e, n) in enumerate(zip(CELL.positioners[:2], ('p1', 'p2'), strict=True))))
    sens = panel_sensitivity(two, MECH)
    assert 'p2.rz' in sens.sources and sens.turns.sum() == 6
    column = sens.matrix[:, sens.sources.index('p2.x')]
    assert column[0] == pytest.approx(0.5, abs=1e-9)
    np.testing.assert_allclose(column[1:6], 0.0, atol=1e-9)
    k = two.panel.stiffness[0]
    assert np.abs(column[6:]).max() == pytest.approx(k / 2.0, rel=1e-9)


def test_the_stackup_is_the_monte_carlo_of_the_positioners_errors_through_the_simulator(
        ) -> None:
    """10 µm per axis on every positioner, 600 draws through the nonlinear panel: the test
    point's scatter per axis and each pair's RMS force are the RSS (within 12 %, 600 draws:
    ~3 % standard error); no draw inside the balls exceeds the worst case, which the draw
    along each ball's row attains."""
    sens = panel_sensitivity(CELL, MECH)
    error = 10e-6
    stack = panel_stackup(sens, error)
    draws = sampled_errors(sens, error, 0.0, 600, np.random.default_rng(3))
    moved = by_positioner(sens, draws, [e.name for e in CELL.positioners])
    results = [_panel_moved(CELL, m[:, :3]) for m in moved]
    scatter = np.array([r[0] for r in results]).std(axis=0)
    np.testing.assert_allclose(scatter, stack.rss[:3], rtol=0.12)
    for k, name in enumerate(stack.outputs[6:], start=6):
        pair = tuple(name.removeprefix('force ').split('-'))
        rms = np.sqrt(np.mean([r[2][pair] ** 2 for r in results]))
        assert rms == pytest.approx(stack.rss[k], rel=0.12), name
    # the worst case: attained by each ball along its row, never exceeded inside the balls
    for row, worst in zip(sens.matrix, stack.worst, strict=True):
        along = np.concatenate([error * row[a:a + 3] / max(np.linalg.norm(row[a:a + 3]), 1e-300)
                                for a in range(0, 9, 3)])
        assert row @ along == pytest.approx(worst, rel=1e-12)
        inside = draws / np.maximum(1.0, np.linalg.norm(draws.reshape(-1, 3, 3), axis=2)
                                    .repeat(3, axis=1) / error)
        assert np.abs(inside @ row).max() <= worst * (1.0 + 1e-12)
    np.testing.assert_allclose(stack.shares.sum(axis=1), 1.0)


def test_the_table_names_every_output_and_bad_figures_are_refused() -> None:
    sens = panel_sensitivity(CELL, MECH)
    lines = stackup_lines(panel_stackup(sens, 10e-6), 10e-6)
    assert lines[0].startswith('each positioner off by at most 10 um')
    assert len(lines) == 2 + len(sens.outputs)
    assert any(line.lstrip().startswith('force p1-p2 (N)') for line in lines)
    with pytest.raises(InputError, match='finite and >= 0'):
        panel_stackup(sens, -1e-6)
    with pytest.raises(InputError, match='test point'):
        panel_sensitivity(CELL, MECH, [0.0, np.nan, 0.0])
