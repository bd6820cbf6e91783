"""The drives' last line of defence (positioning_cell.sim.guard, positioning_cell.sim.drives):
every trajectory and every point checked against the axis limits before it is accepted; a
refusal names the axis, the value and the limit and changes nothing; the setpoint never leaves
the axis ranges; the drives refuse motion until referenced; a lost encoder faults its drive."""

from __future__ import annotations

import numpy as np
import pytest

from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.moves.fingerprint import fingerprint
from positioning_cell.moves.trajectory import time_law
from positioning_cell.parameters import parse
from positioning_cell.sim.drives import DriverSettings, LegDriver
from positioning_cell.sim.guard import Refusal
from positioning_cell.sim.paths import JointPath

SETTINGS = parse(DriverSettings, {'referenced_at_start': True})
HOME = SETTINGS.home_positions()


def points(delta: np.ndarray, duration: float = 1.0, n: int = 21,
           start: np.ndarray = HOME) -> tuple[list[float], list[list[float]], list[list[float]]]:
    """A rest-to-rest move by ``delta`` (6,) over ``duration`` s, as trajectory fields."""
    times = np.linspace(0.0, duration, n)
    s, sd = time_law(duration / 3.0, 1.5 / duration, duration, times)
    return (times.tolist(), (start + s[:, None] * delta).tolist(),
            (sd[:, None] * delta).tolist())


def follow(driver: LegDriver, times: list[float], positions: list[list[float]],
           velocities: list[list[float]], names: tuple[str, ...] = JOINT_NAMES) -> object:
    return driver.follow(names, times, positions, velocities, None, driver.servos.time)


def test_a_legal_trajectory_is_accepted_with_its_key() -> None:
    driver = LegDriver(SETTINGS)
    times, positions, velocities = points(np.array([1e-3, -1e-3, 5e-4, 0.01, -0.01, 0.005]))
    outcome = follow(driver, times, positions, velocities)
    assert outcome.accepted and outcome.code is None and outcome.sequence == 1
    assert outcome.key == fingerprint(times, positions)


@pytest.mark.parametrize(('change', 'code', 'words'), [
    # The probe of the issue: leg 1 to 0.240 m, leg 2 to 0.150 m, θ1 to 1.2 rad.
    ({0: 0.240}, Refusal.OUT_OF_RANGE,
     'point 20: leg1_length 240.0000 mm is above its limit 220.0000 mm'),
    ({1: 0.150}, Refusal.OUT_OF_RANGE,
     'point 20: leg2_length 150.0000 mm is below its limit 180.0000 mm'),
    ({3: 1.2}, Refusal.OUT_OF_RANGE,
     'point 20: leg1_theta 68.7549 deg is above its limit 45.0000 deg'),
    ({4: float('nan')}, Refusal.INVALID_GOAL, 'point 20, leg2_theta is NaN'),
    ({5: float('inf')}, Refusal.INVALID_GOAL, 'point 20, leg3_theta is infinite'),
])
def test_a_final_point_beyond_a_limit_is_refused_naming_axis_value_and_limit(
        change: dict[int, float], code: Refusal, words: str) -> None:
    driver = LegDriver(SETTINGS)
    goal = HOME.copy()
    for axis, value in change.items():
        goal[axis] = value
    times, positions, velocities = points(np.zeros(6))  # holds, then the last point
    positions[-1] = goal.tolist()
    outcome = follow(driver, times, positions, velocities)
    assert not outcome.accepted and outcome.code is code
    assert words in outcome.message, outcome.message
    driver.step(3.0)  # the axes hold
    np.testing.assert_allclose(driver.servos.state.position, HOME, atol=1e-12)


def test_speed_acceleration_jump_and_overshoot_between_points_are_refused() -> None:
    driver = LegDriver(SETTINGS)
    fast = points(np.array([0.015, 0, 0, 0, 0, 0]), duration=0.2)  # 0.11 m/s > 0.05 m/s
    outcome = follow(driver, *fast)
    assert outcome.code is Refusal.SPEED and 'leg1_length speed' in outcome.message
    assert 'exceeds its limit 50.0000 mm/s' in outcome.message
    # 2 mm in 0.1 s with a rest-to-rest law: peak acceleration ~0.94 m/s² > 0.5 m/s².
    jerky = points(np.array([0, 2e-3, 0, 0, 0, 0]), duration=0.1, n=11)
    outcome = follow(driver, *jerky)
    assert outcome.code is Refusal.ACCELERATION and 'leg2_length acceleration' in outcome.message
    times, positions, velocities = points(np.array([1e-3, 0, 0, 0, 0, 0]))
    positions = [[p[0] + 5e-4, *p[1:]] for p in positions]  # starts 0.5 mm off the axis
    outcome = follow(driver, times, positions, velocities)
    assert outcome.code is Refusal.JUMP and 'leg1_length would jump 0.5000 mm' in outcome.message
    # Points within the stroke, but a velocity that makes the cubic swing beyond it.
    top = HOME.copy()
    top[0] = 0.2195
    rising = [0.03, 0.0, 0.0, 0.0, 0.0, 0.0]
    swing = [[0.0, 1.0, 2.0], [HOME.tolist(), top.tolist(), top.tolist()],
             [[0.0] * 6, rising, [0.0] * 6]]
    driver2 = LegDriver(SETTINGS)
    outcome = follow(driver2, *swing)  # type: ignore[arg-type]
    assert outcome.code is Refusal.OUT_OF_RANGE, outcome.message
    assert 'between points 1 and 2: leg1_length reaches 223' in outcome.message
    assert driver.received == 3 and driver2.received == 1


