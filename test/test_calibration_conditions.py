"""Each calibration pose's conditions (positioning_cell.calibration.collect): the air
temperature of its window (the sensor's readings; a stale or absent one leaves the run
without temperature, and says why) and the side each axis approached it from (encoder dither
below the threshold ignored), by one rule for the live run and the bag."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from positioning_cell.calibration import collect as col
from positioning_cell.calibration import program as prog
from positioning_cell.metrology.instrument import Registration

RATE_HZ, TRACKER_HZ, AIR_HZ = 100.0, 20.0, 1.0
SAMPLES = 20
RESOLUTION = np.sqrt(12) * col.JOINT_SIGMA_FLOOR
HOME = np.r_[[0.2] * 3, [0.1] * 3]


class Run(NamedTuple):
    markers: list[col.Marker]
    joints: col.Stream
    poses: col.Stream
    air: col.Stream
    approach: np.ndarray  # (P, 6) the side each axis came from, by construction
    windows: np.ndarray  # (P, 2) start, end of each pose's tracker window


def run(seed: int, poses: int = 8, dither_counts: float = 2.0, still: int | None = None,
        air_until: float = np.inf) -> Run:
    """A synthetic calibration run: each pose reached through an approach point on a random
    side of it (1 mm away per axis; axis ``still`` never moves), the encoders dithering by
    ``dither_counts`` counts at rest, the tracker at 20 Hz over each window, the air sensor at
    1 Hz until ``air_until`` s."""
    rng = np.random.default_rng(seed)
    t0, here = 0.0, HOME.copy()
    stamps, values, markers, sides, windows = [], [], [], [], []
    for k in range(poses):
        goal = HOME + rng.uniform(-5e-3, 5e-3, 6)
        side = rng.choice([-1.0, 1.0], 6)
        if still is not None:
            goal[still], side[still] = HOME[still], 0.0
        via = goal - side * 1e-3
        for a, b in ((here, via), (via, goal)):  # two ramps of 0.5 s
            s = np.linspace(0.0, 1.0, int(0.5 * RATE_HZ), endpoint=False)
            stamps.append(t0 + s * 0.5)
            values.append(a + s[:, None] * (b - a))
            t0 += 0.5
        rest = np.arange(int(2.0 * RATE_HZ)) / RATE_HZ  # settle, then the window, at rest
        dither = np.round(rng.uniform(-dither_counts, dither_counts, (rest.size, 6))) * RESOLUTION
        stamps.append(t0 + rest)
        values.append(goal + dither)
        start = t0 + 0.5
        windows.append((start, start + (SAMPLES - 1) / TRACKER_HZ))
        markers.append(col.Marker('r', k, col.FIT if k % 4 else col.HOLD_OUT,
                                  (0.0, 0.0, 0.2), (0.0, 0.0, 0.0, 1.0), start, SAMPLES))
        sides.append(side)
        t0 += 2.0
        here = goal
    w = np.asarray(windows)
    p_t = np.concatenate([a + np.arange(SAMPLES) / TRACKER_HZ for a in w[:, 0]])
    n = p_t.size
    cov = np.broadcast_to(np.diag([1e-12] * 3 + [1e-10] * 3), (n, 6, 6)).copy()
    pose_stream = col.Stream(p_t, (np.tile([0.0, 0.0, 0.2], (n, 1)),
                                   np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), cov))
    a_t = np.arange(0.3, min(t0, air_until), 1.0 / AIR_HZ)
    air = col.Stream(a_t, (20.5 + 1e-4 * a_t + rng.normal(0.0, 0.02, a_t.size),))
    return Run(markers, col.Stream(np.concatenate(stamps), (np.vstack(values),)), pose_stream,
               air, np.asarray(sides), w)


def _collect(r: Run, air: col.Stream | None) -> col.Collected:
    return col.collect(r.markers, r.joints, r.poses, col.JOINT_SIGMA_FLOOR, air)


def _both(c: col.Collected, field: str) -> np.ndarray:
    """A condition of every pose in marker order (fit and hold-out put back together)."""
    fit, hold = getattr(c.fit, field), getattr(c.hold_out, field)
    assert fit is not None and hold is not None
    out = np.empty((fit.shape[0] + hold.shape[0], *fit.shape[1:]))
    is_fit = np.arange(out.shape[0]) % 4 != 0
    out[is_fit], out[~is_fit] = fit, hold
    return out


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), dither=st.floats(0.0, 3.0))
def test_approach_is_the_side_each_axis_came_from(seed: int, dither: float) -> None:
    """Dither of up to three counts at the pose (below the ten-count threshold) does not
    count as a motion."""
    r = run(seed, dither_counts=dither)
    np.testing.assert_array_equal(_both(_collect(r, r.air), 'approach'), r.approach)


def test_dither_beyond_the_threshold_is_a_motion() -> None:
    """The check above can fail: with dither of 30 counts the rest is read as motion."""
    r = run(3, dither_counts=30.0)
    assert not np.array_equal(_both(_collect(r, r.air), 'approach'), r.approach)


def test_an_axis_that_never_moved_has_no_approach() -> None:
    r = run(4, still=4)
    got = _both(_collect(r, r.air), 'approach')
    assert np.all(got[:, 4] == 0.0)
    np.testing.assert_array_equal(got, r.approach)


def test_temperature_is_the_mean_of_the_readings_in_the_window() -> None:
    r = run(5)
    got = _collect(r, r.air)
    assert got.missing == ()
    t, (v,) = r.air
    want = [v[(t >= a) & (t <= b)].mean() for a, b in r.windows]
    np.testing.assert_allclose(_both(got, 'temperature'), want, rtol=0.0, atol=1e-12)


def test_a_window_without_reading_takes_the_latest_before_it() -> None:
    r = run(6)
    start, end = r.windows[2]
    t, (v,) = r.air
    outside = (t < start) | (t > end)
    got = col.window_temperature(t[outside], v[outside], start, end)
    assert got == v[outside][t[outside] < start][-1]
    assert col.window_temperature(t[outside], v[outside], start, end,
                                  max_age=start - t[outside][t[outside] < start][-1] - 1e-6) \
        is None


def test_a_stale_temperature_leaves_the_run_without_temperature_and_says_why() -> None:
    r = run(7, poses=40)
    late = r.windows[-1][0] - col.TEMPERATURE_AGE - 10.0  # the sensor fell silent before
    kept = r.air.stamps < late
    got = _collect(r, col.Stream(r.air.stamps[kept], (r.air.values[0][kept],)))
    assert got.fit.temperature is None and got.hold_out.temperature is None
    assert got.fit.approach is not None
    last = r.air.stamps[kept][-1]
    stale = int(np.sum(r.windows[:, 0] - last > col.TEMPERATURE_AGE))
    assert stale >= 3
    assert got.missing == (f'temperature: {stale} of 40 poses without an air-temperature '
                           f'reading in their window or the {col.TEMPERATURE_AGE:.0f} s '
                           'before',)


def test_no_temperature_recorded_leaves_it_out_and_says_why() -> None:
    r = run(8)
    got = _collect(r, None)
    assert got.fit.temperature is None and 'temperature: 8 of 8 poses' in got.missing[0]


@pytest.mark.parametrize('seed', [1, 2])
def test_the_live_path_gets_what_the_bag_path_gets(seed: int) -> None:
    """The procedure's rule (pose by pose, from what the port holds since the previous
    pose's start: :func:`pose_conditions`, :func:`pose_data`, :func:`assemble`) against the
    bag's (:func:`collect` over the whole streams)."""
    r = run(seed, dither_counts=2.5)
    j_t, (j_v,) = r.joints
    a_t, (a_v,) = r.air
    p_t, (p_p, p_q, p_c) = r.poses
    live: list[col.PoseData] = []
    since, prior = j_t[0], None
    for marker, (start, end) in zip(r.markers, r.windows, strict=True):
        upto = j_t <= end  # what the port holds once the window is read
        window = (j_t >= start) & upto
        mean, sem = col.encoder_window(j_v[window])
        held = (j_t >= since) & upto
        cond = col.pose_conditions(col.Stream(j_t[held], (j_v[held],)),
                                   col.Stream(a_t[a_t <= end], (a_v[a_t <= end],)),
                                   start, end, mean, prior)
        take = (p_t >= start) & (p_t <= end)
        live.append(col.pose_data(marker, mean, sem, p_p[take], p_q[take], p_c[take],
                                  col.JOINT_SIGMA_FLOOR, cond))
        since, prior = start, cond.approach
    got, want = col.assemble(live), _collect(r, r.air)
    for part in ('fit', 'hold_out'):
        for a, b in zip(getattr(got, part), getattr(want, part), strict=True):
            if a is None or b is None:  # a field neither path has (no registration here)
                assert a is None and b is None
                continue
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0.0)
    assert got.missing == want.missing == ()


