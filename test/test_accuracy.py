"""positioning_cell.accuracy: ISO 9283 figures against hand-computed examples, settle detection on
synthetic series, streaming == batch, tolerance verdicts and bad input. No ROS."""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from dataclasses import astuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from positioning_cell import accuracy as acc
from positioning_cell.accuracy.tracker_errors import combined_rows
from positioning_cell.errors import ConfigError, InputError

ID = np.array([0.0, 0.0, 0.0, 1.0])
HOME = np.array([0.0, 0.0, 0.19596])
Arr = NDArray[np.float64]


def quat_abc(abc: Arr) -> Arr:
    """Quaternions from ISO angles a, b, c (roll, pitch, yaw about fixed x, y, z)."""
    return np.asarray(Rotation.from_euler('xyz', np.atleast_2d(abc)).as_quat())


# -- ISO 9283 formulas -----------------------------------------------------------------------
def test_iso_figures_match_a_hand_computed_example() -> None:
    c = np.array([0.01, 0.02, 0.2])
    unit = 1e-5
    # Attained positions c + (0,0,0), c + (0,0,0), c + (3,0,0)·unit, then shifted by (1, 2, −1)
    # units so the barycentre is off the commanded point.
    shift = np.array([1.0, 2.0, -1.0]) * unit
    p = c + shift + np.array([[0.0, 0, 0], [0, 0, 0], [3.0, 0, 0]]) * unit
    # Roll 1, 2, 6 mrad about x, no pitch or yaw; commanded roll 0.
    q = quat_abc(np.array([[1e-3, 0, 0], [2e-3, 0, 0], [6e-3, 0, 0]]))
    f = acc.iso9283(c, ID, p, q, key=7)
    # Barycentre c + shift + (1, 0, 0) units: AP = (2, 2, −1) units, AP_p = 3 units.
    assert f.key == 7 and f.n == 3
    np.testing.assert_allclose([f.ap_x, f.ap_y, f.ap_z], np.array([2.0, 2.0, -1.0]) * unit,
                               atol=1e-15)
    assert f.ap_p == pytest.approx(3.0 * unit, rel=1e-12)
    np.testing.assert_allclose(f.barycentre, c + shift + [unit, 0, 0], atol=1e-15)
    # l_j = 1, 1, 2 units; l̄ = 4/3; S_l = √((1/9 + 1/9 + 4/9)/2) = √(1/3); RP_l = 4/3 + √3.
    assert f.l_mean == pytest.approx(4.0 / 3.0 * unit, rel=1e-12)
    assert f.s_l == pytest.approx(math.sqrt(1.0 / 3.0) * unit, rel=1e-9)
    assert f.rp_l == pytest.approx((4.0 / 3.0 + math.sqrt(3.0)) * unit, rel=1e-9)
    # a_j − a_c = 1, 2, 6 mrad: AP_a = 3 mrad; S_a = √((4 + 1 + 9)/2) = √7 mrad; RP_a = 3 S_a.
    assert f.ap_a == pytest.approx(3e-3, rel=1e-9)
    assert f.s_a == pytest.approx(math.sqrt(7.0) * 1e-3, rel=1e-9)
    assert f.rp_a == pytest.approx(3.0 * math.sqrt(7.0) * 1e-3, rel=1e-9)
    assert abs(f.ap_b) < 1e-12 and abs(f.ap_c) < 1e-12
    assert f.rp_b is not None and f.rp_b < 1e-12


def test_ap_zero_and_rp_l_for_a_symmetric_set() -> None:
    d = 2e-5
    offsets = np.vstack([np.eye(3), -np.eye(3)]) * d
    f = acc.iso9283(HOME, ID, HOME + offsets, np.tile(ID, (6, 1)))
    assert f.ap_p < 1e-15
    # Every l_j = d, so S_l = 0 and RP_l = l̄ = d.
    assert f.l_mean == pytest.approx(d, rel=1e-9)
    assert f.s_l is not None and f.s_l < 1e-15
    assert f.rp_l == pytest.approx(d, rel=1e-9)


def test_rp_l_follows_the_formula_on_a_random_set() -> None:
    rng = np.random.default_rng(3)
    p = HOME + rng.normal(0.0, 1e-5, (30, 3))
    f = acc.iso9283(HOME, ID, p, np.tile(ID, (30, 1)))
    # The standard's sums written out term by term.
    n = len(p)
    xb, yb, zb = (sum(p[j, k] for j in range(n)) / n for k in range(3))
    lj = [math.sqrt((p[j, 0] - xb) ** 2 + (p[j, 1] - yb) ** 2 + (p[j, 2] - zb) ** 2)
          for j in range(n)]
    lb = sum(lj) / n
    sl = math.sqrt(sum((x - lb) ** 2 for x in lj) / (n - 1))
    assert f.rp_l == pytest.approx(lb + 3.0 * sl, rel=1e-9)
    ap_p = math.sqrt((xb - HOME[0]) ** 2 + (yb - HOME[1]) ** 2 + (zb - HOME[2]) ** 2)
    assert f.ap_p == pytest.approx(ap_p, rel=1e-9)


def test_single_visit_has_no_repeatability() -> None:
    f = acc.iso9283(HOME, ID, HOME + [1e-5, 0, 0], ID)
    assert f.n == 1 and f.ap_p == pytest.approx(1e-5)
    assert f.s_l is None and f.rp_l is None and f.rp_a is None and f.rp_c is None
    assert acc.PoseFigures.from_dict(json.loads(json.dumps(f.to_dict()))) == f


