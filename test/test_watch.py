"""The watch window's library (positioning_cell.watch): the 6-D deviation in base and in the
user frame against independent constructions (hand-built matrices, the monitor's pose_error,
finite differences of the uncertainty map), the scene against the kinematics, the state's
refusals, the table and the rich rendering with its colours, and the recording line (the
recorder's status through positioning_cell.recording's rule)."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rich.console import Console
from scipy.spatial.transform import Rotation
from workspace import MECH, poses

from positioning_cell.accuracy.decisions import Decision, norm_expanded_uncertainty
from positioning_cell.accuracy.verdicts import Tolerances
from positioning_cell.core import kinematics
from positioning_cell.core.poses import pose_error
from positioning_cell.errors import InputError
from positioning_cell.frames.systems import CoordinateSystems
from positioning_cell.frames.transforms import Transform
from positioning_cell.limits.axis_ranges import AxisRange, AxisRanges
from positioning_cell.limits.boxes import AXES
from positioning_cell.nodes.live_view_messages import status_document
from positioning_cell.recording import SILENT_AFTER_S, RecorderReport
from positioning_cell.tools.cell_watch import render
from positioning_cell.watch.deviation import deviation, watched_pose
from positioning_cell.watch.scene import arrow_quaternion, scene, stroke_colour
from positioning_cell.watch.state import Snapshot, Status, WatchState
from positioning_cell.watch.table import IN, OUT, rows
from positioning_cell.watch.throttle import Throttle

HOME = (MECH.home_position, np.array([0.0, 0.0, 0.0, 1.0]))
SYSTEMS = CoordinateSystems(user=Transform.from_human([10.0, -5.0, 2.0, 0.0, 0.0, 30.0]),
                            object=Transform.from_human([20.0, 0.0, 50.0, 0.0, 0.0, 0.0]))
COV = np.diag([4e-12, 9e-12, 16e-12, 1e-10, 4e-10, 9e-10])
small = st.floats(-1e-3, 1e-3, allow_nan=False)


def _moved(pose: tuple[np.ndarray, np.ndarray], dp: np.ndarray,
           rotvec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``pose`` shifted by dp (base) and turned by rotvec (base axes, about its origin)."""
    r = Rotation.from_rotvec(rotvec) * Rotation.from_quat(pose[1])
    return pose[0] + dp, r.as_quat()


@settings(max_examples=60, deadline=None)
@given(poses(), st.tuples(small, small, small), st.tuples(small, small, small))
def test_base_deviation_is_the_monitors_error(cmd: tuple, dp: tuple, rv: tuple) -> None:
    meas = _moved(cmd, np.array(dp) * 0.1, np.array(rv))
    dev = deviation(cmd, meas, COV, 'base', SYSTEMS, MECH, Tolerances())
    np.testing.assert_allclose(dev.deviation[:3], np.array(dp) * 0.1, atol=1e-15)
    np.testing.assert_allclose(dev.deviation[3:], rv, atol=1e-12)
    ep, er = pose_error(meas[0][None], meas[1][None], cmd[0][None], cmd[1][None])
    assert dev.position_error == pytest.approx(float(np.linalg.norm(ep)), abs=1e-15)
    assert dev.orientation_error == pytest.approx(float(np.linalg.norm(er)), abs=1e-12)
    np.testing.assert_allclose(dev.uncertainty, np.sqrt(np.diag(COV)), rtol=1e-12)


@settings(max_examples=60, deadline=None)
@given(poses(), st.tuples(small, small, small), st.tuples(small, small, small))
def test_user_deviation_is_the_object_origin_in_user_axes(cmd: tuple, dp: tuple,
                                                          rv: tuple) -> None:
    meas = _moved(cmd, np.array(dp) * 0.1, np.array(rv))
    dev = deviation(cmd, meas, COV, 'user', SYSTEMS, MECH, Tolerances())
    # by hand: T_base_user = (p_home + t_user, R_user), object origin p + R t_object
    r_user = SYSTEMS.user.R
    origin_user = MECH.home_position + SYSTEMS.user.p

    def object_in_user(pose: tuple) -> np.ndarray:
        r = Rotation.from_quat(pose[1]).as_matrix()
        return r_user.T @ (pose[0] + r @ SYSTEMS.object.p - origin_user)

    np.testing.assert_allclose(dev.deviation[:3], object_in_user(meas) - object_in_user(cmd),
                               atol=1e-15)
    np.testing.assert_allclose(dev.deviation[3:], r_user.T @ np.array(rv), atol=1e-12)
    g = watched_pose(*cmd, 'user', SYSTEMS, MECH)
    np.testing.assert_allclose(dev.commanded[:3], g.p, atol=1e-15)
    assert dev.orientation_error == pytest.approx(float(np.linalg.norm(rv)), abs=1e-12)