def test_a_poses_covariance_keeps_the_registrations_part_undiminished() -> None:
    """With the tracker's registration recorded, each pose states its readings' common part
    (the registration's covariance at the pose) plus the rest over the readings' number, on
    the bag's path as on the live one; without, the mean covariance over that number. The
    registration in force is the newest stamped up to the pose's start (else the first)."""
    r = run(3)
    p_t, (p_p, p_q, p_c) = r.poses
    a = np.diag([4e-6, 3e-6, 5e-6, 2e-6, 3e-6, 1e-6]) ** 2
    first = Registration(np.array([0.8, 0.3, 2.2]), a)
    later = Registration(np.array([0.8, 0.3, 2.2]), 4.0 * a)
    switch = float(r.windows[4, 0]) - 0.5  # a re-location between poses 4 and 5
    registrations = [(switch, later), (float(r.windows[0, 0]) + 0.01, first)]
    got = col.collect(r.markers, r.joints, r.poses, col.JOINT_SIGMA_FLOOR, r.air,
                      registrations)
    plain = _collect(r, r.air)
    for k, (marker, (start, end)) in enumerate(zip(r.markers, r.windows, strict=True)):
        take = (p_t >= start) & (p_t <= end)
        in_force = later if start >= switch else first  # pose 0 starts before `first`
        assert col.registration_at(registrations, float(start)) is in_force
        common = in_force.covariance_at(p_p[take].mean(axis=0))[0]
        mean_cov = p_c[take].mean(axis=0)
        n = marker.samples
        live = col.pose_data(marker, np.zeros(6), np.zeros(6), p_p[take], p_q[take], p_c[take],
                             col.JOINT_SIGMA_FLOOR, None, in_force)
        np.testing.assert_allclose(live.covariance, common + (mean_cov - common) / n,
                                   rtol=1e-12, atol=0.0)
        np.testing.assert_allclose(_pose_covariance(got, k), live.covariance, rtol=1e-12,
                                   atol=0.0)
        np.testing.assert_allclose(_pose_covariance(plain, k), mean_cov / n, rtol=1e-12,
                                   atol=0.0)
        # the data name the registration each pose was measured through, for the fit
        np.testing.assert_array_equal(_both(got, 'registration_covariance')[k],
                                      in_force.covariance)
        np.testing.assert_array_equal(_both(got, 'registration_origin')[k], in_force.position)
    assert plain.fit.registration_origin is None and plain.fit.registration_covariance is None
    assert col.registration_at([], 0.0) is None


def _pose_covariance(c: col.Collected, k: int) -> np.ndarray:
    """The measured pose covariance of the k-th pose in marker order."""
    return np.asarray(_both(c, 'covariance')[k])


def test_alternate_approaches_each_pose_from_below_then_above() -> None:
    p = np.tile([0.0, 0.0, 0.2], (5, 1))
    below = prog.approach_poses(p, 5e-4, 'below')
    alternate = prog.approach_poses(p, 5e-4, 'alternate')
    np.testing.assert_allclose(below[:, 2], 0.2 - 5e-4, rtol=0.0, atol=1e-15)
    np.testing.assert_allclose(alternate[:, 2], 0.2 + 5e-4 * np.array([-1, 1, -1, 1, -1]),
                               rtol=0.0, atol=1e-15)
    np.testing.assert_array_equal(alternate[:, :2], p[:, :2])


def test_an_unknown_approach_rule_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match='approach_rule'):
        prog.ProgramSettings(approach_rule='sideways')
    with pytest.raises(ValueError, match='approach_rule'):
        prog.approach_poses(np.zeros((1, 3)), 5e-4, 'sideways')
