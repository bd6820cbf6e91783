"""Statics (seed 002): payload parameters, actuator efforts by the Jacobian transpose checked by
virtual work against finite differences of the forward kinematics, joint forces in
equilibrium, and the platform's compliance against forward kinematics of the deformed drives."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from workspace import MECH, random_poses

from positioning_cell import config
from positioning_cell.core import kinematics
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.mechanics import statics as st
from positioning_cell.parameters import parse, to_params

PAYLOAD = st.Payload(mass=50.0, centre_of_gravity=(0.03, -0.02, 0.12),
                     external_wrench=(40.0, -25.0, 60.0, 3.0, -2.0, 5.0),
                     gravity=(1.5, -8.9, -3.7))
STRUCTURE = st.Structure()


def potential(p: np.ndarray, q: np.ndarray, p_ref: np.ndarray, q_ref: np.ndarray) -> float:
    """Potential energy (J) of every body's weight and of the (constant) external wrench,
    from positions only: independent of the library's velocity maps."""
    g = np.asarray(PAYLOAD.gravity)
    rot = Rotation.from_quat(q).as_matrix()
    energy = 0.0
    for mass, centre in ((PAYLOAD.mass, PAYLOAD.centre_of_gravity),
                         (STRUCTURE.platform_mass, STRUCTURE.platform_centre_of_gravity)):
        energy -= mass * g @ (p + rot @ np.asarray(centre))
    b = p + MECH.platform_joints @ rot.T
    u = (b - MECH.base_joints) / np.linalg.norm(b - MECH.base_joints, axis=1)[:, None]
    energy -= STRUCTURE.cylinder_mass * np.sum(
        (MECH.base_joints + STRUCTURE.cylinder_offset * u) @ g)
    energy -= STRUCTURE.rod_mass * np.sum((b - STRUCTURE.rod_offset * u) @ g)
    wrench = np.asarray(PAYLOAD.external_wrench)
    turn = (Rotation.from_quat(q) * Rotation.from_quat(q_ref).inv()).as_rotvec()
    return float(energy - wrench[:3] @ (p - p_ref) - wrench[3:] @ turn)


def test_efforts_by_virtual_work_against_finite_differences() -> None:
    """τ_j = ∂V/∂q_j: move each actuated joint by ±h through the forward kinematics and
    difference the potential energy of the loads the actuators hold."""
    p, q = random_poses(4, np.random.default_rng(20))
    efforts = st.actuator_efforts(MECH, p, q, PAYLOAD, STRUCTURE)
    joints = kinematics.inverse(MECH, p, q)
    h = 1e-6
    for k in range(len(p)):
        q0 = np.concatenate([joints.lengths[k], joints.thetas[k]])
        steps = q0 + h * np.vstack([np.eye(6), -np.eye(6)])
        fk = kinematics.forward(MECH, steps[:, :3], steps[:, 3:], joints.phis[k])
        assert fk.converged.all()
        v = [potential(fk.position[j], fk.quaternion[j], p[k], q[k]) for j in range(12)]
        numeric = (np.array(v[:6]) - np.array(v[6:])) / (2 * h)
        np.testing.assert_allclose(efforts[k], numeric, rtol=1e-6, atol=2e-6 * np.abs(
            numeric).max())


def test_joint_forces_hold_the_platform_in_equilibrium() -> None:
    """Newton-Euler of the platform alone: the ball forces of the three legs balance the
    payload, the platform's weight and the external wrench; each leg balances too."""
    p, q = random_poses(20, np.random.default_rng(21))
    forces = st.joint_forces(MECH, p, q, PAYLOAD, STRUCTURE)
    g = np.asarray(PAYLOAD.gravity)
    rot = Rotation.from_quat(q).as_matrix()
    r = np.einsum('nij,kj->nki', rot, MECH.platform_joints)
    total_f = forces.at_platform.sum(axis=1) + np.asarray(PAYLOAD.external_wrench[:3])
    total_m = np.cross(r, forces.at_platform).sum(axis=1) + PAYLOAD.external_wrench[3:]
    for mass, centre in ((PAYLOAD.mass, PAYLOAD.centre_of_gravity),
                         (STRUCTURE.platform_mass, STRUCTURE.platform_centre_of_gravity)):
        total_f += mass * g
        total_m += np.cross(rot @ np.asarray(centre), mass * g)
    scale = PAYLOAD.mass * np.linalg.norm(g)
    np.testing.assert_allclose(total_f, 0.0, atol=1e-10 * scale)
    np.testing.assert_allclose(total_m, 0.0, atol=1e-10 * scale)
    # Leg force balance: base + platform reactions carry the leg's own weight.
    np.testing.assert_allclose(forces.at_base + forces.at_platform,
                               np.broadcast_to(STRUCTURE.leg_mass * g, forces.at_base.shape),
                               atol=1e-9)


def test_home_with_base_vertical_is_symmetric() -> None:
    """Default payload, base −y down: legs 2 and 3 mirror each other about x = 0 (equal leg
    forces, opposite θ torques) and the top leg's θ drive carries nothing."""
    efforts = st.actuator_efforts(MECH, MECH.home_position, MECH.home_quaternion, st.Payload())[0]
    assert efforts[1] == pytest.approx(efforts[2], rel=1e-12)
    assert efforts[4] == pytest.approx(-efforts[5], rel=1e-12)
    assert abs(efforts[3]) < 1e-9
    assert efforts[0] < 0.0 < efforts[1]  # the CoG 0.1 m out pulls the top leg, pushes the rest


