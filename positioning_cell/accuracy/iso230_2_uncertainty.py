"""The expanded uncertainty U (k = 2) of the ISO 230-2 axis figures from the measurement's own
uncertainty (issue 25; ISO/TR 230-9 is the pattern: the figures of a machine tool test stated
with the uncertainty of the measurement that gave them).

Each stop's positional deviation x_ij = P_ij − P_i was measured with a standard uncertainty
u_ij (the tracker's averaged pose taken to the axis through the machine's inverse kinematics:
:func:`positioning_cell.analysis.axis_test.actuator_uncertainty`). The axis figures are
maxima, minima and spreads of those deviations (:func:`~.iso230_2.axis_figures`), and the
measurement's errors e_ij inflate the spreads by an amount that depends on the unknown truth
(a Monte Carlo of F(x − e) around the measured F(x) covered the true A and R in only 83-88 %
of seeded axes measured with errors larger than their scatter). As for RP_l
(:mod:`positioning_cell.accuracy.figure_uncertainty`), each figure's U is the quantile of a
bound of its change that holds whatever the truth. With ē_i the mean error of target i's
stops in one direction and S_i = √(Σ_j (e_ij − ē_i)²/(n − 1)): x̄_i moves by ē_i exactly,
s_i by at most S_i (triangle inequality; centring is a projection), hence

- A↑ = max(x̄↑ + 2s↑) − min(x̄↑ − 2s↑) by at most 2·max_i(|ē_i↑| + 2S_i↑); A↓ alike; A by 2·the
  larger of the two maxima;
- R_i↑ = 4s_i↑ by 4S_i↑ (R↑, R↓ their maxima); R_i by max(2S↑ + 2S↓ + |ē↑ − ē↓|, 4S↑, 4S↓),
  R by its maximum over i;
- B_i by |ē_i↑ − ē_i↓| (B by its maximum), B̄ by the mean of ē_i↑ − ē_i↓;
- E↑ by 2·max_i |ē_i↑|, E↓ alike, E by 2·the larger; M by 2·max_i |ē_i↑ + ē_i↓|/2.

U is the quantile of each bound at the coverage probability of k (95.45 % for k = 2) over
draws of the errors e_ij ~ N(0, u_ij²), independent (JCGM 101:2008's adaptive procedure:
:func:`~positioning_cell.accuracy.figure_uncertainty.adaptive_quantiles`): the machine's
figure lies within U of the measured one with at least that probability.

A part of the error common to every stop (the tracker's registration) shifts every deviation
alike and leaves every axis figure unchanged (each is a difference of deviations); the u_ij
include it and the draws treat it as independent, so U cannot understate.

Test: test/test_iso230_2.py (no uncertainty gives U 0; the figures of seeded simulated axes
from their true deviations lie within U of those from their measurements in ≥ 95 % of
runs)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.decisions import COVERAGE_FACTOR
from positioning_cell.accuracy.figure_uncertainty import (
    NormalSource,
    SeededDraws,
    adaptive_quantiles,
)
from positioning_cell.accuracy.iso230_2 import AXIS_FIGURES, AxisFigures
from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]


def axis_figure_uncertainty(figures: AxisFigures, u_up: ArrayLike, u_down: ArrayLike,
                            k: float = COVERAGE_FACTOR, rng: NormalSource | None = None
                            ) -> dict[str, float]:
    """U (module docstring) of each axis figure of ``figures`` (by its name in
    :data:`~.iso230_2.AXIS_FIGURES`: A, A_up … M; the unit of the figures) from the standard
    uncertainties (n, m) of its deviations x_up and x_down. ``rng``: default seeded
    (:class:`~positioning_cell.accuracy.figure_uncertainty.SeededDraws`). InputError: shapes
    that do not match, an uncertainty negative or not finite, k ≤ 0."""
    x_up = figures.x_up
    u = [np.asarray(v, dtype=float) for v in (u_up, u_down)]
    if any(v.shape != x_up.shape for v in u):
        raise InputError(f'uncertainties: expected shape {x_up.shape} (cycles, targets) for '
                         f'each direction, got {u[0].shape} and {u[1].shape}')
    if not all(np.all(np.isfinite(v)) and np.all(v >= 0.0) for v in u):
        raise InputError('uncertainties: each must be finite and ≥ 0')
    if not (math.isfinite(k) and k > 0.0):
        raise InputError(f'the coverage factor k must be > 0, got {k}')
    names = [name for name, _ in AXIS_FIGURES]
    if not any(v.any() for v in u):
        return dict.fromkeys(names, 0.0)
    source: NormalSource = rng if rng is not None else SeededDraws()
    scale = np.stack(u)  # (2, n, m)

    def bounds(draws: int) -> FloatArray:
        return departure_bounds(source.standard_normal((draws, *scale.shape)) * scale)

    found = adaptive_quantiles(bounds, k, scale.size)
    return dict(zip(names, found.tolist(), strict=True))


def departure_bounds(errors: FloatArray) -> FloatArray:
    """The bounds (draws, 12) (module docstring; :data:`~.iso230_2.AXIS_FIGURES` order) of
    how far measurement errors (draws, 2, n, m) (↑ then ↓) move each axis figure."""
    mean = errors.mean(axis=2)  # (draws, 2, m): ē_i of each direction
    n = errors.shape[2]
    spread = np.sqrt(((errors - mean[:, :, None]) ** 2).sum(axis=2) / (n - 1))  # S_i
    a_dir = 2.0 * (np.abs(mean) + 2.0 * spread).max(axis=2)  # (draws, 2): A↑, A↓
    r_dir = 4.0 * spread.max(axis=2)  # R↑, R↓
    b_i = mean[:, 0] - mean[:, 1]
    r_i = np.maximum(2.0 * spread[:, 0] + 2.0 * spread[:, 1] + np.abs(b_i),
                     4.0 * spread.max(axis=1))
    e_dir = 2.0 * np.abs(mean).max(axis=2)  # E↑, E↓
    out: FloatArray = np.stack([
        a_dir.max(axis=1), a_dir[:, 0], a_dir[:, 1],
        r_i.max(axis=1), r_dir[:, 0], r_dir[:, 1],
        np.abs(b_i).max(axis=1), np.abs(b_i.mean(axis=1)),
        e_dir.max(axis=1), e_dir[:, 0], e_dir[:, 1],
        np.abs(mean[:, 0] + mean[:, 1]).max(axis=1)], axis=1)
    return out


__all__ = ['axis_figure_uncertainty', 'departure_bounds']