def test_user_uncertainty_is_the_first_order_map_of_the_covariance() -> None:
    """Finite differences of the watched pose against the analytic map of the covariance."""
    cmd = _moved(HOME, np.array([0.002, -0.001, 0.0]), np.array([0.02, -0.01, 0.03]))
    meas = cmd
    dev = deviation(cmd, meas, COV, 'user', SYSTEMS, MECH, Tolerances())
    g0 = watched_pose(*meas, 'user', SYSTEMS, MECH)
    jac = np.zeros((6, 6))
    h = 1e-7
    for k in range(6):
        step = np.zeros(6)
        step[k] = h
        g = watched_pose(*_moved(meas, step[:3], step[3:]), 'user', SYSTEMS, MECH)
        jac[:3, k] = (g.p - g0.p) / h
        jac[3:, k] = Rotation.from_matrix(g.R @ g0.R.T).as_rotvec() / h
    expected = np.sqrt(np.diag(jac @ COV @ jac.T))
    np.testing.assert_allclose(dev.uncertainty, expected, rtol=1e-5)


def test_verdict_and_axis_markers_follow_the_tolerances() -> None:
    meas = _moved(HOME, np.array([60e-6, -20e-6, 0.0]), np.zeros(3))
    dev = deviation(HOME, meas, COV, 'base', SYSTEMS, MECH, Tolerances())
    assert not dev.ok and dev.axis_ok.tolist() == [False, True, True, True, True, True]
    table = rows(dev)
    assert [r.marker for r in table[:2]] == [OUT, IN]
    assert table[0].deviation == '+60.0 µm' and table[0].tolerance == '±50.0 µm'
    # |Δp| 63.2 µm, U (k = 2) along it 2·√(0.9²·4 + 0.3²·9) µm = 4.2 µm: beyond 50 + U
    u = norm_expanded_uncertainty(np.array([[60e-6, -20e-6, 0.0]]), COV[None, :3, :3])[0]
    assert table[6].axis == '|Δp|' and table[6].marker == OUT
    assert table[6].uncertainty == f'U {u * 1e6:.1f} µm' and table[6].level == 'error'
    assert table[6].deviation == f'{math.hypot(60, 20):.1f} µm'
    loose = deviation(HOME, meas, COV, 'base', SYSTEMS, MECH, Tolerances(position=70e-6))
    assert loose.ok and loose.axis_ok.all()  # 63.2 µm within 70 µm, and 70 − U
    assert rows(loose)[6].marker == IN and rows(loose)[6].level == 'ok'  # conforms
    # 62 µm: 63.2 is out as measured, but within U of the tolerance: indeterminate
    near = deviation(HOME, meas, COV, 'base', SYSTEMS, MECH, Tolerances(position=62e-6))
    assert not near.ok and rows(near)[6].marker == OUT and rows(near)[6].level == 'warn'
    assert near.verdict.decision is Decision.INDETERMINATE
    simple = deviation(HOME, meas, COV, 'base', SYSTEMS, MECH,
                       Tolerances(position=62e-6, decision_rule='simple_acceptance'))
    assert rows(simple)[6].level == 'error'  # U not used: out is out
    edge = deviation(HOME, _moved(HOME, np.array([50e-6, 0, 0]), np.zeros(3)), COV, 'base',
                     SYSTEMS, MECH, Tolerances(position=50e-6))
    assert edge.axis_ok[0]  # equal to the tolerance passes, as the monitor's verdict


def test_bad_inputs_are_refused_and_change_nothing() -> None:
    state = WatchState(MECH)
    state.measurement(*HOME, COV, 1.0)
    before = state.snapshot()
    with pytest.raises(InputError, match='not finite'):
        state.measurement(np.array([np.nan, 0, 0]), HOME[1], COV, 2.0)
    with pytest.raises(InputError, match='norm'):
        state.command(HOME[0], np.array([0.0, 0.0, 0.5, 1.0]), 2.0)
    with pytest.raises(InputError, match='covariance'):
        state.measurement(*HOME, np.eye(3), 2.0)
    with pytest.raises(InputError, match='watch frame'):
        deviation(HOME, HOME, COV, 'tracker', SYSTEMS, MECH, Tolerances())
    assert state.snapshot() is before
    assert state.snapshot().deviation('base') is None  # no command yet
    assert '/positioner/target' in state.snapshot().waiting_for()


def test_the_user_frame_waits_for_the_machine() -> None:
    state = WatchState(None)
    state.command(*HOME, 1.0)
    state.measurement(*HOME, COV, 1.0)
    snap = state.snapshot()
    assert snap.deviation('user') is None and snap.deviation('base') is not None
    assert any('mechanism' in w for w in snap.waiting_for())
    assert snap.scene(1000.0) is None
    state.mechanism(MECH)
    assert state.snapshot().deviation('user') is not None


