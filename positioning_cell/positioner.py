"""Decisions of the positioner that are not kinematics: its state machine, the frame and goal
checks, arrival of the drives, and the closed-loop correction from a measured pose (the way
digital assembly cells close the loop through a laser tracker)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from positioning_cell.errors import InputError
from positioning_cell.poses import as_pose_batch, as_vectors, pose_error

FloatArray = NDArray[np.float64]
BASE_FRAME = 'base'


class State(Enum):
    """States of a move, as reported on /diagnostics."""

    IDLE = 'idle'
    MOVING = 'moving'
    SETTLING = 'settling'
    CORRECTING = 'correcting'
    SETTLED = 'settled'
    ABORTED = 'aborted'
    FAULT = 'fault'


class CompensationMode(Enum):
    """none: nominal IK; model: the configured clearance model; measured: the model, then
    closed-loop correction from the measured pose."""

    NONE = 'none'
    MODEL = 'model'
    MEASURED = 'measured'


def validate_goal(frame_id: str, position: ArrayLike,
                  quaternion: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """A goal pose as (3,) m and a unit quaternion (4,); InputError names what is wrong (a frame
    other than ``base``, NaN or infinite numbers, a zero or non-unit quaternion)."""
    if frame_id != BASE_FRAME:
        raise InputError(f"goal frame '{frame_id}' is not '{BASE_FRAME}': poses are commanded "
                         f"in the base frame")
    p, q = as_pose_batch(position, quaternion)
    return p[0], q[0]


@dataclass(frozen=True)
class Tolerance:
    """A pose tolerance: position (m) and orientation (rad)."""

    position: float
    orientation: float

    def holds(self, position_error: ArrayLike, rotation_error: ArrayLike) -> bool:
        """True when |Δp| ≤ position and |rotation vector| ≤ orientation."""
        return bool(np.linalg.norm(position_error) <= self.position
                    and np.linalg.norm(rotation_error) <= self.orientation)


def corrected_command(command_p: ArrayLike, command_q: ArrayLike, desired_p: ArrayLike,
                      desired_q: ArrayLike, measured_p: ArrayLike,
                      measured_q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Next pose to command so that the measured pose moves onto the desired one.

    The machine's error is nearly constant over a correction step, so the command moves by the
    measured deviation: p' = p_cmd + (p_des − p_meas); R' = R_des·R_measᵀ·R_cmd (base frame).
    """
    cp, cq = as_pose_batch(command_p, command_q)
    dp, dq = as_pose_batch(desired_p, desired_q)
    mp, mq = as_pose_batch(measured_p, measured_q)
    rot = Rotation.from_quat(dq) * Rotation.from_quat(mq).inv() * Rotation.from_quat(cq)
    return (cp + dp - mp)[0], np.asarray(rot.as_quat(canonical=True))[0]


def deviation(measured_p: ArrayLike, measured_q: ArrayLike, desired_p: ArrayLike,
              desired_q: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Measured − desired: Δp (3,) m and the rotation vector of R_desᵀ·R_meas (3,) rad."""
    mp, mq = as_pose_batch(measured_p, measured_q)
    dp, dq = as_pose_batch(desired_p, desired_q)
    e_p, e_r = pose_error(mp, mq, dp, dq)
    return e_p[0], e_r[0]


def mean_pose(positions: ArrayLike, quaternions: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Mean of k poses: arithmetic mean position (3,) m, chordal L2 mean rotation (4,)."""
    p, q = as_pose_batch(positions, quaternions)
    return p.mean(axis=0), np.asarray(Rotation.from_quat(q).mean().as_quat(canonical=True))


def joints_arrived(position: ArrayLike, velocity: ArrayLike, target: ArrayLike,
                   position_tolerance: ArrayLike, velocity_tolerance: ArrayLike) -> bool:
    """True when every axis is within its position tolerance of the target and slower than its
    velocity tolerance; all (6,) in joint order (m, rad; m/s, rad/s)."""
    pos = as_vectors(position, 6, 'position')[0]
    vel = as_vectors(velocity, 6, 'velocity')[0]
    tgt = as_vectors(target, 6, 'target')[0]
    return bool(np.all(np.abs(pos - tgt) <= np.asarray(position_tolerance))
                and np.all(np.abs(vel) <= np.asarray(velocity_tolerance)))
