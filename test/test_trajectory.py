"""Moves: exact end points, straight line and SLERP, within speed and acceleration limits,
joint rates consistent with the joint commands, every sample checked."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp
from workspace import MECH

from positioning_cell import clearance as cl
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.moves.trajectory import MotionLimits, plan_move, pose_at
from positioning_cell.parameters import parse
from positioning_cell.sim.drives import DriverSettings, LegDriver

LIMITS = MotionLimits(linear_speed=0.01, linear_acceleration=0.05, angular_speed=0.1,
                      angular_acceleration=0.5)
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def goal(dp: list[float], rv: list[float]) -> tuple[np.ndarray, np.ndarray]:
    return MECH.home_position + dp, Rotation.from_rotvec(rv).as_quat()


@pytest.mark.parametrize(('dp', 'rv'), [
    ([0.005, 0.0, 0.0], [0.0, 0.0, 0.0]),      # short: no cruise phase
    ([0.0, 0.0, 0.012], [0.0, 0.0, 0.0]),      # long: cruises at the speed limit
    ([0.0, 0.0, 0.0], [0.05, -0.02, 0.03]),    # rotation only
    ([0.003, -0.004, 0.002], [0.02, 0.0, -0.04]),
])
def test_move_respects_limits_and_ends_on_goal(dp: list[float], rv: list[float]) -> None:
    period = 0.002
    p_goal, q_goal = goal(dp, rv)
    traj = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=period,
                     limits=LIMITS)
    assert traj.limits.ok
    np.testing.assert_allclose(traj.position[0], MECH.home_position, atol=1e-15)
    np.testing.assert_allclose(traj.position[-1], p_goal, atol=1e-15)
    rot_end = Rotation.from_quat(traj.quaternion[-1]) * Rotation.from_quat(q_goal).inv()
    assert rot_end.magnitude() < 1e-12
    assert np.all(np.diff(traj.times) > 0) and np.diff(traj.times).max() <= period + 1e-12
    # Straight line: every sample lies on the segment start → goal.
    d = np.asarray(dp)
    if np.linalg.norm(d) > 0:
        rel = traj.position - MECH.home_position
        along = rel @ d / (d @ d)
        np.testing.assert_allclose(rel, along[:, None] * d, atol=1e-15)
        assert np.all(np.diff(along) >= -1e-15)
    # Speeds and accelerations by finite differences of the samples.
    dt = np.diff(traj.times)
    v = np.linalg.norm(np.diff(traj.position, axis=0), axis=1) / dt
    w = (Rotation.from_quat(traj.quaternion[1:]) *
         Rotation.from_quat(traj.quaternion[:-1]).inv()).magnitude() / dt
    assert v.max() <= LIMITS.linear_speed * (1 + 1e-6)
    assert w.max() <= LIMITS.angular_speed * (1 + 1e-6)
    inner = slice(0, -1)  # the last interval may be shorter than the period
    a = np.abs(np.diff(v[inner])) / dt[1:-1]
    alpha = np.abs(np.diff(w[inner])) / dt[1:-1]
    assert a.max() <= LIMITS.linear_acceleration * 1.01
    assert alpha.max() <= LIMITS.angular_acceleration * 1.01
    # One of the two limits is reached (the profile is not needlessly slow).
    reached = max(v.max() / LIMITS.linear_speed, w.max() / LIMITS.angular_speed,
                  a.max() / LIMITS.linear_acceleration,
                  alpha.max() / LIMITS.angular_acceleration)
    assert reached > 0.95
    # The profile starts and ends at rest.
    assert np.abs(traj.length_rates[[0, -1]]).max() < 1e-12
    assert np.abs(traj.theta_rates[[0, -1]]).max() < 1e-12


@pytest.mark.parametrize(('dp', 'rv'), [
    ([0.005, 0.0, 0.0], [0.0, 0.0, 0.0]),
    ([0.003, -0.004, 0.002], [0.02, 0.0, -0.04]),
])
def test_the_coordinated_time_law_is_one_shape_within_the_limits(dp: list[float],
                                                                 rv: list[float]) -> None:
    """A duration asks for the coordinated law: ramps a quarter of it each, so that two
    moves of different lengths sent one duration stay in proportion all along (a panel
    turned: its platforms travel different distances); asked for less than its limits allow,
    a move takes the least duration they do, and keeps within them (finite differences)."""
    period = 0.002
    p_goal, q_goal = goal(dp, rv)
    fastest = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=period,
                        limits=LIMITS, duration=1e-6)
    assert fastest.limits.ok
    free = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=period,
                     limits=LIMITS)
    assert free.duration <= fastest.duration <= 1.5 * free.duration  # the fixed shape's cost
    dt = np.diff(fastest.times)
    v = np.linalg.norm(np.diff(fastest.position, axis=0), axis=1) / dt
    w = (Rotation.from_quat(fastest.quaternion[1:])
         * Rotation.from_quat(fastest.quaternion[:-1]).inv()).magnitude() / dt
    assert v.max() <= LIMITS.linear_speed * (1 + 1e-6)
    assert w.max() <= LIMITS.angular_speed * (1 + 1e-6)
    a = np.abs(np.diff(v[:-1])) / dt[1:-1]
    assert a.max() <= LIMITS.linear_acceleration * 1.01
    # A longer duration: the same shape, longer; a move 0.7 times as long, the same s(t).
    longer = 1.7 * fastest.duration
    slow = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=period,
                     limits=LIMITS, duration=longer)
    assert slow.duration == pytest.approx(longer, rel=1e-12)
    p_short = MECH.home_position + 0.7 * np.asarray(dp)
    q_short = Rotation.from_rotvec(0.7 * np.asarray(rv)).as_quat()
    short = plan_move(MECH, MECH.home_position, IDENTITY, p_short, q_short, period=period,
                      limits=LIMITS, duration=longer)
    assert short.duration == pytest.approx(longer, rel=1e-12)
    np.testing.assert_allclose(short.position - MECH.home_position,
                               0.7 * (slow.position - MECH.home_position), atol=1e-12)
    # The ramps: a quarter of the duration each (the speed peaks from t = T/4 to 3T/4).
    speed = np.linalg.norm(np.diff(slow.position, axis=0), axis=1) / np.diff(slow.times)
    cruise = speed >= speed.max() * (1 - 1e-9)
    mid = slow.times[:-1][cruise]
    assert mid.min() == pytest.approx(longer / 4, abs=2 * period)
    assert mid.max() == pytest.approx(3 * longer / 4, abs=2 * period)


@pytest.mark.parametrize('duration', [-1.0, float('nan'), float('inf')])
def test_a_bad_least_duration_is_refused(duration: float) -> None:
    p_goal, q_goal = goal([0.001, 0.0, 0.0], [0.0, 0.0, 0.0])
    with pytest.raises(InputError, match='duration'):
        plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=0.002,
                  limits=LIMITS, duration=duration)


def test_joint_rates_match_finite_differences_of_joint_commands() -> None:
    p_goal, q_goal = goal([0.004, 0.002, -0.003], [0.02, 0.01, 0.03])
    traj = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=0.001,
                     limits=LIMITS)
    t = traj.times[:-1]
    for cmd, rate in ((traj.lengths, traj.length_rates), (traj.thetas, traj.theta_rates)):
        fd = np.gradient(cmd[:-1], t, axis=0)
        np.testing.assert_allclose(fd[1:-1], rate[1:-2], atol=2e-6)


#: A point of a panel a metre from the platform (platform frame, m).
PIVOT = np.array([0.9, -0.4, 0.3])


def test_a_pivot_goes_straight_while_the_platform_turns_about_it() -> None:
    """With a pivot, the pivot's point (p + R·pivot) goes on the straight line from its start
    to its goal at the path's pace, the platform turning on the SLERP about it; the platform
    ends exactly on its goal, keeps within the linear speed along its arc (finite
    differences), and its joint rates are those of its joint commands. Planned without the
    pivot, that point leaves the line by the chord of the arc (tens of µm): what a panel held
    by several positioners would be pulled by (issue 27)."""
    period = 0.002
    p_goal, q_goal = goal([0.003, -0.002, 0.004], [0.01, -0.008, 0.012])
    traj = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=period,
                     limits=LIMITS, pivot=PIVOT)
    assert traj.limits.ok
    np.testing.assert_allclose(traj.position[0], MECH.home_position, atol=1e-15)
    np.testing.assert_array_equal(traj.position[-1], p_goal)
    turned = Rotation.from_quat(traj.quaternion)
    c = traj.position + turned.apply(PIVOT)
    d = c[-1] - c[0]
    along = (c - c[0]) @ d / (d @ d)
    np.testing.assert_allclose(c - c[0], along[:, None] * d, rtol=0, atol=1e-12)
    assert np.all(np.diff(along) >= -1e-15)
    slerp = Slerp([0.0, 1.0], Rotation.from_quat([IDENTITY, q_goal]))(along)
    assert (slerp.inv() * turned).magnitude().max() < 1e-12
    dt = np.diff(traj.times)
    for point in (traj.position, c):
        v = np.linalg.norm(np.diff(point, axis=0), axis=1) / dt
        assert v.max() <= LIMITS.linear_speed * (1 + 1e-6)
    fd = np.gradient(traj.lengths[:-1], traj.times[:-1], axis=0)
    np.testing.assert_allclose(fd[1:-1], traj.length_rates[1:-2], atol=2e-6)
    fd = np.gradient(traj.thetas[:-1], traj.times[:-1], axis=0)
    np.testing.assert_allclose(fd[1:-1], traj.theta_rates[1:-2], atol=2e-6)
    plain = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=period,
                      limits=LIMITS)
    c_plain = plain.position + Rotation.from_quat(plain.quaternion).apply(PIVOT)
    rel = c_plain - c_plain[0]
    off_line = rel - np.outer(rel @ d / (d @ d), d)
    assert np.linalg.norm(off_line, axis=1).max() > 10e-6
    origin = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=period,
                       limits=LIMITS, pivot=np.zeros(3))
    np.testing.assert_array_equal(origin.position[:-1], plain.position[:-1])
    np.testing.assert_array_equal(origin.lengths, plain.lengths)


@pytest.mark.parametrize(('pivot', 'words'), [
    ([np.nan, 0.0, 0.0], 'three finite'), ([0.1, 0.2], 'three finite'),
    ([25.0, 0.0, 0.0], 'beyond 20 m')])
def test_a_bad_pivot_is_refused(pivot: list[float], words: str) -> None:
    p_goal, q_goal = goal([0.001, 0.0, 0.0], [0.0, 0.0, 0.0])
    with pytest.raises(InputError, match=f'pivot.*{words}'):
        plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=0.002,
                  pivot=pivot)


def test_compensated_move_ends_on_goal_with_the_model() -> None:
    model = cl.EffectiveLengthClearance.random(1.6e-4, 1.6e-4, np.random.default_rng(0))
    p_goal, q_goal = goal([0.005, 0.0, 0.0], [0.0, 0.0, 0.0])
    traj = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=0.01,
                     limits=LIMITS, clearance=model)
    att = cl.attained_pose(MECH, model, traj.lengths[-1:], traj.thetas[-1:])
    np.testing.assert_allclose(att.position[0], p_goal, atol=1e-12)


def test_path_outside_limits_reports_first_bad_sample() -> None:
    p_goal, q_goal = goal([0.0, 0.0, 0.03], [0.0, 0.0, 0.0])
    traj = plan_move(MECH, MECH.home_position, IDENTITY, p_goal, q_goal, period=0.01,
                     limits=LIMITS)
    assert not traj.limits.ok
    first = traj.limits.first_bad_sample
    assert first is not None and 0 < first < len(traj.times) - 1
    assert traj.limits.violations[0].constraint == 'length_max'


def test_zero_move_holds_for_one_period_and_the_drives_take_it() -> None:
    """Already at the goal (homing where the axes stand): two samples one period apart, not
    two at t = 0, which no trajectory consumer accepts (times must increase)."""
    traj = plan_move(MECH, MECH.home_position, IDENTITY, MECH.home_position, IDENTITY,
                     period=0.01)
    np.testing.assert_allclose(traj.times, [0.0, 0.01])
    np.testing.assert_allclose(traj.position, MECH.home_position[None].repeat(2, 0))
    np.testing.assert_allclose(np.hstack([traj.length_rates, traj.theta_rates]), 0.0)
    driver = LegDriver(parse(DriverSettings, {'referenced_at_start': True}))
    joints = np.hstack([traj.lengths, traj.thetas])
    outcome = driver.follow(JOINT_NAMES, traj.times.tolist(), joints.tolist(),
                            np.zeros_like(joints).tolist(), None, driver.servos.time)
    assert outcome.accepted, outcome.message


@pytest.mark.parametrize('duration', [0.0, 1e-9])
def test_a_move_within_one_period_lasts_one_period_and_its_stamps_increase(
        duration: float) -> None:
    """A femtometre step (round-off of a move to where the platform stands; the coordinated
    cell's relaxes sent such, as fastest moves and as coordinated ones asking a least
    duration of about that) lasts one period: its end stamped on absolute ROS time is after
    its start's, where it fell on it (0.24 us of float spacing near 1.8e9 s), and every set
    sent that duration has the same time law."""
    step = np.array([1e-15, 0.0, 0.0])
    traj = plan_move(MECH, MECH.home_position, IDENTITY, MECH.home_position + step, IDENTITY,
                     period=0.01, limits=LIMITS, duration=duration)
    np.testing.assert_allclose(traj.times, [0.0, 0.01])
    assert (np.diff(1.8e9 + traj.times) > 0.0).all()
    np.testing.assert_array_equal(traj.position[-1], MECH.home_position + step)
    np.testing.assert_allclose(traj.position[0], MECH.home_position, atol=1e-18)
    assert traj.limits.ok


def test_bad_arguments() -> None:
    with pytest.raises(InputError, match='period'):
        plan_move(MECH, MECH.home_position, IDENTITY, MECH.home_position, IDENTITY, period=0.0)
    with pytest.raises(InputError, match='not finite'):
        plan_move(MECH, MECH.home_position, IDENTITY, [np.nan, 0, 0.2], IDENTITY, period=0.01)
    with pytest.raises(ConfigError, match='linear_speed'):
        MotionLimits(linear_speed=-1.0)


def test_path_near_a_singularity_is_refused_with_the_sample() -> None:
    """A path that turns the platform toward the π/2-about-z singularity (seed 001 rank loss)
    is refused at the first sample past the margin, even with joint limits relaxed."""
    from positioning_cell.core.mechanism import Mechanism

    mech = Mechanism(theta_min=-1.5, theta_max=1.5, phi_min=-1.5, phi_max=1.5, tilt_max=1.5,
                     length_min=0.05, length_max=0.4, min_leg_distance=0.0,
                     min_conditioning=0.0)
    q_goal = Rotation.from_rotvec([0.0, 0.0, 1.55]).as_quat()
    traj = plan_move(mech, mech.home_position, IDENTITY, mech.home_position, q_goal,
                     period=0.05, limits=LIMITS)
    assert not traj.limits.ok
    first = traj.limits.violations[0]
    assert first.constraint == 'conditioning_min' and 0 < first.sample < len(traj.times) - 1
    assert 'conditioning' in traj.limits.message()


@given(st.floats(0.0, 1.0))
def test_the_pose_at_a_time_is_the_planned_path_between_its_samples(share: float) -> None:
    """pose_at against the path's own samples (at them: exact) and between them against
    scipy's slerp of the two around it (the setpoint `cell watch` judges against)."""
    traj = plan_move(MECH, MECH.home_position, [0, 0, 0, 1],
                     MECH.home_position + [0.004, -0.002, 0.001],
                     Rotation.from_rotvec([0.02, 0.0, -0.01]).as_quat(), period=0.01)
    t = share * traj.duration
    p, q = pose_at(traj, t)
    k = min(int(np.searchsorted(traj.times, t, side='right')) - 1, traj.times.size - 2)
    w = (t - traj.times[k]) / (traj.times[k + 1] - traj.times[k])
    np.testing.assert_allclose(p, traj.position[k] + w * (traj.position[k + 1]
                                                          - traj.position[k]), atol=1e-12)
    slerp = Slerp(traj.times[k:k + 2], Rotation.from_quat(traj.quaternion[k:k + 2]))
    assert (Rotation.from_quat(q).inv() * slerp([t])[0]).magnitude() < 1e-9
    for i in (0, traj.times.size // 2, traj.times.size - 1):
        np.testing.assert_allclose(pose_at(traj, traj.times[i])[0], traj.position[i],
                                   atol=1e-12)
    np.testing.assert_allclose(pose_at(traj, -1.0)[0], traj.position[0], atol=1e-12)
    np.testing.assert_allclose(pose_at(traj, traj.duration + 1.0)[0], traj.position[-1],
                               atol=1e-12)
