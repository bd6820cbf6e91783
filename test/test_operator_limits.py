"""The operator's limits (positioning_cell.limits): the validity bitmask and margins of a check,
the factory, machine and user boxes, the speeds an operator sets, and the jog of one axis."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from workspace import MECH

from positioning_cell.core import kinematics
from positioning_cell.core.limits import check_poses, limit_values, within_limits
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.limits.boxes import (
    AXES,
    BoxLimits,
    FactoryBoxSettings,
    LimitLayers,
    base_pq_of_machine_pose6,
    derived_factory_box,
)
from positioning_cell.limits.jog import jog_target, jog_trajectory
from positioning_cell.limits.speed import Speeds, motion_limits, scaled, set_speeds
from positioning_cell.limits.validity import (
    CONSTRAINT_BITS,
    VALID,
    CheckResult,
    Validity,
    bit_names,
    bits_of,
    factory_check,
    factory_constraints,
    factory_margins,
    invalid_goal,
    result_code,
    state_check,
)
from positioning_cell.moves.outcomes import ResultCode
from positioning_cell.moves.trajectory import MotionLimits
from positioning_cell.parameters import parse

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
MM, DEG = 1e-3, math.radians(1.0)


def pose6_of(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Machine pose6 (N, 6) of base poses, as frames/ defines it (zero at home)."""
    p, q = np.atleast_2d(p), np.atleast_2d(q)
    return np.hstack([p - MECH.home_position, Rotation.from_quat(q).as_euler('xyz')])


# -- the validity bitmask -------------------------------------------------------------------------
def test_the_bits_are_those_of_the_message() -> None:
    from positioning_cell_interfaces.msg import Validity as ValidityMsg
    constants = {k: v for k, v in vars(ValidityMsg).items() if k.isupper() and k[0] != '_'
                 and isinstance(v, int)}
    assert {b.name: int(b) for b in Validity} == constants
    assert constants['WORKSPACE'] == 1 and constants['TRACKER_SILENT'] == 32768


def test_every_constraint_of_the_core_has_a_bit_in_order() -> None:
    p, q = MECH.home_position[None], IDENTITY[None]
    assert [name for name, *_ in limit_values(MECH, p, q)] == list(CONSTRAINT_BITS)
    assert CONSTRAINT_BITS['length_min'] is CONSTRAINT_BITS['length_max'] is Validity.STROKE
    assert CONSTRAINT_BITS['conditioning_min'] is Validity.SINGULARITY


def test_home_is_valid_with_positive_margins() -> None:
    result = factory_check(MECH, MECH.home_position, IDENTITY)
    assert result.valid and result.bits == VALID and result.violations == ()
    assert result.message() == 'valid' and result.code is ResultCode.SUCCESS
    assert bits_of(check_poses(MECH, MECH.home_position, IDENTITY)) == VALID
    margins = factory_margins(MECH, MECH.home_position, IDENTITY)
    assert set(margins) == set(CONSTRAINT_BITS) and min(margins.values()) > 0.0
    assert margins['length_max'] == pytest.approx(MECH.length_max - MECH.home_length)
    assert result.margins == {f'factory.{k}': v for k, v in margins.items()}


def test_a_raised_pose_is_out_of_stroke() -> None:
    high = MECH.home_position + [0.0, 0.0, 0.050]
    report = check_poses(MECH, high, IDENTITY)
    assert bits_of(report) == Validity.STROKE
    result = factory_check(MECH, high, IDENTITY)
    assert result.bits == Validity.STROKE and result.code is ResultCode.REFUSED_LIMITS
    length = kinematics.inverse(MECH, high, IDENTITY).lengths[0, 0]
    assert result.margins['factory.length_max'] == pytest.approx(MECH.length_max - length)
    assert result.margins['factory.length_min'] > 0.0
    assert result.violations[0].startswith('factory: sample 0: leg 1 length')
    assert 'above the maximum 220.0000 mm' in result.violations[0]
    assert bit_names(result.bits) == ('stroke',)


def test_a_strongly_tilted_pose_breaks_stroke_and_the_spherical_joints() -> None:
    q = Rotation.from_euler('xyz', [0.9, 0.0, 0.0]).as_quat()
    expected = Validity.STROKE | Validity.SPHERICAL_TILT
    assert bits_of(check_poses(MECH, MECH.home_position, q)) == expected
    result = factory_check(MECH, MECH.home_position, q)
    assert result.bits == expected
    assert result.margins['factory.spherical_tilt'] < 0.0
    assert any('spherical-joint tilt' in line for line in result.violations)