def test_a_malformed_trajectory_is_refused_with_its_key() -> None:
    """The sender matches answers by key: a trajectory refused before it could be parsed
    (times not increasing, NaN) is answered with the key of what was sent, so the sender
    learns of the refusal at once instead of waiting out a timeout."""
    driver = LegDriver(SETTINGS)
    for times, positions in (([0.0, 0.0], [HOME.tolist()] * 2),
                             ([0.0, 1.0], [HOME.tolist(), [float('nan')] * 6])):
        outcome = follow(driver, times, positions, [[0.0] * 6] * 2)
        assert not outcome.accepted and outcome.code is Refusal.INVALID_GOAL
        assert outcome.key == fingerprint(times, positions) != ''


def test_unknown_joint_names_and_unreferenced_drives_are_refused() -> None:
    driver = LegDriver(SETTINGS)
    outcome = follow(driver, *points(np.zeros(6)), names=('leg7_length', *JOINT_NAMES[1:]))
    assert outcome.code is Refusal.INVALID_JOINTS and 'leg7_length' in outcome.message
    cold = LegDriver(parse(DriverSettings, {}))  # config default: not referenced
    outcome = follow(cold, *points(np.array([1e-3, 0, 0, 0, 0, 0])))
    assert outcome.code is Refusal.NOT_REFERENCED and 'home them first' in outcome.message
    assert 'virtual homing' in cold.reference(0.0) and cold.referenced
    assert follow(cold, *points(np.array([1e-3, 0, 0, 0, 0, 0]))).accepted


def test_a_referencing_run_moves_to_home_slowly_then_references() -> None:
    start = HOME + np.array([2e-3, -1e-3, 0.0, 0.02, 0.0, -0.01])
    settings = parse(DriverSettings, {'homing.virtual': False, 'initial_at_home': False,
                                      'initial_positions': start.tolist()})
    driver = LegDriver(settings)
    message = driver.reference(0.0)
    assert 'referencing run' in message and not driver.referenced and driver.referencing
    speeds = []
    t = 0.0
    while driver.referencing and t < 30.0:
        t += 0.005
        driver.heartbeat(t)  # the positioner waits for the referencing, alive
        driver.step(t)
        speeds.append(np.abs(driver.servos.state.velocity))
    assert driver.referenced and not driver.referencing
    np.testing.assert_allclose(driver.servos.state.position, HOME, atol=1e-6)
    limit = settings.servo.velocity_limits * settings.homing.speed_fraction
    assert (np.max(speeds, axis=0) <= limit * 1.6).all()  # slow: about the fraction asked


def test_the_setpoint_never_leaves_the_axis_ranges_whatever_the_path() -> None:
    """The servos' soft limit: a path straight through the top of the stroke (handed to the
    servos directly, past the guard) holds the setpoint at the limit; the axis, arriving at
    0.02 m/s, passes it by less than its braking distance v²/(2 a_max)."""
    driver = LegDriver(SETTINGS)
    servos, upper = driver.servos, SETTINGS.mechanism.length_max
    start = HOME.copy()
    start[0] = upper - 1e-3
    servos.state = servos.state._replace(position=start)
    through = JointPath(np.array([0.0, 0.1]), np.vstack([start, start + [2e-3, 0, 0, 0, 0, 0]]),
                        np.vstack([[0.02, 0, 0, 0, 0, 0]] * 2))
    servos.command(through, 0.0)
    t, highest_setpoint, highest = 0.0, 0.0, 0.0
    while t < 1.0:
        t += 0.005
        driver.step(t)
        if abs(t - 0.05) < 0.003:
            servos.stop()
        highest_setpoint = max(highest_setpoint, servos.setpoint()[0][0])
        highest = max(highest, servos.state.position[0])
    assert highest_setpoint == upper  # reached, never passed
    braking = 0.02**2 / (2 * SETTINGS.servo.linear.max_acceleration)
    assert highest <= upper + braking


def test_an_encoder_without_signal_faults_its_drive() -> None:
    settings = parse(DriverSettings, {'referenced_at_start': True,
                                      'fault.encoder_dropout': 'leg3_length',
                                      'fault.encoder_dropout_mode': 'missing'})
    driver = LegDriver(settings)
    assert follow(driver, *points(np.array([1e-3, 0, 0, 0, 0, 0]), duration=2.0)).accepted
    driver.step(0.5)
    driver.readings()
    assert driver.servos.fault is not None
    assert driver.servos.fault.message() == 'encoder signal lost on leg3_length'
    level, _, values = driver.status()
    assert level == 'error' and values['fault_axis'] == 'leg3_length'
    assert not follow(driver, *points(np.zeros(6))).accepted