@pytest.mark.parametrize('axis', [0, 2])
def test_orientation_terms_wrap_near_pi(axis: int) -> None:
    # Commanded roll (axis 0) or yaw (axis 2) at π − 1 mrad; attained at −3, +2 (past π, so
    # reported near −π) and +1 mrad from it.
    c_angle = math.pi - 1e-3
    dev = np.array([-3e-3, 2e-3, 1e-3])
    abc_c = np.zeros(3)
    abc_c[axis] = c_angle
    abc = np.zeros((3, 3))
    abc[:, axis] = c_angle + dev
    q = quat_abc(abc)
    assert acc.orientation_angles(q)[1, axis] < 0.0  # the wrapped one
    f = acc.iso9283(HOME, quat_abc(abc_c)[0], np.tile(HOME, (3, 1)), q)
    ap = (f.ap_a, f.ap_b, f.ap_c)[axis]
    s = (f.s_a, f.s_b, f.s_c)[axis]
    assert ap == pytest.approx(dev.mean(), abs=1e-12)
    assert s == pytest.approx(dev.std(ddof=1), rel=1e-9)
    assert (f.rp_a, f.rp_b, f.rp_c)[axis] == pytest.approx(3.0 * dev.std(ddof=1), rel=1e-9)


def test_pose_figures_json_round_trip() -> None:
    rng = np.random.default_rng(5)
    p = HOME + rng.normal(0, 1e-5, (5, 3))
    q = Rotation.from_rotvec(rng.normal(0, 1e-4, (5, 3))).as_quat()
    f = acc.iso9283(HOME, ID, p, q, key=2)
    assert acc.PoseFigures.from_dict(json.loads(json.dumps(f.to_dict()))) == f
    assert f.for_people()['n'] == '5'
    with pytest.raises(InputError, match='expected keys'):
        acc.PoseFigures.from_dict({'key': 1})


# -- settle detection ------------------------------------------------------------------------
RATE = 100.0  # Hz


def approach(start: Arr, goal: Arr, t: Arr, move: float, overshoot: float,
             noise: float, rng: np.random.Generator) -> Arr:
    """Positions (N, 3): a smooth move of ``move`` s from start to goal, then a decaying
    oscillation of amplitude ``overshoot`` (m, along the move) and white noise ``noise`` (m)."""
    s = np.clip(t / move, 0.0, 1.0)
    s = s - np.sin(2 * np.pi * s) / (2 * np.pi)
    direction = (goal - start) / max(np.linalg.norm(goal - start), 1e-12)
    ring = overshoot * np.exp(-(t - move) / 0.15) * np.sin(2 * np.pi * 3.0 * (t - move))
    ring[t < move] = 0.0
    return (start + s[:, None] * (goal - start) + ring[:, None] * direction
            + rng.normal(0.0, noise, (t.size, 3)))


def reference_settle(t: Arr, p: Arr, rv: Arr, target_time: float,
                     settings: acc.SettleSettings) -> int | None:
    """Index of the last sample of the first stable window of one segment, by brute force."""
    for i in range(t.size):
        if t[i] - settings.window < target_time + settings.dwell:
            continue
        j = [k for k in range(i + 1) if t[k] > t[i] - settings.window]
        if len(j) < settings.min_samples:
            continue
        box_p = np.linalg.norm(p[j].max(axis=0) - p[j].min(axis=0))
        box_r = np.linalg.norm(rv[j].max(axis=0) - rv[j].min(axis=0))
        if box_p <= settings.position_threshold and box_r <= settings.angle_threshold:
            return i
    return None


def test_settle_after_a_move_with_overshoot_and_noise() -> None:
    rng = np.random.default_rng(11)
    settings = acc.SettleSettings()
    t = np.arange(0, 3.0, 1.0 / RATE)
    goal = HOME + [0.004, -0.002, 0.001]
    offset = np.array([30e-6, -20e-6, 10e-6])
    p = approach(HOME, goal + offset, t, move=0.6, overshoot=0.4e-3, noise=5e-6, rng=rng)
    q = Rotation.from_rotvec(rng.normal(0, 2e-5, (t.size, 3))).as_quat()
    # The move end reported with the target: the first stable window settles the visit.
    visits = acc.settled_visits(t, p, q, [0.0], goal, ID, settings, end_times=[0.0])
    assert len(visits) == 1
    v = visits[0]
    _, rv = acc.measurement_error(p, q, goal, ID)
    i = reference_settle(t, p, rv, 0.0, settings)
    assert i is not None and v.settle_time == t[i]
    # The ring decays by e per 0.15 s: 0.4 mm needs ~0.6 s to fall inside the threshold, so the
    # window cannot start before the move has ended and the ring has died down.
    assert v.window_start > 0.6 + 0.15 * math.log(0.4e-3 / settings.position_threshold)
    assert v.samples == round(settings.window * RATE)
    # Attained pose = the window mean: goal + offset within what is left of the ring (its
    # mean over the window, ~10 µm along the move) and the noise of the mean.
    np.testing.assert_allclose(v.position, goal + offset, atol=15e-6)
    np.testing.assert_allclose(v.position, p[t.searchsorted(v.window_start):i + 1].mean(axis=0),
                               rtol=0, atol=1e-15)
    dp, _ = v.error()
    np.testing.assert_allclose(dp, offset, atol=15e-6)


def test_no_settle_while_noise_exceeds_the_threshold() -> None:
    rng = np.random.default_rng(12)
    t = np.arange(0, 3.0, 1.0 / RATE)
    p = HOME + rng.normal(0, 1e-4, (t.size, 3))  # 0.1 mm noise: bounding box ≫ 0.15 mm
    q = np.tile(ID, (t.size, 1))
    assert acc.settled_visits(t, p, q, [0.0], HOME, ID) == []
    # The same with quiet positions but a drifting orientation: 4 mrad/s, 2 mrad per window.
    rv = np.outer(t, [4e-3, 0, 0])
    assert acc.settled_visits(t, np.tile(HOME, (t.size, 1)),
                              Rotation.from_rotvec(rv).as_quat(), [0.0], HOME, ID) == []


