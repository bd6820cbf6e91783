"""Live axis ranges (positioning_cell.limits.axis_ranges, issue 26 item 6): each of the twelve
bounds agrees to 1 µm / 1 µrad with a brute-force scan that shares nothing with the kernel (the
positioner's own numpy checks: core.limits.within_limits, the boxes' margins on scipy's Euler
angles, the frames' composition), and the binding constraint is named where it is known."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from positioning_cell.core.limits import limit_values, within_limits
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.frames.systems import CoordinateSystems, machine_origin
from positioning_cell.frames.transforms import (
    Transform,
    compose_poses,
    pose6_from_pq,
    pq_from_pose6,
)
from positioning_cell.limits.axis_ranges import (
    CONSTRAINTS,
    SPAN_LIMIT,
    AxisRangeSettings,
    RangeModel,
)
from positioning_cell.limits.boxes import AXES, BoxLimits, LimitLayers, base_pq_of_machine_pose6
from positioning_cell.parameters import ParameterError

MECH = Mechanism.default()
#: A factory box wide enough that the mechanism's own limits bind inside it.
WIDE = BoxLimits((-0.1, -0.1, -0.1, -1.2, -1.2, -1.2), (0.1, 0.1, 0.1, 1.2, 1.2, 1.2))
SPANS = (0.08, 0.08, 0.08, 0.9, 0.9, 0.9)
#: The agreement asked for: 1 µm, 1 µrad.
AGREE = 1e-6
#: Coarse samples of the brute-force scan over each span, then a 1 µm / 1 µrad scan.
COARSE = 4000


def valid_user_poses(layers: LimitLayers, systems: CoordinateSystems,
                     user_pose6: np.ndarray) -> np.ndarray:
    """Per user pose6 row (N, 6), whether every layer passes it, as the positioner checks a
    goal (numpy, scipy): the factory layer, the machine box, the user box."""
    p, q = pq_from_pose6(user_pose6)
    base_p, base_q = compose_poses(machine_origin(MECH) @ systems.user, p, q,
                                   systems.object.inverse())
    ok = within_limits(MECH, base_p, base_q)
    machine = pose6_from_pq(base_p - MECH.home_position, base_q)
    ok &= layers.machine_box.margins(machine).min(axis=1) >= 0.0
    if not layers.user_box.is_unlimited:
        user = pose6_from_pq(*systems.user_positions(base_p, base_q, MECH))
        ok &= layers.user_box.margins(user).min(axis=1) >= 0.0
    return ok


def brute_force_bound(layers: LimitLayers, systems: CoordinateSystems, start: np.ndarray,
                      k: int, sign: float, span: float) -> float:
    """The far end along axis ``k`` in direction ``sign``: the last valid value of a scan of
    :data:`COARSE` samples over ``span``, then of a 1 µm / 1 µrad scan of the step where the
    first invalid sample lies (``start ± span`` when none is)."""
    def ok_at(offsets: np.ndarray) -> np.ndarray:
        poses = np.tile(start, (offsets.size, 1))
        poses[:, k] = start[k] + sign * offsets
        return valid_user_poses(layers, systems, poses)

    offsets = np.linspace(0.0, span, COARSE + 1)[1:]
    ok = ok_at(offsets)
    if ok.all():
        return float(start[k] + sign * span)
    first = int(np.argmin(ok))
    good = offsets[first - 1] if first else 0.0
    fine = np.arange(good, offsets[first] + AGREE, AGREE)
    fine_ok = ok_at(fine)
    last = int(np.argmin(fine_ok)) - 1 if not fine_ok.all() else fine.size - 1
    return float(start[k] + sign * fine[max(last, 0)])


def layers_with(user: BoxLimits | None = None, systems: CoordinateSystems | None = None,
                machine: BoxLimits = WIDE) -> LimitLayers:
    layers = LimitLayers.of(WIDE)
    if user is None:
        return layers.validated(machine, BoxLimits.unlimited(), lambda v: v)
    systems = systems or CoordinateSystems()

    def to_machine(vertices: np.ndarray) -> np.ndarray:
        p, q = compose_poses(systems.user, *pq_from_pose6(vertices), systems.object.inverse())
        return pose6_from_pq(p, q)

    return layers.validated(machine, user, to_machine)


def assert_agrees(layers: LimitLayers, systems: CoordinateSystems, start: np.ndarray) -> None:
    model = RangeModel.of(MECH, layers, systems, SPANS)
    found = model.ranges(start)
    start_ok = bool(valid_user_poses(layers, systems, start[None])[0])
    assert found.valid is start_ok, found.reason
    if not start_ok:
        assert found.reason.startswith('the pose itself is not valid')
        return
    for k, axis_range in enumerate(found.ranges):
        assert axis_range.axis == AXES[k]
        for sign, value in ((-1.0, axis_range.low), (1.0, axis_range.high)):
            reference = brute_force_bound(layers, systems, start, k, sign, SPANS[k])
            assert abs(value - reference) <= AGREE + 1e-12, (
                f'{AXES[k]} {"+" if sign > 0 else "-"}: {value!r} vs brute force '
                f'{reference!r} ({found})')


def test_the_kernels_margins_are_the_positioners() -> None:
    rng = np.random.default_rng(3)
    poses = rng.uniform(-1, 1, (200, 6)) * [0.03, 0.03, 0.03, 0.4, 0.4, 0.4]
    layers = layers_with()
    margins = RangeModel.of(MECH, layers, CoordinateSystems()).margins(poses)
    p, q = base_pq_of_machine_pose6(MECH, poses)
    with np.errstate(all='ignore'):
        reference = np.stack([np.where(np.isfinite(m := (sign * (limit - value)).min(axis=1)),
                                       m, -np.inf)
                              for _, value, limit, sign, _ in limit_values(MECH, p, q)], axis=1)
    np.testing.assert_allclose(margins[:, :9], reference, atol=1e-12, rtol=1e-9)
    box = layers.machine_box.margins(poses)
    np.testing.assert_allclose(np.minimum(margins[:, 9:21:2], margins[:, 10:21:2]), box,
                               atol=1e-12)
    assert np.all(margins[:, 21:] == np.inf)  # no user box


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(pose=st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
       user=st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6),
       pivot=st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3))
def test_every_bound_agrees_with_a_brute_force_scan(pose: list[float], user: list[float],
                                                    pivot: list[float]) -> None:
    """Poses in the workspace, in a user CS moved and turned from the machine CS and with an
    object CS whose pivot is off the platform's centre: the mechanism's limits bind."""
    systems = CoordinateSystems(
        Transform.from_pose6(np.array(user) * [0.01, 0.01, 0.01, 0.1, 0.1, 0.1]),
        Transform.from_pose6(np.array(pivot + [0.0, 0.0, 0.0]) * 0.02))
    start = np.array(pose) * [0.025, 0.025, 0.02, 0.3, 0.3, 0.3]
    assume(valid_user_poses(layers_with(), systems, start[None])[0])
    assert_agrees(layers_with(), systems, start)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(pose=st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6))
def test_bounds_agree_within_machine_and_user_boxes(pose: list[float]) -> None:
    machine = BoxLimits((-0.03, -0.02, -0.015, -0.3, -0.25, -0.4),
                        (0.025, 0.03, 0.02, 0.35, 0.3, 0.45))
    user_box = BoxLimits((-0.01, -0.012, -0.008, -0.1, -0.12, -0.15),
                         (0.012, 0.01, 0.009, 0.11, 0.1, 0.2))
    systems = CoordinateSystems(Transform.from_pose6([0.002, -0.001, 0.003, 0.02, -0.03, 0.1]))
    layers = layers_with(user_box, systems, machine)
    # strictly inside the user box: a pose exactly on a bound is valid for the kernel and
    # out by a rounding error (1e-17) for the round trip through base
    start = np.array(pose) * [0.0095, 0.0095, 0.0075, 0.095, 0.095, 0.14]
    assert_agrees(layers, systems, start)


def test_a_user_box_edge_binds_by_its_name() -> None:
    user_box = BoxLimits((-0.004, -0.005, -0.006, -0.05, -0.06, -0.07),
                         (0.003, 0.002, 0.001, 0.04, 0.03, 0.02))
    systems = CoordinateSystems()
    found = RangeModel.of(MECH, layers_with(user_box, systems), systems,
                          SPANS).ranges(np.zeros(6))
    for k, axis_range in enumerate(found.ranges):
        assert axis_range.low_binding == f'user.{AXES[k]}_min'
        assert axis_range.high_binding == f'user.{AXES[k]}_max'
        assert axis_range.low == pytest.approx(user_box.lower[k], abs=AGREE)
        assert axis_range.high == pytest.approx(user_box.upper[k], abs=AGREE)
        assert axis_range.low >= user_box.lower[k] and axis_range.high <= user_box.upper[k]


def test_the_machine_box_of_a_turned_user_cs_binds_across_axes() -> None:
    """User x along machine y (the object turned back: the platform is not): the user Tx
    range ends at the machine box's Ty bounds."""
    machine = BoxLimits((-0.03, -0.01, -0.015, -0.3, -0.3, -0.4),
                        (0.03, 0.02, 0.015, 0.3, 0.3, 0.4))
    turn = Transform.from_pose6([0, 0, 0, 0, 0, math.pi / 2])
    systems = CoordinateSystems(turn, turn)
    layers = LimitLayers.of(WIDE).validated(machine, BoxLimits.unlimited(), lambda v: v)
    found = RangeModel.of(MECH, layers, systems, SPANS).ranges(np.zeros(6))
    tx = found.ranges[0]
    assert (tx.low_binding, tx.high_binding) == ('machine.Ty_min', 'machine.Ty_max')
    assert (tx.low, tx.high) == (pytest.approx(-0.01, abs=AGREE), pytest.approx(0.02, abs=AGREE))


