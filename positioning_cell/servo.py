"""Simulated drives of the three legs: six position servos, the trajectory sampler, controlled
stops, the following-error monitor and the encoder model. No ROS here.

Axes in ``mechanism.JOINT_NAMES`` order (design/kinematics.md): three linear leg drives
l_1..l_3 (m) and three rotary drives θ_1..θ_3 on the second U axes (rad). Velocities in m/s and
rad/s, accelerations in m/s² and rad/s², times in s. Every state is a vector (6,).

Servo model per axis (a cascade, as in an industrial drive): a P position loop with velocity
feed-forward from the trajectory, v_cmd = v_ff + K_p (x_sp − x), saturated at ±v_max; a
first-order velocity loop with time constant τ, v̇ = (v_cmd − v) / τ, saturated at ±a_max.
Without saturation the error obeys τ ë + ė + K_p e = τ ẍ_sp: a second-order lag with damping
ζ = 1 / (2 √(K_p τ)), critically damped at K_p τ = 1/4.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicHermiteSpline, make_interp_spline

from positioning_cell.errors import ConfigError, InputError, PositioningError
from positioning_cell.mechanism import JOINT_NAMES

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

AXES = len(JOINT_NAMES)
#: True for the linear axes (m), False for the rotary ones (rad), in JOINT_NAMES order.
LINEAR_AXES: BoolArray = np.array([name.endswith('_length') for name in JOINT_NAMES])
#: Largest number of integration sub-steps in one advance (a longer stall uses longer steps).
MAX_SUBSTEPS = 1000


class MotionRefusedError(PositioningError):
    """The drives refuse a motion command: disabled, in fault, or the trajectory is over."""


# -- settings --------------------------------------------------------------------------------
def _positive(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
        raise ConfigError(f'{owner}.{name} = {value!r}: must be a finite number > 0')


@dataclass(frozen=True)
class AxisLimits:
    """Limits of one axis type: ``velocity`` (m/s or rad/s), ``acceleration`` (m/s² or rad/s²)
    and the ``following_error`` limit |x_sp − x| (m or rad)."""

    velocity: float
    acceleration: float
    following_error: float

    def __post_init__(self) -> None:
        for name in ('velocity', 'acceleration', 'following_error'):
            _positive('limits', name, getattr(self, name))


def per_axis(linear: float, rotary: float) -> FloatArray:
    """A (6,) vector holding ``linear`` on the length axes and ``rotary`` on the θ axes."""
    return np.where(LINEAR_AXES, float(linear), float(rotary))


@dataclass(frozen=True)
class ServoSettings:
    """The six servos: limits per axis type, position gain K_p (1/s), velocity-loop time
    constant τ (s) and the largest integration step (s)."""

    linear: AxisLimits = AxisLimits(velocity=0.05, acceleration=0.5, following_error=1e-3)
    rotary: AxisLimits = AxisLimits(velocity=0.5, acceleration=5.0, following_error=0.01)
    position_gain: float = 25.0
    velocity_lag: float = 0.01
    max_step: float = 0.002

    def __post_init__(self) -> None:
        for name in ('position_gain', 'velocity_lag', 'max_step'):
            _positive('servo', name, getattr(self, name))

    @cached_property
    def velocity_limits(self) -> FloatArray:
        """v_max (6,), m/s and rad/s."""
        return per_axis(self.linear.velocity, self.rotary.velocity)

    @cached_property
    def acceleration_limits(self) -> FloatArray:
        """a_max (6,), m/s² and rad/s²."""
        return per_axis(self.linear.acceleration, self.rotary.acceleration)

    @cached_property
    def following_error_limits(self) -> FloatArray:
        """Following-error limits (6,), m and rad."""
        return per_axis(self.linear.following_error, self.rotary.following_error)


@dataclass(frozen=True)
class EncoderSettings:
    """Encoders: linear resolution (m per count), rotary counts per revolution, and the
    standard deviations of their Gaussian noise, linear (m) and rotary (rad)."""

    linear_resolution: float = 1e-6
    rotary_counts: int = 2**20
    linear_noise: float = 0.0
    rotary_noise: float = 0.0

    def __post_init__(self) -> None:
        _positive('encoder', 'linear_resolution', self.linear_resolution)
        _positive('encoder', 'rotary_counts', self.rotary_counts)
        for name in ('linear_noise', 'rotary_noise'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f'encoder.{name} = {value!r}: must be a finite number >= 0')

    @cached_property
    def resolution(self) -> FloatArray:
        """One count (6,): m on the length axes, 2π / counts rad on the θ axes."""
        return per_axis(self.linear_resolution, 2.0 * math.pi / self.rotary_counts)

    @cached_property
    def noise(self) -> FloatArray:
        """Noise standard deviation (6,), m and rad."""
        return per_axis(self.linear_noise, self.rotary_noise)


def settings_from_params(values: Mapping[str, Any]) -> tuple[ServoSettings, EncoderSettings]:
    """Servo and encoder settings from the flat ``leg_driver`` parameters (config/cell.yaml):
    ``servo.*``, ``linear.*``, ``rotary.*``, ``encoder.*``. ConfigError names a bad value."""
    def limits(kind: str) -> AxisLimits:
        return AxisLimits(float(values[f'{kind}.max_velocity']),
                          float(values[f'{kind}.max_acceleration']),
                          float(values[f'{kind}.following_error_limit']))

    try:
        servo = ServoSettings(limits('linear'), limits('rotary'),
                              float(values['servo.position_gain']),
                              float(values['servo.velocity_lag']),
                              float(values['servo.max_step']))
        encoder = EncoderSettings(float(values['encoder.linear_resolution']),
                                  int(values['encoder.rotary_counts_per_rev']),
                                  float(values['encoder.linear_noise']),
                                  float(values['encoder.rotary_noise']))
    except KeyError as err:
        raise ConfigError(f'leg_driver parameter {err} is missing') from err
    return servo, encoder


# -- setpoint paths --------------------------------------------------------------------------
@dataclass(frozen=True)
class JointPath:
    """Setpoints of the six axes: points at ``times`` (M,) s from the path's start (finite,
    ≥ 0, strictly increasing), ``positions`` (M, 6) in m / rad and ``velocities`` (M, 6) in
    m/s / rad/s, or None for linear interpolation. Between points the setpoint is the cubic
    Hermite interpolant of positions and velocities (or linear); before the first point it is
    the first point, after the last one it holds the last position with zero velocity."""

    times: FloatArray
    positions: FloatArray
    velocities: FloatArray | None = None

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=float)
        if times.ndim != 1 or times.size == 0 or not np.isfinite(times).all():
            raise InputError(f'times: expected M >= 1 finite values, got {self.times!r}')
        if times[0] < 0.0 or (np.diff(times) <= 0.0).any():
            raise InputError(f'times must be >= 0 and strictly increasing, got {times.tolist()}')
        object.__setattr__(self, 'times', times)
        for name in ('positions', 'velocities'):
            value = getattr(self, name)
            if value is None:
                continue
            arr = np.asarray(value, dtype=float)
            if arr.shape != (times.size, AXES) or not np.isfinite(arr).all():
                raise InputError(f'{name}: expected {times.size} finite rows of {AXES}, '
                                 f'got shape {arr.shape}')
            object.__setattr__(self, name, arr)

    @property
    def duration(self) -> float:
        """Time of the last point, s."""
        return float(self.times[-1])

    @property
    def final(self) -> FloatArray:
        """The last point's positions (6,)."""
        final: FloatArray = self.positions[-1]
        return final

    @cached_property
    def _splines(self) -> tuple[Any, Any]:
        """The interpolant and its derivative (built once, on first use)."""
        if self.velocities is not None:
            spline = CubicHermiteSpline(self.times, self.positions, self.velocities, axis=0)
        else:
            spline = make_interp_spline(self.times, self.positions, k=1, axis=0)
        return spline, spline.derivative()

    def sample(self, t: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Setpoint positions and feed-forward velocities (K, 6) at times ``t`` (K,) s from
        the path's start."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if self.times.size == 1:
            return np.tile(self.positions[0], (t.size, 1)), np.zeros((t.size, AXES))
        spline, derivative = self._splines
        clipped = np.clip(t, self.times[0], self.times[-1])
        position: FloatArray = spline(clipped)
        velocity: FloatArray = derivative(clipped)
        velocity[(t < self.times[0]) | (t >= self.times[-1])] = 0.0
        return position, velocity

    def starting_from(self, position: FloatArray, velocity: FloatArray) -> JointPath:
        """This path with the point (``position``, ``velocity``) put at t = 0 when its first
        point is later (how a new trajectory joins the current motion)."""
        if self.times[0] == 0.0:
            return self
        velocities = (None if self.velocities is None
                      else np.vstack([velocity, self.velocities]))
        return JointPath(np.concatenate([[0.0], self.times]),
                         np.vstack([position, self.positions]), velocities)


def hold_path(position: ArrayLike) -> JointPath:
    """A path that holds ``position`` (6,)."""
    return JointPath(np.zeros(1), np.reshape(np.asarray(position, dtype=float), (1, AXES)),
                     np.zeros((1, AXES)))


def stop_path(position: ArrayLike, velocity: ArrayLike, acceleration: ArrayLike) -> JointPath:
    """Controlled stop from (``position``, ``velocity``) (6,): all axes decelerate uniformly and
    stop together after T = max_i |v_i| / a_i, so no axis exceeds its deceleration a_i (6,) and
    the joint-space direction of motion is kept. The axis that sets T stops after v²/(2a), the
    others after v_i T / 2 (≥ v_i²/(2 a_i)). The setpoint is quadratic in t (the cubic Hermite
    of the two points is exactly that quadratic)."""
    p = np.asarray(position, dtype=float)
    v = np.asarray(velocity, dtype=float)
    stop_time = float(np.max(np.abs(v) / np.asarray(acceleration, dtype=float)))
    if stop_time <= 0.0:
        return hold_path(p)
    return JointPath(np.array([0.0, stop_time]), np.vstack([p, p + 0.5 * v * stop_time]),
                     np.vstack([v, np.zeros(AXES)]))


def path_from_points(names: Sequence[str], times: Sequence[float],
                     positions: Sequence[Sequence[float]],
                     velocities: Sequence[Sequence[float]],
                     settings: ServoSettings | None = None) -> JointPath:
    """A JointPath from trajectory points (trajectory_msgs/JointTrajectory): ``names`` the six
    JOINT_NAMES in any order; per point k its time_from_start ``times[k]`` (s), ``positions[k]``
    and ``velocities[k]`` (one value per name; velocities empty on every point = linear
    interpolation). Columns are reordered to JOINT_NAMES. With ``settings``, point velocities
    and mean segment velocities above v_max are refused. Raises InputError naming the problem.
    """
    names = list(names)
    unknown = sorted(set(names) - set(JOINT_NAMES))
    if unknown:
        raise InputError(f'unknown joint names {unknown}; expected {list(JOINT_NAMES)}')
    if len(set(names)) != len(names):
        raise InputError(f'duplicate joint names in {names}')
    missing = [n for n in JOINT_NAMES if n not in names]
    if missing:
        raise InputError(f'joint names {missing} missing; all six axes are commanded together')
    if len(times) == 0:
        raise InputError('a trajectory needs at least one point (an empty one stops)')
    for k, row in enumerate(positions):
        if len(row) != AXES:
            raise InputError(f'point {k} has {len(row)} positions, expected {AXES}')
    given = [len(row) for row in velocities]
    if any(n not in (0, AXES) for n in given) or 0 < given.count(AXES) < len(given):
        raise InputError(f'velocities: give {AXES} on every point or none, got counts {given}')
    order = [names.index(n) for n in JOINT_NAMES]
    pos = np.asarray(positions, dtype=float)[:, order]
    vel = np.asarray(velocities, dtype=float)[:, order] if given and given[0] else None
    path = JointPath(np.asarray(times, dtype=float), pos, vel)
    if settings is not None:
        _check_speeds(path, settings.velocity_limits)
    return path


def _check_speeds(path: JointPath, v_max: FloatArray) -> None:
    speeds = np.abs(np.diff(path.positions, axis=0) / np.diff(path.times)[:, None])
    if path.velocities is not None:
        speeds = np.vstack([speeds, np.abs(path.velocities)])
    over = speeds > v_max * (1.0 + 1e-9)
    if over.any():
        axis = int(np.flatnonzero(over.any(axis=0))[0])
        unit = 'm/s' if LINEAR_AXES[axis] else 'rad/s'
        raise InputError(f'{JOINT_NAMES[axis]} speed {speeds[:, axis].max():.6g} {unit} '
                         f'exceeds its limit {v_max[axis]:.6g} {unit}')


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
    """A following-error fault: axis index (JOINT_NAMES order), the error x_sp − x and the
    limit it exceeded (m or rad)."""

    axis: int
    error: float
    limit: float

    @property
    def name(self) -> str:
        """The joint name of the axis."""
        return JOINT_NAMES[self.axis]

    def message(self) -> str:
        """For people: mm on linear axes, degrees on rotary ones."""
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
                 *, enabled: bool = True) -> None:
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

    # -- commands ------------------------------------------------------------------------
    def command(self, path: JointPath, start: float) -> None:
        """Follow ``path`` from absolute time ``start`` (s); it replaces the current motion at
        that time, joining from the current setpoint when its first point is later than 0.
        MotionRefusedError when disabled, in fault, or if the path ends before the current
        time."""
        if not self.enabled:
            raise MotionRefusedError('drives disabled: trajectory ignored, axes hold')
        if self.fault is not None:
            raise MotionRefusedError(f'in fault ({self.fault.message()}): re-enable to clear it')
        if start + path.duration < self.time:
            late = self.time - start - path.duration
            raise MotionRefusedError(f'trajectory ended {late:.3f} s ago (start stamp too old)')
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
        """Setpoint position and feed-forward velocity (6,) at ``time`` (default: now)."""
        t = self.time if time is None else time
        position, velocity = self._path.sample(t - self._start)
        return position[0], velocity[0]

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
        setpoints, feedforward = self._path.sample(self.time + step * np.arange(1, n + 1)
                                                   - self._start)
        state = self.state
        for k in range(n):  # the ODE is sequential; n is 1-3 at the usual physics rates
            state = servo_step(state, setpoints[k], feedforward[k], step, self.settings,
                               self.stuck)
        self.state, self.time = state, until