def test_scene_matches_the_kinematics() -> None:
    cmd = _moved(HOME, np.array([0.004, 0.0, 0.01]), np.array([0.0, 0.05, 0.0]))
    meas = _moved(cmd, np.array([30e-6, 0.0, -40e-6]), np.zeros(3))
    targets = np.array([[0.1, 0.0, 0.02], [0.0, 0.1, 0.02], [-0.1, 0.0, 0.02]])
    s = scene(MECH, cmd, cmd, meas, targets, Tolerances(), 500.0)
    ik = kinematics.inverse(MECH, cmd[0], cmd[1])
    stroke = (ik.lengths[0] - MECH.length_min) / (MECH.length_max - MECH.length_min)
    np.testing.assert_allclose(s.stroke, stroke, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(s.platform_joints - s.base_joints, axis=1),
                               ik.lengths[0], atol=1e-12)
    start, vector = s.arrow
    np.testing.assert_allclose(start, cmd[0])
    np.testing.assert_allclose(vector, 500.0 * (meas[0] - cmd[0]), atol=1e-15)
    assert s.tolerance_radius == pytest.approx(500.0 * 50e-6)
    r = Rotation.from_quat(meas[1]).as_matrix()
    np.testing.assert_allclose(s.targets, meas[0] + targets @ r.T, atol=1e-15)
    with pytest.raises(InputError, match='magnification'):
        scene(MECH, cmd, cmd, meas, None, Tolerances(), 0.0)


def test_stroke_colours_run_green_yellow_red() -> None:
    c = stroke_colour(np.array([0.5, 0.25, 0.0, 1.0, 1.3]))
    np.testing.assert_allclose(c[0], (0.1, 0.75, 0.2, 1.0))
    np.testing.assert_allclose(c[1], (0.95, 0.8, 0.1, 1.0))
    np.testing.assert_allclose(c[2], (0.9, 0.1, 0.1, 1.0))
    np.testing.assert_allclose(c[3], c[2])
    np.testing.assert_allclose(c[4], c[2])


@settings(max_examples=100, deadline=None)
@given(st.tuples(*[st.floats(-10, 10, allow_nan=False)] * 3).filter(
    lambda v: np.linalg.norm(v) > 1e-6))
def test_arrow_quaternion_turns_x_onto_the_vector(v: tuple) -> None:
    q = arrow_quaternion(np.array(v))
    assert np.linalg.norm(q) == pytest.approx(1.0)
    x = Rotation.from_quat(q).apply([1.0, 0.0, 0.0])
    np.testing.assert_allclose(x, np.array(v) / np.linalg.norm(v), atol=1e-9)


def test_render_shows_values_markers_and_colours() -> None:
    state = WatchState(MECH)
    state.command(*HOME, 100.0)
    state.measurement(*_moved(HOME, np.array([60e-6, -20e-6, 0.0]), np.zeros(3)), COV, 100.0)
    state.positioner(Status(0, 'settled', 100.0))
    console = Console(record=True, width=120, force_terminal=True, color_system='standard',
                      file=io.StringIO())
    console.print(render(state.snapshot(), 'base', 100.2))
    text = console.export_text(clear=False)
    assert '+60.0 µm' in text and 'settled' in text
    assert 'pose: DOES NOT CONFORM (ISO 14253-1, U at k = 2; as measured: out of tolerance)' \
        in text
    assert 'measurement 0.20 s old' in text
    ansi = console.export_text(styles=True)
    assert '\x1b[1;31mOUT' in ansi and '\x1b[1;32mIN' in ansi
    stale = Console(record=True, width=120, file=io.StringIO())
    stale.print(render(state.snapshot(), 'base', 105.0))
    assert 'STALE' in stale.export_text()


def _text(state: WatchState, now: float) -> str:
    console = Console(record=True, width=120, file=io.StringIO())
    console.print(render(state.snapshot(), 'base', now))
    return console.export_text()


