"""The simulated leg drives (positioning_cell.sim): servo lag and limits, controlled stops,
following-error faults, setpoint paths, encoder quantisation, noise and dropout, injected
faults, the driver's settings. ROS-free."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.moves.trajectory import time_law
from positioning_cell.parameters import parse
from positioning_cell.sim.axes import AXES, LINEAR_AXES
from positioning_cell.sim.drives import DriverSettings
from positioning_cell.sim.encoders import Encoders, EncoderSettings, quantise
from positioning_cell.sim.faults import DriveFaults, axis_mask
from positioning_cell.sim.paths import JointPath, path_from_points, stop_path
from positioning_cell.sim.servo import (
    AxisLimits,
    AxisState,
    LegServos,
    MotionRefusedError,
    ServoSettings,
    following_error_fault,
    servo_step,
)

HOME = np.array([0.2, 0.2, 0.2, 0.0, 0.0, 0.0])
SETTINGS = ServoSettings()
NOISELESS = EncoderSettings(linear_noise=0.0, rotary_noise=0.0)
MOVE = np.array([4e-3, -3e-3, 2e-3, 0.05, -0.02, 0.01])


def smooth_move(start: np.ndarray, delta: np.ndarray, duration: float,
                n: int = 101) -> JointPath:
    """A rest-to-rest move with the library's sinusoidal-acceleration time law."""
    times = np.linspace(0.0, duration, n)
    s, sd = time_law(duration / 3.0, 1.5 / duration, duration, times)
    return JointPath(times, start + s[:, None] * delta, sd[:, None] * delta)


