"""Forces in a panel held by positioners that disagree
(positioning_cell.coordinated.internal_forces): hand-derived cases, a second solver (the
springs' exact energy minimised over the panel's pose by scipy), and the pair named when one
positioner is off."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from positioning_cell.config import config_path
from positioning_cell.coordinated.attachments import Attachment
from positioning_cell.coordinated.cell_file import GRAVITY, CellFile, load
from positioning_cell.coordinated.internal_forces import internal_forces
from positioning_cell.errors import InputError

RADIUS = 0.5
#: An equilateral triangle of balls about the cell origin.
BALLS = [Attachment(f'p{i + 1}', 'spherical', (RADIUS * np.cos(a), RADIUS * np.sin(a), 0.0))
         for i, a in enumerate(np.pi / 2 + np.arange(3) * 2 * np.pi / 3)]
K_FORCE, K_COUPLE = 1.0e7, 1.0e6  # N/m, N·m/rad


def test_balls_pushed_outward_stretch_every_side_equally() -> None:
    """Each ball 20 µm outward: by symmetry the panel stays, each spring pulls its ball's
    point outward with k·d, and the sides carry k·d/√3 (a vertex's two side tensions at 30°)."""
    d = 20e-6
    outward = np.array([np.r_[np.asarray(a.point) / RADIUS * d, 0.0, 0.0, 0.0] for a in BALLS])
    found = internal_forces(BALLS, outward, (K_FORCE, K_COUPLE))
    np.testing.assert_allclose(found.displacement, 0.0, atol=1e-18)
    for a, wrench in zip(BALLS, found.wrenches, strict=True):
        np.testing.assert_allclose(wrench[:3], K_FORCE * d * np.asarray(a.point) / RADIUS,
                                   rtol=1e-12, atol=1e-9)
    assert [size for _, size in found.pairs] == pytest.approx([K_FORCE * d / np.sqrt(3)] * 3,
                                                              rel=1e-12)
    np.testing.assert_allclose(found.internal, found.wrenches, atol=1e-9)  # no load


def test_agreeing_positioners_and_a_tilt_strain_nothing() -> None:
    """A common rigid displacement, or one ball raised (the panel tilts about the other two):
    the panel follows and carries no force."""
    common = np.tile([1e-5, -2e-5, 3e-5, 0.0, 0.0, 0.0], (3, 1))
    found = internal_forces(BALLS, common, (K_FORCE, K_COUPLE))
    np.testing.assert_allclose(found.displacement, common[0], atol=1e-15)
    assert np.abs(found.wrenches).max() < 1e-6
    raised = np.zeros((3, 6))
    raised[2, 2] = 1e-4
    assert np.abs(internal_forces(BALLS, raised, (K_FORCE, K_COUPLE)).wrenches).max() < 1e-6


def test_the_weight_at_the_centroid_shares_equally_and_strains_nothing() -> None:
    found = internal_forces(BALLS, np.zeros((3, 6)), (K_FORCE, K_COUPLE),
                            load=(0.0, 0.0, -300.0, 0.0, 0.0, 0.0))
    np.testing.assert_allclose(found.wrenches[:, 2], 100.0, rtol=1e-12)
    np.testing.assert_allclose(found.wrenches[:, :2], 0.0, atol=1e-9)
    assert found.largest_internal_force < 1e-9


def _exact_energy_forces(points: np.ndarray, moved: np.ndarray, k: np.ndarray,
                         start: np.ndarray) -> np.ndarray:
    """The second solver: the panel's pose minimising Σ ½ k_i |R b_i + p − q_i|² (exact rotation,
    isotropic ball springs, no load) as scipy's nonlinear least squares on √k_i (R b_i + p −
    q_i), the pose in µm and µrad, polished from ``start`` (6,) m, rad (from zero it stops
    short of the optimum on some cases, at a higher energy); the forces k_i (q_i − (R b_i +
    p))."""
    target = points + moved

    def residuals(x: np.ndarray) -> np.ndarray:
        at = Rotation.from_rotvec(x[3:] * 1e-6).apply(points) + x[:3] * 1e-6
        out: np.ndarray = (np.sqrt(k)[:, None] * (at - target)).ravel()
        return out

    best = least_squares(residuals, start * 1e6, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    at = Rotation.from_rotvec(best.x[3:] * 1e-6).apply(points) + best.x[:3] * 1e-6
    forces: np.ndarray = k[:, None] * (target - at)
    return forces


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-1.0, 1.0)] * 3), min_size=3, max_size=3),
       st.lists(st.floats(0.5, 2.0), min_size=3, max_size=3))