def test_during_a_move_the_deviation_is_against_the_moving_setpoint() -> None:
    """Moving: phase and progress, mode and drives shown, and the measured pose judged
    against where the trajectory is now, not against its end (every axis was OUT during a
    move). Settled: against the goal."""
    state = WatchState(MECH)
    goal = _moved(HOME, np.array([0.004, 0.0, 0.0]), np.zeros(3))
    state.command(*goal, 100.0)
    setpoint = _moved(HOME, np.array([0.0017, 0.0, 0.0]), np.zeros(3))
    state.setpoint(*setpoint, 100.5)
    state.measurement(*_moved(setpoint, np.array([3e-6, 0.0, 0.0]), np.zeros(3)), COV, 100.5)
    state.positioner(Status(0, 'moving', 100.5, {'state': 'moving', 'progress': '0.42',
                                                 'mode': 'measured'}))
    state.driver(Status(0, 'following', 100.5, {'enabled': 'true', 'state': 'following'}))
    text = _text(state, 100.6)
    assert 'motion: moving 42%  mode measured  drives on (following)  vs the moving setpoint' \
        in text
    assert '+3.0 µm' in text and 'DOES NOT CONFORM' not in text
    state.goal_progress('moving', 0.57, 100.55)  # the goal's feedback: finer than the status
    assert 'motion: moving 57%' in _text(state, 100.7)
    assert 'motion: moving 42%' in _text(state, 102.0)  # that feedback stale: the status's
    state.positioner(Status(0, 'settled', 101.0, {'state': 'settled', 'progress': '1.0',
                                                  'mode': 'measured'}))
    text = _text(state, 101.1)
    assert 'motion: settled  mode measured' in text and 'vs the goal' in text
    assert '-2297.0 µm' in text  # the same reading against the goal, 4 mm away
    # a setpoint older than the newest target is the last move's: the goal instead
    state.positioner(Status(0, 'moving', 102.0, {'state': 'moving', 'progress': '0.1'}))
    state.command(*goal, 102.0)
    assert 'vs the goal' in _text(state, 102.1)


def test_snapshot_defaults_to_the_default_tolerances() -> None:
    snap = Snapshot(mech=MECH)
    assert snap.judged_tolerances == Tolerances() and snap.tolerances is None


def test_throttle_passes_jittered_inputs_at_the_limit_and_thins_faster_ones() -> None:
    rng = np.random.default_rng(0)
    # a 20 Hz tracker: readings on its 50 ms schedule, each arriving up to 20 ms late or early
    at_rate = np.arange(2000) * 0.05 + rng.uniform(-0.02, 0.02, 2000)
    throttle = Throttle(20.0)
    assert all(throttle.allow(t) for t in at_rate)
    fast = np.arange(0.0, 100.0, 0.01)  # 100 Hz for 100 s
    throttle = Throttle(20.0)
    passed = sum(throttle.allow(t) for t in fast)
    assert 2000 <= passed <= 2002  # 20 Hz on average, the burst of 2 at the start
    for bad in ((0.0, 2.0), (float('nan'), 2.0), (20.0, 0.5)):
        with pytest.raises(InputError):
            Throttle(*bad)


def test_the_watch_tells_when_recording_stopped() -> None:
    """The recording line of ``cell watch`` and the live view's status follow the recorder's
    status through the one rule (positioning_cell.recording): no recorder heard of, recording,
    silent, failed."""
    state = WatchState(MECH)

    def shown(now: float, styles: bool = False) -> str:
        console = Console(record=True, width=200, force_terminal=True,
                          color_system='standard', file=io.StringIO())
        console.print(render(state.snapshot(), 'base', now))
        return console.export_text(styles=styles)

    assert 'recording: no recorder seen' in shown(100.0)
    assert status_document(state.snapshot(), 100.0)['recording'] is None
    state.recorder(RecorderReport(0, 'recording', {'state': 'recording'}, 100.0))
    assert 'recording: OK recording' in shown(101.0)
    assert status_document(state.snapshot(), 101.0)['recording'] == {
        'level': 0, 'message': 'recording', 'stopped': False}
    silent = shown(100.0 + SILENT_AFTER_S + 1.0)
    assert 'recording: ERROR recording stopped: recorder silent since' in silent
    failure = ('recording stopped: ENOSPC (No space left on device) on write of '
               '/runs/x/bag/bag_0.mcap; bag closed with 1234 messages, 0 lost')
    state.recorder(RecorderReport(2, failure, {'state': 'failed'}, 102.0))
    assert f'recording: ERROR {failure}' in shown(102.5)
    assert f'recording: \x1b[0m\x1b[1;31mERROR \x1b[0m\x1b[1m{failure}' in shown(102.5, True)
    assert status_document(state.snapshot(), 200.0)['recording'] == {
        'level': 2, 'message': failure, 'stopped': True}


def test_render_shows_the_axis_ranges_or_waits_for_them() -> None:
    state = WatchState(MECH)
    assert 'waiting for /positioner/axis_ranges' in _text(state, 100.0)
    state.axis_ranges(AxisRanges((0.0,) * 6, tuple(
        AxisRange(axis, -0.002, 0.003, f'machine.{axis}_min', 'factory.length_max')
        for axis in AXES)))
    text = _text(state, 100.0)
    assert 'Tx     -2.000 mm ..     3.000 mm  (low: machine.Tx_min; high: ' \
        'factory.length_max)' in text
    assert 'Rz    -0.115 deg ..    0.172 deg  (low: machine.Rz_min' in text
    state.axis_ranges(AxisRanges.unknown('the pose itself is not valid: user.Tx_max -1e-05'))
    assert 'none: the pose itself is not valid: user.Tx_max' in _text(state, 100.0)
