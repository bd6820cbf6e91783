"""Jog: one actuator moved by a relative step, outside the kinematics (Symétrie's jog of one
axis). Only the axis's own range is checked (stroke length_min..length_max, second U angle
theta_min..theta_max); the platform pose that results is not, nor the other limits of the
mechanism: a jog is how an operator gets the machine out of where the kinematics cannot
take it. Axes in :data:`positioning_cell.core.mechanism.JOINT_NAMES` order, m and rad."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.core.poses import as_number
from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: The first three axes are leg lengths (m), the last three second-U angles (rad).
LINEAR_AXES = 3


def _amount(axis: int, value: float) -> str:
    if axis < LINEAR_AXES:
        return f'{value * 1e3:.3f} mm'
    return f'{math.degrees(value):.3f} deg'


def _range_text(axis: int, low: float, high: float) -> str:
    if axis < LINEAR_AXES:
        return f'[{low * 1e3:.3f}, {high * 1e3:.3f}] mm'
    return f'[{math.degrees(low):.3f}, {math.degrees(high):.3f}] deg'


def axis_index(axis: str | int) -> int:
    """The index 0..5 of an axis given by name (JOINT_NAMES) or index; InputError otherwise."""
    if isinstance(axis, str):
        if axis in JOINT_NAMES:
            return JOINT_NAMES.index(axis)
    elif isinstance(axis, (int, np.integer)) and not isinstance(axis, bool) \
            and 0 <= axis < len(JOINT_NAMES):
        return int(axis)
    raise InputError(f'jog: unknown axis {axis!r}: one of {", ".join(JOINT_NAMES)} or an index '
                     f'0..{len(JOINT_NAMES) - 1}')


def axis_range(mech: Mechanism, axis: str | int) -> tuple[float, float]:
    """The range (low, high) of an axis, m or rad."""
    k = axis_index(axis)
    if k < LINEAR_AXES:
        return mech.length_min, mech.length_max
    return mech.theta_min, mech.theta_max


def _joints(value: ArrayLike, name: str) -> FloatArray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise InputError(f'{name}: expected 6 numbers, got {value!r}') from err
    if arr.shape != (len(JOINT_NAMES),):
        raise InputError(f'{name}: expected 6 numbers ({", ".join(JOINT_NAMES)}), got shape '
                         f'{arr.shape}')
    if not np.isfinite(arr).all():
        bad = JOINT_NAMES[int(np.flatnonzero(~np.isfinite(arr))[0])]
        raise InputError(f'{name}: {bad} is not finite (NaN or infinite)')
    return arr


def _positive(name: str, value: float, unit: str) -> float:
    number = as_number(value, name)
    if not (math.isfinite(number) and number > 0.0):
        raise InputError(f'{name} = {value!r}: must be a finite number > 0 {unit}')
    return number


def jog_target(mech: Mechanism, joints_now: ArrayLike, axis: str | int, delta: float,
               largest_step_linear: float, largest_step_angular: float) -> FloatArray:
    """The joints (6,) after jogging ``axis`` (name or index) by ``delta`` (m for a length, rad
    for a theta) from ``joints_now`` (6,); the other axes unchanged. A zero step is allowed
    (the same joints). InputError, naming the axis, when the axis is unknown, ``delta`` is not
    finite, |delta| exceeds the largest step of its kind (m / rad, finite > 0) or the
    target lies outside the axis's range (texts in mm / deg)."""
    k = axis_index(axis)
    now = _joints(joints_now, 'joints_now')
    largest = (_positive('largest_step_linear', largest_step_linear, 'm') if k < LINEAR_AXES
               else _positive('largest_step_angular', largest_step_angular, 'rad'))
    name = JOINT_NAMES[k]
    step = as_number(delta, f'jog {name}: step')
    if not math.isfinite(step):
        raise InputError(f'jog {name}: step {step!r} is not finite')
    if abs(step) > largest:
        raise InputError(f'jog {name}: step {_amount(k, step)} exceeds the largest step '
                         f'{_amount(k, largest)}')
    low, high = axis_range(mech, k)
    target = now.copy()
    target[k] = now[k] + step
    if not low <= target[k] <= high:
        raise InputError(f'jog {name}: target {_amount(k, float(target[k]))} outside the range '
                         f'{_range_text(k, low, high)}')
    return target


def jog_trajectory(joints_now: ArrayLike, target: ArrayLike, speed: float,
                   acceleration: float, period: float) -> tuple[FloatArray, FloatArray]:
    """Times (K,) s from 0 and joints (K, 6) of the move from ``joints_now`` to ``target``
    (6,), which differ in one axis at most: a trapezoidal speed profile on that axis (a
    triangular one when the step is too short to reach ``speed``), within ``speed`` (m/s or
    rad/s) and ``acceleration`` (m/s², rad/s²), the other axes held. Points every ``period``
    s, the last one at the end (the last interval between half and one and a half periods,
    or the whole move when shorter); K >= 2: a zero move holds for one period, times
    [0, period]. InputError for non-finite joints, more than one axis moving, or a speed,
    acceleration or period that is not finite and > 0."""
    now = _joints(joints_now, 'joints_now')
    goal = _joints(target, 'target')
    v = _positive('speed', speed, 'm/s or rad/s')
    a = _positive('acceleration', acceleration, 'm/s^2 or rad/s^2')
    dt = _positive('period', period, 's')
    moving = np.flatnonzero(goal != now)
    if moving.size > 1:
        names = ', '.join(JOINT_NAMES[int(i)] for i in moving)
        raise InputError(f'a jog moves one axis; the target moves {names}')
    if moving.size == 0:
        return np.array([0.0, dt]), np.tile(now, (2, 1))
    k = int(moving[0])
    delta = float(goal[k] - now[k])
    distance = abs(delta)
    if v * v / a >= distance:  # triangular: the peak speed is never reached
        peak = math.sqrt(a * distance)
        ramp, cruise = peak / a, 0.0
    else:
        peak, ramp = v, v / a
        cruise = (distance - v * v / a) / v
    total = 2.0 * ramp + cruise
    n = max(round(total / dt), 1)
    times = np.append(np.arange(n) * dt, total)
    t = times
    s = np.where(t < ramp, 0.5 * a * t * t,
                 np.where(t < ramp + cruise, 0.5 * a * ramp * ramp + peak * (t - ramp),
                          distance - 0.5 * a * (total - t) ** 2))
    s = np.clip(s, 0.0, distance)
    joints = np.tile(now, (times.size, 1))
    joints[:, k] = now[k] + math.copysign(1.0, delta) * s
    joints[-1] = goal
    return times, joints
