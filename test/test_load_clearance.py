"""Load-aware clearance (seed 004's gap connector closed by the joint force): the model, its
exact compensation, and compensation with it against direction-agnostic models when the truth
is load-driven."""

from __future__ import annotations

import numpy as np
import pytest
from workspace import MECH, random_poses

from positioning_cell import clearance as cl
from positioning_cell.clearance.load import LoadAwareClearance, inverse_with_offsets
from positioning_cell.core import kinematics
from positioning_cell.core.poses import matrix_from_quaternion, pose_error
from positioning_cell.errors import ConfigError
from positioning_cell.mechanics import statics as st

R = 0.16e-3  # seed 000 Table 1
TRUTH = LoadAwareClearance(R, R, st.Payload())


def _errors(model: cl.ClearanceModel, p: np.ndarray, q: np.ndarray) -> tuple[float, float]:
    """Mean position error (m) and rotation error (rad) of the load-driven truth commanded by
    ``model``'s compensation."""
    cmd = cl.compensate(MECH, model, p, q)
    att = TRUTH.attained_pose(MECH, cmd.lengths, cmd.thetas, cmd.phis)
    assert att.converged.all()
    dp, dr = pose_error(att.position, att.quaternion, p, q)
    return float(np.linalg.norm(dp, axis=1).mean()), float(np.linalg.norm(dr, axis=1).mean())


def test_offsets_follow_the_joint_forces() -> None:
    p, q = random_poses(20, np.random.default_rng(40))
    u_off, s_off = TRUTH.offsets(MECH, p, q)
    forces = st.joint_forces(MECH, p, q, TRUTH.payload, TRUTH.structure)
    rot = matrix_from_quaternion(q)
    s_base = np.einsum('nij,nkj->nki', rot, s_off)
    for offset, force in ((u_off, forces.at_base), (s_base, forces.at_platform)):
        assert np.linalg.norm(force, axis=2).min() > 50.0  # all seated (F ≫ F_0 = 1 N)
        np.testing.assert_allclose(np.linalg.norm(offset, axis=2), R, rtol=1e-4)
        cosine = np.sum(offset * force, axis=2) / (R * np.linalg.norm(force, axis=2))
        np.testing.assert_allclose(cosine, 1.0, rtol=1e-4)


def test_compression_shortens_a_leg() -> None:
    """At home with the base vertical, legs 2 and 3 push (compression): their clearances close
    toward each other along the leg, so the leg is effectively shorter; leg 1 pulls, longer."""
    p, q = MECH.home_position[None], MECH.home_quaternion[None]
    efforts = st.actuator_efforts(MECH, p, q, TRUTH.payload)[0]
    shift = TRUTH.compensate(MECH, p, q).lengths - kinematics.inverse(MECH, p, q).lengths
    assert efforts[0] < 0.0 < efforts[1]
    assert shift[0, 0] < 0.0 < shift[0, 1]  # compensation lengthens what the load shortens
    assert np.abs(shift).max() <= 2 * R


def test_compensation_round_trip_and_fixed_point() -> None:
    p, q = random_poses(40, np.random.default_rng(41))
    cmd = TRUTH.compensate(MECH, p, q)
    att = TRUTH.attained_pose(MECH, cmd.lengths, cmd.thetas, cmd.phis)
    assert att.converged.all()
    dp, dr = pose_error(att.position, att.quaternion, p, q)
    assert np.abs(dp).max() < 1e-11 and np.abs(dr).max() < 1e-10
    # Uncompensated: the attained pose is where the displaced joints meet the commands.
    nominal = kinematics.inverse(MECH, p, q)
    att = TRUTH.attained_pose(MECH, nominal.lengths, nominal.thetas)
    back = inverse_with_offsets(MECH, att.position, att.quaternion,
                                *TRUTH.offsets(MECH, att.position, att.quaternion))
    np.testing.assert_allclose(back.lengths, nominal.lengths, atol=1e-13)
    np.testing.assert_allclose(back.thetas, nominal.thetas, atol=1e-12)