def run(servos: LegServos, until: float, rng: np.random.Generator,
        period: float = 0.004) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advance with jittered periods (as the VM's timers do); times, positions, velocities."""
    times, positions, velocities = [], [], []
    t = servos.time
    while t < until:
        t = min(t + period * rng.uniform(0.5, 4.0), until)
        servos.advance(t)
        times.append(t)
        positions.append(servos.state.position)
        velocities.append(servos.state.velocity)
    return np.array(times), np.array(positions), np.array(velocities)


def test_trajectory_followed_with_lag_but_bounded_error() -> None:
    servos = LegServos(SETTINGS, HOME)
    path = smooth_move(HOME, MOVE, 1.0)
    servos.command(path, start=0.1)
    errors = []
    t = 0.0
    rng = np.random.default_rng(3)
    while t < 1.6:
        t += 0.004 * rng.uniform(0.5, 4.0)
        assert servos.advance(t) is None
        errors.append(servos.following_error)
    peak = np.abs(np.array(errors)).max(axis=0)
    # A real lag on every moving axis, well inside the fault limits.
    assert (peak > 1e-3 * SETTINGS.following_error_limits).all()
    assert (peak < 0.1 * SETTINGS.following_error_limits).all()
    np.testing.assert_allclose(servos.state.position, path.final, atol=1e-9)
    assert servos.mode == 'holding'


def test_step_response_lags_then_settles_without_overshoot() -> None:
    servos = LegServos(SETTINGS, HOME)
    step = per_type(0.5e-3, 5e-3)  # half the following-error limits
    servos.command(JointPath(np.zeros(1), (HOME + step)[None], np.zeros((1, AXES))), 0.0)
    servos.advance(SETTINGS.velocity_lag)
    moved = (servos.state.position - HOME) / step
    assert (moved > 0.0).all() and (moved < 0.5).all()  # it lags
    _, positions, _ = run(servos, 1.0, np.random.default_rng(4))
    overshoot = ((positions - HOME) / step - 1.0).max()
    assert overshoot < 0.01
    np.testing.assert_allclose(servos.state.position, HOME + step, atol=1e-9)


def per_type(linear: float, rotary: float) -> np.ndarray:
    return np.where(LINEAR_AXES, linear, rotary)


def test_velocity_and_acceleration_limits_never_exceeded() -> None:
    rng = np.random.default_rng(5)
    settings = ServoSettings(position_gain=60.0, velocity_lag=0.003)  # aggressive loop
    v_max, a_max = settings.velocity_limits, settings.acceleration_limits
    for _ in range(30):
        state = AxisState(HOME.copy(), rng.uniform(-1.0, 1.0, AXES) * v_max)
        setpoint = HOME + rng.uniform(-1.0, 1.0, AXES) * per_type(0.05, 0.5)
        feedforward = rng.uniform(-2.0, 2.0, AXES) * v_max
        for _ in range(100):
            h = rng.uniform(1e-4, 0.02)
            new = servo_step(state, setpoint, feedforward, h, settings)
            assert (np.abs(new.velocity) <= v_max * (1 + 1e-12)).all()
            assert (np.abs(new.velocity - state.velocity) <= a_max * h * (1 + 1e-12)).all()
            state = new


def test_limits_hold_in_the_simulated_state_during_a_fast_move() -> None:
    # A move that asks for more than the drives can do (no fault: limits raised).
    settings = ServoSettings(AxisLimits(0.01, 0.05, 1.0), AxisLimits(0.1, 0.5, 10.0))
    servos = LegServos(settings, HOME)
    servos.command(smooth_move(HOME, MOVE * 2.0, 0.4), 0.0)
    times, _, velocities = run(servos, 3.0, np.random.default_rng(6))
    assert (np.abs(velocities) <= settings.velocity_limits * (1 + 1e-12)).all()
    assert np.isclose(np.abs(velocities[:, 0]).max(), 0.01)  # it saturates
    accel = np.diff(velocities, axis=0) / np.diff(times)[:, None]
    assert (np.abs(accel) <= settings.acceleration_limits * (1 + 1e-9)).all()


def test_stop_path_distance_is_v2_over_2a_for_the_limiting_axis() -> None:
    v = per_type(0.02, 0.1) * np.array([1.0, -0.5, 0.25, 0.5, -1.0, 0.1])
    a = SETTINGS.acceleration_limits
    path = stop_path(HOME, v, a)
    distance = path.final - HOME
    limiting = int(np.argmax(np.abs(v) / a))
    assert distance[limiting] == pytest.approx(v[limiting] ** 2 / (2 * a[limiting])
                                               * np.sign(v[limiting]), rel=1e-12)
    # All axes stop together (the direction of motion is kept): the others decelerate less
    # and so run on a little further than their own v²/(2a).
    assert path.duration == pytest.approx(abs(v[limiting]) / a[limiting], rel=1e-12)
    np.testing.assert_allclose(distance, v * path.duration / 2, rtol=1e-12)
    assert (np.abs(distance) >= v**2 / (2 * a) * (1 - 1e-12)).all()
    t = np.linspace(0.0, path.duration, 200)
    _, vel = path.sample(t)
    decel = np.abs(np.diff(vel, axis=0) / np.diff(t)[:, None])
    assert (decel <= a * (1 + 1e-9)).all()
    np.testing.assert_allclose(path.sample(path.duration + 1.0)[1], 0.0)


def test_stop_decelerates_the_axes_and_holds_where_they_stopped() -> None:
    servos = LegServos(SETTINGS, HOME)
    v = per_type(0.02, 0.2)
    ramp = JointPath(np.array([0.0, 10.0]), np.vstack([HOME, HOME + 10.0 * v]),
                     np.vstack([v, v]))
    servos.command(ramp, 0.0)
    rng = np.random.default_rng(7)
    run(servos, 0.5, rng)  # cruising
    at_stop, velocity = servos.setpoint()
    np.testing.assert_allclose(velocity, v)
    servos.stop()
    times, _, velocities = run(servos, 1.5, rng)
    a = SETTINGS.acceleration_limits
    expected = v**2 / (2 * a)  # every axis at its limit here (v / a equal per type)
    np.testing.assert_allclose(servos.state.position - at_stop, expected, rtol=1e-6, atol=1e-9)
    accel = np.diff(velocities, axis=0) / np.diff(times)[:, None]
    assert (np.abs(accel) <= a * (1 + 1e-9)).all()
    assert servos.mode == 'holding'


def test_following_error_fault_names_the_axis() -> None:
    limits = SETTINGS.following_error_limits
    position = HOME.copy()
    assert following_error_fault(HOME + 0.9 * limits, position, limits) is None
    setpoint = HOME + 0.5 * limits
    setpoint[4] = HOME[4] - 1.5 * limits[4]
    fault = following_error_fault(setpoint, position, limits)
    assert fault is not None
    assert (fault.axis, fault.name) == (4, 'leg2_theta')
    assert fault.error == pytest.approx(-1.5 * limits[4])
    assert 'leg2_theta' in fault.message() and 'deg' in fault.message()
    setpoint[0] = HOME[0] + 2.0 * limits[0]
    fault = following_error_fault(setpoint, position, limits)
    assert fault is not None and fault.name == 'leg1_length' and 'mm' in fault.message()


def test_stuck_axis_trips_the_fault_stops_and_refuses_until_reenabled() -> None:
    servos = LegServos(SETTINGS, HOME)
    servos.stuck = axis_mask('leg2_length')
    servos.command(smooth_move(HOME, MOVE, 1.0), 0.0)
    rng = np.random.default_rng(8)
    fault = None
    t = 0.0
    while fault is None and t < 1.0:
        t += 0.004
        fault = servos.advance(t)
    assert fault is not None and fault.name == 'leg2_length'
    assert servos.mode == 'fault'
    run(servos, t + 0.5, rng)
    assert not servos.moving
    stopped = servos.state.position
    assert np.abs(stopped - HOME)[1] == 0.0  # the stuck axis never moved
    assert (np.abs(stopped - (HOME + MOVE)) > 1e-4 * np.abs(MOVE)).all()  # short of the goal
    with pytest.raises(MotionRefusedError, match='fault'):
        servos.command(smooth_move(stopped, MOVE, 1.0), servos.time)
    run(servos, t + 1.0, rng)
    np.testing.assert_allclose(servos.state.position, stopped, atol=1e-9)  # holds
    servos.stuck = axis_mask('')
    servos.enable(True)
    assert servos.fault is None and servos.mode == 'holding'
    servos.command(smooth_move(stopped, -MOVE * 0.1, 0.5), servos.time)
    run(servos, servos.time + 1.0, rng)
    np.testing.assert_allclose(servos.state.position, stopped - 0.1 * MOVE, atol=1e-9)


def test_disabled_drives_refuse_motion_and_hold() -> None:
    servos = LegServos(SETTINGS, HOME, enabled=False)
    assert servos.mode == 'disabled'
    with pytest.raises(MotionRefusedError, match='disabled'):
        servos.command(smooth_move(HOME, MOVE, 1.0), 0.0)
    run(servos, 1.0, np.random.default_rng(9))
    np.testing.assert_array_equal(servos.state.position, HOME)
    servos.enable(True)
    servos.command(smooth_move(HOME, MOVE, 0.5), servos.time)
    servos.advance(servos.time + 0.25)
    servos.enable(True)  # already enabled: changes nothing
    assert servos.mode == 'moving' and servos.setpoint()[1].any()
    servos.enable(False)  # disabling mid-move: controlled stop, short of the goal
    run(servos, 2.0, np.random.default_rng(10))
    assert not servos.moving
    assert (np.abs(servos.state.position - HOME) < np.abs(MOVE)).all()


def test_a_future_start_keeps_the_current_motion_until_then() -> None:
    servos = LegServos(SETTINGS, HOME)
    later = smooth_move(HOME, MOVE, 0.5)
    servos.command(later, start=0.3)
    servos.advance(0.29)
    np.testing.assert_array_equal(servos.state.position, HOME)
    run(servos, 1.5, np.random.default_rng(11))
    np.testing.assert_allclose(servos.state.position, HOME + MOVE, atol=1e-9)
    with pytest.raises(MotionRefusedError, match='ago'):
        servos.command(later, start=0.2)  # ended at 0.7 s, now is 1.5 s


def test_a_path_starting_after_zero_joins_from_the_current_setpoint() -> None:
    servos = LegServos(SETTINGS, HOME)
    goal = HOME + 0.1 * MOVE
    servos.command(JointPath(np.array([0.5]), goal[None], np.zeros((1, AXES))), 0.0)
    servos.advance(0.25)
    setpoint, _ = servos.setpoint()
    np.testing.assert_allclose(setpoint, HOME + 0.5 * (goal - HOME))  # halfway, cubic
    run(servos, 1.5, np.random.default_rng(12))
    np.testing.assert_allclose(servos.state.position, goal, atol=1e-9)


def test_path_sampling_hermite_and_linear() -> None:
    times = np.array([0.0, 1.0, 3.0])
    positions = np.outer([0.0, 1.0, 2.0], np.ones(AXES))
    hermite = JointPath(times, positions, np.outer([0.0, 1.0, 0.0], np.ones(AXES)))
    pos, vel = hermite.sample([0.0, 1.0, 3.0, 5.0])
    np.testing.assert_allclose(pos[:, 0], [0.0, 1.0, 2.0, 2.0])
    np.testing.assert_allclose(vel[:, 0], [0.0, 1.0, 0.0, 0.0])
    linear = JointPath(times, positions)
    pos, vel = linear.sample([0.5, 2.0, 4.0])
    np.testing.assert_allclose(pos[:, 0], [0.5, 1.5, 2.0])
    np.testing.assert_allclose(vel[:, 0], [1.0, 0.5, 0.0])
    with pytest.raises(InputError, match='strictly increasing'):
        JointPath(np.array([0.0, 0.0]), positions[:2])


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 12), st.integers(0, 2**32 - 1), st.booleans())
def test_path_sampling_matches_scipy_interpolation(points: int, seed: int,
                                                   hermite: bool) -> None:
    """The numpy sampler is the cubic Hermite (or linear) interpolant scipy.interpolate
    builds, with its derivative, at random times, the knots among them (the segment that
    starts there), before the start and beyond the end (held, zero velocity)."""
    from scipy.interpolate import CubicHermiteSpline, make_interp_spline

    rng = np.random.default_rng(seed)
    times = np.concatenate([[rng.uniform(0.0, 0.5)],
                            rng.uniform(0.01, 0.3, points - 1)]).cumsum()
    positions = rng.normal(0.0, 0.01, (points, AXES))
    velocities = rng.normal(0.0, 0.05, (points, AXES)) if hermite else None
    t = np.concatenate([rng.uniform(times[0], times[-1], 50), times])
    spline = (CubicHermiteSpline(times, positions, velocities, axis=0) if hermite
              else make_interp_spline(times, positions, k=1, axis=0))
    pos, vel = JointPath(times, positions, velocities).sample(t)
    np.testing.assert_allclose(pos, spline(t), rtol=0.0, atol=1e-12)
    last = t == times[-1]
    np.testing.assert_allclose(vel[~last], spline.derivative()(t[~last]), rtol=1e-9,
                               atol=1e-9)
    np.testing.assert_array_equal(vel[last], 0.0)
    pos, vel = JointPath(times, positions, velocities).sample([times[0] - 0.1,
                                                               times[-1] + 1.0])
    np.testing.assert_allclose(pos, positions[[0, -1]], rtol=0.0, atol=1e-12)
    np.testing.assert_array_equal(vel, 0.0)
    # only held times (the driver at rest): the last point, as from the interpolant at its end
    pos, vel = JointPath(times, positions, velocities).sample([times[-1], times[-1] + 2.0])
    np.testing.assert_allclose(pos, spline([times[-1]] * 2), rtol=0.0, atol=1e-12)
    np.testing.assert_array_equal(vel, 0.0)


