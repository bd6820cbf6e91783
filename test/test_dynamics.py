"""Inverse dynamics along a trajectory: the actuators' power equals the rate of change of the
bodies' energy, computed independently from positions sampled along the move."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from workspace import MECH

from positioning_cell.errors import InputError
from positioning_cell.mechanics import dynamics
from positioning_cell.mechanics import statics as st
from positioning_cell.moves.trajectory import MotionLimits, Trajectory, plan_move

FAST = MotionLimits(linear_speed=0.1, linear_acceleration=1.0, angular_speed=1.0,
                    angular_acceleration=10.0)
STRUCTURE = st.Structure()


def _move(period: float = 1e-3) -> Trajectory:
    goal = MECH.home_position + np.array([0.01, -0.008, 0.006])
    goal_q = Rotation.from_rotvec([0.05, 0.04, -0.06]).as_quat()
    return plan_move(MECH, MECH.home_position, MECH.home_quaternion, goal, goal_q,
                     period=period, limits=FAST)


def _energy(trajectory: Trajectory, payload: st.Payload) -> np.ndarray:
    """Kinetic + potential energy (M,) J of every body from sampled positions only (finite
    differences for velocities)."""
    t = trajectory.times
    p = trajectory.position
    rot = Rotation.from_quat(trajectory.quaternion)
    g = np.asarray(payload.gravity)
    omega = np.zeros_like(p)
    omega[1:-1] = (rot[2:] * rot[:-2].inv()).as_rotvec() / (t[2:] - t[:-2])[:, None]
    energy = np.zeros(len(t))
    for mass, centre, inertia in (
            (payload.mass, payload.centre_of_gravity, payload.inertia),
            (STRUCTURE.platform_mass, STRUCTURE.platform_centre_of_gravity,
             STRUCTURE.platform_inertia)):
        c = p + rot.apply(centre)
        v = np.gradient(c, t, axis=0, edge_order=2)
        i_base = rot.as_matrix() @ np.asarray(inertia) @ rot.as_matrix().transpose(0, 2, 1)
        energy += 0.5 * mass * np.sum(v * v, axis=1) - mass * c @ g
        energy += 0.5 * np.einsum('ni,nij,nj->n', omega, i_base, omega)
    b = p[:, None, :] + np.einsum('nij,kj->nki', rot.as_matrix(), MECH.platform_joints)
    u = (b - MECH.base_joints) / np.linalg.norm(b - MECH.base_joints, axis=2, keepdims=True)
    for mass, c in ((STRUCTURE.cylinder_mass, MECH.base_joints + STRUCTURE.cylinder_offset * u),
                    (STRUCTURE.rod_mass, b - STRUCTURE.rod_offset * u)):
        v = np.gradient(c, t, axis=0, edge_order=2)
        energy += 0.5 * mass * np.sum(v * v, axis=(1, 2)) - mass * np.sum(c @ g, axis=1)
    u_dot = np.gradient(u, t, axis=0, edge_order=2)
    energy += 0.5 * (STRUCTURE.cylinder_inertia + STRUCTURE.rod_inertia) * np.sum(
        u_dot * u_dot, axis=(1, 2))
    return energy


@pytest.mark.parametrize('gravity', [(0.0, 0.0, 0.0), st.VERTICAL_BASE_GRAVITY],
                         ids=['inertia only', 'base vertical'])
def test_actuator_power_equals_energy_rate(gravity: tuple[float, float, float]) -> None:
    """τ·q̇ + w_ext·t = d(T + V)/dt at every interior sample (to the finite-difference error
    of the independent energy, < 0.1 % of the peak power)."""
    trajectory = _move()
    payload = st.Payload(gravity=gravity, external_wrench=(5.0, 0.0, -3.0, 0.5, 0.0, 0.0))
    profile = dynamics.trajectory_efforts(MECH, trajectory, payload, STRUCTURE)
    rates = np.hstack([trajectory.length_rates, trajectory.theta_rates])
    power = np.sum(profile.efforts * rates, axis=1)
    external = profile.twist @ np.asarray(payload.external_wrench)
    rate = np.gradient(_energy(trajectory, payload), profile.times, edge_order=2)
    peak = np.abs(power).max()
    assert peak > 5.0  # a move with real inertia loads
    np.testing.assert_allclose((power + external - rate)[2:-2], 0.0, atol=1e-3 * peak)


def test_inertia_matters_on_a_fast_move_and_vanishes_at_rest() -> None:
    profile = dynamics.trajectory_efforts(MECH, _move(), st.Payload(), STRUCTURE)
    inertial = np.abs(profile.efforts - profile.static).max(axis=0)
    assert inertial[:3].max() > 50.0  # N: the 50 kg panel accelerated at ~1 m/s²
    # The sinusoidal ramp starts and ends with zero acceleration and speed (up to the one-sided
    # difference of the twist at the ends).
    np.testing.assert_allclose(profile.efforts[[0, -1]], profile.static[[0, -1]], atol=1e-2)
    assert profile.peak.shape == (6,)


def test_short_trajectory_is_refused() -> None:
    trajectory = plan_move(MECH, MECH.home_position, MECH.home_quaternion, MECH.home_position,
                           MECH.home_quaternion, period=0.01)
    with pytest.raises(InputError, match='at least 3 samples'):
        dynamics.trajectory_efforts(MECH, trajectory, st.Payload())
