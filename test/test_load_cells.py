"""The panel's internal force from the legs' load cells (positioning_cell.coordinated.
load_cells, positioning_cell.mechanics.statics.wrench_from_efforts), checked against the
panel simulator's truth: the wrenches it puts on the platforms turned into efforts as the
simulated drives do, and the internal force the estimate gives back compared with the one
the simulator computed from the misfits."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from load_cell_truth import set_readings
from scipy.spatial.transform import Rotation

from positioning_cell.analysis.panel import (
    PanelForces,
    PanelRecording,
    SetJoints,
    StampedPoses,
    panel_figures,
    report_lines,
)
from positioning_cell.config import config_path
from positioning_cell.coordinated import cell_file
from positioning_cell.coordinated.load_cells import (
    attachment_forces,
    internal_force_sizes,
    relaxing_steps,
)
from positioning_cell.coordinated.panel_motion import bases, platform_goals
from positioning_cell.core.kinematics import forward
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.mechanics.statics import (
    efforts_from_wrench,
    wrench_from_efforts,
)
from positioning_cell.parameters import parse
from positioning_cell.procedures.panel_program import PanelStep
from positioning_cell.sim.drives import DriverSettings, LegDriver
from positioning_cell.sim.panel import PanelTruth

MECH = Mechanism.default()
CELL = cell_file.load(config_path('three_positioners.yaml'))
TRUTH = PanelTruth(CELL, MECH)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-4e-3, 4e-3), min_size=6, max_size=6),
       st.lists(st.floats(-500.0, 500.0), min_size=6, max_size=6))
def test_the_wrench_comes_back_from_the_efforts(move: list[float], wrench: list[float]
                                                ) -> None:
    """τ = Jᵀ·w and back, over the workspace about home."""
    p = MECH.home_position + np.array(move[:3])
    q = Rotation.from_rotvec(np.array(move[3:]) * 5.0).as_quat()
    tau = efforts_from_wrench(MECH, p[None], q[None], np.array([wrench]))
    np.testing.assert_allclose(wrench_from_efforts(MECH, p[None], q[None], tau)[0], wrench,
                               rtol=0, atol=1e-7)


def _readings(misfit: np.ndarray, truth: PanelTruth = TRUTH
              ) -> tuple[np.ndarray, np.ndarray, float]:
    """The sets' encoder values and load-cell efforts, and the ``truth``'s largest internal
    force, with each platform ``misfit`` (N, 3) m (its base frame) off its goal for the panel
    at home."""
    goals = platform_goals(CELL, MECH, np.zeros(3), [0.0, 0.0, 0.0, 1.0])
    return set_readings(truth, [(p + d, q) for (p, q), d in zip(goals, misfit, strict=True)])


def test_the_load_cells_give_the_truths_internal_force() -> None:
    misfit = np.array([[0.0, 0.0, 0.0], [2e-4, -1e-4, 0.0], [0.0, 1.5e-4, 5e-5]])
    joints, efforts, largest = _readings(misfit)
    forces = attachment_forces(CELL, MECH, joints, efforts)
    sizes = internal_force_sizes(CELL, MECH, forces)
    assert largest > 100.0  # a strain worth seeing
    assert sizes.max() == pytest.approx(largest, rel=0.02)
    # no misfit: the weight's share only, nothing internal
    joints, efforts, largest = _readings(np.zeros((3, 3)))
    sizes = internal_force_sizes(CELL, MECH, attachment_forces(CELL, MECH, joints, efforts))
    assert largest < 1e-6 and sizes.max() < 1.0
    # the weight: the attachments' forces on the panel hold it up
    total = attachment_forces(CELL, MECH, joints, efforts).sum(axis=0)
    np.testing.assert_allclose(total, -CELL.panel.weight()[:3], atol=1e-6)


@settings(max_examples=20, deadline=None)
@given(st.lists(st.floats(-4e-4, 4e-4), min_size=9, max_size=9))
def test_a_relaxing_step_takes_the_internal_force_away(misfit: list[float]) -> None:
    """The steps the load cells give, taken by the platforms, leave the truth's internal force
    within the load cells' own error (the nominal Jacobian, the weight's share at home): 2 %
    of what it was, or a newton."""
    before = np.array(misfit).reshape(3, 3)
    joints, efforts, largest = _readings(before)
    steps = relaxing_steps(CELL, MECH, attachment_forces(CELL, MECH, joints, efforts))
    *_, after = _readings(before + steps)
    assert after <= 0.02 * largest + 1.0
    # least-norm: the steps hold no rigid translation of the panel (it loads nothing)
    in_cell = np.array([b.R @ s for b, s in zip(bases(CELL), steps, strict=True)])
    assert np.linalg.norm(in_cell.mean(axis=0)) <= 0.02 * np.abs(in_cell).max() + 1e-9


def test_a_panel_softer_than_its_file_is_relaxed_step_by_step() -> None:
    """On a panel at 0.75 of the cell file's stiffness the load cells read 0.75 of the force
    the file gives the misfit, and a step (the file's) takes 0.75 of the misfit away: it
    leaves a quarter of the force, each further step a quarter again."""
    soft = replace(CELL, panel=replace(CELL.panel, stiffness=tuple(
        0.75 * np.asarray(CELL.panel.stiffness))))
    truth = PanelTruth(soft, MECH)
    misfit = np.array([[0.0, 0.0, 0.0], [2e-4, -1e-4, 0.0], [0.0, 1.5e-4, 5e-5]])
    largest = []
    for _ in range(3):
        joints, efforts, force = _readings(misfit, truth)
        largest.append(force)
        misfit = misfit + relaxing_steps(CELL, MECH, attachment_forces(CELL, MECH, joints,
                                                                       efforts))
    assert largest[0] > 1000.0
    assert largest[1] == pytest.approx(largest[0] / 4.0, rel=0.05)
    assert largest[2] == pytest.approx(largest[1] / 4.0, rel=0.1)


def test_a_sets_load_cells_read_nothing_before_the_panels_first_push() -> None:
    """A coordinated cell's set (``panel_pushes``) carries nothing of its own: before the
    panel simulator's first push its load cells would say an unstrained panel (a relax in a
    CI read 0 N there and took away nothing), so they read nothing; from the push on, the
    platform's own statics plus the push's efforts. A set without a panel reads at once."""
    settings = parse(DriverSettings, {'panel_pushes': True, 'payload': {'mass': 0.0}})
    driver = LegDriver(settings)
    assert driver.update_effort() is None and driver.effort is None
    wrench = np.array([120.0, -80.0, 900.0, 15.0, -4.0, 7.0])
    driver.push(wrench)
    own = LegDriver(parse(DriverSettings, {'payload': {'mass': 0.0}})).update_effort()
    assert own is not None  # a set without a panel reads at once
    fk = forward(MECH, settings.home_positions()[:3], settings.home_positions()[3:])
    expected = own + efforts_from_wrench(MECH, fk.position, fk.quaternion, -wrench[None])[0]
    got = driver.update_effort()
    assert got is not None
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-6)


def test_forces_that_are_not_the_cells_are_refused() -> None:
    with pytest.raises(InputError, match=r'expected \(3, 3\)'):
        relaxing_steps(CELL, MECH, np.zeros((2, 3)))
    with pytest.raises(InputError, match='finite'):
        relaxing_steps(CELL, MECH, np.full((3, 3), np.inf))


def test_readings_that_are_not_the_cells_are_refused() -> None:
    with pytest.raises(InputError, match=r'expected \(3, 6\)'):
        attachment_forces(CELL, MECH, np.zeros((2, 6)), np.zeros((2, 6)))
    with pytest.raises(InputError, match='finite'):
        attachment_forces(CELL, MECH, np.full((3, 6), np.nan), np.zeros((3, 6)))


def test_the_panel_analysis_says_what_the_load_cells_read() -> None:
    """panel_figures with the cell: each settled step's load-cell figure from the sets' joint
    states over its reading window (here one step, the panel at home, strained)."""
    misfit = np.array([[0.0, 0.0, 0.0], [2e-4, -1e-4, 0.0], [0.0, 1.5e-4, 5e-5]])
    joints, efforts, largest = _readings(misfit)
    home = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)
    step = PanelStep(1, 'P1', (0.6, 0.3, 0.3), *home, 9.0, 10.0, 'success', '', 5, *home)
    stamps = 10.0 + 0.05 * np.arange(1, 6)
    poses = StampedPoses(stamps, np.zeros((5, 3)), np.tile(home[1], (5, 1)))
    sets = {e.name: SetJoints(np.array([10.0, 10.1, 10.2, 10.3]), np.tile(q, (4, 1)),
                              np.tile(t, (4, 1)))
            for e, q, t in zip(CELL.positioners, joints, efforts, strict=True)}
    forces = PanelForces(np.array([10.1]), np.array([largest]), np.array([1e-5]))
    recording = PanelRecording([step], poses, poses, forces, sets)
    figures = panel_figures(recording, CELL, MECH)
    (said,) = figures.load_cells_n
    assert said == pytest.approx(largest, rel=0.02)
    assert "The legs' load cells say at most" in '\n'.join(report_lines(figures))
    assert panel_figures(recording).load_cells_n == ()  # without the cell: not figured
    lacking = recording._replace(joints={k: v for k, v in sets.items() if k != 'p2'})
    assert np.isnan(panel_figures(lacking, CELL, MECH).load_cells_n[0])
    # a driver that reports no efforts (NaN): no figure, the rest of the analysis stands
    silent = dict(sets, p2=sets['p2']._replace(efforts=np.full((4, 6), np.nan)))
    figures = panel_figures(recording._replace(joints=silent), CELL, MECH)
    assert np.isnan(figures.load_cells_n[0]) and figures.same_as_live
    assert "The legs' load cells gave no figure" in '\n'.join(report_lines(figures))