def test_path_from_points_reorders_names_and_refuses_bad_trajectories() -> None:
    names = list(reversed(JOINT_NAMES))
    rows = [HOME[::-1], (HOME + 0.01 * MOVE)[::-1]]
    path = path_from_points(names, [0.0, 1.0], rows, [[0.0] * AXES, [0.0] * AXES],
                            SETTINGS.velocity_limits)
    np.testing.assert_allclose(path.final, HOME + 0.01 * MOVE)
    assert path_from_points(JOINT_NAMES, [0.0], [HOME], [[]]).velocities is None
    bad = {
        'unknown joint names': (['leg9_length', *JOINT_NAMES[1:]], [0.0], [HOME], [[]]),
        'duplicate': ([*JOINT_NAMES[:5], 'leg1_length'], [0.0], [HOME], [[]]),
        'missing': (JOINT_NAMES[:5], [0.0], [HOME[:5]], [[]]),
        'point 1 has 5 positions': (JOINT_NAMES, [0.0, 1.0], [HOME, HOME[:5]], [[], []]),
        'every point or none': (JOINT_NAMES, [0.0, 1.0], [HOME, HOME], [[], [0.0] * 6]),
        'strictly increasing': (JOINT_NAMES, [1.0, 1.0], [HOME, HOME], [[], []]),
        'leg1_length speed': (JOINT_NAMES, [0.0, 0.01], [HOME, HOME + 0.01], [[], []]),
        'at least one point': (JOINT_NAMES, [], [], []),
    }
    for reason, args in bad.items():
        with pytest.raises(InputError, match=reason):
            path_from_points(*args, SETTINGS.velocity_limits)


