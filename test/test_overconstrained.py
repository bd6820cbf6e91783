"""Limb forces of redundant limb sets closed by deformation compatibility (seed 002 §3), on the
n-UPS/UPP of seed 001, and the stiffness method against the positioner's compliance."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import null_space
from workspace import MECH, random_poses

from positioning_cell.core import kinematics
from positioning_cell.errors import InputError
from positioning_cell.mechanics import overconstrained as oc
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