# -- encoders --------------------------------------------------------------------------------
def quantise(values: ArrayLike, resolution: ArrayLike) -> FloatArray:
    """``values`` rounded to whole counts of ``resolution`` (broadcast), same units."""
    res = np.asarray(resolution, dtype=float)
    counts = np.round(np.asarray(values, dtype=float) / res)
    result: FloatArray = counts * res
    return result


class EncoderReading(NamedTuple):
    """What the drives report: position (6,) quantised, velocity (6,) from the drives'
    velocity observer; frozen values on axes whose encoder dropped out, NaN if missing."""

    position: FloatArray
    velocity: FloatArray


class Encoders:
    """The six encoders: Gaussian noise (σ per axis, times a burst scale) added to the true
    position, then quantisation to the resolution. A dropped-out encoder repeats its last
    reading with zero velocity ('freeze', as a stalled count would) or reads NaN ('missing').
    Randomness only from the injected ``rng``."""

    def __init__(self, settings: EncoderSettings, rng: np.random.Generator) -> None:
        self.settings = settings
        self._rng = rng
        self._last: FloatArray | None = None

    def read(self, state: AxisState, *, dropout: BoolArray | None = None,
             missing: bool = False, noise_scale: float = 1.0) -> EncoderReading:
        """One reading of the true ``state``; ``dropout`` (6,) marks failed encoders."""
        noise = self._rng.standard_normal(AXES) * (self.settings.noise * noise_scale)
        position = quantise(state.position + noise, self.settings.resolution)
        velocity = state.velocity.copy()
        if dropout is not None and dropout.any():
            last = self._last if self._last is not None else position
            position = np.where(dropout, last, position)
            velocity[dropout] = 0.0
        self._last = position
        if missing and dropout is not None:
            position = np.where(dropout, np.nan, position)
            velocity[dropout] = np.nan
        return EncoderReading(position, velocity)


