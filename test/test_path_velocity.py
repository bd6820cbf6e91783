"""Path velocity characteristics (ISO 9283 §8.6, positioning_cell.accuracy.path_velocity): the
plan's cruise, a hand-worked example, bad input, and the figures of seeded simulated paths
from their true crossing times within U of those from their readings."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from positioning_cell.accuracy.path import PLANE_FRACTIONS, PathCrossings, path_crossings
from positioning_cell.accuracy.path_velocity import cruise_planes, path_velocity_figures
from positioning_cell.errors import InputError
from positioning_cell.moves.trajectory import MotionLimits, cruise, plan_profile, time_law

A = np.array([0.0, 0.0, 0.196])
L = 0.010
B = A + [L, 0.0, 0.0]
P = len(PLANE_FRACTIONS)


@pytest.mark.parametrize('distance', [0.002, 0.004, 0.0069, 0.0113, 0.05])
def test_the_cruise_is_where_the_plans_speed_is_at_its_peak(distance: float) -> None:
    """cruise() against the time law sampled finely: the speed is the peak (to 1e-9) exactly
    between the two distances it gives, below it outside."""
    limits = MotionLimits()
    speed, begins, ends = cruise(distance, 0.0, limits)
    ta, peak, total = plan_profile(distance, 0.0, limits)
    s, sd = time_law(ta, peak, total, np.linspace(0.0, total, 200_001))
    at_peak = sd * distance >= speed * (1.0 - 1e-9)
    assert speed == pytest.approx(peak * distance) and speed <= limits.linear_speed + 1e-15
    if begins < ends:
        inside = s[at_peak] * distance
        assert inside.min() == pytest.approx(begins, abs=1e-4 * distance)
        assert inside.max() == pytest.approx(ends, abs=1e-4 * distance)
    else:  # no cruise: the ramps meet in the middle
        assert begins == ends == pytest.approx(distance / 2)
    assert cruise(0.0, 0.0, limits) == (0.0, 0.0, 0.0)


def crossings(times: np.ndarray, sigma: float = 0.0) -> PathCrossings:
    """A cycle crossing the planes at ``times`` (P,) s, each crossing stated with σ per axis."""
    f = np.asarray(PLANE_FRACTIONS)
    return PathCrossings(tuple(A), tuple(B), A + np.outer(f * L, [1.0, 0.0, 0.0]),
                         np.tile(np.eye(3) * sigma**2, (P, 1, 1)), np.asarray(times, float))


def test_a_hand_worked_example() -> None:
    """The plan cruises from 2.5 to 7.5 mm at 10 mm/s: planes 0.3 … 0.7, four intervals of
    1 mm. Cycle 1 crosses them 0.1 s apart (10 mm/s); cycle 2 0.1, 0.1, 0.125, 0.1 s apart
    (10, 10, 8, 10 mm/s). Cycle means 10 and 9.5 mm/s: v̄ 9.75, AV −2.5 %; S_v = 0.3536,
    RV 10.61 %; FV (10 − 8)/10 = 20 %."""
    f = np.asarray(PLANE_FRACTIONS)
    one = crossings(f * 1.0)
    t2 = f * 1.0
    t2[5:] += 0.025  # the interval 0.5 → 0.6 takes 0.125 s
    figures = path_velocity_figures([one, crossings(t2)], 0.01, (0.0025, 0.0075))
    assert figures is not None
    assert figures.intervals == ((0.3, 0.4), (0.4, 0.5), (0.5, 0.6), (0.6, 0.7))
    assert figures.mean == pytest.approx(0.00975)
    assert figures.av == pytest.approx(-0.025)
    assert figures.rv == pytest.approx(3.0 * math.sqrt(0.5 * 0.25e-6) / 0.01)
    assert figures.fv == pytest.approx(0.2)
    assert figures.u_av == figures.u_rv == figures.u_fv == 0.0  # exact crossings
    doc = json.loads(json.dumps(figures.to_dict()))
    assert doc['intervals'][0] == [0.3, 0.4] and doc['u_av'] == 0.0


def test_no_cruise_between_two_planes_gives_none_and_bad_input_is_refused() -> None:
    f = np.asarray(PLANE_FRACTIONS)
    assert cruise_planes(L, (0.0045, 0.0055)).tolist() == [f == 0.5 for f in PLANE_FRACTIONS]
    assert path_velocity_figures([crossings(f)], 0.01, (0.0045, 0.0055)) is None
    backwards = f.copy()
    backwards[4] = backwards[3] - 0.01
    assert path_velocity_figures([crossings(backwards)], 0.01, (0.0, L)) is None
    single = path_velocity_figures([crossings(f, 1e-6)], 0.01, (0.0, L))
    assert single is not None and single.rv is None and math.isnan(single.u_rv)
    with pytest.raises(InputError, match='one cycle'):
        path_velocity_figures([], 0.01, (0.0, L))
    with pytest.raises(InputError, match='commanded velocity'):
        path_velocity_figures([crossings(f)], 0.0, (0.0, L))


@pytest.mark.parametrize(('common', 'noise'), [(4e-6, 3e-6), (0.0, 6e-6)])
def test_the_true_figures_lie_within_u_of_the_measured_ones_in_95_percent_of_runs(
        common: float, noise: float) -> None:
    """200 seeded runs of 5 cycles of a 10 mm path, read at 20 Hz: each cycle's speed profile
    is the plan's (10 mm/s, 50 mm/s²) times 1 ± 2 % and rippled by up to 3 % (random per run),
    the readings off by an error ``common`` to the run and ``noise`` per reading, each stated
    with the sum of both covariances. The truth: the crossings of the true points at the
    same times."""
    limits = MotionLimits()
    speed, begins, ends = cruise(L, 0.0, limits)
    ta, peak, total = plan_profile(L, 0.0, limits)
    runs, n = 200, 5
    covered = np.zeros((runs, 3), dtype=bool)
    for seed in range(runs):
        rng = np.random.default_rng(seed)
        ripple = rng.uniform(0.0, 0.03)
        shared = rng.normal(0.0, common, 3)
        true, measured = [], []
        for _ in range(n):
            scale = 1.0 + rng.normal(0.0, 0.02)
            t = np.arange(-0.1, total / scale + 0.1, 0.05) + rng.uniform(0.0, 0.05)
            s, _ = time_law(ta, peak, total, t * scale)
            along = L * (s + ripple / (2 * np.pi * 4) * np.sin(2 * np.pi * 4 * t * scale) * s
                         * (1 - s))
            points = A + np.outer(along, [1.0, 0.0, 0.0])
            cov = np.tile(np.eye(3) * (common**2 + noise**2), (t.size, 1, 1))
            true.append(path_crossings(A, B, t, points))
            measured.append(path_crossings(
                A, B, t, points + shared + rng.normal(0.0, noise, points.shape), cov))
        f_true = path_velocity_figures(true, speed, (begins, ends))  # type: ignore[arg-type]
        f_meas = path_velocity_figures(measured, speed, (begins, ends),  # type: ignore[arg-type]
                                       rng=np.random.default_rng(10_000 + seed))
        assert f_true is not None and f_meas is not None
        assert f_true.rv is not None and f_meas.rv is not None
        covered[seed] = (abs(f_meas.av - f_true.av) <= f_meas.u_av,
                         abs(f_meas.rv - f_true.rv) <= f_meas.u_rv,
                         abs(f_meas.fv - f_true.fv) <= f_meas.u_fv)
    share = covered.mean(axis=0)
    print(f'AV, RV, FV covered in {share[0]:.1%}, {share[1]:.1%}, {share[2]:.1%} of {runs}')
    assert np.all(share >= 0.95), share