def test_dwell_and_window_bound_the_earliest_settle() -> None:
    t = np.arange(0, 2.0, 1.0 / RATE) + 10.0
    p, q = np.tile(HOME, (t.size, 1)), np.tile(ID, (t.size, 1))
    settings = acc.SettleSettings(window=0.3, dwell=0.4, min_samples=5)
    (v,) = acc.settled_visits(t, p, q, [10.0], HOME, ID, settings, end_times=[10.0])
    # Already at the target: the first complete window ends at target + dwell + window.
    first = int(np.flatnonzero(t - 0.3 >= 10.0 + 0.4)[0])
    assert v.settle_time == t[first] and v.window_start > 10.0 + 0.4
    assert acc.settled_visits(t[:first], p[:first], q[:first], [10.0], HOME, ID,
                              settings, end_times=[10.0]) == []


def cycle_series(n_cycles: int, rng: np.random.Generator, rate: float = RATE,
                 period: float = 1.6) -> tuple[Arr, Arr, Arr, Arr, Arr, Arr]:
    """Targets A, B, C visited ``n_cycles`` times with moves, overshoot and noise."""
    goals = HOME + np.array([[0.0, 0, 0], [0.004, 0, 0.002], [0, -0.003, -0.001]])
    goal_rv = np.array([[0.0, 0, 0], [0.01, 0, 0], [0, 0.02, -0.01]])
    tt, tp, tq, ts, ps, qs = [], [], [], [], [], []
    start_p, start_rv, now = goals[0], goal_rv[0], 0.0
    for _ in range(n_cycles):
        for k in range(3):
            tt.append(now)
            tp.append(goals[k])
            tq.append(Rotation.from_rotvec(goal_rv[k]).as_quat())
            t = np.arange(1, int(period * rate)) / rate
            off = rng.normal(0, 20e-6, 3)
            ps.append(approach(start_p, goals[k] + off, t, 0.5, 0.3e-3, 4e-6, rng))
            s = np.clip(t / 0.5, 0, 1)[:, None]
            qs.append(Rotation.from_rotvec(start_rv + s * (goal_rv[k] - start_rv)
                                           + rng.normal(0, 2e-5, (t.size, 3))).as_quat())
            ts.append(now + t)
            start_p, start_rv, now = goals[k] + off, goal_rv[k], now + period
    return (np.concatenate(ts), np.vstack(ps), np.vstack(qs), np.array(tt), np.array(tp),
            np.array(tq))


def test_visits_are_grouped_per_commanded_pose() -> None:
    t, p, q, tt, tp, tq = cycle_series(3, np.random.default_rng(21))
    # A repeated target 0.1 µm off the current one is the same command: no new segment.
    tt = np.insert(tt, 1, tt[0] + 0.05)
    tp = np.insert(tp, 1, tp[0] + 1e-7, axis=0)
    tq = np.insert(tq, 1, tq[0], axis=0)
    visits = acc.settled_visits(t, p, q, tt, tp, tq)
    assert [(v.key, v.cycle) for v in visits] == [(k, c) for c in (1, 2, 3) for k in (0, 1, 2)]
    assert visits[0].target_time == 0.0
    result = acc.analyse(t, p, q, tt, tp, tq)
    assert [f.n for f in result.poses] == [3, 3, 3]
    # Offsets drawn with σ = 20 µm per axis: the barycentre error is tens of µm at most.
    assert all(f.ap_p < 100e-6 and f.rp_l is not None for f in result.poses)


def feed(stream: acc.AccuracyAccumulator, t: Arr, p: Arr, q: Arr, tt: Arr, tp: Arr,
         tq: Arr, te: Arr | None = None) -> list[acc.SampleUpdate]:
    """Drive the accumulator with the events in time order (a target before samples of its
    time, a move end after the targets and before the samples of its time), as a node
    receives them."""
    te = np.empty(0) if te is None else te
    events = sorted([(x, 1, i) for i, x in enumerate(tt)] + [(x, 2, i) for i, x in enumerate(te)]
                    + [(x, 3, i) for i, x in enumerate(t)])
    updates = []
    for _, kind, i in events:
        if kind == 1:
            stream.add_target(tt[i], tp[i], tq[i])
        elif kind == 2:
            stream.end_move(te[i])
        else:
            updates.append(stream.add_sample(t[i], p[i], q[i]))
    return updates


@pytest.mark.parametrize('with_ends', [True, False])
def test_streaming_accumulator_equals_batch(with_ends: bool) -> None:
    rng = np.random.default_rng(31)
    t, p, q, tt, tp, tq = cycle_series(4, rng)
    # Samples before the first target are ignored by both.
    t, tt = t + 0.2, tt + 0.3
    te = tt + 0.7 if with_ends else None
    stream = acc.AccuracyAccumulator()
    updates = feed(stream, t, p, q, tt, tp, tq, te)
    batch = acc.analyse(t, p, q, tt, tp, tq, end_times=() if te is None else te)
    assert len(batch.visits) == 12
    settled = [u.visit for u in updates if u.visit is not None]
    # With move ends each visit settles on a sample after its end; without, each is closed by
    # the next target and the last by the end of the stream.
    assert len(settled) == (12 if with_ends else 0)
    assert stream.finish() is (None if with_ends else stream.visits[-1])
    assert stream.result() == batch  # exactly, not approximately
    assert stream.result().to_dict() == batch.to_dict()
    if with_ends:
        assert settled == list(batch.visits)
        assert all(v.window_start >= e for v, e in zip(batch.visits, te, strict=True))
    # The visits of one commanded pose share its tuples (one copy per pose kept, issue 24).
    by_pose: dict[tuple[float, ...], tuple[float, ...]] = {}
    for v in stream.visits:
        assert v.commanded_position is by_pose.setdefault(v.commanded_position,
                                                         v.commanded_position)
        assert v.commanded_quaternion is by_pose.setdefault(v.commanded_quaternion,
                                                           v.commanded_quaternion)
    assert len(by_pose) == 6 and len(stream.visits) == 12
    # Per-sample errors against the target in force.
    seg = np.searchsorted(tt, t, side='right') - 1
    have = seg >= 0
    dp, rv = acc.measurement_error(p[have], q[have], tp[seg[have]], tq[seg[have]])
    assert all(u.position_error is None for u, h in zip(updates, have, strict=True) if not h)
    np.testing.assert_allclose([u.position_error for u in updates if u.position_error is not None],
                               dp, atol=1e-15)
    np.testing.assert_allclose([u.orientation_error for u in updates
                                if u.orientation_error is not None], rv, atol=1e-15)