def test_a_degenerate_pose_is_out_of_the_workspace() -> None:
    # The platform joint of leg 1 on its base joint: a leg of zero length.
    degenerate = (MECH.base_radius - MECH.platform_radius) * MECH.radial[0]
    p = np.vstack([degenerate, MECH.home_position])
    result = factory_check(MECH, p, np.tile(IDENTITY, (2, 1)))
    assert result.bits == Validity.WORKSPACE
    assert result.violations == ('factory: sample 0: no pose, the inverse kinematics fails',)
    assert result.margins['factory.length_min'] == -math.inf
    assert factory_check(MECH, MECH.home_position, IDENTITY).valid


def test_a_long_path_has_every_bit_though_its_report_lists_fifty() -> None:
    mech = Mechanism(theta_min=-0.1, theta_max=0.1)
    twisted = Rotation.from_rotvec([0.0, 0.0, 0.8]).as_quat()
    p = np.vstack([np.tile(mech.home_position + [0.0, 0.0, 0.03], (30, 1)),
                   mech.home_position])
    q = np.vstack([np.tile(IDENTITY, (30, 1)), twisted])
    report = check_poses(mech, p, q)
    assert report.n_violations > len(report.violations)
    assert bits_of(report) == Validity.STROKE  # only what the report lists
    result = factory_check(mech, p, q)
    assert result.bits == Validity.STROKE | Validity.THETA
    # a line per violated constraint and leg, at its worst sample, with the count outside
    assert all('(the worst of 30 of 31 samples outside)' in v
               for v in result.violations if 'length' in v), result.violations
    assert any('sample 30: leg' in v and 'theta' in v for v in result.violations)
    assert len(result.violations) <= 6


_UNIT = st.floats(-1.0, 1.0, allow_nan=False)


@given(st.tuples(*[_UNIT] * 6))
def test_margins_are_negative_exactly_where_a_bit_is_set(u: tuple[float, ...]) -> None:
    """Over a wide box around home (valid and invalid poses alike)."""
    p = MECH.home_position + np.array(u[:3]) * [0.06, 0.06, 0.04]
    q = Rotation.from_rotvec(np.array(u[3:]) * 1.2).as_quat()
    result = factory_check(MECH, p, q)
    margins = factory_margins(MECH, p, q)
    for bit in set(CONSTRAINT_BITS.values()):
        worst = min(m for name, m in margins.items() if CONSTRAINT_BITS[name] is bit)
        assert (worst < 0.0) == bool(result.bits & bit), (bit, margins)
    assert result.valid == bool(within_limits(MECH, p, q)[0])
    assert bits_of(check_poses(MECH, p, q)) == result.bits


def test_the_margins_of_a_path_are_those_of_its_worst_sample() -> None:
    rng = np.random.default_rng(7)
    p = MECH.home_position + rng.uniform(-1.0, 1.0, (40, 3)) * [0.05, 0.05, 0.03]
    q = Rotation.from_rotvec(rng.uniform(-1.0, 1.0, (40, 3)) * 0.8).as_quat()
    path = factory_margins(MECH, p, q)
    each = [factory_margins(MECH, p[i], q[i]) for i in range(40)]
    bits = VALID
    for i in range(40):
        bits |= factory_check(MECH, p[i], q[i]).bits
    for name in CONSTRAINT_BITS:
        assert path[name] == pytest.approx(min(m[name] for m in each), abs=1e-12)
    assert factory_check(MECH, p, q).bits == bits and bits != VALID


