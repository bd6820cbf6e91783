"""Path accuracy and repeatability (ISO 9283 §8.2, positioning_cell.accuracy.path): crossings
of the normal planes, a hand-worked path, bad input, and the figures of seeded simulated
paths from their true points within U of those from their readings."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from positioning_cell.accuracy.path import (
    PLANE_FRACTIONS,
    PathCrossings,
    path_crossings,
    path_figures,
)
from positioning_cell.errors import InputError

A = np.array([0.0, 0.0, 0.196])
L = 0.010
B = A + [L, 0.0, 0.0]
P = len(PLANE_FRACTIONS)


def readings(x_mm: np.ndarray, y_um: np.ndarray) -> np.ndarray:
    """Positions (k, 3) m at x (mm) along the path and y (µm) off it."""
    return A + np.stack([x_mm * 1e-3, y_um * 1e-6, np.zeros_like(x_mm)], axis=1)


def test_the_crossings_interpolate_between_the_readings_either_side() -> None:
    """Readings every 0.5 mm from 0.25 mm on a line y = x/1000 (off the commanded x axis):
    each plane f·L lies halfway between two readings, and the crossing is the line's point
    there, at the time halfway between theirs; each crossing's covariance the readings'
    weighted alike."""
    x = np.arange(0.25, 10.5, 0.5)
    position = readings(x, x)  # y (µm) = x (mm): a slope of 1e-3
    time = np.arange(x.size) * 0.05
    cov = np.tile(np.eye(3), (x.size, 1, 1)) * (np.arange(x.size) + 1.0)[:, None, None] * 1e-12
    c = path_crossings(A, B, time, position, cov)
    assert c is not None and c.crossed.all()
    f = np.asarray(PLANE_FRACTIONS)
    np.testing.assert_allclose(c.points, readings(f * 10.0, f * 10.0), atol=1e-12)
    j = np.searchsorted(x, f * 10.0) - 1  # the reading before each plane
    np.testing.assert_allclose(c.time, time[j] + 0.025, atol=1e-12)
    np.testing.assert_allclose(c.covariance[:, 0, 0], (j + 1.5) * 1e-12, rtol=1e-12)


def test_planes_behind_the_start_are_not_crossed_and_a_short_path_has_none() -> None:
    x = np.arange(3.0, 10.5, 0.5)  # the platform started 3 mm along
    c = path_crossings(A, B, np.arange(x.size) * 0.05, readings(x, np.zeros_like(x)))
    assert c is not None
    assert c.crossed.tolist() == [f > 0.3 for f in PLANE_FRACTIONS]
    assert np.isnan(c.points[0]).all() and np.isnan(c.time[0])
    assert path_crossings(A, A + [0.0005, 0.0, 0.0], [0.0, 1.0], [A, A]) is None
    one = path_crossings(A, B, [0.0], [A])
    assert one is not None and not one.crossed.any()


def test_a_hand_worked_path() -> None:
    """Two cycles along x, readings every 0.5 mm (on the planes): the first 2 µm off in y,
    the second 4 µm, but 10 µm at x = 5 mm. Planes but the middle one: barycentre 3 µm off,
    AT_i 3 µm, l_ij 1 µm, S 0, RT_i 1 µm; the middle plane: barycentre 6 µm off, l_ij 4 µm:
    AT_p 6 µm, RT_l 4 µm. Each reading stated with σ 2 µm per axis: U of AT_p is that of
    a 6 µm offset with the in-plane covariance σ²/… (the mean of the crossings'), at the
    coverage factor that holds for the nine planes together."""
    x = np.arange(0.0, 10.5, 0.5)
    second = np.full(x.size, 4.0)
    second[x == 5.0] = 10.0
    cov = np.tile(np.eye(3) * 4e-12, (x.size, 1, 1))
    cycles = [path_crossings(A, B, np.arange(x.size) * 0.05, readings(x, y), cov)
              for y in (np.full(x.size, 2.0), second)]
    assert all(c is not None for c in cycles)
    figures = path_figures([c for c in cycles if c is not None])
    assert figures is not None and figures.n == 2 and figures.length == pytest.approx(L)
    assert figures.planes == PLANE_FRACTIONS
    middle = PLANE_FRACTIONS.index(0.5)
    expected_at = [6e-6 if i == middle else 3e-6 for i in range(P)]
    expected_rt = [4e-6 if i == middle else 1e-6 for i in range(P)]
    np.testing.assert_allclose(figures.at_planes, expected_at, atol=1e-12)
    np.testing.assert_allclose(figures.rt_planes, expected_rt, atol=1e-12)
    assert figures.at_p == pytest.approx(6e-6, abs=1e-12)
    assert figures.rt_l == pytest.approx(4e-6, abs=1e-12)
    # 6 µm off along y with σ 2 µm: about the linear U, k of nine planes (> 2)
    assert 2 * 2e-6 < figures.u_at_p < 4 * 2e-6
    assert figures.u_rt_l > 0.0
    doc = json.loads(json.dumps(figures.to_dict()))
    assert doc['at_p'] == pytest.approx(6e-6) and len(doc['rt_planes']) == P
    # one cycle's own largest deviation (the live monitor's path_deviation)
    assert cycles[0].deviation() == pytest.approx(2e-6, abs=1e-12)  # type: ignore[union-attr]
    assert cycles[1].deviation() == pytest.approx(10e-6, abs=1e-12)  # type: ignore[union-attr]
    single = path_figures([cycles[0]])  # type: ignore[list-item]
    assert single is not None and single.rt_l is None and math.isnan(single.u_rt_l)
    assert single.to_dict()['u_rt_l'] is None


def test_a_plane_one_cycle_missed_is_left_out() -> None:
    x = np.arange(0.0, 10.5, 0.5)
    late = x[x >= 2.5]
    cycles = [path_crossings(A, B, np.arange(v.size) * 0.05, readings(v, np.zeros_like(v)))
              for v in (x, late)]
    figures = path_figures([c for c in cycles if c is not None])
    assert figures is not None and figures.planes == PLANE_FRACTIONS[2:]
    never = PathCrossings(cycles[0].start, cycles[0].end,  # type: ignore[union-attr]
                          np.full((P, 3), math.nan), np.full((P, 3, 3), math.nan),
                          np.full(P, math.nan))
    assert path_figures([never]) is None and math.isnan(never.deviation())


def test_bad_input_is_refused() -> None:
    with pytest.raises(InputError, match='times'):
        path_crossings(A, B, [0.0], [A, B])
    with pytest.raises(InputError, match='finite'):
        path_crossings(A, B, [0.0, math.nan], [A, B])
    with pytest.raises(InputError, match='one cycle'):
        path_figures([])
    x = np.arange(0.0, 10.5, 0.5)
    one = path_crossings(A, B, np.arange(x.size) * 0.05, readings(x, np.zeros_like(x)))
    other = path_crossings(A, A + [0.0, L, 0.0], np.arange(x.size) * 0.05,
                           A + np.stack([np.zeros_like(x), x * 1e-3, np.zeros_like(x)], 1))
    with pytest.raises(InputError, match='different commanded paths'):
        path_figures([one, other])  # type: ignore[list-item]


@pytest.mark.parametrize(('common', 'noise'), [
    (4e-6, 3e-6),  # a registration error shared by every reading of the run
    (0.0, 6e-6),  # independent errors only
])
def test_the_true_figures_lie_within_u_of_the_measured_ones_in_95_percent_of_runs(
        common: float, noise: float) -> None:
    """200 seeded runs of 5 cycles of a 10 mm path read at 20 Hz at 10 mm/s (a random phase
    each cycle): the path bows off the line by up to 20 µm (random per run) and each cycle
    is off by 3 µm (random per cycle and axis); the readings are the true points plus an
    error ``common`` to the run and ``noise`` per reading, each stated with the sum of both
    covariances. The truth: the same crossings of the true points at the same times."""
    runs, n = 200, 5
    covered = np.zeros((runs, 2), dtype=bool)
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        bow = rng.uniform(-20e-6, 20e-6, 3) * [0.0, 1.0, 1.0]
        shared = rng.normal(0.0, common, 3)
        true, measured = [], []
        for _ in range(n):
            s = np.arange(-0.3, 10.6, 0.5) + rng.uniform(0.0, 0.5)  # mm along the path
            points = (A + np.outer(s * 1e-3, [1.0, 0.0, 0.0])
                      + np.outer(np.sin(np.pi * np.clip(s / 10.0, 0, 1)), bow)
                      + rng.normal(0.0, 3e-6, 3) * [0.0, 1.0, 1.0])
            t = s / 10.0  # s at 10 mm/s
            cov = np.tile(np.eye(3) * (common**2 + noise**2), (s.size, 1, 1))
            true.append(path_crossings(A, B, t, points))
            measured.append(path_crossings(
                A, B, t, points + shared + rng.normal(0.0, noise, points.shape), cov))
        f_true = path_figures(true)  # type: ignore[arg-type]
        f_measured = path_figures(measured, rng=np.random.default_rng(10_000 + seed))  # type: ignore[arg-type]
        assert f_true is not None and f_measured is not None
        assert f_true.planes == f_measured.planes == PLANE_FRACTIONS
        assert f_true.rt_l is not None and f_measured.rt_l is not None
        covered[seed] = (abs(f_measured.at_p - f_true.at_p) <= f_measured.u_at_p,
                         abs(f_measured.rt_l - f_true.rt_l) <= f_measured.u_rt_l)
    share = covered.mean(axis=0)
    print(f'AT_p, RT_l covered in {share[0]:.1%}, {share[1]:.1%} of {runs} runs')
    assert share[0] >= 0.95 and share[1] >= 0.95, share
