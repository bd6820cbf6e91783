"""The operator's surface of the positioner node (typed interfaces), in the test process with
the test client playing the leg driver (test_positioner_node.FakeDriver): coordinate systems
set, persisted and used by moves; relative moves about the pivot; limit layers and their bits;
speeds; jog; the MoveToPose and Home actions with feedback and cancel. The coordinate-system
algebra itself: test_frames.py; the layers: test_operator_limits.py; through the executables
and the CLI: test_cli_on_the_cell.py."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from action_msgs.msg import GoalStatus
from cell_harness import InProcess
from geometry_msgs.msg import PoseStamped
from positioning_cell_interfaces.action import Home
from positioning_cell_interfaces.action import MoveToPose as MoveAction
from positioning_cell_interfaces.msg import (
    AxisRanges,
    BoxLimits,
    CoordinateSystems,
    MoveCommand,
    MoveOutcome,
    Validity,
)
from positioning_cell_interfaces.msg import Speeds as SpeedsMsg
from positioning_cell_interfaces.srv import (
    CheckPose,
    DefineCoordinateSystem,
    GetCoordinateSystems,
    GetLimits,
    Jog,
    MoveToPose,
    SelectCoordinateSystems,
    SetCoordinateSystems,
    SetLimits,
    SetSpeed,
)
from test_positioner_node import HOME_P, HOME_Q, Positioner, command
from workspace import MECH

from positioning_cell.core import kinematics
from positioning_cell.frames import file as frames_file
from positioning_cell.frames.systems import CoordinateSystems as Systems
from positioning_cell.frames.transforms import Transform
from positioning_cell.limits.range_worker import BUSY_REASON, LATE_REASON
from positioning_cell.polling import wait_until
from positioning_cell.ros.client import GoalClient
from positioning_cell.ros.messages import pose_arrays, pose_msg
from positioning_cell.ros.qos import LATCHED_QOS, STREAM_QOS

pytestmark = pytest.mark.nodes

USER = Transform.from_human([10.0, -5.0, 2.0, 0.0, 0.0, 10.0])  # mm, deg
OBJECT = Transform.from_human([0.0, 0.0, 50.0, 0.0, 0.0, 0.0])  # the pivot 50 mm above


@pytest.fixture
def positioner(ros: InProcess, tmp_path: Path) -> Iterator[Positioner]:
    yield Positioner(ros, tmp_path / 'coordinate_systems.yaml')


def move(positioner: Positioner, cmd: MoveCommand) -> Any:
    return positioner.client.call(MoveToPose, '/positioner/move_to_pose',
                                  MoveToPose.Request(command=cmd)).outcome


def check(positioner: Positioner, cmd: MoveCommand) -> Any:
    return positioner.client.call(CheckPose, '/positioner/check_pose',
                                  CheckPose.Request(command=cmd))


def _late(ranges: Any) -> bool:
    """Axis ranges not searched this time because the worker answered late or was busy (a
    loaded machine: the search is bounded to 0.1 s, range_worker)."""
    return str(ranges.reason).startswith((LATE_REASON, BUSY_REASON))


def checked_ranges(positioner: Positioner, cmd: MoveCommand) -> Any:
    """The first CheckPose answer to ``cmd`` whose axis ranges the worker searched in time:
    asked again while its worker loads (pending) or answers late (:func:`_late`)."""
    def answered() -> Any:
        answer = check(positioner, cmd)
        return None if answer.axis_ranges.pending or _late(answer.axis_ranges) else answer

    return wait_until(answered, 30.0, 'the range worker to answer a check in time')


def set_systems(positioner: Positioner, user: Transform, obj: Transform) -> Any:
    systems = CoordinateSystems(user=pose_msg(*user.to_pq()), object=pose_msg(*obj.to_pq()))
    return positioner.client.call(SetCoordinateSystems, '/positioner/set_coordinate_systems',
                                  SetCoordinateSystems.Request(systems=systems))


def last_goal_joints(positioner: Positioner) -> np.ndarray:
    return np.array(positioner.driver.trajectories[-1].points[-1].positions)


def ik(p: Any, q: Any) -> np.ndarray:
    j = kinematics.inverse(MECH, p, q)
    return np.concatenate([j.lengths[0], j.thetas[0]])


def test_coordinate_systems_are_persisted_and_never_move(positioner: Positioner,
                                                         tmp_path: Path) -> None:
    published = positioner.client.collect(CoordinateSystems, '/positioner/coordinate_systems',
                                          LATCHED_QOS)
    wait_until(lambda: published, 20.0, 'the coordinate systems at start (latched)')
    assert Transform.from_pq(*pose_arrays(published[0].user)) == Transform.identity()
    answer = set_systems(positioner, USER, OBJECT)
    assert answer.success, answer.reason
    wait_until(lambda: len(published) >= 2, 20.0, 'the coordinate systems after the set')
    np.testing.assert_allclose(Transform.from_pq(*pose_arrays(published[-1].user)).to_pose6(),
                               USER.to_pose6(), atol=1e-12)
    got = positioner.client.call(GetCoordinateSystems, '/positioner/get_coordinate_systems',
                                 GetCoordinateSystems.Request())
    assert got.file == str(tmp_path / 'coordinate_systems.yaml')
    for msg, want in ((got.systems.user, USER), (got.systems.object, OBJECT)):
        np.testing.assert_allclose(Transform.from_pq(*pose_arrays(msg)).to_pose6(),
                                   want.to_pose6(), atol=1e-12)
    saved = frames_file.load(got.file)  # what a restarted node reads
    np.testing.assert_allclose(saved.user.to_pose6(), USER.to_pose6(), atol=1e-12)
    assert not positioner.driver.trajectories  # changing them moved nothing
    bad = CoordinateSystems(user=pose_msg(HOME_P, [0.0, 0.0, 0.0, 2.0]))
    refused = positioner.client.call(SetCoordinateSystems,
                                     '/positioner/set_coordinate_systems',
                                     SetCoordinateSystems.Request(systems=bad))
    assert not refused.success and 'quaternion' in refused.reason
    assert frames_file.load(got.file).user == saved.user  # nothing changed
    assert len(published) == 2  # a refused set publishes nothing


def test_named_systems_are_stored_switched_and_persisted(positioner: Positioner) -> None:
    """Several user and object systems by name, one active of each (PI's work and tool
    systems): define, switch, refuse an unknown name with nothing changed, and a restarted
    node reads them back."""
    client = positioner.client
    work = Transform.from_human([5, 0, 0, 0, 0, 90])

    def get() -> Any:
        return client.call(GetCoordinateSystems, '/positioner/get_coordinate_systems',
                           GetCoordinateSystems.Request())

    def define(kind: str, name: str, t: Transform, activate: bool) -> Any:
        return client.call(DefineCoordinateSystem, '/positioner/define_coordinate_system',
                           DefineCoordinateSystem.Request(kind=kind, name=name,
                                                          pose=pose_msg(*t.to_pq()),
                                                          activate=activate))

    def select(user: str, obj: str) -> Any:
        return client.call(SelectCoordinateSystems, '/positioner/select_coordinate_systems',
                           SelectCoordinateSystems.Request(user=user, object=obj))

    assert define('user', 'work', work, True).success
    assert define('object', 'tool', OBJECT, False).success
    got = get()
    assert (got.active_user, got.active_object) == ('work', 'default')
    assert list(got.user_names) == ['default', 'work'] and list(got.object_names) == \
        ['default', 'tool']
    np.testing.assert_allclose(Transform.from_pq(*pose_arrays(got.systems.user)).to_pose6(),
                               work.to_pose6(), atol=1e-12)
    assert select('', 'tool').success  # the user system stays
    got = get()
    assert (got.active_user, got.active_object) == ('work', 'tool')
    refused = select('nowhere', '')
    assert not refused.success and "no user system named 'nowhere'" in refused.reason
    refused = define('user', 'bad name', work, True)
    assert not refused.success and 'a letter, then letters' in refused.reason
    assert (get().active_user, get().active_object) == ('work', 'tool')  # nothing changed
    saved = frames_file.load_named(got.file)  # what a restarted node reads
    assert (saved.active_user, saved.active_object) == ('work', 'tool')
    assert set(saved.users) == {'default', 'work'}
    assert select('default', 'default').success
    assert Transform.from_pq(*pose_arrays(get().systems.user)) == Transform.identity()
    assert not positioner.driver.trajectories  # switching moved nothing


def test_a_user_move_commands_t_user_g_t_object_inverse(positioner: Positioner) -> None:
    assert set_systems(positioner, USER, OBJECT).success
    g = Transform.from_human([1.0, 2.0, 48.0, 0.5, -0.3, 1.0])
    outcome = move(positioner, command(*g.to_pq(), frame='user'))
    assert outcome.code == MoveOutcome.SUCCESS, outcome.reason
    p, q = Systems(USER, OBJECT).base_goal_absolute(g, MECH)
    np.testing.assert_allclose(last_goal_joints(positioner), ik(p, q), atol=1e-12)
    attained = Transform.from_pq(*pose_arrays(outcome.attained_user))
    np.testing.assert_allclose(attained.to_pose6(), g.to_pose6(), atol=1e-9)
    # relative to the object: a pure rotation turns about the pivot, which stays put
    pivot_before = _pivot(p, q)
    turn = Transform.from_human([0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    outcome = move(positioner, command(*turn.to_pq(), frame='object',
                                       mode=MoveCommand.RELATIVE_OBJECT))
    assert outcome.code == MoveOutcome.SUCCESS, outcome.reason
    p2, q2 = pose_arrays(positioner.targets[-1].pose)
    np.testing.assert_allclose(_pivot(p2, q2), pivot_before, atol=1e-12)
    assert math.degrees(2 * math.acos(min(1.0, abs(float(np.dot(q, q2)))))) == \
        pytest.approx(1.0, abs=1e-9)
    # relative to the user: a pure translation moves the pivot along the user axes
    step = Transform.from_human([0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    outcome = move(positioner, command(*step.to_pq(), frame='user',
                                       mode=MoveCommand.RELATIVE_USER))
    assert outcome.code == MoveOutcome.SUCCESS, outcome.reason
    p3, q3 = pose_arrays(positioner.targets[-1].pose)
    np.testing.assert_allclose(_pivot(p3, q3) - _pivot(p2, q2), USER.R @ [0.0005, 0.0, 0.0],
                               atol=1e-12)


def _pivot(p: Any, q: Any) -> np.ndarray:
    """The object origin (the pivot) in base of a platform pose."""
    return Transform.from_pq(p, q).apply(OBJECT.p)


def test_wrong_frames_and_modes_are_refused_with_the_allowed_ones(
        positioner: Positioner) -> None:
    for cmd, words in ((command(HOME_P, HOME_Q, frame='object'), "not in frame_id 'object'"),
                       (command(HOME_P, HOME_Q, frame='base', mode=MoveCommand.RELATIVE_USER),
                        "frame_id must be 'user'"),
                       (command(HOME_P, HOME_Q, mode=7), 'mode 7')):
        outcome = move(positioner, cmd)
        assert outcome.code == MoveOutcome.REFUSED_INVALID_GOAL and words in outcome.reason, \
            outcome.reason
        answer = check(positioner, cmd)
        assert answer.validity.bits == Validity.INVALID_GOAL and not answer.valid
    assert not positioner.driver.trajectories


def test_limit_layers_are_validated_checked_and_named(positioner: Positioner) -> None:
    client = positioner.client
    limits = client.call(GetLimits, '/positioner/get_limits', GetLimits.Request())
    assert list(limits.machine.lower) == list(limits.factory.lower)
    assert all(math.isinf(v) for v in limits.user.upper)
    assert any('length' in line for line in limits.factory_constraints)
    unlimited = BoxLimits(lower=[-math.inf] * 6, upper=[math.inf] * 6)
    wide = BoxLimits(lower=[v - 0.01 for v in limits.factory.lower],
                     upper=list(limits.factory.upper))
    refused = client.call(SetLimits, '/positioner/set_limits',
                          SetLimits.Request(machine=wide, user=unlimited))
    assert not refused.success and 'outside the factory box' in refused.reason
    narrow = BoxLimits(lower=[-0.001, -0.001, -0.001, -0.01, -0.01, -0.01],
                       upper=[0.001, 0.001, 0.001, 0.01, 0.01, 0.01])
    outside_user = BoxLimits(lower=[-0.002] * 3 + [-0.001] * 3, upper=[0.002] * 3 + [0.001] * 3)
    refused = client.call(SetLimits, '/positioner/set_limits',
                          SetLimits.Request(machine=narrow, user=outside_user))
    assert not refused.success and 'user limits: vertex' in refused.reason
    assert client.call(SetLimits, '/positioner/set_limits',
                       SetLimits.Request(machine=narrow, user=unlimited)).success
    goal = command(HOME_P + [0.002, 0.0, 0.0], HOME_Q)
    answer = check(positioner, goal)
    assert answer.validity.bits == Validity.MACHINE_LIMITS, answer.validity.violations
    assert any(v.startswith('machine limits: Tx') for v in answer.validity.violations)
    outcome = move(positioner, goal)
    assert outcome.code == MoveOutcome.REFUSED_LIMITS and 'machine limits: Tx' in outcome.reason
    assert not positioner.driver.trajectories
    user = BoxLimits(lower=[-0.0005] * 3 + [-0.005] * 3, upper=[0.0005] * 3 + [0.005] * 3)
    assert client.call(SetLimits, '/positioner/set_limits',
                       SetLimits.Request(machine=narrow, user=user)).success
    answer = check(positioner, command(HOME_P + [0.0008, 0.0, 0.0], HOME_Q))
    assert answer.validity.bits == Validity.USER_LIMITS, answer.validity.violations
    # The first check starts the range worker: no ranges yet, pending, then the worker's.
    assert answer.axis_ranges.pending or _late(answer.axis_ranges) \
        or 'user.Tx_max' in answer.axis_ranges.reason
    answer = checked_ranges(positioner, command(HOME_P + [0.0008, 0.0, 0.0], HOME_Q))
    assert not answer.axis_ranges.valid and 'user.Tx_max' in answer.axis_ranges.reason
    # the axis ranges from a valid goal end at the user box (identity user CS: along x, the
    # goal's 0.2 mm to the box's 0.5 mm)
    ranges = checked_ranges(positioner, command(HOME_P + [0.0002, 0.0, 0.0], HOME_Q)).axis_ranges
    assert ranges.valid and list(ranges.axes) == ['Tx', 'Ty', 'Tz', 'Rx', 'Ry', 'Rz']
    assert (ranges.low_binding[0], ranges.high_binding[0]) == ('user.Tx_min', 'user.Tx_max')
    assert ranges.pose[0] == pytest.approx(0.0002, abs=1e-9)
    assert (ranges.low[0], ranges.high[0]) == (pytest.approx(-0.0005, abs=1e-6),
                                               pytest.approx(0.0005, abs=1e-6))
    # and on /positioner/axis_ranges, from where the platform stands (home), latched
    published = client.collect(AxisRanges, '/positioner/axis_ranges', LATCHED_QOS)
    wait_until(lambda: any(r.valid and r.high_binding[5] == 'user.Rz_max' for r in published),
               20.0, 'the axis ranges within the user box on /positioner/axis_ranges')
    newest = next(r for r in reversed(published) if r.valid)
    assert newest.user_cs and newest.high[5] == pytest.approx(0.005, abs=1e-6)
    # `cell limits reset`'s request: the factory box for the machine, no user box
    assert client.call(SetLimits, '/positioner/set_limits',
                       SetLimits.Request(machine=limits.factory, user=unlimited)).success
    after = client.call(GetLimits, '/positioner/get_limits', GetLimits.Request())
    assert list(after.machine.lower) == list(limits.factory.lower)
    assert list(after.machine.upper) == list(limits.factory.upper)
    assert all(math.isinf(v) for v in [*after.user.lower, *after.user.upper])
    assert check(positioner, command(HOME_P + [0.0008, 0.0, 0.0], HOME_Q)).valid


def test_speeds_within_the_factory_maxima_or_refused(positioner: Positioner) -> None:
    client = positioner.client
    query = client.call(SetSpeed, '/positioner/set_speed', SetSpeed.Request())
    assert query.success and query.current.linear_speed == pytest.approx(0.01)
    goal = command(HOME_P + [0.01, 0.0, 0.0], HOME_Q)
    before = check(positioner, goal).duration
    too_fast = SpeedsMsg(linear_speed=query.maximum.linear_speed * 2)
    refused = client.call(SetSpeed, '/positioner/set_speed', SetSpeed.Request(request=too_fast))
    assert not refused.success and 'linear_speed' in refused.reason
    assert refused.current.linear_speed == query.current.linear_speed  # not clamped, unchanged
    slow = SpeedsMsg(linear_speed=0.005)
    answer = client.call(SetSpeed, '/positioner/set_speed', SetSpeed.Request(request=slow))
    assert answer.success and answer.current.linear_speed == 0.005
    assert answer.current.angular_speed == query.current.angular_speed  # 0 kept it
    after = check(positioner, goal).duration
    assert after > 1.5 * before, (before, after)


def test_jog_moves_one_axis_within_its_range(positioner: Positioner) -> None:
    client = positioner.client
    start = positioner.driver.position.copy()
    answer = client.call(Jog, '/positioner/jog', Jog.Request(axis='leg1_length', delta=0.001))
    assert answer.success, answer.reason
    assert answer.position == pytest.approx(start[0] + 0.001, abs=1e-12)
    end = last_goal_joints(positioner)
    np.testing.assert_allclose(end, start + [0.001, 0, 0, 0, 0, 0], atol=1e-12)
    sent = len(positioner.driver.trajectories)
    for axis, delta, code in (('leg1_length', 0.006, 'refused_limits'),  # above the largest
                              ('leg2_theta', 1.0, 'refused_limits'),  # step (the axis range:
                              # test_operator_limits)
                              ('leg9_length', 0.001, 'refused_invalid_goal')):
        refused = client.call(Jog, '/positioner/jog', Jog.Request(axis=axis, delta=delta))
        assert not refused.success and refused.code_name == code, refused.reason
    assert len(positioner.driver.trajectories) == sent  # the refused jogs sent nothing
    # the next move plans from where the encoders are
    outcome = move(positioner, command(HOME_P, HOME_Q))
    assert outcome.code == MoveOutcome.SUCCESS, outcome.reason
    np.testing.assert_allclose(positioner.driver.trajectories[-1].points[0].positions[0],
                               start[0] + 0.001, atol=1e-6)


def test_a_goal_already_reached_succeeds_without_moving(positioner: Positioner) -> None:
    goal = command(HOME_P + [0.001, 0.0, 0.0], HOME_Q)
    assert move(positioner, goal).code == MoveOutcome.SUCCESS
    sent = len(positioner.driver.trajectories)
    outcome = move(positioner, goal)
    assert outcome.code == MoveOutcome.SUCCESS and 'already within tolerance' in outcome.reason
    assert len(positioner.driver.trajectories) == sent


def _send(goals: GoalClient, goal: Any, feedback: list[Any]) -> Any:
    goals.ready(30.0)  # a busy machine discovers slowly; the error says what was missing
    handle = goals.send(goal, feedback.append)
    assert handle.accepted
    return handle


def test_the_move_action_gives_feedback_and_a_result(positioner: Positioner) -> None:
    driver = positioner.driver
    driver.follow = False  # the drives arrive when the test has seen the moving phase
    feedback: list[Any] = []
    setpoints = positioner.client.collect(PoseStamped, '/positioner/setpoint', STREAM_QOS)
    goal = MoveAction.Goal(command=command(HOME_P + [0.004, 0.0, 0.0], HOME_Q))
    with GoalClient(positioner.client, MoveAction, '/positioner/move') as goals:
        handle = _send(goals, goal, feedback)
        goals.until(lambda: any(f.phase == MoveAction.Feedback.MOVING for f in feedback), 20.0,
                    'feedback of the moving phase')
        goals.until(lambda: len(setpoints) >= 3, 20.0, 'setpoints of the running trajectory')
        # on the planned straight path from home to the goal, advancing
        along = [pose_arrays(s.pose)[0] - HOME_P for s in list(setpoints)]
        assert all(-1e-9 <= a[0] <= 0.004 + 1e-9 and abs(a[1]) < 1e-9 and abs(a[2]) < 1e-9
                   for a in along), along
        assert along[-1][0] >= along[0][0]
        with driver.lock:
            driver.position = np.array(driver.trajectories[-1].points[-1].positions)
        result = goals.result(handle, 30.0)
    outcome = result.result.outcome
    assert outcome.code == MoveOutcome.SUCCESS, outcome.reason
    assert result.status == GoalStatus.STATUS_SUCCEEDED
    assert {f.phase_name for f in feedback} <= {'moving', 'settling', 'settled', 'correcting'}
    assert outcome.attained_source == 'estimated'  # mode none: the encoders through the model


def test_a_refused_goal_shows_no_progress_and_where_the_platform_stands(
        positioner: Positioner) -> None:
    """Refused before it moved: no feedback at all (the state is still the last move's: it
    showed "settled 100%"), and the outcome says where the platform stands and how far the
    goal is from there, not zeros."""
    assert move(positioner, command(HOME_P + [0.002, 0.0, 0.0], HOME_Q)).code == 0
    feedback: list[Any] = []
    far = HOME_P + [0.5, 0.0, 0.0]  # far outside the workspace
    with GoalClient(positioner.client, MoveAction, '/positioner/move') as goals:
        result = goals.result(_send(goals, MoveAction.Goal(command=command(far, HOME_Q)),
                                    feedback), 30.0)
    outcome = result.result.outcome
    assert outcome.code_name.startswith('refused'), outcome.reason
    assert feedback == []
    assert outcome.attained_source == 'estimated'
    p, _ = pose_arrays(outcome.attained.pose)
    np.testing.assert_allclose(p, HOME_P + [0.002, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(outcome.position_error, [-0.498, 0.0, 0.0], atol=1e-6)


def test_cancel_stops_the_drives_and_ends_aborted_stop(positioner: Positioner) -> None:
    driver = positioner.driver
    driver.follow = False  # the drives never arrive: the move waits
    feedback: list[Any] = []
    goal = MoveAction.Goal(command=command(HOME_P + [0.004, 0.0, 0.0], HOME_Q))
    with GoalClient(positioner.client, MoveAction, '/positioner/move') as goals:
        handle = _send(goals, goal, feedback)
        goals.until(lambda: any(f.phase == MoveAction.Feedback.MOVING for f in feedback), 20.0,
                    'feedback of the moving phase')
        goals.cancel(handle)
        result = goals.result(handle, 30.0)
    outcome = result.result.outcome
    assert outcome.code == MoveOutcome.ABORTED_STOP
    assert result.status == GoalStatus.STATUS_CANCELED
    # where it stopped (the drives never left home here), and how far from the goal that is
    assert outcome.attained_source == 'estimated'
    np.testing.assert_allclose(pose_arrays(outcome.attained.pose)[0], HOME_P, atol=1e-6)
    np.testing.assert_allclose(outcome.position_error, [-0.004, 0.0, 0.0], atol=1e-6)
    assert len(driver.trajectories[-1].points) == 0  # the stop: an empty trajectory
    assert 0.0 <= min(f.progress for f in feedback) <= max(f.progress for f in feedback) <= 1.0


def test_the_home_action_references_and_homes(positioner: Positioner) -> None:
    assert move(positioner, command(HOME_P + [0.002, 0.0, 0.0], HOME_Q)).code == 0
    feedback: list[Any] = []
    with GoalClient(positioner.client, Home, '/positioner/homing') as goals:
        result = goals.result(_send(goals, Home.Goal(), feedback), 30.0)
    assert result.result.outcome.code == MoveOutcome.SUCCESS
    np.testing.assert_allclose(last_goal_joints(positioner), ik(HOME_P, HOME_Q), atol=1e-12)