def test_inverse_with_fixed_offsets_is_the_vector_model() -> None:
    """With the same offsets for every pose, the per-leg shifted IK equals the exact vector
    model's IK of the displaced machine."""
    rng = np.random.default_rng(42)
    p, q = random_poses(10, rng)
    vector = cl.VectorClearance.random(R, R, rng)
    n = len(p)
    ours = inverse_with_offsets(MECH, p, q, np.broadcast_to(vector.u_offsets, (n, 3, 3)),
                                np.broadcast_to(vector.s_offsets, (n, 3, 3)))
    theirs = vector.compensate(MECH, p, q)
    np.testing.assert_allclose(ours.lengths, theirs.lengths, atol=1e-15)
    np.testing.assert_allclose(ours.thetas, theirs.thetas, atol=1e-14)


def test_load_aware_compensation_beats_direction_agnostic_models() -> None:
    """Truth load-driven (50 kg panel, base vertical). Direction-agnostic compensation (eq. 9
    and vector models with directions drawn at random) does no better than none; the
    load-aware model removes the error, and still does with the payload known only roughly."""
    rng = np.random.default_rng(43)
    p, q = random_poses(40, rng)
    none = _errors(None, p, q)
    exact = _errors(TRUTH, p, q)
    rough = _errors(LoadAwareClearance(R, R, st.Payload(mass=45.0)), p, q)
    agnostic = np.array([_errors(make(R, R, rng), p, q)
                         for make in (cl.EffectiveLengthClearance.random,
                                      cl.VectorClearance.random) for _ in range(4)])
    assert none[0] > 100e-6  # a clearance error worth compensating (µm scale)
    assert agnostic[:, 0].mean() > 0.8 * none[0]
    assert exact[0] < 1e-9 and exact[1] < 1e-9
    assert rough[0] < 0.05 * agnostic[:, 0].mean() and rough[1] < 0.05 * agnostic[:, 1].mean()


def test_model_from_params_registers_load() -> None:
    payload = st.Payload(mass=45.0, gravity=(0.0, 0.0, -9.80665))
    nested = cl.model_from_params({'model': 'load', 'r_a': 1e-4, 'load': {'seating_force': 2.0}},
                                  MECH, payload)
    dotted = cl.model_from_params({'model': 'load', 'r_a': 1e-4, 'load.seating_force': 2.0},
                                  MECH, payload, st.Structure())
    assert isinstance(nested, LoadAwareClearance) and nested == dotted
    assert nested.r_a == 1e-4 and nested.r_b == MECH.joint_clearance_s
    assert nested.payload == payload and nested.seating_force == 2.0
    with pytest.raises(ConfigError, match=r'clearance.load.seating_force = -1.0: must be > 0 N'):
        cl.model_from_params({'model': 'load', 'load.seating_force': -1.0}, MECH)
    with pytest.raises(ConfigError, match=r"clearance.model = 'loaded': expected one of"):
        cl.model_from_params({'model': 'loaded'}, MECH)


def test_nodes_can_select_the_load_model_by_parameter() -> None:
    """The simulator's truth and the positioner's compensation both build it from a
    `clearance.model: load` parameter block (as in config/cell.yaml)."""
    from positioning_cell.clearance import model_from_params
    from positioning_cell.clearance.load import LoadAwareClearance
    from positioning_cell.core.mechanism import Mechanism
    from positioning_cell.sim.truth import truth_from_params

    mech = Mechanism.default()
    truth = truth_from_params({'truth': {'clearance': {'model': 'load', 'seed': 0}}}, mech)
    assert isinstance(truth.clearance, LoadAwareClearance)
    positioner = model_from_params({'model': 'load', 'r_a': 1.6e-4, 'r_b': 1.6e-4}, mech)
    assert isinstance(positioner, LoadAwareClearance)
