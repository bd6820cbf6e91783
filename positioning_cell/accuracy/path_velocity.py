"""Path velocity characteristics (ISO 9283:1998 §8.6) of the cell's straight-line moves: path
velocity accuracy AV, repeatability RV and fluctuation FV, with their expanded uncertainty U
(k = 2). SI: m/s, s; the figures in % of the commanded velocity.

The attained path velocity is taken between the normal planes of a path
(:mod:`positioning_cell.accuracy.path`): v_ij = Δs / (t_{i+1,j} − t_ij), Δs the planes'
spacing along the commanded line and t_ij the time cycle j's readings crossed plane i. The
commanded velocity v_c is the cruise speed of the positioner's plan for the path
(:func:`positioning_cell.moves.trajectory.plan_profile` with its motion limits), and only the
plane intervals that lie wholly within its cruise count (the standard measures the constant
velocity part of the path). Over the n cycles, v̄_j the mean of cycle j's samples and v̄ the
mean of the v̄_j:

- AV = (v̄ − v_c)/v_c;
- RV = 3·S_v/v_c, S_v = √(Σ_j (v̄_j − v̄)²/(n − 1)) (the standard's ±, the half-width stored);
- FV = max_j (max_i v_ij − min_i v_ij)/v_c (the largest velocity range within a cycle).

U: a reading's error along the path, e, moves the time its crossing is seen by −e/v, so a
sample moves by δv_ij = v_ij·(e_{i+1,j} − e_ij)/Δs (first order: e is µm, Δs a millimetre). The
crossings' along-path errors are drawn independent, N(0, uᵀΣu) with the crossing's stated
covariance (a part common to all readings moves every crossing alike and cancels), and U of
each figure is the quantile, at the coverage probability of k, of a bound of its change:
|mean δv|/v_c for AV, the bound of RP_l's kind for the spread of the cycle means
(‖δv̄ − mean δv̄‖/√(n − 1), ×3) for RV, 2·max |δv| for FV. The readings' time stamps are
taken as exact (the simulated tracker stamps each reading when it measured).

Test: test/test_path_velocity.py (a hand-worked example; the figures of seeded simulated
paths from their true crossing times within U of those from their readings)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell.accuracy.decisions import COVERAGE_FACTOR
from positioning_cell.accuracy.figure_uncertainty import (
    NormalSource,
    SeededDraws,
    adaptive_quantiles,
)
from positioning_cell.accuracy.path import PLANE_FRACTIONS, PathCrossings
from positioning_cell.errors import InputError
from positioning_cell.records import plain_fields

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PathVelocityFigures:
    """ISO 9283 §8.6 of one commanded path (module docstring): the commanded velocity
    ``commanded`` (m/s), the plane intervals used (``intervals``, each the pair of plane
    fractions), ``n`` cycles, the mean attained velocity (m/s), AV, RV, FV (fractions of the
    commanded velocity; RV None below two cycles) and U (k = 2) of each (NaN: not stated)."""

    commanded: float
    n: int
    intervals: tuple[tuple[float, float], ...]
    mean: float
    av: float
    rv: float | None
    fv: float
    u_av: float = math.nan
    u_rv: float = math.nan
    u_fv: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI and fractions; None where undefined or, for a U, not stated)."""
        out = plain_fields(self)
        out['intervals'] = [list(pair) for pair in self.intervals]
        for key in ('u_av', 'u_rv', 'u_fv'):
            out[key] = out[key] if math.isfinite(out[key]) else None
        return out


def cruise_planes(length: float, cruise: tuple[float, float]) -> NDArray[np.bool_]:
    """Which planes (:data:`~.path.PLANE_FRACTIONS`) of a path of ``length`` m lie within its
    cruise, ``cruise`` the distances (m) along it where the commanded speed reaches and
    leaves its peak."""
    at = np.asarray(PLANE_FRACTIONS) * length
    return np.asarray((at >= cruise[0] - 1e-12) & (at <= cruise[1] + 1e-12))


