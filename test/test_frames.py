"""The operator's coordinate systems (positioning_cell.frames): rigid transforms, the six numbers
(SI and human, R = Rz·Ry·Rx checked against hand-built matrices), the machine, user and object
CS (round trips of absolute and relative moves, the pivot), move requests, and the file."""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from workspace import MECH, poses

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import SMALL_BATCH
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.frames import (
    ABSOLUTE,
    MACHINE_FRAME,
    OBJECT_FRAME,
    RELATIVE_OBJECT,
    RELATIVE_USER,
    USER_FRAME,
    CoordinateSystems,
    CoordinateSystemsFileError,
    Transform,
    compose_poses,
    distance,
    format_human,
    human_from_pose6,
    load,
    pose6_from_human,
    pose6_from_pq,
    pq_from_pose6,
    write,
)
from positioning_cell.names import BASE_FRAME

FloatArray = NDArray[np.float64]
TOL = 1e-12
FEW = settings(max_examples=60)

_coordinate = st.floats(-0.5, 0.5, allow_nan=False, allow_infinity=False)
_unit = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)


@st.composite
def quaternions(draw: st.DrawFn) -> FloatArray:
    """Any rotation: a unit quaternion x, y, z, w."""
    q = np.array(draw(st.tuples(_unit, _unit, _unit, _unit)
                      .filter(lambda v: float(np.linalg.norm(v)) > 0.1)))
    return np.asarray(q / np.linalg.norm(q))


@st.composite
def transforms(draw: st.DrawFn) -> Transform:
    """Any rigid transform within half a metre."""
    return Transform.from_pq(np.array([draw(_coordinate) for _ in range(3)]), draw(quaternions()))


def assert_close(a: Transform, b: Transform, tol: float = TOL) -> None:
    dp, angle = distance(a, b)
    assert dp <= tol and angle <= tol, (dp, angle)
    np.testing.assert_allclose(a.R, b.R, rtol=0.0, atol=tol)