def corrected_visit(rate: float = RATE) -> tuple[Arr, Arr, Arr, float, Arr, Arr]:
    """A ``measured``-mode visit: the platform stops 200 µm and 0.3° off the goal for 1.5 s
    (the pause that measures), then a correction brings it to within 4 µm, where it stays
    3 s; the move ends (the positioner reports it settled) once the correction is over.
    Times (N,) s, positions (N, 3), quaternions (N, 4), the move end (s), the goal's final
    offset (3,) m and the pause's offset (3,) m."""
    rng = np.random.default_rng(5)
    t = np.arange(1, int(6.0 * rate)) / rate
    pause_off = np.array([200e-6, -50e-6, 30e-6])
    final_off = np.array([3e-6, -2e-6, 1e-6])
    off = np.where((t < 2.0)[:, None], pause_off, final_off)
    rv = np.where((t < 2.0)[:, None], [math.radians(0.3), 0.0, 0.0], [0.0, 0.0, 0.0])
    p = HOME + off + rng.normal(0, 3e-6, (t.size, 3))
    q = Rotation.from_rotvec(rv + rng.normal(0, 1e-5, (t.size, 3))).as_quat()
    return t, p, q, 2.3, final_off, pause_off


def test_a_corrected_visit_is_judged_on_its_final_window() -> None:
    t, p, q, end, final_off, pause_off = corrected_visit()
    # The pause before the correction is stable: the old rule (first stable window) judged it.
    settings = acc.SettleSettings()
    _, rv = acc.measurement_error(p, q, HOME, ID)
    first = reference_settle(t, p, rv, 0.0, settings)
    assert first is not None and t[first] < 2.0
    window = (t > t[first] - settings.window) & (t <= t[first])
    np.testing.assert_allclose(p[window].mean(axis=0) - HOME, pause_off, atol=3e-6)
    # With the move end: the first stable window after it, at the corrected pose.
    (v,) = acc.settled_visits(t, p, q, [0.0], HOME, ID, end_times=[end])
    assert v.window_start >= end
    dp, rot = v.error()
    np.testing.assert_allclose(dp, final_off, atol=3e-6)
    assert np.linalg.norm(rot) < 1e-4
    # Fallback without a move end: the last stable window before the next target.
    t_next = t[-1] + 0.01
    (w,) = acc.settled_visits(t, p, q, [0.0, t_next], [HOME, HOME + [1e-3, 0, 0]], [ID, ID])
    assert w.settle_time == t[-1] and w.window_start > end
    np.testing.assert_allclose(w.error()[0], final_off, atol=3e-6)
    # Streaming, one event at a time: the same visits, the fallback one closed by the target.
    stream = acc.AccuracyAccumulator()
    stream.add_target(0.0, HOME, ID)
    assert all(stream.add_sample(t[i], p[i], q[i]).visit is None for i in range(t.size))
    assert stream.visits == ()
    stream.add_target(t_next, HOME + [1e-3, 0, 0], ID)
    assert stream.visits == (w,)


def test_the_monitor_judges_a_visit_closed_by_the_next_target() -> None:
    """Without a move end the monitor's verdict of a visit comes with the next target (the
    live node publishes it then), on the last stable window; with one, with the sample that
    completes the first stable window after it."""
    t, p, q, _, final_off, _ = corrected_visit()
    monitor = acc.Monitor()
    monitor.target(0.0, 'base', HOME, ID)
    assert all(isinstance(monitor.measurement(t[i], 'base', p[i], q[i]), acc.Measured)
               for i in range(t.size))
    assert monitor.verdicts == [] and monitor.report()['target']['move_end'] is None
    fed = monitor.feed(targets=acc.PoseMessages.one(t[-1] + 0.01, 'base', HOME + [1e-3, 0, 0],
                                                    ID))
    ((index, visit, verdict),) = fed.closed
    assert index == 0 and monitor.verdicts == [verdict] and verdict.ok
    np.testing.assert_allclose(visit.error()[0], final_off, atol=3e-6)
    # The next visit reports its end: the verdict comes with a measurement.
    assert monitor.move_end(t[-1] + 0.02) is None
    assert monitor.report()['target']['move_end'] == t[-1] + 0.02
    assert isinstance(monitor.move_end(math.nan), acc.Ignored)
    later = t[-1] + 0.03 + t
    done = [monitor.measurement(x, 'base', p[-1] + [1e-3, 0, 0], q[-1]) for x in later]
    settled = [d for d in done if isinstance(d, acc.Measured) and d.verdict is not None]
    assert len(settled) == 1 and len(monitor.verdicts) == 2
    assert settled[0].update.visit is not None
    assert settled[0].update.visit.window_start >= t[-1] + 0.02


def test_a_move_end_applies_to_samples_that_arrive_after_it() -> None:
    """A window is judged with the move ends that arrived before its last sample: a sample
    stamped after the end but received before it was judged without it (the same however the
    messages are grouped)."""
    t, p, q, end, _, _ = corrected_visit()
    late = int(np.searchsorted(t, end + 1.0))  # the end arrives 1 s after its stamp
    for split in (None, late - 3, late + 5):
        stream = acc.AccuracyAccumulator()
        targets = acc.Targets(np.zeros(1, dtype=np.intp), np.zeros(1), HOME[None], ID[None])
        ends = acc.Ends(np.array([late]), np.array([end]), np.ones(1, dtype=np.intp))
        if split is None:
            batch = stream.add(t, p, q, targets, ends)
            ((row, v),) = batch.visits
            assert t[row] == v.settle_time and row >= late
        else:
            stream.add(t[:split], p[:split], q[:split], targets)
            rest = acc.Ends(np.array([late - split]), np.array([end]), np.zeros(1, dtype=np.intp))
            batch = stream.add(t[split:], p[split:], q[split:], ends=rest if split < late
                               else None)
            if split >= late:
                stream.end_move(end)  # arrives after the samples fed: nothing settles yet
                assert stream.visits == ()
                stream.add_sample(t[-1] + 0.01, p[-1], q[-1])
            (v,) = stream.visits
        assert v.window_start >= end
        if split is None or split < late:
            assert v.settle_time == t[late + max(0, int(np.searchsorted(
                t, end + acc.SettleSettings().window)) - late)]


