"""Point-to-point moves: a straight line in position and SLERP in orientation, timed by a
smooth (sinusoidal-acceleration) law within speed and acceleration limits, sampled at a fixed
period, every sample checked against the mechanism's limits and the singularity margin.

The straight line is that of a point of the platform, its ``pivot`` (platform frame; by
default the platform's origin): with the pivot at c and the platform turning by R(s) (SLERP),
the platform's origin is at p(s) = c(s) − R(s)·pivot. A coordinated cell gives every
positioner the same point of the panel as its pivot, so that every platform follows the one
rigid motion of the panel (its point on a straight line, the panel turning about it) instead
of each its own chord (issue 27)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance import ClearanceModel, compensate
from positioning_cell.core.kinematics import _inverse_jacobian
from positioning_cell.core.limits import LimitReport, check_poses
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import (
    as_pose_batch,
    interpolated_pose,
    quaternion_inverse,
    quaternion_product,
    rotate,
    rotation_vector,
    slerp,
)
from positioning_cell.core.vectors import cross
from positioning_cell.errors import InputError
from positioning_cell.mechanics.singularity import check_path
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class MotionLimits:
    """Cartesian limits of a move (the positioner's ``motion:`` block, dynamic)."""

    linear_speed: float = setting(0.01, 'linear speed of a move', 'm/s', low=1e-5, high=1.0,
                                  dynamic=True)
    linear_acceleration: float = setting(0.05, 'linear acceleration of a move', 'm/s^2',
                                         low=1e-5, high=10.0, dynamic=True)
    angular_speed: float = setting(0.1, 'angular speed of a move', 'rad/s', low=1e-5,
                                   high=10.0, dynamic=True)
    angular_acceleration: float = setting(0.5, 'angular acceleration of a move', 'rad/s^2',
                                          low=1e-5, high=100.0, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class Trajectory:
    """A sampled move. times (M,) s from the start; position (M, 3) m; quaternion (M, 4);
    joint commands lengths, thetas (M, 3) m, rad and their rates (M, 3) m/s, rad/s; ``limits``
    is the check of every sample."""

    times: FloatArray
    position: FloatArray
    quaternion: FloatArray
    lengths: FloatArray
    thetas: FloatArray
    length_rates: FloatArray
    theta_rates: FloatArray
    limits: LimitReport

    @property
    def path(self) -> tuple[FloatArray, FloatArray]:
        """The planned poses: positions (M, 3) m, quaternions (M, 4)."""
        return self.position, self.quaternion

    @property
    def duration(self) -> float:
        """Duration of the move, s."""
        return float(self.times[-1])


def pose_at(traj: Trajectory, t: float) -> tuple[FloatArray, FloatArray]:
    """The planned platform pose of ``traj`` at ``t`` s from its start (held at its ends):
    position (3,) m linear between the two samples around ``t``, quaternion (4,) their
    normalised linear blend (:func:`~positioning_cell.core.poses.interpolated_pose`)."""
    return interpolated_pose(traj.times, traj.position, traj.quaternion, t)


def time_law(duration_accel: float, peak: float, total: float,
             times: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Normalised path s(t) ∈ [0, 1] and ṡ(t) for a profile whose speed rises as
    (1 − cos)/2 over ``duration_accel`` to ``peak``, cruises, and falls symmetrically;
    ``total`` is the duration (s)."""
    ta, v = duration_accel, peak
    t = np.clip(times, 0.0, total)
    s = np.empty_like(t)
    sd = np.empty_like(t)
    rise = t < ta
    fall = t > total - ta
    cruise = ~(rise | fall)
    # Rising: ṡ = v (1 − cos(π t/ta))/2, s = v (t − ta/π sin(π t/ta))/2.
    tr = t[rise]
    sd[rise] = 0.5 * v * (1.0 - np.cos(math.pi * tr / ta))
    s[rise] = 0.5 * v * (tr - ta / math.pi * np.sin(math.pi * tr / ta))
    sd[cruise] = v
    s[cruise] = 0.5 * v * ta + v * (t[cruise] - ta)
    tf = total - t[fall]
    sd[fall] = 0.5 * v * (1.0 - np.cos(math.pi * tf / ta))
    s[fall] = 1.0 - 0.5 * v * (tf - ta / math.pi * np.sin(math.pi * tf / ta))
    return s, sd


#: The coordinated time law (a move given a duration): each ramp lasts this share of the
#: duration. One shape for every positioner of a coordinated cell, whatever each travels: the
#: platforms stay in proportion all along, as the rigid panel they hold moves them.
COORDINATED_RAMP_SHARE = 0.25


def plan_profile(distance: float, angle: float, limits: MotionLimits,
                 duration: float = 0.0) -> tuple[float, float, float]:
    """(ramp time, peak ṡ, duration) in s, 1/s, s for a move of ``distance`` m and ``angle`` rad
    keeping both within the speed and acceleration limits. Peak acceleration of the
    sinusoidal ramp is π·v/(2·ta). ``duration`` 0: the fastest such profile. ``duration`` > 0:
    the coordinated time law: ramps of :data:`COORDINATED_RAMP_SHARE` r of the duration T
    each (v = 1/((1 − r)·T), peak acceleration π/(2·r·(1 − r)·T²)), T the duration or, when
    the limits need longer, the least T they allow; the same s(t) for every positioner sent
    the same T (the coordinated cell asks each for its least T, then sends them all the
    longest)."""
    if not (math.isfinite(duration) and duration >= 0.0):
        raise InputError(f'duration = {duration!r}: must be a finite number of seconds >= 0')
    if distance <= 0.0 and angle <= 0.0:
        return 0.0, 0.0, 0.0
    with np.errstate(divide='ignore'):
        v_max = min(limits.linear_speed / distance if distance > 0 else math.inf,
                    limits.angular_speed / angle if angle > 0 else math.inf)
        a_max = min(limits.linear_acceleration / distance if distance > 0 else math.inf,
                    limits.angular_acceleration / angle if angle > 0 else math.inf)
    if duration > 0.0:
        r = COORDINATED_RAMP_SHARE
        least = max(1.0 / ((1.0 - r) * v_max),
                    math.sqrt(math.pi / (2.0 * r * (1.0 - r) * a_max)))
        total = max(duration, least)
        return r * total, 1.0 / ((1.0 - r) * total), total
    v = v_max
    ta = math.pi * v / (2.0 * a_max)
    if v * ta > 1.0:  # no cruise: the ramps alone cover the path, s = v·ta = 1
        v = math.sqrt(2.0 * a_max / math.pi)
        ta = 1.0 / v
    total = 2.0 * ta + (1.0 - v * ta) / v
    return ta, v, total


def cruise(distance: float, angle: float, limits: MotionLimits) -> tuple[float, float, float]:
    """The cruise of a move of ``distance`` m and ``angle`` rad as :func:`plan_move` plans it
    (:func:`plan_profile`): its linear speed (m/s) and the distances (m) along the path where
    the speed reaches its peak and leaves it (equal: the ramps meet, no cruise)."""
    ta, peak, total = plan_profile(distance, angle, limits)
    if total == 0.0:
        return 0.0, 0.0, 0.0
    ramp = min(0.5, 0.5 * peak * ta)  # the share of the path one ramp covers: s(ta) = v·ta/2
    return peak * distance, ramp * distance, (1.0 - ramp) * distance


#: The farthest a move's pivot may be from the platform's origin, m: a point of the panel a
#: positioner holds (a wing panel's few metres), not a number gone wrong.
PIVOT_REACH = 20.0


def checked_pivot(pivot: ArrayLike | None) -> FloatArray:
    """A move's pivot (3,) m in the platform frame (None: the origin); InputError naming a
    pivot that is not three finite numbers within :data:`PIVOT_REACH` m."""
    if pivot is None:
        return np.zeros(3)
    arr = np.array(pivot, dtype=float)  # a copy: not the caller's array
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f'pivot = {np.asarray(pivot).tolist()!r}: expected three finite '
                         'coordinates (m, platform frame)')
    if float(np.linalg.norm(arr)) > PIVOT_REACH:
        raise InputError(f'pivot = {arr.tolist()!r}: {float(np.linalg.norm(arr)):.3g} m from '
                         f'the platform origin, beyond {PIVOT_REACH:g} m')
    return arr


def plan_move(mech: Mechanism, start_position: ArrayLike, start_quaternion: ArrayLike,
              goal_position: ArrayLike, goal_quaternion: ArrayLike, *, period: float,
              limits: MotionLimits | None = None,
              clearance: ClearanceModel = None, duration: float = 0.0,
              pivot: ArrayLike | None = None) -> Trajectory:
    """Sample the move from start to goal every ``period`` s (the last sample is the goal); with
    ``duration`` > 0 on the coordinated time law lasting at least that long
    (:func:`plan_profile`; 0: as fast as ``limits`` allow). A move that would be over within
    one period (a step of femtometres: what round-off leaves of a move to where the platform
    already is) lasts one period, on the coordinated time law: its samples are stamped on
    absolute ROS time, whose float spacing near 1.8e9 s is 0.24 us, so that a shorter move's
    end fell on its start's stamp and its plan was refused as not increasing (the force
    watch's, at the coordinated cell's relaxes).

    The ``pivot`` (3,) m, platform frame (None: the origin) goes on a straight line and the
    platform turns about it on SLERP (module docstring): p(s) = c₀ + s·(c₁ − c₀) − R(s)·pivot,
    c_k = p_k + R_k·pivot. The time law is that of the longest way a point of the platform
    between its origin and the pivot travels: |c₁ − c₀| + angle·|pivot| (at least the origin's
    arc), so that the platform keeps within the linear limits along its arc.

    Joint commands come from :func:`positioning_cell.clearance.compensate` with ``clearance``
    (None: nominal inverse kinematics); joint rates from the inverse Jacobian times the
    platform twist (v = ṡ·(Δc − ω × R(s)·pivot), ω = ṡ·R₀·rotvec). The returned ``limits``
    report covers every sample; callers refuse the move when it is not ok.
    """
    limits = limits or MotionLimits()
    if not (math.isfinite(period) and period > 0.0):
        raise InputError(f'period = {period!r}: must be a finite number of seconds > 0')
    pivot_platform = checked_pivot(pivot)
    p, q = as_pose_batch(np.vstack([np.reshape(start_position, (-1, 3)),
                                    np.reshape(goal_position, (-1, 3))]),
                         np.vstack([np.reshape(start_quaternion, (-1, 4)),
                                    np.reshape(goal_quaternion, (-1, 4))]))
    if p.shape[0] != 2:
        raise InputError('plan_move takes exactly one start and one goal pose')
    ends_c = p + rotate(q, pivot_platform)  # the pivot at the start and at the goal
    delta_c = ends_c[1] - ends_c[0]
    rotvec = rotation_vector(quaternion_product(quaternion_inverse(q[0]), q[1]))
    angle = float(np.linalg.norm(rotvec))
    distance = float(np.linalg.norm(delta_c)) + angle * float(np.linalg.norm(pivot_platform))
    ta, peak, total = plan_profile(distance, angle, limits, duration)
    if 0.0 < total < period:
        ta, peak, total = plan_profile(distance, angle, limits, period)
    n = max(math.ceil(total / period - 1e-9), 1)
    times = np.minimum(np.arange(n + 1) * period, total)
    if total == 0.0:  # already there: hold for one period (times must increase)
        times = np.array([0.0, period])
        s, sd = np.ones(n + 1), np.zeros(n + 1)
    else:
        s, sd = time_law(ta, peak, total, times)
    quaternion = slerp(q[0], q[1], s)
    lever = rotate(quaternion, pivot_platform)  # R(s)·pivot, base frame
    position = ends_c[0] + s[:, None] * delta_c - lever
    position[-1] = p[1]  # the goal exactly, not within rounding of it
    joints = compensate(mech, clearance, position, quaternion)
    # Platform twist in base: ω = ṡ · (R_start · rotvec); v = ṡ · Δc − ω × R(s)·pivot.
    omega_axis = rotate(q[0], rotvec)
    omega = sd[:, None] * omega_axis
    twist = np.hstack([sd[:, None] * delta_c - cross(omega, lever), omega])
    rates = np.einsum('nij,nj->ni', _inverse_jacobian(mech, position, quaternion), twist)
    # Joint, stroke and collision limits, and the singularity margin of the actuation and
    # constraint wrench system (seed 001) along the whole path.
    report = check_poses(mech, position, quaternion).merged(
        check_path(mech, position, quaternion).as_limit_report())
    return Trajectory(times, position, quaternion, joints.lengths, joints.thetas,
                      rates[:, :3], rates[:, 3:], report)
