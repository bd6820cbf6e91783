"""Positioner decisions without DDS: goal checks, closed-loop correction, arrival, averaging."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from workspace import MECH

from positioning_cell import clearance as cl
from positioning_cell import kinematics
from positioning_cell.errors import InputError
from positioning_cell.positioner import (
    Tolerance,
    corrected_command,
    deviation,
    joints_arrived,
    mean_pose,
    validate_goal,
)

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize(('frame', 'p', 'q', 'words'), [
    ('tracker', [0, 0, 0.2], IDENTITY, "goal frame 'tracker' is not 'base'"),
    ('', [0, 0, 0.2], IDENTITY, "goal frame '' is not 'base'"),
    ('base', [0, np.nan, 0.2], IDENTITY, 'not finite'),
    ('base', [0, 0, 0.2], [0, 0, 0, 0], 'is zero'),
    ('base', [0, 0, 0.2], [0, 0, 0.1, 1], 'not 1'),
])
def test_goal_refusals(frame: str, p: list[float], q: np.ndarray, words: str) -> None:
    with pytest.raises(InputError, match=words):
        validate_goal(frame, p, q)


def test_goal_normalises_within_tolerance() -> None:
    _, q = validate_goal('base', [0, 0, 0.2], [0, 0, 0, 1 + 1e-7])
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)


def test_correction_converges_on_a_machine_with_clearance() -> None:
    """Measured correction (exact measurements) against the eq. 9 truth: the error shrinks
    by orders of magnitude per iteration (the clearance error varies slowly with the pose)."""
    rng = np.random.default_rng(0)
    truth = cl.EffectiveLengthClearance.random(1.6e-4, 1.6e-4, rng)
    p_des = MECH.home_position + [0.004, -0.003, 0.002]
    q_des = Rotation.from_rotvec([0.02, 0.01, -0.03]).as_quat()
    command = (p_des, q_des)
    errors = []
    for _ in range(4):
        joints = kinematics.inverse(MECH, *command)
        att = truth.attained_pose(MECH, joints.lengths, joints.thetas)
        e_p, _ = deviation(att.position[0], att.quaternion[0], p_des, q_des)
        errors.append(np.linalg.norm(e_p))
        command = corrected_command(*command, p_des, q_des, att.position[0], att.quaternion[0])
    assert errors[0] > 20e-6
    assert errors[1] < errors[0] / 20 and errors[3] < 1e-9


def test_tolerance_holds() -> None:
    tol = Tolerance(10e-6, 1e-4)
    assert tol.holds([6e-6, 0, 8e-6], [0, 0, 1e-4])
    assert not tol.holds([6e-6, 0, 8.1e-6], [0, 0, 0])
    assert not tol.holds([0, 0, 0], [0, 1.1e-4, 0])


def test_mean_pose() -> None:
    rng = np.random.default_rng(1)
    p = MECH.home_position + rng.normal(0, 1e-5, (50, 3))
    rot = Rotation.from_rotvec([0.1, 0, 0]) * Rotation.from_rotvec(rng.normal(0, 1e-4, (50, 3)))
    mp, mq = mean_pose(p, rot.as_quat())
    np.testing.assert_allclose(mp, p.mean(axis=0))
    err = (Rotation.from_quat(mq) * Rotation.from_rotvec([0.1, 0, 0]).inv()).magnitude()
    assert err < 1e-4 / np.sqrt(50) * 5


def test_joints_arrived() -> None:
    target = np.array([0.2, 0.2, 0.2, 0.0, 0.0, 0.0])
    tol_p, tol_v = [5e-6] * 3 + [5e-5] * 3, [1e-4] * 3 + [1e-3] * 3
    assert joints_arrived(target + 4e-6, np.zeros(6), target, tol_p, tol_v)
    assert not joints_arrived(target + [6e-6, 0, 0, 0, 0, 0], np.zeros(6), target, tol_p, tol_v)
    assert not joints_arrived(target, [0, 0, 0, 0, 2e-3, 0], target, tol_p, tol_v)
