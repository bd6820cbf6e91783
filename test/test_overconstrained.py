"""Limb forces of redundant limb sets closed by deformation compatibility (seed 002 §3), on the
n-UPS/UPP of seed 001, and the stiffness method against the positioner's compliance; the planar
mode (seed 002's mechanism), initial deformations, and a bar under a distributed axial load
(seed 002 eq. 29)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.linalg import null_space
from workspace import MECH, random_poses

from positioning_cell.core import kinematics
from positioning_cell.errors import InputError
from positioning_cell.mechanics import overconstrained as oc
from positioning_cell.mechanics import planar_parallel as pp
from positioning_cell.mechanics import screw
from positioning_cell.mechanics import statics as st

# A 1 t shell (seed 001: metal shells of several tonnes) hung 0.2 m off-centre, with a push.
LOAD = np.array([300.0, -200.0, -9810.0, 1500.0, -800.0, 250.0])

REDUNDANT = [screw.UpsUpp(lock_centre_prismatics=True), screw.UpsUpp(n_ups=6)]


def test_four_ups_upp_with_free_slides_is_statically_determinate() -> None:
    """With its four actuators locked, the 4-UPS/UPP is held by 4 leg forces + the UPP's force
    and couple: six unknowns, rank 6. Equilibrium alone fixes them, so the rigid-body
    pseudo-inverse already is the compatible solution."""
    limbs = oc.ups_upp_elastic_limbs(screw.UpsUpp())
    assert oc.static_indeterminacy(limbs.wrenches) == 0
    assert screw.mobility(screw.UpsUpp().limbs()).redundant_constraints == 0
    compatible = oc.solve_compatible(limbs.wrenches, limbs.stiffness, LOAD)
    rigid = oc.solve_pseudo_inverse(limbs.wrenches, LOAD)
    np.testing.assert_allclose(rigid.forces, compatible.forces, rtol=1e-9, atol=1e-9)
    assert oc.compatibility_residual(limbs.wrenches, limbs.stiffness, rigid.forces) < 1e-12


@pytest.mark.parametrize('mech', REDUNDANT, ids=['4-UPS/UPP braked slides', '6-UPS/UPP'])
def test_compatibility_closes_the_redundant_limbs(mech: screw.UpsUpp) -> None:
    """Two redundant unknowns: the compatible forces satisfy equilibrium and compatibility;
    the pseudo-inverse forces satisfy equilibrium but not compatibility."""
    limbs = oc.ups_upp_elastic_limbs(mech)
    assert oc.static_indeterminacy(limbs.wrenches) == 2
    compatible = oc.solve_compatible(limbs.wrenches, limbs.stiffness, LOAD)
    rigid = oc.solve_pseudo_inverse(limbs.wrenches, LOAD)
    for forces in (compatible.forces, rigid.forces):
        assert oc.equilibrium_residual(limbs.wrenches, forces, LOAD) < 1e-12
    assert oc.compatibility_residual(limbs.wrenches, limbs.stiffness, compatible.forces) < 1e-12
    assert oc.compatibility_residual(limbs.wrenches, limbs.stiffness, rigid.forces) > 0.1
    # The deformations are those of the solution's platform error (seed 002 eq. 28).
    np.testing.assert_allclose(-compatible.forces / limbs.stiffness,
                               limbs.wrenches @ compatible.deflection, rtol=1e-9, atol=1e-15)


@pytest.mark.parametrize('mech', REDUNDANT, ids=['4-UPS/UPP braked slides', '6-UPS/UPP'])
def test_compatible_forces_minimise_complementary_energy(mech: screw.UpsUpp) -> None:
    """Menabrea: among all forces in equilibrium, the compatible ones minimise Σ f²/(2k).
    Checked by parametrising the equilibrium solutions f = f_0 + N z (independent of the
    stiffness method)."""
    limbs = oc.ups_upp_elastic_limbs(mech)
    w, k = limbs.wrenches, limbs.stiffness
    f0 = -np.linalg.lstsq(w.T, LOAD, rcond=None)[0]
    basis = null_space(w.T)
    z = np.linalg.lstsq(basis / np.sqrt(k)[:, None], -f0 / np.sqrt(k), rcond=None)[0]
    np.testing.assert_allclose(oc.solve_compatible(w, k, LOAD).forces, f0 + basis @ z,
                               rtol=1e-8, atol=1e-6)


@pytest.mark.parametrize('mech', [screw.UpsUpp(), *REDUNDANT])
def test_elastic_lines_are_the_screw_theory_wrenches(mech: screw.UpsUpp) -> None:
    """The stiffness model's wrench lines span exactly what the limbs can carry with their
    actuators locked (reciprocal screws of the passive twists, seed 001)."""
    limbs = oc.ups_upp_elastic_limbs(mech)
    carried = screw.moved(np.vstack([limb.transmitted_wrenches for limb in mech.limbs()]),
                          limbs.reference)
    assert carried.shape[0] == limbs.wrenches.shape[0]
    assert screw.span_contains(carried, limbs.wrenches)
    assert screw.span_contains(limbs.wrenches, carried)


def test_stiffness_method_reproduces_positioner_compliance() -> None:
    """The 3-UPS positioner (determinate): the stiffness method with the inverse-Jacobian rows
    as wrench lines gives the deflection of statics.deflection (compliance J K⁻¹ Jᵀ), and
    the line forces are the actuator efforts (same sign: + pushes the platform)."""
    payload = st.Payload()
    p, q = random_poses(5, np.random.default_rng(30))
    lines = kinematics.inverse_jacobian(MECH, p, q)
    k = 1.0 / st.joint_compliance(st.Structure())
    wrench = st.required_wrench(MECH, p, q, payload)
    expected = st.deflection(MECH, p, q, payload)
    for n in range(len(p)):
        solution = oc.solve_compatible(lines[n], k, -wrench[n])
        assert solution.deflection is not None
        np.testing.assert_allclose(solution.deflection[:3], expected.translation[n],
                                   rtol=1e-7, atol=1e-13)
        np.testing.assert_allclose(solution.deflection[3:], expected.rotation[n],
                                   rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(solution.forces, expected.efforts[n], rtol=1e-7, atol=1e-6)


def test_bad_input() -> None:
    limbs = oc.ups_upp_elastic_limbs(screw.UpsUpp())
    with pytest.raises(InputError, match='stiffness'):
        oc.solve_compatible(limbs.wrenches, limbs.stiffness[:-1], LOAD)
    with pytest.raises(InputError, match='rank 4'):
        oc.solve_compatible(limbs.wrenches[:4], limbs.stiffness[:4], LOAD)
    with pytest.raises(InputError):
        oc.solve_pseudo_inverse(limbs.wrenches, LOAD[:5])


# -- planar mode (seed 002 §1: the platform moves in its plane) --------------------------------
# Seed 002's mechanism at x = 0.05 m, y = 0 (positioning_cell.mechanics.planar_parallel): four
# links (two parallelograms) on a platform that only moves in the plane, moments about its
# centre; unit wrenches of the links' tensions, stiffness E·S/L with unequal sections.
PLANAR_POSITION = (0.05, 0.0)
PLANAR_LOAD = np.array([800.0, -2971.0, 60.0])
PLANAR_K = np.array([3.5e8, 2.0e8, 4.2e8, 3.5e8])


def planar_wrenches() -> np.ndarray:
    return pp.link_wrenches(pp.PlanarParallel(), PLANAR_POSITION)


def embedded(planar: np.ndarray) -> np.ndarray:
    """Planar rows (f_x, f_y, m_z) as spatial wrenches (f_x, f_y, 0, 0, 0, m_z): z = 0 lines."""
    out = np.zeros(planar.shape[:-1] + (6,))
    out[..., [0, 1, 5]] = planar
    return out


def test_planar_line() -> None:
    np.testing.assert_allclose(oc.planar_line((2.0, 0.0), (0.0, 1.0)), [1.0, 0.0, -1.0])
    np.testing.assert_allclose(oc.planar_line((0.0, 1.0), (1.0, 5.0), (0.5, 0.0)),
                               [0.0, 1.0, 0.5])
    spatial = screw.line((0.6, -0.8, 0.0), (0.3, 0.2, 0.0))
    np.testing.assert_allclose(embedded(oc.planar_line((0.6, -0.8), (0.3, 0.2))), spatial)
    with pytest.raises(InputError):
        oc.planar_line((0.0, 0.0), (1.0, 1.0))


def test_planar_mode_needs_no_out_of_plane_workaround() -> None:
    """The planar lines embedded in space span rank 3 < 6 and the spatial solve refuses them;
    the planar mode solves them, and agrees with the old workaround (three stiff out-of-plane
    constraints added by hand) on the in-plane forces and platform error."""
    w = planar_wrenches()
    with pytest.raises(InputError, match=r'rank 3 < 6 \(spatial\)'):
        oc.solve_compatible(embedded(w), PLANAR_K, embedded(PLANAR_LOAD))
    planar = oc.solve_compatible(w, PLANAR_K, PLANAR_LOAD)
    assert planar.deflection is not None and planar.deflection.shape == (3,)
    stiff_out = np.array([[0, 0, 1, 0, 0, 0], [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 1, 0]], float)
    workaround = oc.solve_compatible(np.vstack([embedded(w), stiff_out]),
                                     np.concatenate([PLANAR_K, [1e12] * 3]),
                                     embedded(PLANAR_LOAD))
    assert workaround.deflection is not None
    np.testing.assert_allclose(planar.forces, workaround.forces[:4], rtol=1e-9)
    np.testing.assert_allclose(planar.deflection, workaround.deflection[[0, 1, 5]], rtol=1e-9)
    assert oc.static_indeterminacy(w) == 1
    assert oc.equilibrium_residual(w, planar.forces, PLANAR_LOAD) < 1e-14
    assert oc.compatibility_residual(w, PLANAR_K, planar.forces) < 1e-12
    rigid = oc.solve_pseudo_inverse(w, PLANAR_LOAD)
    assert oc.equilibrium_residual(w, rigid.forces, PLANAR_LOAD) < 1e-14
    assert oc.compatibility_residual(w, PLANAR_K, rigid.forces) > 0.01


def test_the_space_from_the_width_or_named() -> None:
    w = planar_wrenches()
    named = oc.solve_compatible(w, PLANAR_K, PLANAR_LOAD, space='planar')
    np.testing.assert_array_equal(named.forces, oc.solve_compatible(w, PLANAR_K,
                                                                    PLANAR_LOAD).forces)
    assert oc.space_of(w) == 'planar' and oc.space_of(np.zeros((2, 6))) == 'spatial'
    limbs = oc.ups_upp_elastic_limbs(REDUNDANT[0])
    np.testing.assert_array_equal(
        oc.solve_compatible(limbs.wrenches, limbs.stiffness, LOAD, space='spatial').forces,
        oc.solve_compatible(limbs.wrenches, limbs.stiffness, LOAD).forces)
    with pytest.raises(InputError, match=r'spatial wrenches must be \(k, 6\)'):
        oc.solve_compatible(w, PLANAR_K, PLANAR_LOAD, space='spatial')
    with pytest.raises(InputError, match='expected'):
        oc.solve_pseudo_inverse(np.zeros((4, 4)), np.zeros(4))
    with pytest.raises(InputError, match='space'):
        oc.static_indeterminacy(w, space='plane')
    with pytest.raises(InputError, match=r'load \(3,\)'):
        oc.equilibrium_residual(w, np.zeros(4), LOAD)
    with pytest.raises(InputError, match=r'rank 2 < 3 \(planar\)'):
        oc.solve_compatible(w[:2], PLANAR_K[:2], PLANAR_LOAD)


def test_initial_deformations_enter_the_compatibility() -> None:
    """A link's deformation is d0 − f/k: an initial d0 that is a rigid displacement of the
    platform (d0 = W·δ) moves it by δ and changes no force; one that no displacement matches
    (d0 = K⁻¹ν, ν a self-stress) adds the self-stress ν and moves nothing."""
    w = planar_wrenches()
    base = oc.solve_compatible(w, PLANAR_K, PLANAR_LOAD)
    assert base.deflection is not None
    delta = np.array([3e-6, -2e-6, 1e-5])
    shifted = oc.solve_compatible(w, PLANAR_K, PLANAR_LOAD, initial=w @ delta)
    assert shifted.deflection is not None
    np.testing.assert_allclose(shifted.forces, base.forces, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(shifted.deflection, base.deflection + delta, rtol=1e-9,
                               atol=1e-15)
    nu = 500.0 * null_space(w.T)[:, 0]
    stressed = oc.solve_compatible(w, PLANAR_K, PLANAR_LOAD, initial=nu / PLANAR_K)
    assert stressed.deflection is not None
    np.testing.assert_allclose(stressed.forces, base.forces + nu, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(stressed.deflection, base.deflection, rtol=1e-9, atol=1e-15)
    assert oc.equilibrium_residual(w, stressed.forces, PLANAR_LOAD) < 1e-14
    assert oc.compatibility_residual(w, PLANAR_K, stressed.forces, nu / PLANAR_K) < 1e-12
    assert oc.compatibility_residual(w, PLANAR_K, stressed.forces) > 0.01
    with pytest.raises(InputError, match='initial'):
        oc.solve_compatible(w, PLANAR_K, PLANAR_LOAD, initial=[0.0, 0.0, float('nan'), 0.0])


@pytest.mark.parametrize('mech', REDUNDANT, ids=['4-UPS/UPP braked slides', '6-UPS/UPP'])
def test_spatial_initial_deformations(mech: screw.UpsUpp) -> None:
    limbs = oc.ups_upp_elastic_limbs(mech)
    d0 = np.random.default_rng(4).normal(0.0, 1e-5, len(limbs.stiffness))
    solution = oc.solve_compatible(limbs.wrenches, limbs.stiffness, LOAD, initial=d0)
    assert oc.equilibrium_residual(limbs.wrenches, solution.forces, LOAD) < 1e-12
    assert oc.compatibility_residual(limbs.wrenches, limbs.stiffness, solution.forces,
                                     d0) < 1e-10
    assert solution.deflection is not None
    np.testing.assert_allclose(d0 - solution.forces / limbs.stiffness,
                               limbs.wrenches @ solution.deflection, rtol=1e-9, atol=1e-14)


def test_planar_compatible_forces_minimise_complementary_energy() -> None:
    """Menabrea in the plane with unequal stiffness and initial deformations: the compatible
    forces minimise Σ f²/(2k) − Σ f·d0 over the equilibrium solutions f = f_0 + N z."""
    w = planar_wrenches()
    d0 = np.array([2e-6, -1e-6, 0.0, 4e-6])
    f0 = -np.linalg.lstsq(w.T, PLANAR_LOAD, rcond=None)[0]
    basis = null_space(w.T)
    root = np.sqrt(PLANAR_K)
    # min_z Σ (f_0 + N z)²/(2k) − (f_0 + N z)·d0  ⇔  least squares of (N/√k) z ≈ √k·d0 − f_0/√k
    z = np.linalg.lstsq(basis / root[:, None], root * d0 - f0 / root, rcond=None)[0]
    np.testing.assert_allclose(oc.solve_compatible(w, PLANAR_K, PLANAR_LOAD, d0).forces,
                               f0 + basis @ z, rtol=1e-9, atol=1e-6)


# -- a bar under an end force and a uniform axial load (seed 002 eq. 29) ------------------------
@pytest.mark.parametrize(('f', 'w', 'length', 'rigidity'), [
    (1200.0, 77.0, 0.6, 2.1e8), (-3500.0, -40.0, 0.6, 2.1e8), (0.0, 120.0, 1.3, 5.0e7),
    (250.0, -900.0, 0.25, 1.0e6)])
def test_distributed_axial_load_elongation_against_quad(f: float, w: float, length: float,
                                                         rigidity: float) -> None:
    """ΔL = ∫₀ᴸ N(x)/(E·S) dx integrated numerically equals f·L/(E·S) + w·L²/(2·E·S); the ends
    carry N(0) = f + w·L and N(L) = f."""
    bar = oc.axial_loading(f, w, length, rigidity)
    numeric = quad(lambda x: float(oc.axial_force(x, f, w, length)) / rigidity, 0.0, length)[0]
    np.testing.assert_allclose(bar.elongation, numeric, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(bar.elongation, f * length / rigidity
                               + w * length**2 / (2 * rigidity), rtol=1e-12)
    assert bar.force_at_start == pytest.approx(f + w * length)
    assert bar.force_at_end == pytest.approx(f)
    np.testing.assert_allclose(oc.axial_force([0.0, length], f, w, length),
                               [bar.force_at_start, bar.force_at_end])


def test_hanging_bar_and_broadcasting() -> None:
    """A bar hanging from its top (x = 0), free at the bottom (f = 0), its weight m·g along the
    axis: the top carries m·g and it lengthens by m·g·L/(2·E·S), the classic result."""
    m, g, length, rigidity = 4.71, 9.80665, 0.6, 2.1e8
    bar = oc.axial_loading(0.0, m * g / length, length, rigidity)
    assert bar.force_at_start == pytest.approx(m * g)
    assert bar.elongation == pytest.approx(m * g * length / (2 * rigidity))
    many = oc.axial_loading(np.array([100.0, 200.0, 300.0]), 50.0, 0.6, [[2e8], [4e8]])
    assert many.elongation.shape == many.force_at_end.shape == (2, 3)
    np.testing.assert_allclose(many.elongation[1], many.elongation[0] / 2)
    with pytest.raises(InputError, match='x'):
        oc.axial_force(0.7, 0.0, 1.0, 0.6)
    with pytest.raises(InputError, match='length'):
        oc.axial_loading(0.0, 1.0, -0.6, 2e8)
    with pytest.raises(InputError, match='axial_rigidity'):
        oc.axial_loading(0.0, 1.0, 0.6, 0.0)