def test_a_check_result_keeps_bits_and_reasons_together() -> None:
    with pytest.raises(InputError, match='needs a line'):
        CheckResult(Validity.STROKE)
    with pytest.raises(InputError, match='needs a line'):
        CheckResult(VALID, ('factory: something',))
    with pytest.raises(InputError, match='not a validity bitmask'):
        CheckResult(1 << 20, ('x',))  # type: ignore[arg-type]
    state = state_check(referenced=False, busy=True)
    assert state.bits == Validity.NOT_REFERENCED | Validity.BUSY
    assert state.violations[0].startswith('state: ') and state.code is ResultCode.REFUSED_BUSY
    merged = factory_check(MECH, MECH.home_position + [0.0, 0.0, 0.05], IDENTITY).merged(
        state, invalid_goal('position is NaN'))
    assert merged.bits == (Validity.STROKE | Validity.NOT_REFERENCED | Validity.BUSY
                           | Validity.INVALID_GOAL)
    assert merged.violations[-1] == 'state: invalid goal: position is NaN'
    assert '(+' in merged.message(most=2)
    with pytest.raises(TypeError):
        merged.margins['factory.length_max'] = 0.0  # type: ignore[index]
    assert state_check().valid
    lines = factory_constraints(MECH)
    assert lines[0] == 'stroke: leg length 180.000 .. 220.000 mm' and len(lines) == 6


def test_the_result_code_follows_the_positioner_order() -> None:
    assert result_code(0) is ResultCode.SUCCESS
    assert result_code(Validity.USER_LIMITS) is ResultCode.REFUSED_LIMITS
    assert result_code(Validity.WORKSPACE | Validity.NOT_REFERENCED) is \
        ResultCode.REFUSED_NOT_REFERENCED
    assert result_code(Validity.DRIVE_FAULT | Validity.NOT_REFERENCED) is \
        ResultCode.REFUSED_DRIVE_FAULT
    assert result_code(Validity.DRIVES_OFF | Validity.DRIVE_FAULT) is \
        ResultCode.REFUSED_DRIVES_OFF
    assert result_code(Validity.INVALID_GOAL | Validity.DRIVES_OFF) is \
        ResultCode.REFUSED_INVALID_GOAL
    assert result_code(Validity.BUSY | Validity.INVALID_GOAL) is ResultCode.REFUSED_BUSY


# -- boxes ----------------------------------------------------------------------------------------
def box_mm_deg(half_mm: float, half_deg: float) -> BoxLimits:
    half = np.array([half_mm * MM] * 3 + [half_deg * DEG] * 3)
    return BoxLimits(tuple(-half), tuple(half))


def test_a_box_is_validated_naming_the_axis() -> None:
    lower, upper = [-0.01] * 6, [0.01] * 6
    with pytest.raises(InputError, match=re.escape('Ty: lower bound 20.000 mm above')):
        BoxLimits(tuple(lower[:1] + [0.02] + lower[2:]), tuple(upper))
    with pytest.raises(InputError, match=r'Rz: .*NaN'):
        BoxLimits(tuple(lower[:5] + [math.nan]), tuple(upper))
    with pytest.raises(InputError, match=r'Rx: upper bound 200\.000 deg outside \[-180, 180\]'):
        BoxLimits(tuple(lower), tuple(upper[:3] + [math.radians(200.0)] + upper[4:]))
    with pytest.raises(InputError, match=r'Tx: .*no limit'):
        BoxLimits((math.inf, *lower[1:]), (math.inf, *upper[1:]))
    with pytest.raises(InputError, match='6 numbers'):
        BoxLimits((0.0,) * 5, (0.0,) * 5)
    unlimited = BoxLimits.unlimited()
    assert unlimited.is_unlimited and not unlimited.is_finite
    assert BoxLimits(np.zeros(6), np.ones(6) * 0.1).upper == (0.1,) * 6  # type: ignore[arg-type]


def test_a_box_check_says_which_axis_by_how_much_and_where() -> None:
    box = BoxLimits((-0.05, -0.05, -0.05, -0.5, -0.5, -0.5), (0.05, 0.05, 0.05, 0.5, 0.5, 0.5))
    poses = np.zeros((5, 6))
    poses[3, 2] = 0.052
    poses[1, 3] = -math.radians(31.0)
    poses[4, 5] = 2.0 * math.pi + 0.1  # wraps to 0.1 rad: inside
    ok, lines, margins = box.check(poses, 'machine limits')
    assert ok.tolist() == [True, False, True, False, True]
    assert lines == [  # axis order, each at its worst sample
        'machine limits: Tz 52.000 mm above the maximum 50.000 mm by 2.000 mm at sample 3',
        'machine limits: Rx -31.000 deg below the minimum -28.648 deg by 2.352 deg at sample 1']
    poses[2, 2] = 0.06
    _, lines, _ = box.check(poses, 'machine limits')
    assert lines[0] == ('machine limits: Tz 60.000 mm above the maximum 50.000 mm by 10.000 mm '
                        'at sample 2 (the worst of 2 of 5 samples outside)')
    assert set(margins) == set(AXES)
    assert margins['Tz'] == pytest.approx(-0.002)
    assert margins['Rx'] == pytest.approx(0.5 - math.radians(31.0))
    assert margins['Tx'] == pytest.approx(0.05) and margins['Rz'] == pytest.approx(0.4)
    ok, lines, margins = BoxLimits.unlimited().check(poses, 'user limits')
    assert ok.all() and lines == [] and margins['Tx'] == math.inf