def test_reset_keeps_the_target_and_forgets_the_rest() -> None:
    t, p, q, tt, tp, tq = cycle_series(1, np.random.default_rng(41))
    stream = acc.AccuracyAccumulator()
    feed(stream, t, p, q, tt, tp, tq)
    assert len(stream.visits) == 2  # the last visit is open: no move end, no next target
    last = stream.target
    stream.reset(keep_target=True)
    assert stream.visits == () and stream.result().poses == ()
    assert stream.target is not None and last is not None and stream.target[0] == last[0]
    assert stream.target[3] == 0  # keys start again
    assert stream.add_sample(t[-1] + 0.01, p[-1], q[-1]).position_error is not None
    stream.reset()
    assert stream.target is None and stream.add_sample(0.0, p[0], q[0]).position_error is None


def test_tracker_errors_streaming_equals_batch() -> None:
    rng = np.random.default_rng(51)
    t = np.arange(200) / 50.0
    pt = HOME + rng.normal(0, 1e-3, (200, 3))
    qt = Rotation.from_rotvec(rng.normal(0, 1e-2, (200, 3))).as_quat()
    pm = pt + rng.normal(0, 10e-6, (200, 3))
    qm = (Rotation.from_quat(qt) * Rotation.from_rotvec(rng.normal(0, 1e-5, (200, 3)))).as_quat()
    tm = t + rng.uniform(-2e-4, 2e-4, 200)  # within the 1 ms pairing tolerance
    keep = np.ones(200, dtype=bool)
    keep[::7] = False  # some measurements have no truth
    batch = acc.tracker_errors(tm, pm, qm, t[keep], pt[keep], qt[keep], 1e-3)
    assert batch is not None and batch.samples == int(keep.sum())
    assert 5e-6 < batch.rms_position_error < 30e-6
    for truth_first in (True, False):
        stream = acc.TrackerErrorAccumulator(1e-3)
        for i in range(200):
            if truth_first and keep[i]:
                stream.add_truth(t[i], pt[i], qt[i])
            stream.add_measured(tm[i], pm[i], qm[i])
            if not truth_first and keep[i]:
                stream.add_truth(t[i], pt[i], qt[i])
        _same_statistics(stream.statistics(), batch)
    assert acc.TrackerErrorAccumulator(1e-3).statistics() is None


def _same_statistics(a: acc.ErrorStatistics | None, b: acc.ErrorStatistics | None) -> None:
    """Equal counts and maxima; sums equal but for their last bits (another grouping)."""
    assert a is not None and b is not None and a.samples == b.samples
    assert (a.max_position_error, a.max_orientation_error) == (b.max_position_error,
                                                               b.max_orientation_error)
    np.testing.assert_allclose(
        [*a.mean_position_error, a.rms_position_error, a.rms_orientation_error],
        [*b.mean_position_error, b.rms_position_error, b.rms_orientation_error],
        rtol=1e-12, atol=1e-20)


@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 3), st.booleans()), min_size=1,
                max_size=60),
       st.lists(st.integers(1, 9), min_size=1, max_size=20), st.integers(0, 2**32 - 1))
def test_tracker_pairing_streams_equal_the_batch_rule(
        gaps: list[tuple[int, int, bool]], batches: list[int], seed: int) -> None:
    """However the two series arrive (interleaved, in batches of any size), the pairs are
    those of pair_by_stamp over everything given so far: near-ties, repeated stamps, truths
    missing or extra included (stamps on a 0.5 ms grid, tolerance 1 ms)."""
    rng = np.random.default_rng(seed)
    tm = np.cumsum([g[0] for g in gaps]) * 5e-4
    tt = np.cumsum([g[1] for g in gaps]) * 5e-4 + 2.5e-4 * np.array([g[2] for g in gaps])
    tt = np.sort(tt)
    pm, pt = rng.normal(0, 1e-3, (tm.size, 3)), rng.normal(0, 1e-3, (tt.size, 3))
    qm = Rotation.from_rotvec(rng.normal(0, 1e-3, (tm.size, 3))).as_quat()
    qt = Rotation.from_rotvec(rng.normal(0, 1e-3, (tt.size, 3))).as_quat()
    stream = acc.TrackerErrorAccumulator(1e-3)
    im = it = 0
    k = 0
    while im < tm.size or it < tt.size:
        size = batches[k % len(batches)]
        if (k % 2 == 0 and im < tm.size) or it >= tt.size:
            stream.add_measured(tm[im:im + size], pm[im:im + size], qm[im:im + size])
            im += size
        else:
            stream.add_truth(tt[it:it + size], pt[it:it + size], qt[it:it + size])
            it += size
        k += 1
        batch = acc.tracker_errors(tm[:im], pm[:im], qm[:im], tt[:it], pt[:it], qt[:it], 1e-3)
        if batch is None:
            assert stream.statistics() is None
        else:
            _same_statistics(stream.statistics(), batch)


