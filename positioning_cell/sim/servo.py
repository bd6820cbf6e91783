"""Simulated drives of the three legs: six position servos following setpoint paths, controlled
stops and the following-error monitor. No ROS here.

Velocities in m/s and rad/s, accelerations in m/s² and rad/s², times in s. Every state is a
vector (6,) in ``JOINT_NAMES`` order (:mod:`positioning_cell.sim.axes`).

Servo model per axis (a cascade, as in an industrial drive): a P position loop with velocity
feed-forward from the trajectory, v_cmd = v_ff + K_p (x_sp − x), saturated at ±v_max; a
first-order velocity loop with time constant τ, v̇ = (v_cmd − v) / τ, saturated at ±a_max.
Without saturation the error obeys τ ë + ė + K_p e = τ ẍ_sp: a second-order lag with damping
ζ = 1 / (2 √(K_p τ)), critically damped at K_p τ = 1/4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import InputError
from positioning_cell.parameters import check_fields, group, setting
from positioning_cell.sim.axes import AXES, LINEAR_AXES, per_axis
from positioning_cell.sim.guard import Refusal, TrajectoryRefusedError
from positioning_cell.sim.paths import JointPath, hold_path, stop_path

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Largest number of integration sub-steps in one advance (a longer stall uses longer steps).
MAX_SUBSTEPS = 1000

class MotionRefusedError(TrajectoryRefusedError):
    """The drives refuse a motion command: disabled, in fault, or the trajectory is over."""


@dataclass(frozen=True)
class AxisLimits:
    """Limits of one axis type (``servo.linear`` in m, ``servo.rotary`` in rad)."""

    max_velocity: float = setting(0.05, 'largest speed', 'm/s or rad/s', low=0.0,
                                  low_open=True, high=100.0)
    max_acceleration: float = setting(0.5, 'largest acceleration', 'm/s^2 or rad/s^2',
                                      low=0.0, low_open=True, high=1000.0)
    following_error_limit: float = setting(1e-3, '|setpoint - position| that faults the drive',
                                           'm or rad', low=0.0, low_open=True, high=10.0)
    max_jump: float = setting(1e-4, 'largest step from the current setpoint to the first point '
                              'of a trajectory that starts there', 'm or rad', low=0.0,
                              high=1.0)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class ServoSettings:
    """The six servos (``servo:`` block): limits per axis type, position gain K_p, velocity-loop
    time constant τ and the largest integration step."""

    linear: AxisLimits = group(AxisLimits, 'the leg-length drives, m')
    rotary: AxisLimits = group(AxisLimits, 'the theta drives, rad', default=lambda: AxisLimits(
        max_velocity=0.5, max_acceleration=5.0, following_error_limit=0.01, max_jump=1e-3))
    position_gain: float = setting(25.0, 'K_p of the position loop (K_p tau = 1/4: critical)',
                                   '1/s', low=0.1, high=1000.0)
    velocity_lag: float = setting(0.01, 'tau, velocity-loop time constant', 's', low=1e-4,
                                  high=1.0)
    max_step: float = setting(0.002, 'largest integration step', 's', low=1e-4, high=0.05)

    def __post_init__(self) -> None:
        check_fields(self)

    @cached_property
    def velocity_limits(self) -> FloatArray:
        """v_max (6,), m/s and rad/s."""
        return per_axis(self.linear.max_velocity, self.rotary.max_velocity)

    @cached_property
    def acceleration_limits(self) -> FloatArray:
        """a_max (6,), m/s² and rad/s²."""
        return per_axis(self.linear.max_acceleration, self.rotary.max_acceleration)

    @cached_property
    def following_error_limits(self) -> FloatArray:
        """Following-error limits (6,), m and rad."""
        return per_axis(self.linear.following_error_limit, self.rotary.following_error_limit)

    @cached_property
    def jump_limits(self) -> FloatArray:
        """Largest step to a trajectory's first point (6,), m and rad."""
        return per_axis(self.linear.max_jump, self.rotary.max_jump)


# -- servo dynamics --------------------------------------------------------------------------
class AxisState(NamedTuple):
    """True state of the six axes: position (6,) m / rad, velocity (6,) m/s / rad/s."""

    position: FloatArray
    velocity: FloatArray