def test_containment_names_what_is_outside() -> None:
    outer, inner = box_mm_deg(50.0, 10.0), box_mm_deg(20.0, 5.0)
    assert outer.contains(inner) == [] and outer.contains(outer) == []
    wide = BoxLimits(inner.lower[:4] + (-math.radians(12.0),) + inner.lower[5:],
                     inner.upper[:2] + (0.06,) + inner.upper[3:])
    assert outer.contains(wide) == [
        'Tz upper bound 60.000 mm above the maximum 50.000 mm by 10.000 mm',
        'Ry lower bound -12.000 deg below the minimum -10.000 deg by 2.000 deg']
    vertices = inner.vertices()
    assert vertices.shape == (64, 6) and len({tuple(v) for v in vertices}) == 64
    assert np.array_equal(np.abs(vertices), np.tile(inner.high, (64, 1)))
    with pytest.raises(InputError, match='no vertices'):
        BoxLimits.unlimited().vertices()


def test_the_derived_factory_box_is_the_reach_of_each_axis_alone() -> None:
    box = derived_factory_box(MECH)
    stroke = MECH.length_max - MECH.length_min
    assert box.upper[0] <= stroke and box.lower[2] == pytest.approx(
        MECH.length_min - MECH.home_length)
    assert box.upper[2] == pytest.approx(MECH.length_max - MECH.home_length)
    assert all(abs(v) <= math.radians(30.0) + 1e-12 for v in box.lower[3:] + box.upper[3:])
    assert box.is_finite and all(lo < 0.0 < hi for lo, hi in zip(box.lower, box.upper,
                                                                   strict=True))
    # Each face centre is within limits; where the reach is not the cap, a little further is not.
    caps_up = [stroke, stroke, 0.02] + [math.radians(30.0)] * 3
    for k in range(6):
        for bound, cap, sign in ((box.upper[k], caps_up[k], 1.0), (box.lower[k], caps_up[k],
                                                                     -1.0)):
            face = np.zeros((2, 6))
            face[0, k] = bound
            face[1, k] = bound + sign * cap / 200
            inside = within_limits(MECH, *base_pq_of_machine_pose6(MECH, face))
            assert inside[0], (AXES[k], bound)
            if abs(bound) < cap * (1 - 1e-9) and k != 2:
                assert not inside[1], (AXES[k], bound)
    settings = parse(FactoryBoxSettings, {'lower': [-0.01] * 6, 'upper': [0.01] * 6})
    assert settings.box(MECH) == BoxLimits((-0.01,) * 6, (0.01,) * 6)
    assert FactoryBoxSettings().box(MECH) == box
    with pytest.raises(ConfigError, match='give both'):
        parse(FactoryBoxSettings, {'lower': [-0.01] * 6})
    with pytest.raises(ConfigError, match='lower'):
        parse(FactoryBoxSettings, {'lower': [0.02] * 6, 'upper': [0.01] * 6})


def test_the_default_layers() -> None:
    layers = LimitLayers.for_mechanism(MECH)
    assert layers.machine_box == layers.factory_box == derived_factory_box(MECH)
    assert layers.user_box.is_unlimited
    home = np.zeros(6)
    assert layers.check(home).valid
    with pytest.raises(InputError, match='every bound must be finite'):
        LimitLayers.of(BoxLimits.unlimited())


def identity(pose6: np.ndarray) -> np.ndarray:
    return pose6