@given(st.integers(0, 2**32 - 1), st.integers(1, 4))
def test_tracker_sums_per_pair_of_labels_equal_the_batch_grouping(seed: int, size: int) -> None:
    """The sums kept per (measurement's label, truth's label) (columns, joined every 64
    pairings; issue 24) are those of grouping every pair of pair_by_stamp at once."""
    rng = np.random.default_rng(seed)
    n = 150
    tt = np.arange(n) * 0.02
    tm = tt + rng.uniform(-2e-4, 2e-4, n)
    lm, lt = np.sort(rng.integers(0, 8, n)), np.sort(rng.integers(0, 8, n))
    pt = HOME + rng.normal(0, 1e-3, (n, 3))
    qt = Rotation.from_rotvec(rng.normal(0, 1e-2, (n, 3))).as_quat()
    pm = pt + rng.normal(0, 10e-6, (n, 3))
    qm = (Rotation.from_quat(qt) * Rotation.from_rotvec(rng.normal(0, 1e-5, (n, 3)))).as_quat()
    stream = acc.TrackerErrorAccumulator(1e-3)
    for i in range(0, n, size):
        cut = slice(i, i + size)
        stream.add_truth(tt[cut], pt[cut], qt[cut], lt[cut])
        stream.add_measured(tm[cut], pm[cut], qm[cut], lm[cut])
    ia, ib = acc.pair_by_stamp(tm, tt, 1e-3)
    dp, rv = acc.measurement_error(pm[ia], qm[ia], pt[ib], qt[ib])
    want = acc.ErrorSums.grouped(lm[ia], lt[ib], dp, rv)
    got = stream.sums()
    assert list(got) == sorted(want)
    for key, sums in want.items():
        _same_statistics(got[key].statistics(), sums.statistics())
    _same_statistics(stream.statistics(), acc.error_statistics(dp, rv))


def test_combined_rows_add_counts_and_sums_and_keep_the_maxima() -> None:
    labels = np.array([[2, 2], [0, 1], [2, 2], [0, 1], [0, 0]])
    rows = np.array([[3, 1e-6, 0, 0, 3e-12, 1e-10, 2e-6, 1e-5],
                     [1, 2e-6, 1, 0, 4e-12, 0, 2e-6, 0],
                     [2, -1e-6, 0, 0, 1e-12, 2e-10, 1e-6, 2e-5],
                     [4, 1e-6, 0, 5, 1e-12, 0, 3e-6, 0],
                     [1, 0, 0, 0, 0, 0, 0, 0]])
    got_labels, got = combined_rows(labels, rows)
    assert got_labels.tolist() == [[0, 0], [0, 1], [2, 2]]
    np.testing.assert_array_equal(got[:, 0], [1, 5, 5])
    np.testing.assert_allclose(got[1, 1:6], [3e-6, 1, 5, 5e-12, 0], rtol=1e-15)
    np.testing.assert_allclose(got[2, 1:6], [0, 0, 0, 4e-12, 3e-10], rtol=1e-15, atol=1e-30)
    np.testing.assert_array_equal(got[:, 6:], [[0, 0], [3e-6, 0], [2e-6, 2e-5]])