def test_quantisation_to_the_resolution() -> None:
    settings = NOISELESS
    assert settings.resolution[0] == 1e-6
    assert settings.resolution[3] == pytest.approx(2 * math.pi / 2**20)
    encoders = Encoders(settings, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for _ in range(200):
        truth = HOME + rng.uniform(-1.0, 1.0, AXES) * per_type(0.02, 0.7)
        reading = encoders.read(AxisState(truth, np.zeros(AXES)))
        counts = reading.position / settings.resolution
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
        assert (np.abs(reading.position - truth) <= settings.resolution / 2 * (1 + 1e-9)).all()
    np.testing.assert_allclose(quantise([1.4e-6, -2.6e-6], 1e-6), [1e-6, -3e-6])


def test_encoder_noise_statistics_and_seeded_repeatability() -> None:
    settings = EncoderSettings(linear_noise=5e-6, rotary_noise=3e-5)
    truth = AxisState(HOME + per_type(0.3e-6, 2e-6), np.zeros(AXES))
    n = 4000

    def errors(seed: int, scale: float = 1.0) -> np.ndarray:
        encoders = Encoders(settings, np.random.default_rng(seed))
        return np.array([encoders.read(truth, noise_scale=scale).position
                         for _ in range(n)]) - truth.position

    e = errors(42)
    sigma = np.sqrt(settings.noise**2 + settings.resolution**2 / 12)  # noise + quantisation
    assert (np.abs(e.mean(axis=0)) < 4 * sigma / math.sqrt(n)).all()
    np.testing.assert_allclose(e.std(axis=0), sigma, rtol=0.06)
    np.testing.assert_array_equal(errors(42), e)  # same seed, same readings
    np.testing.assert_allclose(errors(43, scale=10.0).std(axis=0), 10 * settings.noise,
                               rtol=0.06)


def test_encoder_dropout_freezes_or_goes_missing() -> None:
    encoders = Encoders(NOISELESS, np.random.default_rng(0))
    dropout = axis_mask('leg1_length, 4')
    first = encoders.read(AxisState(HOME, np.zeros(AXES)))
    moved = AxisState(HOME + 0.01, np.full(AXES, 0.001))
    frozen = encoders.read(moved, dropout=dropout)
    np.testing.assert_array_equal(frozen.position[dropout], first.position[dropout])
    np.testing.assert_array_equal(frozen.velocity[dropout], 0.0)
    half_count = encoders.settings.resolution / 2 * (1 + 1e-9)
    assert (np.abs(frozen.position - moved.position)[~dropout] <= half_count[~dropout]).all()
    gone = encoders.read(moved, dropout=dropout, missing=True)
    assert np.isnan(gone.position[dropout]).all() and np.isfinite(gone.position[~dropout]).all()
    back = encoders.read(moved)
    assert (np.abs(back.position - moved.position) <= half_count).all()


def test_fault_parameters_are_validated() -> None:
    np.testing.assert_array_equal(axis_mask('leg2_theta, 0'), [1, 0, 0, 0, 1, 0])
    assert not axis_mask('').any()
    with pytest.raises(ConfigError, match='leg7_theta'):
        axis_mask('leg7_theta')
    with pytest.raises(ConfigError, match='6'):
        axis_mask('6')
    faults = DriveFaults(encoder_dropout='1', encoder_dropout_mode='missing',
                         stuck_axis='leg3_theta')
    assert faults.missing and faults.dropout[1] and faults.stuck[5]
    quiet = {'encoder.linear_noise': 0.0, 'encoder.rotary_noise': 0.0}
    for key, value, reason in [
            ('fault.encoder_dropout_mode', 'drop', "fault.encoder_dropout_mode = 'drop': expected "
                                                   'one of freeze, missing'),
            ('fault.encoder_dropout', 'leg7_theta', "fault.encoder_dropout = 'leg7_theta': "
                                                    "'leg7_theta' is neither a joint name"),
            ('fault.noise_burst', [0.5, 1.0], 'scale >= 1'),
            ('fault.noise_burst', [2.0], 'fault.noise_burst = [2.0]: expected 2 numbers'),
            ('fault.noise_burst', [5.0, 1.0], 'the encoders have no noise to scale')]:
        with pytest.raises(ConfigError, match=re.escape(reason)):
            parse(DriverSettings, {**quiet, key: value})
    burst = DriveFaults(noise_burst=(5.0, 2.0))
    assert (burst.noise_scale(1.0), burst.noise_scale(2.5), burst.noise_scale(-1.0)) == (
        5.0, 1.0, 1.0)


def test_driver_settings_from_parameters_and_their_validation() -> None:
    values = {'servo.linear.max_velocity': 0.05, 'servo.linear.max_acceleration': 0.5,
              'servo.linear.following_error_limit': 1e-3, 'servo.rotary.max_velocity': 0.5,
              'servo.rotary.max_acceleration': 5.0, 'servo.rotary.following_error_limit': 0.01,
              'servo.position_gain': 25.0, 'servo.velocity_lag': 0.01, 'servo.max_step': 0.002,
              'encoder.linear_resolution': 1e-6, 'encoder.rotary_counts_per_rev': 2**20}
    settings = parse(DriverSettings, values)
    assert settings.servo == ServoSettings() and settings.encoder == EncoderSettings()
    assert settings.publish_rate == settings.physics_rate / settings.publish_every
    with pytest.raises(ConfigError, match=r'servo.rotary.following_error_limit = 0.0: must be'):
        parse(DriverSettings, {**values, 'servo.rotary.following_error_limit': 0.0})
    with pytest.raises(ConfigError, match=r'encoder.rotary_counts_per_rev = 2.5: expected an '
                                          r'integer'):
        parse(DriverSettings, {**values, 'encoder.rotary_counts_per_rev': 2.5})