def rx(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def ry(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rz(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pivot_in_base(systems: CoordinateSystems, goal: Transform) -> FloatArray:
    """The object origin (the pivot) in ``base`` when the object is at user position ``goal``."""
    p, q = systems.base_goal_absolute(goal, MECH)
    return Transform.from_pq(p, q).apply(systems.object.p)


# -- transforms ----------------------------------------------------------------------------------
@FEW
@given(transforms(), transforms(), transforms())
def test_composition_inverse_and_associativity(a: Transform, b: Transform,
                                               c: Transform) -> None:
    assert_close(a @ a.inverse(), Transform.identity())
    assert_close(a.inverse() @ a, Transform.identity())
    assert_close((a @ b) @ c, a @ (b @ c))
    assert_close((a @ b).inverse(), b.inverse() @ a.inverse())
    x = np.array([[0.1, -0.2, 0.3], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose((a @ b).apply(x), a.apply(b.apply(x)), rtol=0.0, atol=TOL)


@FEW
@given(st.tuples(_coordinate, _coordinate, _coordinate), quaternions())
def test_pq_round_trip(p: tuple[float, float, float], q: FloatArray) -> None:
    t = Transform.from_pq(p, q)
    p2, q2 = t.to_pq()
    assert np.array_equal(p2, p)
    assert q2[3] >= 0.0
    assert abs(abs(float(q2 @ q)) - 1.0) <= TOL  # q or −q
    assert_close(Transform.from_pq(p, -q), t)
    np.testing.assert_allclose(t.R, Rotation.from_quat(q).as_matrix(), rtol=0.0, atol=TOL)


def test_transform_is_immutable_and_compares_by_value() -> None:
    t = Transform.from_human([1.0, 2.0, 3.0, 10.0, 20.0, 30.0])
    same = Transform(np.array(t.p), np.array(t.R))
    assert t == same and hash(t) == hash(same) and t != Transform.identity()
    with pytest.raises(ValueError, match='read-only'):
        t.p[0] = 1.0
    with pytest.raises(AttributeError):
        t.p = np.zeros(3)  # type: ignore[misc]
    source = np.zeros(3)
    u = Transform(source, np.eye(3))
    source[0] = 1.0
    assert u.p[0] == 0.0  # a copy


@pytest.mark.parametrize(('p', 'r', 'message'), [
    ([0.0, 0.0], np.eye(3), r'expected shape \(\.\.\., 3\)'),
    ([0.0, np.nan, 0.0], np.eye(3), 'not finite'),
    ([0.0, 0.0, 0.0], np.eye(2), r'expected shape \(3, 3\)'),
    ([0.0, 0.0, 0.0], np.diag([1.0, 1.0, np.inf]), 'not finite'),
    ([0.0, 0.0, 0.0], np.diag([1.0, 1.0, -1.0]), 'not a proper rotation'),
    ([0.0, 0.0, 0.0], 1.001 * np.eye(3), 'not a proper rotation'),
])
def test_transform_refuses_bad_numbers(p: list[float], r: FloatArray, message: str) -> None:
    with pytest.raises(InputError, match=message):
        Transform(np.asarray(p), r)


def test_transform_refuses_bad_poses() -> None:
    with pytest.raises(InputError, match='not finite'):
        Transform.from_pq([0.0, 0.0, np.inf], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(InputError, match='norm'):
        Transform.from_pq([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 2.0])
    with pytest.raises(InputError, match='expected one pose'):
        Transform.from_pq(np.zeros((2, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)))
    with pytest.raises(InputError, match=r'expected shape \(6,\)'):
        Transform.from_pose6(np.zeros((2, 6)))
    with pytest.raises(InputError, match='not finite'):
        Transform.from_human([0.0, 0.0, 0.0, 0.0, np.nan, 0.0])


# -- six numbers ---------------------------------------------------------------------------------
def test_the_rotation_is_rz_ry_rx_about_fixed_axes() -> None:
    """R = Rz(Rz)·Ry(Ry)·Rx(Rx), built by hand, for angles of every sign and size."""
    rng = np.random.default_rng(7)
    angles = np.vstack([rng.uniform(-math.pi, math.pi, (20, 3)),
                        [[0.3, 0.0, 0.0], [0.0, -0.4, 0.0], [0.0, 0.0, 2.5],
                         [math.pi / 2, math.pi / 2, math.pi / 2]]])
    for a, b, c in angles:
        hand = rz(c) @ ry(b) @ rx(a)
        np.testing.assert_allclose(Transform.from_pose6([0, 0, 0, a, b, c]).R, hand,
                                   rtol=0.0, atol=1e-15)
        _, q = pq_from_pose6([0.0, 0.0, 0.0, a, b, c])
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), hand, rtol=0.0, atol=1e-15)
    # The order matters: Rx 90° then Rz 90° (fixed axes) takes y to z; the other order to −x.
    r = Transform.from_human([0.0, 0.0, 0.0, 90.0, 0.0, 90.0]).R
    np.testing.assert_allclose(r @ [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], atol=1e-15)


@FEW
@given(st.tuples(_coordinate, _coordinate, _coordinate),
       st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_six_numbers_round_trip(p: tuple[float, float, float], a: float, b: float,
                                c: float) -> None:
    pose6 = np.array([*p, a, b, c])
    pos, q = pq_from_pose6(pose6)
    np.testing.assert_allclose(pose6_from_pq(pos, q), pose6, rtol=0.0, atol=TOL)
    t = Transform.from_pose6(pose6)
    np.testing.assert_allclose(t.to_pose6(), pose6, rtol=0.0, atol=TOL)
    human = human_from_pose6(pose6)
    np.testing.assert_allclose(human[:3], np.asarray(p) * 1e3, rtol=1e-15)
    np.testing.assert_allclose(human[3:], np.degrees([a, b, c]), rtol=1e-15)
    np.testing.assert_allclose(pose6_from_human(human), pose6, rtol=1e-15, atol=1e-18)
    assert_close(Transform.from_human(t.to_human()), t)


@FEW
@given(transforms())
def test_any_rotation_survives_six_numbers(t: Transform) -> None:
    """Every rotation, gimbal lock included, comes back from its six numbers."""
    assert_close(Transform.from_pose6(pose6_from_pq(*t.to_pq())), t)
    pose6 = t.to_pose6()
    assert abs(pose6[3]) <= math.pi and abs(pose6[4]) <= math.pi / 2 and abs(pose6[5]) <= math.pi


def test_gimbal_lock_is_silent_and_sets_rz_to_zero() -> None:
    for b in (math.pi / 2, -math.pi / 2):
        t = Transform.from_pose6([0.0, 0.0, 0.0, 0.3, b, 0.2])
        with warnings.catch_warnings():
            warnings.simplefilter('error')
            pose6 = t.to_pose6()
            batch = pose6_from_pq(*t.to_pq())
        assert pose6[5] == 0.0 and batch[5] == 0.0
        assert_close(Transform.from_pose6(pose6), t)


def test_six_numbers_are_vectorised() -> None:
    rng = np.random.default_rng(3)
    pose6 = np.concatenate([rng.uniform(-0.1, 0.1, (2, 5, 3)), rng.uniform(-1.0, 1.0, (2, 5, 3))],
                           axis=-1)
    p, q = pq_from_pose6(pose6)
    assert p.shape == (2, 5, 3) and q.shape == (2, 5, 4)
    assert pose6_from_pq(p, q).shape == (2, 5, 6)
    assert human_from_pose6(pose6).shape == pose6_from_human(pose6).shape == (2, 5, 6)
    for i, j in np.ndindex(2, 5):
        one = Transform.from_pose6(pose6[i, j])
        assert_close(Transform.from_pq(p[i, j], q[i, j]), one)
    empty_p, empty_q = pq_from_pose6(np.empty((0, 6)))
    assert empty_p.shape == (0, 3) and empty_q.shape == (0, 4)


@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
def test_six_numbers_refuse_nan_and_inf(bad: float) -> None:
    pose6 = np.zeros((3, 6))
    pose6[1, 4] = bad
    for convert in (pq_from_pose6, human_from_pose6, pose6_from_human):
        with pytest.raises(InputError, match=r'\[1\].*not finite'):
            convert(pose6)
    with pytest.raises(InputError, match='not finite'):
        pose6_from_pq([0.0, bad, 0.0], [0.0, 0.0, 0.0, 1.0])
    with pytest.raises(InputError, match='not finite'):
        pose6_from_pq([0.0, 0.0, 0.0], [0.0, 0.0, bad, 1.0])


def test_six_numbers_refuse_bad_shapes_and_quaternions() -> None:
    with pytest.raises(InputError, match=r'expected shape \(\.\.\., 6\)'):
        pq_from_pose6(np.zeros(5))
    with pytest.raises(InputError, match=r'expected shape \(\.\.\., 6\)'):
        human_from_pose6(1.0)
    with pytest.raises(InputError, match='expected numbers'):
        pose6_from_human(['a'] * 6)
    with pytest.raises(InputError, match='batch shape'):
        pose6_from_pq(np.zeros((2, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))
    with pytest.raises(InputError, match='is zero'):
        pose6_from_pq(np.zeros(3), np.zeros(4))


def test_format_human() -> None:
    text = format_human(Transform.from_human([10.0, -0.5, 3.25, 0.0, 30.0, -45.0]).to_human())
    assert text == '10.000000 -0.500000 3.250000 mm 0.000000 30.000000 -45.000000 deg'
    assert str(Transform.identity()) == format_human(np.zeros(6))
    with pytest.raises(InputError, match=r'expected shape \(6,\)'):
        format_human(np.zeros((2, 6)))


# -- machine, user and object CS -----------------------------------------------------------------
def test_machine_pose_at_home_is_zero() -> None:
    machine = CoordinateSystems.machine_from_base(MECH.home_position, MECH.home_quaternion, MECH)
    assert np.array_equal(machine.p, np.zeros(3)) and np.array_equal(machine.R, np.eye(3))
    assert np.array_equal(machine.to_pose6(), np.zeros(6))
    p, q = CoordinateSystems.base_from_machine(Transform.identity(), MECH)
    assert np.array_equal(p, MECH.home_position) and np.array_equal(q, MECH.home_quaternion)


class _TiltedHome(Mechanism):
    """A mechanism whose home orientation is not the identity."""

    @property
    def home_quaternion(self) -> FloatArray:
        return np.asarray(Rotation.from_rotvec([0.0, 0.1, 0.0]).as_quat())


def test_machine_axes_stay_parallel_to_base_for_a_tilted_home() -> None:
    mech = _TiltedHome()
    machine = CoordinateSystems.machine_from_base(mech.home_position, mech.home_quaternion, mech)
    assert np.array_equal(machine.p, np.zeros(3))
    np.testing.assert_allclose(machine.R, Rotation.from_rotvec([0.0, 0.1, 0.0]).as_matrix(),
                               atol=1e-15)


@FEW
@given(poses())
def test_machine_pose_is_the_platform_pose_relative_to_home(
        pose: tuple[FloatArray, FloatArray]) -> None:
    p, q = pose
    machine = CoordinateSystems.machine_from_base(p, q, MECH)
    np.testing.assert_allclose(machine.p, p - MECH.home_position, rtol=0.0, atol=TOL)
    back_p, back_q = CoordinateSystems.base_from_machine(machine, MECH)
    assert_close(Transform.from_pq(back_p, back_q), Transform.from_pq(p, q))


@FEW
@given(poses())
def test_identity_systems_make_the_user_position_the_machine_pose(
        pose: tuple[FloatArray, FloatArray]) -> None:
    p, q = pose
    systems = CoordinateSystems()
    assert systems.user == Transform.identity() and systems.object == Transform.identity()
    assert_close(systems.user_position(p, q, MECH),
                 CoordinateSystems.machine_from_base(p, q, MECH))


@FEW
@given(transforms(), transforms(), transforms())
def test_user_position_of_an_absolute_goal_is_the_goal(user: Transform, obj: Transform,
                                                       goal: Transform) -> None:
    systems = CoordinateSystems(user=user, object=obj)
    p, q = systems.base_goal_absolute(goal, MECH)
    assert_close(systems.user_position(p, q, MECH), goal)
    # the same through the request and through a (p, q) pair
    p2, q2 = systems.resolve_goal(ABSOLUTE, USER_FRAME, goal.to_pq(), None, MECH)
    assert_close(Transform.from_pq(p2, q2), Transform.from_pq(p, q))


def test_user_and_object_frames_by_hand() -> None:
    """A user CS 10 mm along machine x; an object 50 mm above the platform origin."""
    systems = CoordinateSystems(user=Transform.from_human([10.0, 0, 0, 0, 0, 0]),
                                object=Transform.from_human([0, 0, 50.0, 0, 0, 0]))
    p, q = systems.base_goal_absolute(Transform.identity(), MECH)
    np.testing.assert_allclose(p, MECH.home_position + [0.010, 0.0, -0.050], atol=1e-15)
    np.testing.assert_allclose(q, [0.0, 0.0, 0.0, 1.0], atol=1e-15)
    # at home the object (50 mm above the platform) is at z = 50 mm, x = −10 mm in the user CS
    g = systems.user_position(MECH.home_position, MECH.home_quaternion, MECH)
    np.testing.assert_allclose(g.to_human(), [-10.0, 0.0, 50.0, 0.0, 0.0, 0.0], atol=1e-12)


@FEW
@given(transforms(), transforms())
def test_batch_user_positions_match_one_by_one(user: Transform, obj: Transform) -> None:
    """A batch larger than core.poses.SMALL_BATCH too (a move's samples against a user box)."""
    systems = CoordinateSystems(user=user, object=obj)
    rng = np.random.default_rng(5)
    n = SMALL_BATCH + 4
    p = MECH.home_position + rng.uniform(-0.01, 0.01, (n, 3))
    q = Rotation.from_rotvec(rng.uniform(-0.1, 0.1, (n, 3))).as_quat()
    bp, bq = systems.user_positions(p, q, MECH)
    left = Transform.from_human([1, 2, 3, 4, 5, 6])
    cp, cq = compose_poses(left, p, q, obj)
    for i in range(n):
        assert_close(Transform.from_pq(bp[i], bq[i]), systems.user_position(p[i], q[i], MECH))
        assert_close(Transform.from_pq(cp[i], cq[i]),
                     left @ Transform.from_pq(p[i], q[i]) @ obj)
    assert (bq[:, 3] >= 0.0).all() and (cq[:, 3] >= 0.0).all()


@FEW
@given(transforms(), transforms())
def test_relative_moves_and_their_inverses_return_to_the_start(goal: Transform,
                                                               delta: Transform) -> None:
    there = CoordinateSystems.relative_object(goal, delta)
    assert_close(CoordinateSystems.relative_object(there, delta.inverse()), goal)
    there = CoordinateSystems.relative_user(goal, delta)
    back = Transform(-delta.p, delta.R.T)
    assert_close(CoordinateSystems.relative_user(there, back), goal)


@FEW
@given(transforms(), transforms(), transforms(), quaternions())
def test_rotations_turn_about_the_pivot(user: Transform, obj: Transform, goal: Transform,
                                        q: FloatArray) -> None:
    """A pure rotation, relative to the object or to the user, leaves the pivot in place."""
    systems = CoordinateSystems(user=user, object=obj)
    rotation = Transform.from_pq(np.zeros(3), q)
    start = pivot_in_base(systems, goal)
    for move in (systems.relative_object, systems.relative_user):
        moved = move(goal, rotation)
        np.testing.assert_allclose(pivot_in_base(systems, moved), start, rtol=0.0, atol=TOL)
        np.testing.assert_allclose(moved.R, goal.R @ rotation.R, rtol=0.0, atol=TOL)


@FEW
@given(transforms(), transforms(), transforms(), st.tuples(_coordinate, _coordinate, _coordinate))
def test_translations_follow_the_user_or_the_object_axes(
        user: Transform, obj: Transform, goal: Transform, t: tuple[float, float, float]) -> None:
    systems = CoordinateSystems(user=user, object=obj)
    shift = Transform(np.asarray(t), np.eye(3))
    start = pivot_in_base(systems, goal)
    moved = systems.relative_user(goal, shift)
    np.testing.assert_allclose(moved.p - goal.p, t, rtol=0.0, atol=TOL)
    np.testing.assert_allclose(moved.R, goal.R, rtol=0.0, atol=0.0)
    # in base: along the user axes (the machine axes are the base axes)
    np.testing.assert_allclose(pivot_in_base(systems, moved) - start, user.R @ t,
                               rtol=0.0, atol=TOL)
    p, q = systems.base_goal_absolute(moved, MECH)
    np.testing.assert_allclose(systems.user_position(p, q, MECH).p - goal.p, t,
                               rtol=0.0, atol=TOL)
    moved = systems.relative_object(goal, shift)
    np.testing.assert_allclose(moved.p - goal.p, goal.R @ t, rtol=0.0, atol=TOL)


# -- requests ------------------------------------------------------------------------------------
SYSTEMS = CoordinateSystems(user=Transform.from_human([5.0, -3.0, 2.0, 1.0, -2.0, 30.0]),
                            object=Transform.from_human([0.0, 10.0, 80.0, 0.0, 5.0, 0.0]))
GOAL = Transform.from_human([1.0, 2.0, 3.0, 0.5, 0.2, -4.0])
DELTA = Transform.from_human([0.3, -0.2, 0.1, 0.0, 1.0, 2.0])


def test_resolve_absolute_goals() -> None:
    p = MECH.home_position + [0.001, 0.0, 0.0]
    q = np.array([0.0, 0.0, -0.6, -0.8])  # w < 0: returned as given
    got_p, got_q = SYSTEMS.resolve_goal(ABSOLUTE, BASE_FRAME, (p, q), None, MECH)
    assert np.array_equal(got_p, p) and np.array_equal(got_q, q)
    machine = Transform.from_human([1.0, 0, 0, 0, 0, 10.0])
    got_p, got_q = SYSTEMS.resolve_goal(ABSOLUTE, MACHINE_FRAME, machine, None, MECH)
    assert_close(Transform.from_pq(got_p, got_q),
                 Transform.from_pq(*CoordinateSystems.base_from_machine(machine, MECH)))
    assert_close(CoordinateSystems.machine_from_base(got_p, got_q, MECH), machine)
    got_p, got_q = SYSTEMS.resolve_goal(ABSOLUTE, USER_FRAME, GOAL, None, MECH)
    assert_close(SYSTEMS.user_position(got_p, got_q, MECH), GOAL)


@pytest.mark.parametrize(('kind', 'frame_id', 'expected'), [
    (RELATIVE_USER, USER_FRAME, CoordinateSystems.relative_user(GOAL, DELTA)),
    (RELATIVE_USER, '', CoordinateSystems.relative_user(GOAL, DELTA)),
    (RELATIVE_OBJECT, OBJECT_FRAME, CoordinateSystems.relative_object(GOAL, DELTA)),
    (RELATIVE_OBJECT, '', CoordinateSystems.relative_object(GOAL, DELTA)),
])
def test_resolve_relative_goals(kind: str, frame_id: str, expected: Transform) -> None:
    p, q = SYSTEMS.resolve_goal(kind, frame_id, DELTA.to_pq(), GOAL, MECH)
    assert_close(SYSTEMS.user_position(p, q, MECH), expected)


@pytest.mark.parametrize(('kind', 'frame_id', 'message'), [
    (ABSOLUTE, OBJECT_FRAME, "absolute goal .* 'base', 'machine', 'user', not in frame_id "
                             "'object'"),
    (ABSOLUTE, '', "'base', 'machine', 'user', not in frame_id ''"),
    (ABSOLUTE, 'platform', "not in frame_id 'platform'"),
    (RELATIVE_USER, BASE_FRAME, "relative_user move is given in the user CS: frame_id must be "
                                "'user' \\(or empty\\), not 'base'"),
    (RELATIVE_USER, OBJECT_FRAME, "must be 'user' .*not 'object'"),
    (RELATIVE_OBJECT, USER_FRAME, "relative_object move is given in the object CS: frame_id "
                                  "must be 'object' \\(or empty\\), not 'user'"),
    ('relative', USER_FRAME, "move kind 'relative' is not one of 'absolute', 'relative_user', "
                             "'relative_object'"),
    ('', BASE_FRAME, "move kind '' is not one of"),
])
def test_resolve_refuses_bad_frames_and_kinds(kind: str, frame_id: str, message: str) -> None:
    with pytest.raises(InputError, match=message):
        SYSTEMS.resolve_goal(kind, frame_id, DELTA, GOAL, MECH)


def test_resolve_refuses_bad_poses_and_a_missing_reference() -> None:
    with pytest.raises(InputError, match='needs the current user position'):
        SYSTEMS.resolve_goal(RELATIVE_OBJECT, '', DELTA, None, MECH)
    with pytest.raises(InputError, match=r'base goal: .*not finite'):
        SYSTEMS.resolve_goal(ABSOLUTE, BASE_FRAME, ([0.0, np.nan, 0.2], [0, 0, 0, 1]), None,
                             MECH)
    with pytest.raises(InputError, match=r'relative move: .*norm'):
        SYSTEMS.resolve_goal(RELATIVE_USER, USER_FRAME, ([0.0, 0.0, 0.0], [0, 0, 0, 3]), GOAL,
                             MECH)
    with pytest.raises(InputError, match='expected a Transform or'):
        SYSTEMS.resolve_goal(ABSOLUTE, USER_FRAME, 3.0, None, MECH)  # type: ignore[arg-type]
    with pytest.raises(InputError, match='user must be a Transform'):
        CoordinateSystems(user=None)  # type: ignore[arg-type]


# -- the file ------------------------------------------------------------------------------------
def test_file_round_trip(tmp_path: Path) -> None:
    path = tmp_path / 'coordinate_systems.yaml'
    assert write(path, SYSTEMS) == path
    loaded = load(path)
    assert_close(loaded.user, SYSTEMS.user, 1e-15)
    assert_close(loaded.object, SYSTEMS.object, 1e-15)
    assert np.array_equal(loaded.user.p, SYSTEMS.user.p)
    text = path.read_text()
    assert 'human: 5.000000 -3.000000 2.000000 mm 1.000000 -2.000000 30.000000 deg' in text
    write(path, CoordinateSystems())  # replaces
    assert load(path) == CoordinateSystems()
    assert sorted(os.listdir(tmp_path)) == ['coordinate_systems.yaml']  # no temporary left


def test_a_missing_file_is_the_identity(tmp_path: Path) -> None:
    assert load(tmp_path / 'none.yaml') == CoordinateSystems()


def test_human_is_optional_and_may_be_shorter(tmp_path: Path) -> None:
    path = tmp_path / 'cs.yaml'
    path.write_text('coordinate_systems:\n'
                    '  user: {position_m: [0.01, 0, 0], quaternion_xyzw: [0, 0, 0, 1],\n'
                    "         human: '10 0 0 mm 0 0 0 deg'}\n"
                    '  object: {position_m: [0, 0, 0.05], quaternion_xyzw: [0, 0, 0, 1]}\n')
    systems = load(path)
    assert np.array_equal(systems.user.p, [0.01, 0.0, 0.0])
    assert np.array_equal(systems.object.p, [0.0, 0.0, 0.05])


_GOOD_USER = '  user: {position_m: [0.0, 0.0, 0.0], quaternion_xyzw: [0.0, 0.0, 0.0, 1.0]}\n'
_GOOD_OBJECT = '  object: {position_m: [0.0, 0.0, 0.0], quaternion_xyzw: [0.0, 0.0, 0.0, 1.0]}\n'


@pytest.mark.parametrize(('text', 'message'), [
    ('coordinate_systems: [unclosed\n', 'not valid YAML'),
    ('', 'expected exactly one mapping "coordinate_systems:", found NoneType'),
    ('systems: {}\n', r"found \['systems'\]"),
    ('coordinate_systems: 3\n', '"coordinate_systems" is not a mapping'),
    ('coordinate_systems:\n' + _GOOD_USER, 'coordinate_systems lacks object'),
    ('coordinate_systems:\n' + _GOOD_USER + _GOOD_OBJECT + '  tool: {}\n',
     'has unknown keys tool'),
    ('coordinate_systems:\n  user: 1\n' + _GOOD_OBJECT, 'user is not a mapping'),
    ('coordinate_systems:\n  user: {position_m: [0, 0, 0], quaternion: [0, 0, 0, 1]}\n'
     + _GOOD_OBJECT, 'user lacks quaternion_xyzw and has unknown keys quaternion'),
    ('coordinate_systems:\n  user: {position_m: [0, .nan, 0], quaternion_xyzw: [0, 0, 0, 1]}\n'
     + _GOOD_OBJECT, r'user.position_m = \[0, nan, 0\]: not finite'),
    ('coordinate_systems:\n' + _GOOD_USER
     + '  object: {position_m: [0, 0, 0], quaternion_xyzw: [0, 0, .inf, 1]}\n',
     'object.quaternion_xyzw = .*not finite'),
    ('coordinate_systems:\n' + _GOOD_USER
     + '  object: {position_m: [0, 0, 0], quaternion_xyzw: [0, 0, 0.1, 1]}\n',
     r'object.quaternion_xyzw\[0\] = .* has norm 1.00498756, not 1'),
    ('coordinate_systems:\n  user: {position_m: [0, 0], quaternion_xyzw: [0, 0, 0, 1]}\n'
     + _GOOD_OBJECT, 'user.position_m = .*: expected a list of 3 numbers'),
    ('coordinate_systems:\n  user: {position_m: [0, true, 0], quaternion_xyzw: [0, 0, 0, 1]}\n'
     + _GOOD_OBJECT, 'expected a list of 3 numbers'),
    ('coordinate_systems:\n  user: {position_m: [1e-3, 0, 0], quaternion_xyzw: [0, 0, 0, 1]}\n'
     + _GOOD_OBJECT, r'YAML reads 1e-3 as text: write 1.0e-3'),
    ('coordinate_systems:\n  user: {position_m: [0, 0, 0], quaternion_xyzw: [0, 0, 0, 1],\n'
     "         human: '1 0 0 mm 0 0 0 deg'}\n" + _GOOD_OBJECT,
     "user.human = '1 0 0 mm 0 0 0 deg' disagrees with position_m and quaternion_xyzw"),
    ('coordinate_systems:\n  user: {position_m: [0, 0, 0], quaternion_xyzw: [0, 0, 0, 1],\n'
     "         human: '0 0 0 0 0 0'}\n" + _GOOD_OBJECT,
     "user.human = '0 0 0 0 0 0': expected 'Tx Ty Tz mm Rx Ry Rz deg'"),
])
def test_bad_files_are_refused_naming_the_file(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / 'cs.yaml'
    path.write_text(text)
    with pytest.raises(CoordinateSystemsFileError, match=message) as caught:
        load(path)
    assert str(path) in str(caught.value)
    assert isinstance(caught.value, ConfigError)
    assert path.read_text() == text  # nothing changed


def test_an_unreadable_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(CoordinateSystemsFileError, match=f"'{tmp_path}': cannot be read"):
        load(tmp_path)  # a directory


def test_a_failed_write_changes_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / 'cs.yaml'
    write(path, SYSTEMS)
    before = path.read_text()

    def refuse(src: str, dst: str) -> None:
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(os, 'replace', refuse)
    with pytest.raises(CoordinateSystemsFileError,
                       match=f"'{path}': cannot be written \\(No space left on device\\)"):
        write(path, CoordinateSystems())
    assert path.read_text() == before
    assert sorted(os.listdir(tmp_path)) == ['cs.yaml']
    monkeypatch.undo()
    with pytest.raises(CoordinateSystemsFileError, match='cannot be written'):
        write(path / 'cs.yaml', SYSTEMS)  # its folder would be a file


def test_a_missing_folder_is_created(tmp_path: Path) -> None:
    """A fresh ROS_HOME has no positioning_cell/ folder: the first write makes it."""
    path = tmp_path / 'fresh_ros_home' / 'positioning_cell' / 'coordinate_systems.yaml'
    assert load(path) == CoordinateSystems()
    assert write(path, SYSTEMS) == path
    assert_close(load(path).user, SYSTEMS.user, 1e-15)