def servo_step(state: AxisState, setpoint: FloatArray, feedforward: FloatArray, step: float,
               settings: ServoSettings, stuck: BoolArray | None = None) -> AxisState:
    """Advance the six servos by ``step`` s toward ``setpoint`` (6,) with velocity feed-forward
    ``feedforward`` (6,) (model in the module docstring). The velocity loop is integrated
    exactly over the step, then its change is limited to a_max·step, so |v| never exceeds v_max
    and |Δv/step| never exceeds a_max; the position uses the trapezoid rule. ``stuck`` axes
    (6,) do not move (a jammed drive)."""
    v_max, a_max = settings.velocity_limits, settings.acceleration_limits
    command = np.minimum(np.maximum(
        feedforward + settings.position_gain * (setpoint - state.position), -v_max), v_max)
    lag = 1.0 - math.exp(-step / settings.velocity_lag)
    dv_max = a_max * step
    dv = np.minimum(np.maximum((command - state.velocity) * lag, -dv_max), dv_max)
    velocity = state.velocity + dv
    position = state.position + 0.5 * (state.velocity + velocity) * step
    if stuck is not None and stuck.any():
        velocity = np.where(stuck, 0.0, velocity)
        position = np.where(stuck, state.position, position)
    return AxisState(position, velocity)

@dataclass(frozen=True)
class Fault:
    """A drive fault on axis ``axis`` (JOINT_NAMES order): a following error (the error
    x_sp − x and the limit it exceeded, m or rad), or, with ``encoder_lost``, an encoder that
    stopped giving a signal."""

    axis: int
    error: float = 0.0
    limit: float = 0.0
    encoder_lost: bool = False

    @property
    def name(self) -> str:
        """The joint name of the axis."""
        return JOINT_NAMES[self.axis]

    def message(self) -> str:
        """For people: mm on linear axes, degrees on rotary ones."""
        if self.encoder_lost:
            return f'encoder signal lost on {self.name}'
        if LINEAR_AXES[self.axis]:
            return (f'following error on {self.name}: {self.error * 1e3:.3f} mm exceeds the '
                    f'limit {self.limit * 1e3:.3f} mm')
        return (f'following error on {self.name}: {math.degrees(self.error):.4f} deg exceeds '
                f'the limit {math.degrees(self.limit):.4f} deg')

def following_error_fault(setpoint: FloatArray, position: FloatArray,
                          limits: FloatArray) -> Fault | None:
    """The fault of the axis whose |x_sp − x| (6,) most exceeds its limit (6,), or None."""
    error = setpoint - position
    ratio = np.abs(error) / limits
    axis = int(np.argmax(ratio))
    if ratio[axis] <= 1.0:
        return None
    return Fault(axis, float(error[axis]), float(limits[axis]))