def test_base_flat_legs_share_the_weight() -> None:
    """Base horizontal, payload on the axis, massless legs: three equal pushes whose vertical
    components add up to the weight, no θ torque."""
    payload = st.Payload(gravity=(0.0, 0.0, -st.STANDARD_GRAVITY))
    massless = st.Structure(cylinder_mass=0.0, rod_mass=0.0)
    efforts = st.actuator_efforts(MECH, MECH.home_position, MECH.home_quaternion, payload,
                                  massless)[0]
    u_z = MECH.home_height / MECH.home_length
    weight = (payload.mass + massless.platform_mass) * st.STANDARD_GRAVITY
    np.testing.assert_allclose(efforts[:3], weight / (3 * u_z), rtol=1e-12)
    np.testing.assert_allclose(efforts[3:], 0.0, atol=1e-9)


@pytest.mark.parametrize('theta_stiffness', [4.0e4, math.inf])
def test_deflection_matches_forward_kinematics_of_the_yielding_drives(
        theta_stiffness: float) -> None:
    """δx = −C·w against the pose FK gives for the drives deformed by −τ/k; and the deflection
    scales with the compliance when the stiffnesses are doubled."""
    structure = st.Structure(theta_stiffness=theta_stiffness)
    p, q = random_poses(10, np.random.default_rng(22))
    result = st.deflection(MECH, p, q, PAYLOAD, structure)
    joints = kinematics.inverse(MECH, p, q)
    dq = result.joint_deformation
    fk = kinematics.forward(MECH, joints.lengths + dq[:, :3], joints.thetas + dq[:, 3:],
                            joints.phis)
    dp = fk.position - p
    dr = (Rotation.from_quat(fk.quaternion) * Rotation.from_quat(q).inv()).as_rotvec()
    size = np.abs(np.hstack([result.translation, result.rotation * MECH.platform_radius])).max()
    np.testing.assert_allclose(dp, result.translation, atol=1e-3 * size)
    np.testing.assert_allclose(dr * MECH.platform_radius, result.rotation * MECH.platform_radius,
                               atol=1e-3 * size)
    stiffer = st.Structure(leg_stiffness=2 * structure.leg_stiffness,
                           theta_stiffness=2 * theta_stiffness)
    half = st.deflection(MECH, p, q, PAYLOAD, stiffer)
    np.testing.assert_allclose(half.translation, 0.5 * result.translation, rtol=1e-9,
                               atol=1e-18)


def test_compliance_is_symmetric_positive_semidefinite() -> None:
    p, q = random_poses(10, np.random.default_rng(23))
    c = st.compliance(MECH, p, q)
    np.testing.assert_allclose(c, c.transpose(0, 2, 1), rtol=1e-9, atol=1e-20)
    assert np.all(np.linalg.eigvalsh(c) > -1e-18)


def test_batch_matches_single_poses() -> None:
    p, q = random_poses(6, np.random.default_rng(24))
    batch = st.actuator_efforts(MECH, p, q, PAYLOAD)
    assert batch.shape == (6, 6)
    for k in range(6):
        np.testing.assert_allclose(st.actuator_efforts(MECH, p[k], q[k], PAYLOAD)[0], batch[k],
                                   rtol=1e-12)


def test_parameters_from_cell_yaml_are_the_defaults() -> None:
    params = config.node_parameters(config.load_parameter_file(config.config_path()),
                                    'leg_driver')
    assert parse(st.Payload, params['payload']) == st.Payload()
    assert parse(st.Structure, params['structure']) == st.Structure()
    assert parse(st.Payload, config.flatten(params['payload'])) == st.Payload()
    assert parse(st.Payload, to_params(st.Payload())) == st.Payload()
    assert parse(st.Structure, to_params(st.Structure())) == st.Structure()
    assert parse(st.Payload, {'gravity': [0, 0, -9.8]}).gravity == (0.0, 0.0, -9.8)
    # Principal moments or the full matrix, as the declaration says.
    assert parse(st.Payload, {'inertia': [1.0, 2.0, 3.0]}).inertia == (
        (1.0, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 3.0))


@pytest.mark.parametrize(('params', 'words'), [
    ({'mas': 50.0}, 'payload.mas: unknown parameter'),
    ({'mass': -1.0}, 'payload.mass = -1.0: must be >= 0 kg'),
    ({'mass': 'heavy'}, "payload.mass = 'heavy': expected a number"),
    ({'centre_of_gravity': [0.0, 0.1]}, 'payload.centre_of_gravity = [0.0, 0.1]: expected 3'),
    ({'gravity': [0.0, float('nan'), 0.0]}, 'payload.gravity = nan: must be finite'),
    ({'inertia': [1.0, -1.0, 1.0]}, 'payload.inertia = ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0)'),
    ({'external_wrench': [0.0] * 5}, 'payload.external_wrench = [0.0, 0.0, 0.0, 0.0, 0.0]'),
])
def test_bad_payload_names_key_and_value(params: dict[str, object], words: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(words)):
        parse(st.Payload, params, 'payload.')


def test_bad_structure_and_input() -> None:
    with pytest.raises(ConfigError, match=r'structure\.leg_stiffness = 0.0: must be > 0'):
        parse(st.Structure, {'leg_stiffness': 0.0}, 'structure.')
    assert st.Structure(theta_stiffness=math.inf).theta_stiffness == math.inf
    with pytest.raises(InputError):
        st.actuator_efforts(MECH, [0.0, 0.0, float('nan')], MECH.home_quaternion, PAYLOAD)
