"""Screw theory (seed 001): joint twists, reciprocal constraint wrenches, mobility and its kind,
and the singularity check of paths."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from workspace import MECH, random_poses

from positioning_cell.core import kinematics
from positioning_cell.core.limits import LimitError, check_poses
from positioning_cell.mechanics import screw, singularity

EZ = np.array([0.0, 0.0, 1.0])


def _parallel(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.linalg.norm(np.cross(a[:3], b[:3])) < 1e-9
                and abs(abs(a @ b) - np.linalg.norm(a) * np.linalg.norm(b)) < 1e-9)


@given(rows=st.integers(0, 9), columns=st.integers(1, 9), rank=st.integers(0, 9),
       seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-3, 1.0, 1e3]))
def test_null_space_rows_is_scipys_null_space(rows: int, columns: int, rank: int, seed: int,
                                              scale: float) -> None:
    """null_space_rows (numpy's SVD) spans what scipy.linalg.null_space spans at the same
    tolerance, on matrices of every shape and of a rank drawn up to full: as many rows,
    orthonormal, annihilated by the matrix, and the same projector."""
    rank = min(rank, rows, columns)
    rng = np.random.default_rng(seed)
    a = scale * rng.normal(size=(rows, rank)) @ rng.normal(size=(rank, columns))
    basis = screw.null_space_rows(a)
    reference = scipy.linalg.null_space(a, rcond=screw.RANK_TOLERANCE).T
    assert basis.shape == reference.shape == (columns - rank, columns)
    np.testing.assert_allclose(basis @ basis.T, np.eye(columns - rank), atol=1e-12)
    np.testing.assert_allclose(a @ basis.T, 0.0, atol=1e-12 * max(scale, 1.0) * columns)
    np.testing.assert_allclose(basis.T @ basis, reference.T @ reference, atol=1e-10)


@pytest.mark.parametrize(('joint', 'constraints'), [
    (screw.revolute([0.3, -0.2, 0.9], [0.1, 0.2, 0.3]), 5),
    (screw.prismatic([1.0, 2.0, 0.5]), 5),
    (screw.universal([1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.1, 0.0, -0.2]), 4),
    (screw.spherical([0.2, -0.1, 0.4]), 3),
    (screw.cylindrical([0.0, 1.0, 1.0], [0.5, 0.0, 0.0]), 4),
])
def test_single_joint_constraints_are_reciprocal(joint: np.ndarray, constraints: int) -> None:
    """A joint alone as a limb: 6 − (its freedoms) constraint wrenches, each reciprocal to every
    twist of the joint (product 0) and independent."""
    wrenches = screw.reciprocal_screws(joint)
    assert wrenches.shape == (constraints, 6)
    assert screw.rank(wrenches) == constraints
    np.testing.assert_allclose(screw.reciprocal_product(joint, wrenches), 0.0, atol=1e-12)


def test_spherical_joint_transmits_forces_through_its_centre_only() -> None:
    centre = np.array([0.2, -0.1, 0.4])
    wrenches = screw.moved(screw.reciprocal_screws(screw.spherical(centre)), centre)
    np.testing.assert_allclose(wrenches[:, 3:], 0.0, atol=1e-12)  # no moment about the centre
    assert screw.rank(wrenches[:, :3]) == 3


def test_ups_limb_imposes_no_constraint_and_positioner_has_six_dof() -> None:
    """Seed 001 eq. 7: a UPS limb's twist system has rank 6; the 3-UPS positioner is 3R3T."""
    p, q = random_poses(5, np.random.default_rng(10))
    for k in range(len(p)):
        limbs = screw.positioner_limbs(MECH, p[k], q[k])
        for limb in limbs:
            assert limb.joints == 'RRPS' and screw.rank(limb.twists) == 6
            assert limb.constraint_wrenches.shape == (0, 6)
        mob = screw.mobility(limbs)
        assert (mob.dof, mob.kind, mob.redundant_constraints) == (6, '3R3T', 0)


def test_upp_limb_constrains_force_and_couple_along_z() -> None:
    """Seed 001 eq. 8-9: the UPP twists (1 0 0; 0 0 0), (0 1 0; 0 0 0), (0 0 0; d3 e3 0),
    (0 0 0; d4 e4 0) have the reciprocal screws (0 0 1; 0 0 0) and (0 0 0; 0 0 1)."""
    upp = screw.UpsUpp().limbs()[-1]
    assert upp.joints == 'UPP'
    expected = np.array([[0, 0, 1, 0, 0, 0], [0, 0, 0, 0, 0, 1]], dtype=float)
    found = upp.constraint_wrenches
    assert found.shape == (2, 6)
    assert screw.span_contains(found, expected) and screw.span_contains(expected, found)


@pytest.mark.parametrize('config', [(0.0, 0.0, 0.0, 0.0), (0.15, -0.1, 0.04, -0.02)])
def test_four_ups_upp_is_2r2t(config: tuple[float, float, float, float]) -> None:
    mech = screw.UpsUpp()
    mob = screw.mobility(mech.limbs(*config))
    assert (mob.dof, mob.kind, mob.redundant_constraints) == (4, '2R2T', 0)
    assert mob.limb_constraints == (0, 0, 0, 0, 2)
    # The two lost freedoms: translation along the platform normal and rotation about it.
    # (the constraint force is along the U body's z, the couple along the U's cross normal).
    normal = mech.centre_rotation(*config[:2])[:, 2]
    couple = np.cross([1.0, 0.0, 0.0], mech.centre_rotation(config[0], 0.0)[:, 1])
    assert np.allclose(mob.translation_directions @ normal, 0.0, atol=1e-9)
    assert np.allclose(mob.rotation_axes @ couple, 0.0, atol=1e-9)
    if config == (0.0, 0.0, 0.0, 0.0):
        assert mob.describe().startswith(
            '4 DOF (2R2T): rotations about x, y; translations along x, y')


def test_actuation_wrenches_closed_form_match_null_space() -> None:
    """The positioner's actuation wrenches in closed form (leg-line force, force along ∂u/∂θ
    through B) equal the screw-theory ones: reciprocal to all the limb's other twists."""
    p, q = random_poses(4, np.random.default_rng(11))
    for k in range(len(p)):
        closed = singularity.positioner_wrenches(MECH, p[k], q[k])[0]
        limbs = screw.positioner_limbs(MECH, p[k], q[k])
        for i, limb in enumerate(limbs):
            theta_w, length_w = screw.moved(limb.actuation_wrenches(), p[k])  # R(θ) before P
            assert _parallel(closed[i], length_w) and _parallel(closed[3 + i], theta_w)


def test_wrench_singularity_coincides_with_jacobian_singularity() -> None:
    """At a rotation of π/2 about z the actuation wrench system loses rank, and the velocity
    Jacobian (kinematics, derived independently) is singular at the same pose."""
    q = Rotation.from_euler('z', math.pi / 2).as_quat()
    result = singularity.positioner_conditioning(MECH, MECH.home_position, q)
    assert result.rank[0] == 5 and result.conditioning[0] < 1e-9
    assert kinematics.jacobian(MECH, MECH.home_position, q).conditioning[0] < 1e-9
    home = singularity.positioner_conditioning(MECH, MECH.home_position, MECH.home_quaternion)
    assert home.rank[0] == 6 and home.conditioning[0] > 0.5


def test_check_path_refuses_and_says_where() -> None:
    angles = np.linspace(0.0, 1.65, 34)
    q = Rotation.from_euler('z', angles[:, None]).as_quat()
    p = np.tile(MECH.home_position, (len(angles), 1))
    report = singularity.check_path(MECH, p, q, margin=0.05)
    measure = singularity.positioner_conditioning(MECH, p, q).conditioning
    first = int(np.flatnonzero(measure < 0.05)[0])
    assert not report.ok and report.first_bad_sample == first
    assert report.bad_samples == tuple(int(i) for i in np.flatnonzero(measure < 0.05))
    assert abs(angles[report.worst_sample] - math.pi / 2) < 0.06
    text = report.message()
    assert f'first at sample {first}' in text and 'margin 0.05' in text
    merged = report.as_limit_report()
    assert merged.n_violations == len(report.bad_samples)
    assert merged.first_bad_sample == first and 'conditioning' in merged.message()
    with pytest.raises(LimitError):
        report.raise_if_violated()


def test_check_path_accepts_the_workspace() -> None:
    p, q = random_poses(200, np.random.default_rng(12))
    assert check_poses(MECH, p, q).ok
    report = singularity.check_path(MECH, p, q)
    assert report.ok and report.margin == singularity.DEFAULT_MARGIN
    assert report.measure.min() > singularity.DEFAULT_MARGIN
    assert 'keep the singularity margin' in report.message()
    report.raise_if_violated()


def test_symmetric_four_ups_upp_is_singular_at_reference() -> None:
    """Opposite legs turned alike add up to the UPP's own constraint wrenches: rank 4."""
    for symmetric, expected in ((True, 4), (False, 6)):
        mech = screw.UpsUpp(symmetric=symmetric)
        centre, _ = mech.pose()
        system = screw.moved(screw.governing_wrenches(mech.limbs()), centre)
        result = singularity.wrench_conditioning(system, mech.platform_radius)
        assert result.rank[0] == expected
        assert (result.conditioning[0] < 1e-12) == symmetric