def test_machine_limits_outside_the_factory_box_are_refused() -> None:
    layers = LimitLayers.of(box_mm_deg(30.0, 20.0))
    machine = BoxLimits(box_mm_deg(10.0, 5.0).lower, (0.01, 0.031, 0.01, 0.1, 0.1, 0.1))
    with pytest.raises(InputError, match=re.escape(
            'machine limits outside the factory box: Ty upper bound 31.000 mm above the '
            'maximum 30.000 mm by 1.000 mm')):
        layers.validated(machine, BoxLimits.unlimited(), identity)
    with pytest.raises(InputError, match='machine limits outside'):
        LimitLayers(layers.factory_box, box_mm_deg(40.0, 1.0))


def test_a_user_box_is_checked_at_its_vertices_in_the_machine_cs() -> None:
    layers = LimitLayers.of(box_mm_deg(30.0, 20.0))
    machine, user = box_mm_deg(20.0, 10.0), box_mm_deg(10.0, 5.0)
    accepted = layers.validated(machine, user, identity)
    assert accepted.machine_box == machine and accepted.user_box == user
    assert accepted.factory_box == layers.factory_box

    def shifted(pose6: np.ndarray) -> np.ndarray:  # the user CS 15 mm along machine x
        return pose6 + [0.015, 0.0, 0.0, 0.0, 0.0, 0.0]

    with pytest.raises(InputError) as refused:
        layers.validated(machine, user, shifted)
    text = str(refused.value)
    assert 'user limits: vertex 1 (Tx 10.000 mm, Ty -10.000 mm' in text
    assert 'maps to Tx 25.000 mm in the machine CS, above the machine maximum 20.000 mm by ' \
        '5.000 mm' in text
    assert text.count('vertex') == 32  # the 32 vertices at Tx = +10 mm
    with pytest.raises(InputError, match='Tz unlimited but not the other axes'):
        layers.validated(machine, BoxLimits(user.lower, user.upper[:2] + (math.inf,)
                                            + user.upper[3:]), identity)
    with pytest.raises(InputError, match='the mapping gave 1 poses'):
        layers.validated(machine, user, lambda v: v[:1])
    assert layers.validated(machine, BoxLimits.unlimited(), shifted).user_box.is_unlimited


def test_the_layers_check_machine_and_user_poses() -> None:
    layers = LimitLayers.of(box_mm_deg(30.0, 20.0)).validated(
        box_mm_deg(20.0, 10.0), box_mm_deg(10.0, 5.0), identity)
    machine = np.zeros((2, 6))
    machine[1, 0] = 0.015  # inside the machine box, outside the user box
    result = layers.check(machine, machine)
    assert result.bits == Validity.USER_LIMITS
    assert result.violations == ('user limits: Tx 15.000 mm above the maximum 10.000 mm by '
                                 '5.000 mm at sample 1',)
    assert result.margins['user.Tx'] == pytest.approx(-0.005)
    assert result.margins['machine.Tx'] == pytest.approx(0.005)
    machine[1, 0] = 0.025
    assert layers.check(machine, machine).bits == Validity.MACHINE_LIMITS | Validity.USER_LIMITS
    with pytest.raises(InputError, match='user CS'):
        layers.check(machine)


# -- speeds ---------------------------------------------------------------------------------------
MAXIMA = Speeds(0.02, 0.2, 0.1, 1.0)
CURRENT = Speeds(0.01, 0.1, 0.05, 0.5)


def test_a_zero_keeps_the_current_value() -> None:
    assert set_speeds(CURRENT, MAXIMA, Speeds.keep()) == CURRENT
    new = set_speeds(CURRENT, MAXIMA, Speeds(0.015, 0.0, 0.0, 1.0))
    assert new == Speeds(0.015, 0.1, 0.05, 1.0)


def test_a_value_above_its_maximum_is_refused_never_clamped() -> None:
    with pytest.raises(InputError, match=r'linear_speed = 0\.03 m/s: above the maximum '
                       r'0\.02 m/s'):
        set_speeds(CURRENT, MAXIMA, Speeds(0.03, 0.0, 0.0, 0.0))
    with pytest.raises(InputError, match=re.escape('angular_acceleration = 1.5 rad/s^2')):
        set_speeds(CURRENT, MAXIMA, Speeds(0.0, 0.0, 0.0, 1.5))
    lowered = Speeds(0.005, 0.2, 0.1, 1.0)
    with pytest.raises(InputError, match=re.escape(
            'linear_speed = the current 0.01 m/s: above the maximum 0.005')):
        set_speeds(CURRENT, lowered, Speeds.keep())