def test_stroke_binds_along_z_and_the_span_where_nothing_does() -> None:
    layers = layers_with()
    found = RangeModel.of(MECH, layers, CoordinateSystems(), SPANS).ranges(np.zeros(6))
    tz = found.ranges[2]
    # along z from home every leg lengthens and shortens together: the stroke binds
    assert (tz.low_binding, tz.high_binding) == ('factory.length_min', 'factory.length_max')
    short = RangeModel.of(MECH, layers, CoordinateSystems(),
                          (0.001,) * 3 + (0.01,) * 3).ranges(np.zeros(6))
    for axis_range, span in zip(short.ranges, (0.001,) * 3 + (0.01,) * 3, strict=True):
        assert (axis_range.low_binding, axis_range.high_binding) == (SPAN_LIMIT, SPAN_LIMIT)
        assert (axis_range.low, axis_range.high) == (-span, span)


def test_an_invalid_pose_has_no_ranges_and_says_why() -> None:
    layers = layers_with()
    found = RangeModel.of(MECH, layers, CoordinateSystems()).ranges(
        [0.0, 0.0, 0.05, 0.0, 0.0, 0.0])
    assert not found.valid and found.ranges == ()
    assert 'factory.length_max' in found.reason
    nowhere = RangeModel.of(MECH, layers, CoordinateSystems()).ranges([0, 0, -0.3, 0, 0, 0])
    assert not nowhere.valid  # no pose: the legs cannot reach, no exception


@pytest.mark.parametrize('bad', [[0.0] * 5, [0.0, 0.0, math.nan, 0.0, 0.0, 0.0], [[0.0] * 6] * 2])
def test_a_malformed_pose_is_refused(bad: object) -> None:
    model = RangeModel.of(MECH, layers_with(), CoordinateSystems())
    with pytest.raises(InputError):
        model.ranges(bad)  # type: ignore[arg-type]


def test_spans_are_validated() -> None:
    with pytest.raises(InputError, match='> 0'):
        RangeModel.of(MECH, layers_with(), CoordinateSystems(), (0.1, 0.1, 0.0, 1, 1, 1))
    with pytest.raises(ParameterError):
        AxisRangeSettings(spans=(0.1, 0.1, -0.1, 1.0, 1.0, 1.0))
    with pytest.raises(ParameterError):
        AxisRangeSettings(spans=(0.1,) * 5)


def test_every_constraint_name_is_one_of_a_check() -> None:
    assert len(set(CONSTRAINTS)) == len(CONSTRAINTS) == 9 + 24
    assert SPAN_LIMIT not in CONSTRAINTS