class LegServos:
    """The six drives as one vectorised state machine: follows JointPaths started at absolute
    times (s, any time base shared with :meth:`advance`), stops with controlled deceleration,
    monitors the following error (fault: stop from the actual state, hold), and refuses motion
    while disabled or in fault. ``stuck`` (6,) marks jammed axes (fault injection)."""

    def __init__(self, settings: ServoSettings, position: ArrayLike, time: float = 0.0,
                 *, enabled: bool = True, low: ArrayLike | None = None,
                 high: ArrayLike | None = None) -> None:
        p = np.asarray(position, dtype=float)
        if p.shape != (AXES,) or not np.isfinite(p).all():
            raise InputError(f'initial position: expected {AXES} finite values, got {position!r}')
        self.settings = settings
        self.state = AxisState(p.copy(), np.zeros(AXES))
        self.time = float(time)
        self.enabled = enabled
        self.fault: Fault | None = None
        self.stuck: BoolArray = np.zeros(AXES, dtype=bool)
        self._path, self._start = hold_path(p), self.time
        self._pending: tuple[JointPath, float] | None = None
        #: Soft limits (6,): setpoints are never outside them, whatever the path says.
        self.low = np.full(AXES, -np.inf) if low is None else np.asarray(low, dtype=float)
        self.high = np.full(AXES, np.inf) if high is None else np.asarray(high, dtype=float)

    # -- commands ------------------------------------------------------------------------
    def command(self, path: JointPath, start: float) -> None:
        """Follow ``path`` from absolute time ``start`` (s); it replaces the current motion at
        that time, joining from the current setpoint when its first point is later than 0.
        MotionRefusedError when disabled, in fault, or if the path ends before the current
        time."""
        if not self.enabled:
            raise MotionRefusedError(Refusal.DISABLED,
                                     'drives disabled: trajectory ignored, axes hold')
        if self.fault is not None:
            raise MotionRefusedError(Refusal.FAULT, f'in fault ({self.fault.message()}): '
                                                    're-enable to clear it')
        if start + path.duration < self.time:
            late = self.time - start - path.duration
            raise MotionRefusedError(Refusal.OLD_HEADER_TIMESTAMP,
                                     f'trajectory ended {late:.3f} s ago (start stamp too old)')
        if start <= self.time:
            self._replace(path, start)
        else:
            self._pending = (path, start)

    def stop(self) -> None:
        """Controlled stop from the current setpoint (see :func:`stop_path`), then hold."""
        position, velocity = self.setpoint()
        self._pending = None
        self._path = stop_path(position, velocity, self.settings.acceleration_limits)
        self._start = self.time

    def enable(self, on: bool) -> None:
        """Enable (clears a fault; the axes hold where they are; a no-op when already enabled
        and healthy) or disable (controlled stop, hold; later commands are refused)."""
        if on and (self.fault is not None or not self.enabled):
            self._stop_from_actual()
            self.fault = None
        elif self.enabled:
            self.stop()
        self.enabled = on

    # -- simulation ----------------------------------------------------------------------
    def advance(self, now: float) -> Fault | None:
        """Integrate the servos to ``now`` (s) in steps ≤ max_step, starting a pending path at
        its start time; check the following error at ``now``. Returns a fault that tripped in
        this call (the axes then decelerate from their actual state and hold)."""
        if now <= self.time:
            return None
        while self._pending is not None and self._pending[1] <= now:
            path, start = self._pending
            self._integrate(start)
            self._replace(path, start)
        self._integrate(now)
        if self.fault is not None:
            return None
        self.fault = following_error_fault(self.setpoint()[0], self.state.position,
                                           self.settings.following_error_limits)
        if self.fault is not None:
            self._stop_from_actual()
        return self.fault

    def setpoint(self, time: float | None = None) -> tuple[FloatArray, FloatArray]:
        """Setpoint position and feed-forward velocity (6,) at ``time`` (default: now), held
        within the soft limits."""
        t = self.time if time is None else time
        position, velocity = self._clamped(*self._path.sample(t - self._start))
        return position[0], velocity[0]

    def _clamped(self, position: FloatArray,
                 velocity: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Setpoints (K, 6) held within the soft limits; where one is held, it does not move."""
        held = (position < self.low) | (position > self.high)
        return np.clip(position, self.low, self.high), np.where(held, 0.0, velocity)

    def fail(self, fault: Fault) -> None:
        """A fault found outside the servo loop (an encoder lost): stop from the actual state,
        hold, refuse motion until re-enabled."""
        if self.fault is None:
            self.fault = fault
            self._stop_from_actual()

    @property
    def pending(self) -> tuple[JointPath, float] | None:
        """A path commanded to start later: (path, start time s), or None."""
        return self._pending

    @property
    def following_error(self) -> FloatArray:
        """x_sp − x (6,), m and rad."""
        return self.setpoint()[0] - self.state.position

    @property
    def moving(self) -> bool:
        """The setpoint is still changing or an axis still moves (> 1e-4 v_max)."""
        return self.time < self._start + self._path.duration or not self._at_rest()

    @property
    def mode(self) -> str:
        """'fault', 'disabled', 'moving' or 'holding'."""
        if self.fault is not None:
            return 'fault'
        if not self.enabled:
            return 'disabled'
        return 'moving' if self.moving else 'holding'

    def _replace(self, path: JointPath, start: float) -> None:
        position, velocity = self.setpoint(max(start, self.time))
        self._path, self._start = path.starting_from(position, velocity), start
        self._pending = None

    def _at_rest(self) -> bool:
        return bool((np.abs(self.state.velocity) <= 1e-4 * self.settings.velocity_limits).all())

    def _stop_from_actual(self) -> None:
        self._pending = None
        self._path = (hold_path(self.state.position) if self._at_rest() else
                      stop_path(self.state.position, self.state.velocity,
                                self.settings.acceleration_limits))
        self._start = self.time

    def _integrate(self, until: float) -> None:
        span = until - self.time
        if span <= 0.0:
            return
        n = min(max(math.ceil(span / self.settings.max_step - 1e-9), 1), MAX_SUBSTEPS)
        step = span / n
        setpoints, feedforward = self._clamped(*self._path.sample(
            self.time + step * np.arange(1, n + 1) - self._start))
        state = self.state
        for k in range(n):  # the ODE is sequential; n is 1-3 at the usual physics rates
            state = servo_step(state, setpoints[k], feedforward[k], step, self.settings,
                               self.stuck)
        self.state, self.time = state, until