@pytest.mark.parametrize('bad', [-0.01, math.nan, math.inf, -math.inf])
def test_negative_or_not_finite_values_are_refused(bad: float) -> None:
    with pytest.raises(InputError, match='angular_speed') as refused:
        set_speeds(CURRENT, MAXIMA, Speeds(0.0, bad, 0.0, 0.0))
    assert 'linear_speed' not in str(refused.value)


def test_every_bad_field_is_named_at_once() -> None:
    with pytest.raises(InputError) as refused:
        set_speeds(CURRENT, MAXIMA, Speeds(1.0, -1.0, math.nan, 0.0))
    text = str(refused.value)
    assert all(name in text for name in ('linear_speed', 'angular_speed',
                                         'linear_acceleration'))
    assert 'angular_acceleration' not in text
    with pytest.raises(InputError, match=re.escape('maxima.linear_speed')):
        set_speeds(CURRENT, Speeds(0.0, 1.0, 1.0, 1.0), Speeds.keep())
    with pytest.raises(InputError, match='expected a number'):
        Speeds('fast', 0.0, 0.0, 0.0)  # type: ignore[arg-type]


def test_a_speed_scale() -> None:
    half = scaled(CURRENT, 0.5)
    assert half == Speeds(0.005, 0.05, 0.0125, 0.125)
    assert scaled(CURRENT, 1.0) == CURRENT
    for bad in (0.0, -0.5, 1.01, math.nan, math.inf):
        with pytest.raises(InputError, match='speed scale'):
            scaled(CURRENT, bad)


def test_the_motion_limits_of_speeds() -> None:
    base = MotionLimits()
    limits = motion_limits(base, CURRENT)
    assert (limits.linear_speed, limits.angular_speed, limits.linear_acceleration,
            limits.angular_acceleration) == (0.01, 0.1, 0.05, 0.5)
    assert Speeds.of(limits) == CURRENT
    with pytest.raises(InputError, match='linear_speed'):
        motion_limits(base, Speeds(1e-7, 0.1, 0.05, 0.5))


# -- jog ------------------------------------------------------------------------------------------
HOME_JOINTS = np.concatenate([kinematics.inverse(MECH, MECH.home_position, IDENTITY).lengths[0],
                              kinematics.inverse(MECH, MECH.home_position, IDENTITY).thetas[0]])


def test_a_jog_moves_one_axis_within_its_range() -> None:
    target = jog_target(MECH, HOME_JOINTS, 'leg2_length', 0.005, 0.01, 0.1)
    expected = HOME_JOINTS.copy()
    expected[1] += 0.005
    assert np.array_equal(target, expected)
    assert np.array_equal(jog_target(MECH, HOME_JOINTS, 4, -0.05, 0.01, 0.1)[[0, 1, 2, 3, 5]],
                          HOME_JOINTS[[0, 1, 2, 3, 5]])
    assert np.array_equal(jog_target(MECH, HOME_JOINTS, 'leg1_theta', 0.0, 0.01, 0.1),
                          HOME_JOINTS)


def test_a_jog_beyond_the_range_is_refused_naming_the_axis() -> None:
    with pytest.raises(InputError, match=r'jog leg3_length: target 225\.000 mm outside the '
                       r'range \[180\.000, 220\.000\] mm'):
        jog_target(MECH, HOME_JOINTS, 'leg3_length', 0.025, 0.03, 0.1)
    near = HOME_JOINTS.copy()
    near[3] = math.radians(44.0)
    with pytest.raises(InputError, match=r'jog leg1_theta: target 46\.000 deg outside the '
                       r'range \[-45\.000, 45\.000\] deg'):
        jog_target(MECH, near, 3, math.radians(2.0), 0.01, 0.1)
    with pytest.raises(InputError, match=r'jog leg1_length: step -20\.000 mm exceeds the '
                       r'largest step 10\.000 mm'):
        jog_target(MECH, HOME_JOINTS, 0, -0.02, 0.01, 0.1)
    with pytest.raises(InputError, match='unknown axis'):
        jog_target(MECH, HOME_JOINTS, 'leg1_phi', 0.001, 0.01, 0.1)
    with pytest.raises(InputError, match='unknown axis'):
        jog_target(MECH, HOME_JOINTS, 6, 0.001, 0.01, 0.1)
    with pytest.raises(InputError, match='not finite'):
        jog_target(MECH, HOME_JOINTS, 0, math.nan, 0.01, 0.1)
    with pytest.raises(InputError, match='largest_step_angular'):
        jog_target(MECH, HOME_JOINTS, 5, 0.01, 0.01, 0.0)