# -- fault injection -------------------------------------------------------------------------
def axis_mask(spec: str, what: str = 'axes') -> BoolArray:
    """Axes named in ``spec``: joint names or 0-based indices (JOINT_NAMES order) separated by
    commas or spaces, '' for none. ConfigError names an unknown entry."""
    mask = np.zeros(AXES, dtype=bool)
    for token in spec.replace(',', ' ').split():
        if token in JOINT_NAMES:
            mask[JOINT_NAMES.index(token)] = True
        elif token.isdigit() and int(token) < AXES:
            mask[int(token)] = True
        else:
            raise ConfigError(f'{what}: {token!r} is neither a joint name {list(JOINT_NAMES)} '
                              f'nor an axis index 0-{AXES - 1}')
    return mask


@dataclass(frozen=True)
class FaultInjection:
    """Injected faults: ``dropout`` (6,) encoders that freeze (or read NaN if ``missing``),
    ``stuck`` (6,) jammed axes, and a noise burst: encoder σ times ``burst_scale`` for
    ``burst_duration`` s after it was set."""

    dropout: BoolArray
    missing: bool
    stuck: BoolArray
    burst_scale: float = 1.0
    burst_duration: float = 0.0

    @classmethod
    def from_params(cls, values: Mapping[str, Any],
                    encoder: EncoderSettings | None = None) -> FaultInjection:
        """From the ``fault.*`` parameters: ``encoder_dropout`` and ``stuck_axis`` (names or
        indices, see :func:`axis_mask`), ``encoder_dropout_mode`` ('freeze' or 'missing'),
        ``noise_burst`` [scale ≥ 1, duration s ≥ 0]. A burst on encoders without noise
        (``encoder``) is refused as it would do nothing."""
        mode = values.get('fault.encoder_dropout_mode', 'freeze')
        if mode not in ('freeze', 'missing'):
            raise ConfigError(f'fault.encoder_dropout_mode = {mode!r}: expected freeze or missing')
        burst = list(values.get('fault.noise_burst', [1.0, 0.0]))
        if (len(burst) != 2 or not all(math.isfinite(float(b)) for b in burst)
                or burst[0] < 1.0 or burst[1] < 0.0):
            raise ConfigError(f'fault.noise_burst = {burst!r}: expected [scale >= 1, '
                              'duration s >= 0]')
        if burst[1] > 0.0 and burst[0] > 1.0 and encoder is not None and not encoder.noise.any():
            raise ConfigError('fault.noise_burst: the encoders have no noise to scale '
                              '(encoder.linear_noise = encoder.rotary_noise = 0)')
        return cls(axis_mask(str(values.get('fault.encoder_dropout', '')),
                             'fault.encoder_dropout'),
                   mode == 'missing',
                   axis_mask(str(values.get('fault.stuck_axis', '')), 'fault.stuck_axis'),
                   float(burst[0]), float(burst[1]))

    def noise_scale(self, since_burst: float) -> float:
        """Noise σ scale ``since_burst`` s after the burst was set."""
        return self.burst_scale if 0.0 <= since_burst < self.burst_duration else 1.0