def path_velocity_figures(crossings: Sequence[PathCrossings], commanded: float,
                          cruise: tuple[float, float], k: float = COVERAGE_FACTOR,
                          rng: NormalSource | None = None) -> PathVelocityFigures | None:
    """AV, RV, FV (module docstring) of the cycles ``crossings`` of one commanded path
    (:func:`~.path.path_figures`'s), ``commanded`` its cruise speed (m/s) and ``cruise`` the
    distances (m) along it between which the plan cruises; None when fewer than two planes
    within the cruise were crossed by every cycle. InputError: no cycles, a commanded speed
    not finite and > 0."""
    if not crossings:
        raise InputError('path_velocity_figures needs the crossings of one cycle at least')
    if not (math.isfinite(commanded) and commanded > 0.0):
        raise InputError(f'commanded velocity {commanded!r}: must be finite and > 0')
    first = crossings[0]
    length = float(np.linalg.norm(np.asarray(first.end) - np.asarray(first.start)))
    used = cruise_planes(length, cruise) & np.all([c.crossed for c in crossings], axis=0)
    # consecutive planes both used: the intervals whose speed is sampled
    pairs = np.flatnonzero(used[:-1] & used[1:])
    if pairs.size == 0:
        return None
    fractions = np.asarray(PLANE_FRACTIONS)
    spacing = (fractions[pairs + 1] - fractions[pairs]) * length  # (I,) m
    times = np.array([c.time for c in crossings])  # (n, P)
    dt = times[:, pairs + 1] - times[:, pairs]  # (n, I)
    if not np.all(dt > 0.0):
        return None  # a cycle crossed a later plane first: no velocity to speak of
    v = spacing / dt  # (n, I)
    n = v.shape[0]
    cycle_mean = v.mean(axis=1)
    mean = float(cycle_mean.mean())
    rv = 3.0 * float(cycle_mean.std(ddof=1)) / commanded if n >= 2 else None
    fv = float((v.max(axis=1) - v.min(axis=1)).max()) / commanded
    start, end = np.asarray(first.start), np.asarray(first.end)
    u = (end - start) / length
    cov = np.array([c.covariance for c in crossings])  # (n, P, 3, 3)
    along = np.einsum('i,njik,k->nj', u, cov, u)  # (n, P): variance along the path
    uncertainties = [math.nan] * 3
    if np.all(np.isfinite(along)):
        uncertainties = _uncertainty(np.sqrt(np.maximum(along, 0.0)), pairs, v / spacing,
                                     commanded, k, rng if rng is not None else SeededDraws())
    return PathVelocityFigures(
        commanded, n, tuple((float(fractions[i]), float(fractions[i + 1])) for i in pairs),
        mean, (mean - commanded) / commanded, rv, fv, *uncertainties)


def _uncertainty(sigma: FloatArray, pairs: NDArray[np.intp], gain: FloatArray,
                 commanded: float, k: float, rng: NormalSource) -> list[float]:
    """U of AV, RV, FV: the quantiles of their bounds (module docstring) over draws of the
    crossings' along-path errors (σ (n, P)); ``gain`` (n, I) = v_ij/Δs."""
    n = sigma.shape[0]

    def bounds(draws: int) -> FloatArray:
        e = rng.standard_normal((draws, *sigma.shape)) * sigma  # (draws, n, P)
        dv = gain * (e[:, :, pairs + 1] - e[:, :, pairs])  # (draws, n, I)
        out = np.empty((draws, 3))
        cycle = dv.mean(axis=2)  # (draws, n)
        out[:, 0] = np.abs(cycle.mean(axis=1))
        centred = cycle - cycle.mean(axis=1, keepdims=True)
        out[:, 1] = 3.0 * np.sqrt((centred ** 2).sum(axis=1) / max(n - 1, 1))
        out[:, 2] = 2.0 * np.abs(dv).max(axis=(1, 2))
        return out / commanded

    found = adaptive_quantiles(bounds, k, sigma.size).tolist()
    if n < 2:
        found[1] = math.nan
    return [float(x) for x in found]


__all__ = ['PathVelocityFigures', 'cruise_planes', 'path_velocity_figures']