def check_profile(now: np.ndarray, target: np.ndarray, speed: float, acceleration: float,
                  period: float) -> None:
    times, joints = jog_trajectory(now, target, speed, acceleration, period)
    assert times.shape[0] == joints.shape[0] >= 2 and joints.shape[1] == 6
    assert np.array_equal(joints[0], now) and np.array_equal(joints[-1], target)
    assert times[0] == 0.0 and np.all(np.diff(times) > 0.0)
    moving = np.flatnonzero(target != now)
    held = np.setdiff1d(np.arange(6), moving)
    assert np.array_equal(joints[:, held], np.tile(now[held], (len(times), 1)))
    if moving.size == 0:
        assert times.tolist() == [0.0, period]
        return
    x = joints[:, moving[0]]
    steps = np.diff(x) * np.sign(target[moving[0]] - now[moving[0]])
    assert np.all(steps >= 0.0)  # monotonic
    v = np.diff(x) / np.diff(times)
    assert np.max(np.abs(v)) <= speed * 1.01
    a = np.diff(v) / (0.5 * (times[2:] - times[:-2]))
    assert a.size == 0 or np.max(np.abs(a)) <= acceleration * 1.01


def test_a_jog_profile_is_trapezoidal_within_speed_and_acceleration() -> None:
    target = HOME_JOINTS.copy()
    target[0] += 0.01
    times, joints = jog_trajectory(HOME_JOINTS, target, 0.002, 0.01, 0.01)
    assert times[-1] == pytest.approx(0.01 / 0.002 + 0.002 / 0.01)  # d/v + v/a
    v = np.diff(joints[:, 0]) / np.diff(times)
    assert np.max(v) == pytest.approx(0.002, rel=1e-9)  # cruises at the speed
    check_profile(HOME_JOINTS, target, 0.002, 0.01, 0.01)
    short = HOME_JOINTS.copy()
    short[4] -= 0.001  # triangular: too short to reach the speed
    times, _ = jog_trajectory(HOME_JOINTS, short, 0.1, 0.5, 0.01)
    assert times[-1] == pytest.approx(2.0 * math.sqrt(0.001 / 0.5))
    check_profile(HOME_JOINTS, short, 0.1, 0.5, 0.01)


def test_a_zero_jog_holds_for_one_period() -> None:
    times, joints = jog_trajectory(HOME_JOINTS, HOME_JOINTS, 0.01, 0.1, 0.02)
    assert times.tolist() == [0.0, 0.02]
    assert np.array_equal(joints, np.tile(HOME_JOINTS, (2, 1)))


def test_a_jog_trajectory_moves_one_axis_only() -> None:
    target = HOME_JOINTS + [0.001, 0.001, 0.0, 0.0, 0.0, 0.0]
    with pytest.raises(InputError, match='one axis; the target moves leg1_length, '
                       'leg2_length'):
        jog_trajectory(HOME_JOINTS, target, 0.01, 0.1, 0.01)
    with pytest.raises(InputError, match='period'):
        jog_trajectory(HOME_JOINTS, HOME_JOINTS, 0.01, 0.1, 0.0)
    with pytest.raises(InputError, match='not finite'):
        jog_trajectory(HOME_JOINTS + [math.nan, 0, 0, 0, 0, 0], HOME_JOINTS, 0.01, 0.1, 0.01)


@given(st.integers(0, 5), st.floats(-0.02, 0.02), st.floats(1e-3, 0.1), st.floats(1e-3, 1.0),
       st.floats(1e-3, 0.05))
def test_every_jog_profile_keeps_its_promises(axis: int, delta: float, speed: float,
                                              acceleration: float, period: float) -> None:
    target = jog_target(MECH, HOME_JOINTS, axis, delta, 0.02, 0.02)
    check_profile(HOME_JOINTS, target, speed, acceleration, period)
    assert JOINT_NAMES[axis]
