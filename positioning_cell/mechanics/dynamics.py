"""Inverse dynamics of the 3-UPS positioner along a trajectory (seed 002 §2: Newton-Euler with
d'Alembert's principle, mapped to the actuators by virtual power).

Bodies: payload and platform (rigid, fixed to the platform frame) and, per leg, a cylinder and a
rod (slender, see :mod:`positioning_cell.mechanics.statics`). The actuator efforts are
τ = Jᵀ·w with w the wrench the actuators must exert on the platform
(:func:`positioning_cell.mechanics.statics.required_wrench`), in the joint order
leg1_length..leg3_length (N), leg1_theta..leg3_theta (N·m).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.kinematics import jacobian
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.mechanics.statics import (
    Payload,
    Structure,
    actuator_efforts,
    efforts_from_wrench,
    required_wrench,
)
from positioning_cell.moves.trajectory import Trajectory

FloatArray = NDArray[np.float64]


def inverse_dynamics(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                     twist: ArrayLike, twist_rate: ArrayLike, payload: Payload,
                     structure: Structure | None = None) -> FloatArray:
    """Actuator efforts (N, 6) at poses (N, 3) m, (N, 4) with platform twist (N, 6)
    (v m/s of the platform origin, ω rad/s; base frame) and its time derivative (N, 6)
    (m/s², rad/s²): gravity, payload external wrench and inertia of every body."""
    wrench = required_wrench(mech, position, quaternion, payload, structure, twist, twist_rate)
    return efforts_from_wrench(mech, position, quaternion, wrench)


class EffortProfile(NamedTuple):
    """Actuator efforts along a trajectory: times (M,) s; efforts (M, 6) with inertia; static
    (M, 6) the same poses held at rest; twist and twist_rate (M, 6) of the platform."""

    times: FloatArray
    efforts: FloatArray
    static: FloatArray
    twist: FloatArray
    twist_rate: FloatArray

    @property
    def peak(self) -> FloatArray:
        """Largest |effort| per joint (6,) over the move."""
        out: FloatArray = np.abs(self.efforts).max(axis=0)
        return out


def trajectory_efforts(mech: Mechanism, trajectory: Trajectory, payload: Payload,
                       structure: Structure | None = None) -> EffortProfile:
    """Actuator force and torque profiles along a planned move
    (:func:`positioning_cell.moves.trajectory.plan_move`). The platform twist is J·q̇ from the
    trajectory's joint rates; its rate is the second-order finite difference over the sample
    times (numpy.gradient)."""
    times = trajectory.times
    if times.shape[0] < 3:
        raise InputError('trajectory needs at least 3 samples to differentiate the twist')
    rates = np.hstack([trajectory.length_rates, trajectory.theta_rates])
    jac = jacobian(mech, trajectory.position, trajectory.quaternion).matrix
    twist = np.einsum('nij,nj->ni', jac, rates)
    twist_rate = np.gradient(twist, times, axis=0, edge_order=2)
    efforts = inverse_dynamics(mech, trajectory.position, trajectory.quaternion, twist,
                               twist_rate, payload, structure)
    static = actuator_efforts(mech, trajectory.position, trajectory.quaternion, payload,
                              structure)
    return EffortProfile(times, efforts, static, twist, twist_rate)
