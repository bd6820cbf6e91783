"""Limit checks say which constraint, which leg, at which sample and by how much."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from workspace import MECH

from positioning_cell.core import kinematics
from positioning_cell.core.limits import (
    LimitError,
    check_poses,
    require_within_limits,
    segment_distance,
    within_limits,
)
from positioning_cell.core.mechanism import Mechanism

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def test_home_is_within_limits() -> None:
    report = check_poses(MECH, MECH.home_position, IDENTITY)
    assert report.ok and report.n_violations == 0
    assert 'within limits' in report.message()


def test_stroke_exceeded_names_leg_sample_and_excess() -> None:
    high = MECH.home_position + [0.0, 0.0, 0.030]
    p = np.vstack([MECH.home_position, high])
    report = check_poses(MECH, p, np.tile(IDENTITY, (2, 1)))
    assert not report.ok
    lengths = kinematics.inverse(MECH, high, IDENTITY).lengths[0]
    first = report.violations[0]
    assert (first.sample, first.constraint, first.leg) == (1, 'length_max', '1')
    assert first.excess == pytest.approx(lengths[0] - MECH.length_max, abs=1e-15)
    assert {v.leg for v in report.violations} == {'1', '2', '3'}
    text = report.message()
    assert 'sample 1: leg 1 length' in text and 'above the maximum 220.0000 mm' in text


def test_stroke_too_short() -> None:
    report = check_poses(MECH, MECH.home_position - [0.0, 0.0, 0.03], IDENTITY)
    assert {v.constraint for v in report.violations} == {'length_min'}
    assert 'below the minimum 180.0000 mm' in report.message()


def test_theta_limit() -> None:
    # A rotation about z swings every leg sideways by the same θ.
    mech = Mechanism(theta_min=-0.1, theta_max=0.1)
    q = Rotation.from_rotvec([0.0, 0.0, 0.8]).as_quat()
    report = check_poses(mech, mech.home_position, q)
    theta = kinematics.inverse(mech, mech.home_position, q).thetas[0]
    assert theta.min() > 0.1
    assert [(v.constraint, v.leg) for v in report.violations] == [
        ('theta_max', '1'), ('theta_max', '2'), ('theta_max', '3')]
    assert report.violations[0].excess == pytest.approx(theta[0] - 0.1)


def test_phi_limit() -> None:
    mech = Mechanism(phi_min=-0.1, phi_max=0.1)
    report = check_poses(mech, mech.home_position, IDENTITY)
    violations = [v for v in report.violations if v.constraint == 'phi_min']
    assert len(violations) == 3
    home_phi = kinematics.home_phis(mech)[0]
    assert violations[0].excess == pytest.approx(-0.1 - home_phi)
    assert 'phi' in report.message() and 'deg' in report.message()


def test_tilt_limit() -> None:
    mech = Mechanism(tilt_max=0.1)
    report = check_poses(mech, mech.home_position, IDENTITY)
    assert {v.constraint for v in report.violations} == {'spherical_tilt'}
    # At home the tilt is the leg's angle to the z axis: atan((R_A − R_B)/h0).
    expected = np.arctan2(mech.base_radius - mech.platform_radius, mech.home_height)
    assert report.violations[0].value == pytest.approx(expected)


def test_leg_distance_limit() -> None:
    mech = Mechanism(min_leg_distance=0.2)
    report = check_poses(mech, mech.home_position, IDENTITY)
    legs = {v.leg for v in report.violations if v.constraint == 'leg_distance_min'}
    assert legs == {'1-2', '2-3', '3-1'}
    # The closest approach at home is between the S-joint centres, √3·R_B apart.
    value = report.violations[0].value
    assert value == pytest.approx(np.sqrt(3) * mech.platform_radius, rel=1e-9)


def test_singularity_margin() -> None:
    mech = Mechanism(min_conditioning=0.9)
    report = check_poses(mech, mech.home_position, IDENTITY)
    assert [v.constraint for v in report.violations] == ['conditioning_min']
    assert 'conditioning' in report.message()


def test_require_within_limits_raises_with_report() -> None:
    with pytest.raises(LimitError, match='length') as info:
        require_within_limits(MECH, MECH.home_position + [0, 0, 0.03], IDENTITY)
    assert not info.value.report.ok


def test_report_caps_listing_but_counts_all() -> None:
    p = np.tile(MECH.home_position + [0, 0, 0.03], (100, 1))
    report = check_poses(MECH, p, np.tile(IDENTITY, (100, 1)))
    assert report.n_violations == 300 and len(report.violations) == 50
    assert '(+297 more)' in report.message()


def test_segment_distance_against_sampling() -> None:
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 4, 3))
    d = segment_distance(pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3])
    s = np.linspace(0, 1, 401)
    for k in range(0, 200, 20):
        a = pts[k, 0] + s[:, None] * (pts[k, 1] - pts[k, 0])
        b = pts[k, 2] + s[:, None] * (pts[k, 3] - pts[k, 2])
        brute = np.linalg.norm(a[:, None] - b[None], axis=2).min()
        assert d[k] <= brute + 1e-12
        assert brute - d[k] < 1e-2


def test_within_limits_agrees_with_check_poses_pose_by_pose() -> None:
    """The vectorised mask against the full report of each pose alone (poses in and out)."""
    rng = np.random.default_rng(7)
    mech = Mechanism.default()
    p = mech.home_position + rng.uniform(-0.03, 0.03, (300, 3))
    q = Rotation.from_rotvec(rng.uniform(-0.3, 0.3, (300, 3))).as_quat()
    mask = within_limits(mech, p, q)
    assert 0 < mask.sum() < len(mask)
    assert mask.tolist() == [check_poses(mech, p[i], q[i]).ok for i in range(len(p))]