# -- whom the drives obey, and the bounds of a command (issue 21) --------------------------------
def test_only_the_commander_is_obeyed_and_others_are_reported() -> None:
    driver = LegDriver(SETTINGS)
    times, positions, velocities = points(np.array([1e-3, 0, 0, 0, 0, 0]))
    outcome = driver.follow(JOINT_NAMES, times, positions, velocities, None, 0.0, '/rogue')
    assert not outcome.accepted and outcome.code is Refusal.FOREIGN_SENDER
    assert outcome.message == ('trajectory refused: sent by /rogue: this driver takes commands '
                               'only from /positioner (command.commander)')
    assert driver.servos.pending is None and not driver.servos.moving
    assert driver.publishers([('/positioner', 'aa'), ('/rogue', 'bb'), ('/rogue', 'cc')])
    level, message, values = driver.status()
    assert level == 'error' and message.startswith(
        'foreign publisher on /legs/joint_trajectory: /rogue (only /positioner is obeyed')
    assert values['commander_seen'] and values['foreign_publishers'] == '/rogue'
    assert values['commander_publishers'] == 'aa'
    assert driver.publishers([('/positioner', 'aa')]) and driver.status()[0] == 'ok'
    assert not driver.publishers([('/positioner', 'aa')])
    assert driver.follow(JOINT_NAMES, times, positions, velocities, None, 0.0,
                         '/positioner').accepted


def test_a_restarted_commander_is_told_apart_from_its_predecessor_by_its_gids() -> None:
    """Within the middleware's lease the graph names a killed commander and its successor
    alike; the status lists both publishers' GIDs, so the successor can tell whether its own
    is among them."""
    driver = LegDriver(SETTINGS)
    assert driver.status()[2]['commander_seen'] is False
    assert driver.publishers([('/positioner', 'old')])
    assert driver.publishers([('/positioner', 'old'), ('/positioner', 'new')])
    values = driver.status()[2]
    assert values['commander_seen'] is True
    assert values['commander_publishers'] == 'new old'
    assert driver.publishers([('/positioner', 'new')])
    assert driver.status()[2]['commander_publishers'] == 'new'


@pytest.mark.parametrize(('start', 'code', 'words'), [
    (10.0 - 0.6, Refusal.OLD_HEADER_TIMESTAMP,
     'header stamp 0.600 s in the past (command.stamp_tolerance 0.05 s): too old to start'),
    (10.0 + 4.0, Refusal.FUTURE_HEADER_TIMESTAMP,
     'header stamp 4.000 s ahead (command.max_start_delay 1 s): too far in the future'),
])
def test_a_start_stamp_too_old_or_too_far_ahead_is_refused(start: float, code: Refusal,
                                                           words: str) -> None:
    driver = LegDriver(SETTINGS, 10.0)
    times, positions, velocities = points(np.array([1e-3, 0, 0, 0, 0, 0]))
    outcome = driver.follow(JOINT_NAMES, times, positions, velocities, start, 10.0)
    assert not outcome.accepted and outcome.code is code and outcome.message.endswith(words)
    ok = driver.follow(JOINT_NAMES, times, positions, velocities, 10.0 + 0.5, 10.0)
    assert ok.accepted and driver.servos.pending is not None  # 0.5 s ahead is within bounds


def test_more_points_than_max_points_are_refused() -> None:
    settings = parse(DriverSettings, {'referenced_at_start': True, 'command.max_points': 20})
    driver = LegDriver(settings)
    outcome = follow(driver, *points(np.array([1e-3, 0, 0, 0, 0, 0]), n=21))
    assert outcome.code is Refusal.TOO_MANY_POINTS  # type: ignore[attr-defined]
    assert outcome.message.endswith(  # type: ignore[attr-defined]
        '21 points: more than command.max_points = 20')


def test_a_move_stops_when_the_commander_falls_silent() -> None:
    """Heartbeats keep a move going; without them the drives stop under control
    heartbeat_timeout after the last word, far before the trajectory's end."""
    driver = LegDriver(SETTINGS)
    delta = np.array([4e-3, 0, 0, 0, 0, 0])
    follow(driver, *points(delta, duration=3.0))
    t, stopped = 0.0, None
    while t < 1.0:  # alive for a second
        t += 0.005
        driver.heartbeat(t)
        assert driver.step(t).stopped is None
    while stopped is None and t < 3.0:
        t += 0.005
        stopped = driver.step(t).stopped
    assert stopped is not None and 1.5 <= t <= 1.51
    assert stopped.startswith('commander /positioner silent for 0.50 s during a move '
                              '(heartbeat_timeout 0.5 s): controlled stop')
    assert driver.status()[2]['silence_stops'] == 1
    while driver.servos.moving:
        t += 0.005
        driver.step(t)
    assert driver.servos.state.position[0] < HOME[0] + 0.9 * delta[0]  # stopped short
    # At rest nobody needs a heartbeat: no further stop.
    assert driver.step(t + 10.0).stopped is None