def test_the_tracker_sums_stay_one_row_per_pair_of_labels_in_a_long_run() -> None:
    """The live monitor pairs at every reading: its sums must not grow with the readings."""
    stream = acc.TrackerErrorAccumulator(1e-3)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for i in range(2000):
        stream.add_truth(i * 0.05, HOME, q, label=i // 1000)
        stream.add_measured(i * 0.05, HOME + 1e-6, q, label=i // 1000)
    kept = len(stream._sums)  # the rows it keeps (private: what this test is about)
    assert kept <= 2 + type(stream._sums).BLOCKS
    stats = stream.statistics()
    assert stats is not None and stats.samples == 2000
    assert stats.rms_position_error == pytest.approx(math.sqrt(3) * 1e-6, rel=1e-9)


# -- verdicts --------------------------------------------------------------------------------
def test_verdicts_at_the_tolerance_boundary() -> None:
    tol = acc.Tolerances()
    assert tol.position == 0.05e-3 and tol.orientation == pytest.approx(math.radians(0.01))
    assert acc.judge(tol.position, tol.orientation, tol).ok
    above_p = float(np.nextafter(tol.position, 1.0))
    above_o = float(np.nextafter(tol.orientation, 1.0))
    v = acc.judge(above_p, 0.0, tol)
    assert not v.ok and not v.position_ok and v.orientation_ok
    v = acc.judge(0.0, above_o, tol)
    assert not v.ok and v.position_ok and not v.orientation_ok
    assert 'INDETERMINATE' in v.message() and '0.0100°' in v.message()  # U not stated
    assert 'DOES NOT CONFORM' in acc.judge(0.0, above_o, tol, 0.0, 0.0).message()
    assert '50.0 µm' in acc.judge(0.0, 0.0).message()
    # Through a settled visit: exactly the tolerance off along x.
    visit = acc.Visit(0, 1, 0.0, 1.0, 1.5, 50, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0),
                      (tol.position, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    assert acc.judge_visit(visit, tol).ok
    tight = acc.Tolerances(position=float(np.nextafter(tol.position, 0.0)))
    assert not acc.judge_visit(visit, tight).ok


@pytest.mark.parametrize('kwargs', [{'position': 0.0}, {'position': -1e-5},
                                    {'orientation': math.nan}, {'orientation': math.inf}])
def test_bad_tolerances_are_refused(kwargs: dict[str, float]) -> None:
    name = next(iter(kwargs))
    with pytest.raises(ConfigError, match=f'{name} = .*: must be '):
        acc.Tolerances(**kwargs)


# -- bad input -------------------------------------------------------------------------------
@pytest.mark.parametrize('kwargs, match', [
    ({'window': 0.0}, r'window = 0.0: must be in \(0, 60\] s'),
    ({'dwell': -1.0}, r'dwell = -1.0: must be in \[0, 600\] s'),
    ({'min_samples': 1}, r'min_samples = 1: must be in \[2, 100000\]'),
    ({'position_threshold': math.nan}, 'position_threshold = nan: must be finite'),
])
def test_bad_settle_settings_are_refused(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        acc.SettleSettings(**kwargs)  # type: ignore[arg-type]


def test_settle_settings_from_params() -> None:
    s = acc.SettleSettings.from_params({'window': 1, 'min_samples': 3})
    assert s.window == 1.0 and s.min_samples == 3 and s.dwell == acc.SettleSettings().dwell
    assert acc.SettleSettings.from_params(s.to_params()) == s
    with pytest.raises(ConfigError, match='unknown'):
        acc.SettleSettings.from_params({'windw': 1.0})


def test_bad_series_raise_clear_errors() -> None:
    t = np.array([0.0, 0.1, 0.2])
    p, q = np.tile(HOME, (3, 1)), np.tile(ID, (3, 1))
    with pytest.raises(InputError, match=r'times\[2\].*non-decreasing'):
        acc.settled_visits([0.0, 0.2, 0.1], p, q, [0.0], HOME, ID)
    with pytest.raises(InputError, match='3 times for 2 poses'):
        acc.settled_visits(t, p[:2], q[:2], [0.0], HOME, ID)
    with pytest.raises(InputError, match='norm'):
        acc.settled_visits(t, p, q * 1.1, [0.0], HOME, ID)
    bad = p.copy()
    bad[1, 2] = np.nan
    with pytest.raises(InputError, match=r'position\[1\].*not finite'):
        acc.settled_visits(t, bad, q, [0.0], HOME, ID)
    with pytest.raises(InputError, match='one commanded pose'):
        acc.iso9283(p, q, p, q)
    with pytest.raises(InputError, match='must be a finite number'):
        acc.judge(-1e-6, 0.0)


def test_stream_refuses_out_of_order_events_and_changes_nothing() -> None:
    stream = acc.AccuracyAccumulator()
    stream.add_target(1.0, HOME, ID)
    stream.add_sample(2.0, HOME, ID)
    with pytest.raises(InputError, match='earlier than the previous sample'):
        stream.add_sample(1.5, HOME, ID)
    with pytest.raises(InputError, match='not after the last sample'):
        stream.add_target(2.0, HOME + [1e-3, 0, 0], ID)
    assert stream.target is not None and stream.target[0] == 1.0
    # With clamp the late target takes effect just after the last sample.
    assert stream.add_target(1.9, HOME + [1e-3, 0, 0], ID, clamp=True) == np.nextafter(2.0, 3.0)
    with pytest.raises(InputError, match='norm'):
        stream.add_sample(3.0, HOME, [0.0, 0.0, 0.0, 2.0])
    with pytest.raises(InputError, match='not finite'):
        stream.add_target(math.nan, HOME, ID)
    assert stream.target is not None and stream.target[3] == 1


# -- one monitor core: the same figures however the messages are grouped ---------------------
def _stream(seed: int) -> list[tuple[str, float, str, Arr, Arr]]:
    """A short run's messages in arrival order (topic, stamp, frame, p, q): two poses, two
    cycles, a target repeated, a measurement in the wrong frame, one with NaN, one with a
    quaternion off unit length, one older than the one before it, a true pose missing."""
    from positioning_cell.testing.synthetic_run import synthetic_run

    run = synthetic_run([[0.0, 0.0, 0.196], [0.004, 0.004, 0.2]], [ID, ID], modes=('model',),
                        cycles=2, dwell_time=1.5, seed=seed)
    out: list[tuple[float, int, tuple[str, float, str, Arr, Arr]]] = []
    for i, t in enumerate(run.target_time):
        out.append((t, 0, ('target', t, 'base', run.target_position[i],
                           run.target_quaternion[i])))
        if i != 2:  # the third move reports no end: its last stable window judges it
            out.append((run.end_time[i], 3, ('end', run.end_time[i], '', HOME, ID)))
    out.append((run.target_time[1] + 0.01, 0, ('target', run.target_time[1] + 0.01, 'base',
                                                run.target_position[1],
                                                run.target_quaternion[1])))
    for i, t in enumerate(run.time):
        out.append((t, 1, ('measured', t, 'base', run.position[i], run.quaternion[i])))
        if i != 33:
            out.append((t, 2, ('truth', t, 'base', run.true_position[i],
                               run.true_quaternion[i])))
    events = [e for _, _, e in sorted(out, key=lambda x: (x[0], x[1]))]
    bad_p = np.array([np.nan, 0.0, 0.2])
    events.insert(40, ('measured', events[39][1], 'tracker', HOME, ID))
    events.insert(80, ('measured', events[79][1], 'base', bad_p, ID))
    events.insert(120, ('measured', events[119][1], 'base', HOME, 2 * ID))
    events.insert(160, ('measured', events[150][1] - 0.2, 'base', HOME, ID))
    events.insert(200, ('target', events[199][1], 'tracker', HOME, ID))
    # the tracker located (its registration, shared by the readings after it), then a
    # registration in the wrong frame (ignored)
    events.insert(20, ('registration', events[19][1], 'base', TRACKER_AT, ID))
    events.insert(230, ('registration', events[229][1], 'tracker', TRACKER_AT, ID))
    return events


#: Where the stream's tracker located itself (m, base) and its registration's covariance.
TRACKER_AT = np.array([2.0, 0.3, 0.5])
REGISTRATION_COVARIANCE = np.diag([(3e-6) ** 2] * 3 + [(2e-6) ** 2] * 3)


def _fed(events: list[tuple[str, float, str, Arr, Arr]], start: int) -> dict[str, object]:
    rows: dict[str, list[tuple[int, float, str, Arr, Arr]]] = {
        'target': [], 'measured': [], 'truth': [], 'end': [], 'registration': []}
    for k, (topic, t, frame, p, q) in enumerate(events):
        rows[topic].append((start + k, t, frame, p, q))

    def messages(kind: str) -> acc.PoseMessages:
        mine = rows[kind]
        if not mine:
            return acc.PoseMessages.empty()
        return acc.PoseMessages(np.array([r[0] for r in mine]), np.array([r[1] for r in mine]),
                                np.array([r[2] for r in mine], dtype=object),
                                np.array([r[3] for r in mine]), np.array([r[4] for r in mine]),
                                np.array([_stated(r[1]) for r in mine])
                                if kind == 'measured' else
                                np.array([REGISTRATION_COVARIANCE for _ in mine])
                                if kind == 'registration' else None)

    ends = acc.MoveEnds(np.array([r[0] for r in rows['end']], dtype=np.intp),
                        np.array([r[1] for r in rows['end']], dtype=float))
    return {'targets': messages('target'), 'measured': messages('measured'),
            'truth': messages('truth'), 'ends': ends,
            'registrations': messages('registration')}


def _stated(t: float) -> Arr:
    """The covariance (6, 6) the tracker states for a reading at ``t`` s (changing with t,
    so that a visit's figure depends on which readings made it)."""
    scale = 1.0 + 0.3 * math.sin(7.0 * t)
    return np.diag([(8e-6 * scale) ** 2] * 3 + [(2e-5 * scale) ** 2] * 3)


@functools.cache
def _one_by_one(seed: int) -> acc.Monitor:
    """The monitor fed :func:`_stream` one message at a time (as the live node)."""
    monitor = acc.Monitor()
    _feed_live(monitor, _stream(seed))
    return monitor


def _feed_live(monitor: acc.Monitor, events: list[tuple[str, float, str, Arr, Arr]],
               truth: Callable[[float, str, Arr, Arr], object] | None = None) -> None:
    """``events`` fed one message at a time, each true pose to ``truth`` (None: the
    monitor's :meth:`~acc.Monitor.truth`)."""
    for topic, t, frame, p, q in events:
        if topic == 'end':
            monitor.move_end(t)
        elif topic == 'measured':
            monitor.measurement(t, frame, p, q, _stated(t).ravel())
        elif topic == 'registration':
            monitor.registration(t, frame, p, q, REGISTRATION_COVARIANCE.ravel())
        elif topic == 'target':
            monitor.target(t, frame, p, q)
        else:
            (truth or monitor.truth)(t, frame, p, q)


@settings(max_examples=25)
@given(st.lists(st.integers(1, 300), min_size=1, max_size=10), st.integers(0, 2))
def test_the_monitor_gives_the_same_figures_however_its_messages_are_grouped(
        sizes: list[int], seed: int) -> None:
    """One message at a time (the live node) and any grouping into feeds of arrays (the replay
    of a bag): the same visits, verdicts, ISO figures and ignored messages, exactly; the
    tracker's figures to their last bits (its sums are grouped differently)."""
    events = _stream(seed)
    live = _one_by_one(seed)
    grouped = acc.Monitor()
    start = 0
    while start < len(events):
        size = sizes[start % len(sizes)]
        grouped.feed(**_fed(events[start:start + size], start))  # type: ignore[arg-type]
        start += size
    a, b = live.report(), grouped.report()
    assert a['verdicts']['ok'] + a['verdicts']['error'] == 4
    assert sum(a['decisions'].values()) == 4
    uncertainties = [(v.position_uncertainty, v.orientation_uncertainty) for v in live.verdicts]
    assert np.all(np.isfinite(uncertainties)) and np.all(np.array(uncertainties) > 0.0)
    assert uncertainties == [(v.position_uncertainty, v.orientation_uncertainty)
                             for v in grouped.verdicts]
    # each visit's stabilisation from its segment's readings: the same, however grouped
    stabilised = np.array([astuple(s) for s in live.stabilisations], dtype=float)
    assert stabilised.shape[0] == 4 and np.isfinite(stabilised[:, :2]).any(axis=0).all()
    np.testing.assert_array_equal(stabilised, [astuple(s) for s in grouped.stabilisations])
    values = live.visit_values(live.measured.visits[0])
    assert float(values['stabilisation_time']) == pytest.approx(live.stabilisations[0].time,
                                                                abs=5e-4)
    # and its positioning time (ISO 9283 §9): from the segment's start to the final entry
    visit, first = live.measured.visits[0], live.stabilisations[0]
    assert float(values['positioning_time']) == pytest.approx(first.positioning_time, abs=5e-4)
    assert first.positioning_time > first.time and visit.target_time + first.positioning_time \
        <= visit.settle_time + 1e-9
    # each visit's path crossings (ISO 9283 8.2) from its segment's readings: the same
    assert len(live.paths) == len(grouped.paths) == 4
    assert live.paths[0] is None and all(p is not None for p in live.paths[1:])  # from nothing
    for one, other in zip(live.paths, grouped.paths, strict=True):
        assert (one is None) == (other is None)
        if one is not None and other is not None:
            np.testing.assert_array_equal(one.points, other.points)
            np.testing.assert_array_equal(one.time, other.time)
    for visit, path in zip(live.measured.visits, live.paths, strict=True):
        shown = float(live.visit_values(visit)['path_deviation'])
        expected = math.nan if path is None else path.deviation()
        assert shown == pytest.approx(expected, abs=1e-7, nan_ok=True)
    tracker_a, tracker_b = a.pop('tracker'), b.pop('tracker')
    assert a == b
    assert tracker_a['samples'] == tracker_b['samples'] > 200
    np.testing.assert_allclose(_numbers_of(tracker_a), _numbers_of(tracker_b), rtol=1e-12,
                               atol=1e-20)
    assert live.ignored == grouped.ignored and len(live.ignored) == 6
    assert [i.topic for i in live.ignored].count('/metrology/pose') == 4
    assert [i.topic for i in live.ignored].count('/metrology/registration') == 1
    # the visits after the registration took it as the readings' common part
    assert len(live.registrations) == len(grouped.registrations) == 1


def _numbers_of(doc: dict[str, object]) -> list[float]:
    out: list[float] = []
    for key in sorted(doc):
        value = doc[key]
        out.extend(value if isinstance(value, list) else [value])  # type: ignore[list-item]
    return out