def test_the_linear_solution_is_the_exact_springs_one(moves: list[tuple[float, ...]],
                                                      scales: list[float]) -> None:
    """Misfits of up to 50 µm: the compatibility solution equals the exact spring energy's
    minimum to second order: within 1e-3 of k·|misfit| (the force scale; 1000 random cases at
    the extremes gave at most 1.7e-4 of it) + 1 mN."""
    moved = np.asarray(moves) * 50e-6
    k = np.asarray(scales) * K_FORCE
    points = np.array([a.point for a in BALLS])
    found = internal_forces(BALLS, np.hstack([moved, np.zeros((3, 3))]),
                            np.column_stack([k, np.full(3, K_COUPLE)]))
    exact = _exact_energy_forces(points, moved, k, found.displacement)
    scale = k.max() * np.abs(moved).max()
    np.testing.assert_allclose(found.wrenches[:, :3], exact, atol=1e-3 * scale + 1e-3)


def test_one_positioner_off_by_its_calibration_is_named() -> None:
    """The shipped cell with p2's calibration wrong by 0.2 mm (its ball off along x): the worst
    internal force system is one of p2's pairs, and it is hundreds of newtons at 1e7 N/m."""
    cell = load(config_path('three_positioners.yaml')).attachments()
    off = np.zeros((3, 6))
    off[1, 0] = 0.2e-3
    found = internal_forces(cell, off, (K_FORCE, K_COUPLE))
    assert found.worst_pair is not None and 'p2' in found.worst_pair, found.pairs
    assert found.largest_internal_force > 100.0
    np.testing.assert_allclose(found.internal.sum(axis=0), 0.0, atol=1e-6)  # self-equilibrium


def test_bad_values_and_a_panel_not_held_are_refused() -> None:
    with pytest.raises(InputError, match='displacements'):
        internal_forces(BALLS, np.zeros((2, 6)), (K_FORCE, K_COUPLE))
    with pytest.raises(InputError, match='must be > 0'):
        internal_forces(BALLS, np.zeros((3, 6)), (0.0, K_COUPLE))
    with pytest.raises(InputError, match='load'):
        internal_forces(BALLS, np.zeros((3, 6)), (K_FORCE, K_COUPLE), load=(np.nan,) * 6)
    with pytest.raises(InputError, match='not held'):
        internal_forces(BALLS[:2], np.zeros((2, 6)), (K_FORCE, K_COUPLE))


def _shipped_case(values: list[float], clamps: bool
                  ) -> tuple[CellFile, list[Attachment], np.ndarray]:
    """The shipped cell (its attachments as clamps when ``clamps``) and the positioners'
    displacements (3, 6) from ``values`` (a ball takes no turn)."""
    shipped = load(config_path('three_positioners.yaml'))
    cell = shipped.attachments()
    if clamps:
        cell = [Attachment(a.name, 'clamp', a.point) for a in cell]
    moved = np.array(values).reshape(3, 6)
    if not clamps:
        moved[:, 3:] = 0.0
    return shipped, cell, moved


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-2e-4, 2e-4), min_size=18, max_size=18), st.booleans())
def test_the_pair_map_is_the_internal_forces_by_superposition(values: list[float],
                                                              clamps: bool) -> None:
    """What the force watch evaluates at every reading (a linear map built from unit
    displacements) gives each pair the size the full solution gives, for balls and clamps."""
    from positioning_cell.coordinated.internal_forces import pair_map

    shipped, cell, moved = _shipped_case(values, clamps)
    by_map = dict(pair_map(cell, shipped.panel.stiffness).sizes(moved))
    solved = dict(internal_forces(cell, moved, shipped.panel.stiffness,
                                  shipped.panel.weight()).pairs)
    assert by_map.keys() == solved.keys()
    for pair, size in solved.items():
        assert by_map[pair] == pytest.approx(size, rel=1e-9, abs=1e-6)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-2e-4, 2e-4), min_size=18, max_size=18), st.booleans())
def test_the_wrench_map_is_the_full_solution_with_the_weight(values: list[float],
                                                             clamps: bool) -> None:
    """What the panel simulator evaluates at every true pose (an affine map built once) gives
    every attachment's wrench and the panel's displacement the full solution gives."""
    from positioning_cell.coordinated.internal_forces import wrench_map

    shipped, cell, moved = _shipped_case(values, clamps)
    mapped = wrench_map(cell, shipped.panel.stiffness, shipped.panel.weight())
    solved = internal_forces(cell, moved, shipped.panel.stiffness, shipped.panel.weight())
    np.testing.assert_allclose(mapped.wrenches(moved), solved.wrenches, rtol=0.0, atol=1e-6)
    np.testing.assert_allclose(mapped.displacement(moved), solved.displacement, rtol=0.0,
                               atol=1e-12)
    if not clamps:  # the weight alone (over the balls' centroid) lowers the panel by m·g / 3k
        lowered = mapped.displacement(np.zeros((3, 6)))
        assert lowered[2] == pytest.approx(
            shipped.panel.mass * GRAVITY[2] / (3 * shipped.panel.stiffness[0]), rel=1e-6)
        np.testing.assert_allclose(lowered[3:], 0.0, atol=1e-12)
