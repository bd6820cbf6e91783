"""The drives' last line of defence: every trajectory, and every point of it, checked against the
axis limits before it is accepted, whatever the sender believed.

Checked, in order, on the path the servos would follow (the trajectory joined to the current
setpoint, see :meth:`JointPath.starting_from`): every number finite; positions within the axis
ranges (stroke l_min..l_max, θ_min..θ_max of the mechanism) at the points and wherever the
cubic interpolant between them reaches further; speeds within v_max at the points and at the
interpolant's fastest; accelerations within a_max (the interpolant's second derivative is
linear in time, so its extremes are at the points); the first point no further than
``max_jump`` from the current setpoint when the trajectory starts there (a step, not a move).
A refusal names the axis, the value and the limit; nothing about the current motion changes.
Units: m and rad, s.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.errors import PositioningError
from positioning_cell.sim.axes import LINEAR_AXES, per_axis, unit_of
from positioning_cell.sim.paths import JointPath

FloatArray = NDArray[np.float64]

#: Relative slack on the limits: numbers computed from a plan at the limit stay at it.
_SLACK = 1e-9


class Refusal(Enum):
    """Why the drives refuse a trajectory (ros2_controllers' names where they exist)."""

    INVALID_JOINTS = 'invalid_joints'
    INVALID_GOAL = 'invalid_goal'
    OUT_OF_RANGE = 'out_of_range'
    SPEED = 'speed'
    ACCELERATION = 'acceleration'
    JUMP = 'jump'
    OLD_HEADER_TIMESTAMP = 'old_header_timestamp'
    FUTURE_HEADER_TIMESTAMP = 'future_header_timestamp'
    TOO_MANY_POINTS = 'too_many_points'
    FOREIGN_SENDER = 'foreign_sender'
    SUPERSEDED = 'superseded'
    NOT_REFERENCED = 'not_referenced'
    DISABLED = 'disabled'
    FAULT = 'fault'


class TrajectoryRefusedError(PositioningError):
    """The drives refuse a trajectory: ``code`` says which rule, the message the details."""

    def __init__(self, code: Refusal, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class AxisGuard:
    """The limits a trajectory is held to, per axis (6,) in JOINT_NAMES order: position range
    ``low``..``high`` (m, rad), ``speed`` (m/s, rad/s), ``acceleration`` (m/s², rad/s²),
    ``jump`` (m, rad)."""

    low: FloatArray
    high: FloatArray
    speed: FloatArray
    acceleration: FloatArray
    jump: FloatArray

    @classmethod
    def of(cls, mech: Mechanism, speed: FloatArray, acceleration: FloatArray,
           jump: FloatArray) -> AxisGuard:
        """The mechanism's strokes and θ ranges with the drives' dynamic limits."""
        return cls(per_axis(mech.length_min, mech.theta_min),
                   per_axis(mech.length_max, mech.theta_max), speed, acceleration, jump)

    def clamp(self, position: FloatArray) -> FloatArray:
        """Positions (..., 6) held within the ranges (the servos' soft limit)."""
        clamped: FloatArray = np.clip(position, self.low, self.high)
        return clamped


def _amount(axis: int, value: float, per_second: int = 0) -> str:
    """A value for people: mm, mm/s, ... on linear axes, degrees on rotary ones."""
    if LINEAR_AXES[axis]:
        return f'{value * 1e3:.4f} {unit_of(axis, per_second).replace("m", "mm", 1)}'
    return f'{np.degrees(value):.4f} {unit_of(axis, per_second).replace("rad", "deg", 1)}'


def _segments(path: JointPath) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray,
                                        FloatArray]:
    """Per segment (M−1,) duration h and the cubic p(s) = a s³ + b s² + c s + d of s ∈ [0, 1]
    (M−1, 6) of the Hermite interpolant (or the line, a = b = 0, without velocities)."""
    h = np.diff(path.times)[:, None]
    p0, p1 = path.positions[:-1], path.positions[1:]
    if path.velocities is None:
        zero = np.zeros_like(p0)
        return h[:, 0], zero, zero, p1 - p0, p0
    m0, m1 = path.velocities[:-1] * h, path.velocities[1:] * h
    a = 2.0 * p0 + m0 - 2.0 * p1 + m1
    b = -3.0 * p0 - 2.0 * m0 + 3.0 * p1 - m1
    return h[:, 0], a, b, m0, p0


def _worst(values: FloatArray, limit: FloatArray) -> tuple[int, int, float] | None:
    """(row, axis, value) of the entry (K, 6) most beyond ±limit (6,), or None."""
    ratio = np.abs(values) / limit
    if not (ratio > 1.0 + _SLACK).any():
        return None
    k, axis = np.unravel_index(int(np.nanargmax(ratio)), ratio.shape)
    return int(k), int(axis), float(values[k, axis])


def check_path(path: JointPath, guard: AxisGuard, current: FloatArray | None = None) -> None:
    """Refuse ``path`` (joined to the current setpoint already) if it breaks a limit of
    ``guard`` anywhere (module docstring); ``current`` (6,): the setpoint when it starts, for
    the jump check of a trajectory whose first point is at t = 0."""
    if current is not None and path.times[0] == 0.0:
        step = path.positions[0] - current
        worst = _worst(step[None], guard.jump)
        if worst is not None:
            _, axis, value = worst
            raise TrajectoryRefusedError(
                Refusal.JUMP, f'{JOINT_NAMES[axis]} would jump {_amount(axis, value)} at the '
                f'start (limit {_amount(axis, float(guard.jump[axis]))}): the first point is '
                'not where the axis is')
    positions = path.positions
    for rows, where in ((positions < guard.low, 'below'), (positions > guard.high, 'above')):
        if rows.any():
            k, axis = (int(i) for i in np.argwhere(rows)[0])
            limit = guard.low[axis] if where == 'below' else guard.high[axis]
            raise TrajectoryRefusedError(
                Refusal.OUT_OF_RANGE, f'point {k}: {JOINT_NAMES[axis]} '
                f'{_amount(axis, positions[k, axis])} is {where} its limit '
                f'{_amount(axis, float(limit))}')
    if path.times.size == 1:
        return
    h, a, b, c, d = _segments(path)
    # Extremes of the position inside a segment: p'(s) = 3a s² + 2b s + c = 0, s ∈ (0, 1).
    disc = np.maximum(b * b - 3.0 * a * c, 0.0)
    with np.errstate(divide='ignore', invalid='ignore'):
        roots = np.stack([(-b + np.sqrt(disc)) / (3.0 * a), (-b - np.sqrt(disc)) / (3.0 * a),
                          -c / (2.0 * b)])
    roots = np.where(np.isfinite(roots) & (roots > 0.0) & (roots < 1.0), roots, 0.0)
    inside = ((a * roots + b) * roots + c) * roots + d
    for bound, where in ((guard.low, 'below'), (guard.high, 'above')):
        beyond = inside < bound if where == 'below' else inside > bound
        beyond &= np.abs(inside - bound) > _SLACK * np.maximum(np.abs(bound), 1.0)
        if beyond.any():
            r, k, axis = (int(i) for i in np.argwhere(beyond)[0])
            raise TrajectoryRefusedError(
                Refusal.OUT_OF_RANGE, f'between points {k} and {k + 1}: {JOINT_NAMES[axis]} '
                f'reaches {_amount(axis, float(inside[r, k, axis]))}, {where} its limit '
                f'{_amount(axis, float(bound[axis]))}')
    # Speed: at the points, and where the interpolant's quadratic speed peaks.
    with np.errstate(divide='ignore', invalid='ignore'):
        vertex = np.where(np.abs(a) > 0.0, -b / (3.0 * a), 0.0)
    vertex = np.clip(np.nan_to_num(vertex), 0.0, 1.0)
    speeds = np.vstack([c / h[:, None], (3.0 * a + 2.0 * b + c) / h[:, None],
                        ((3.0 * a * vertex + 2.0 * b) * vertex + c) / h[:, None]])
    worst = _worst(speeds, guard.speed)
    if worst is not None:
        _, axis, value = worst
        raise TrajectoryRefusedError(
            Refusal.SPEED, f'{JOINT_NAMES[axis]} speed {_amount(axis, abs(value), 1)} exceeds '
            f'its limit {_amount(axis, float(guard.speed[axis]), 1)}')
    # Acceleration: the cubic's second derivative is linear, extremes at the segment ends; a
    # line's velocity steps between segments, spread over the shorter neighbour.
    if path.velocities is not None:
        accel = np.vstack([2.0 * b / (h * h)[:, None], (6.0 * a + 2.0 * b) / (h * h)[:, None]])
    else:
        v = c / h[:, None]
        accel = np.diff(v, axis=0) / np.minimum(h[1:], h[:-1])[:, None]
    if accel.size:
        worst = _worst(accel, guard.acceleration)
        if worst is not None:
            _, axis, value = worst
            raise TrajectoryRefusedError(
                Refusal.ACCELERATION, f'{JOINT_NAMES[axis]} acceleration '
                f'{_amount(axis, abs(value), 2)} exceeds its limit '
                f'{_amount(axis, float(guard.acceleration[axis]), 2)}')
