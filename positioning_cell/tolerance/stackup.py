"""Stack-ups of a sensitivity matrix T (:mod:`.linear`) over the sources' tolerances: the worst
case (seed 004 eq. 15), the root-sum-square, each source's share (a Pareto chart's bars), and
the yield of sampled deviations against a requirement with its confidence interval.

Units: T in Gap units per source unit; tolerances, bounds and standard deviations in source
units; results in Gap units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import binomtest

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]


def worst_case(matrix: FloatArray, bounds: FloatArray,
               balls: tuple[tuple[int, int], ...] = ()) -> FloatArray:
    """Worst-case deviation per output (seed 004 eq. 15 over boxes and balls): T (..., R, S),
    bounds (S,), ``balls`` index ranges [a, b) of offset vectors with |e_j| ≤ r_j (r_j = the
    bound of their columns) → (..., R): Σ_box |T_ci|·t_i + Σ_j r_j·‖T_c,j‖₂, the exact maximum
    of |(T·x)_c| (attained by x_i = ±t_i and e_j = ±r_j·T_c,jᵀ/‖T_c,j‖). Without balls,
    Σ_i |T_ci|·t_i."""
    box = np.ones(matrix.shape[-1], dtype=bool)
    members = np.array([range(a, b) for a, b in balls], dtype=np.int64).reshape(-1, 3)
    box[members.ravel()] = False
    out: FloatArray = np.abs(matrix[..., box]) @ bounds[box]
    if members.size:
        out = out + np.linalg.norm(matrix[..., members], axis=-1) @ bounds[members[:, 0]]
    return out


def root_sum_square(matrix: FloatArray, scale: FloatArray) -> FloatArray:
    """sqrt(Σ_i (T_i·s_i)²) per output (..., R): with s the bounds, the classic RSS stack-up;
    with s the standard deviations, the linear-model σ."""
    out: FloatArray = np.sqrt(np.sum((matrix * scale) ** 2, axis=-1))
    return out


@dataclass(frozen=True)
class Contributions:
    """Each source's share of one output's worst case: ``order`` (S,) the sources by
    decreasing contribution, ``worst`` (S,) |T_i|·t_i in that order (Gap units), ``share`` (S,)
    of the worst case and ``cumulative`` (S,) shares (a Pareto chart); ``variance`` (S,) the
    share of the linear-model variance (T_i·σ_i)² / Σ, in the same order."""

    order: NDArray[np.intp]
    worst: FloatArray
    share: FloatArray
    cumulative: FloatArray
    variance: FloatArray


def contributions(row: FloatArray, bounds: FloatArray, stds: FloatArray) -> Contributions:
    """The Pareto ranking of the sources for one output: T row (S,), bounds (S,), standard
    deviations (S,)."""
    worst = np.abs(row) * bounds
    order = np.argsort(-worst, kind='stable')
    total = float(worst.sum())
    var = (row * stds) ** 2
    var_total = float(var.sum())
    share = worst[order] / total if total > 0.0 else np.zeros(row.size)
    return Contributions(order, worst[order], share, np.cumsum(share),
                         var[order] / var_total if var_total > 0.0 else np.zeros(row.size))


@dataclass(frozen=True)
class YieldEstimate:
    """Probability that the output meets the requirement: ``inside`` of ``trials`` samples,
    estimate ``probability`` and its Wilson interval [``low``, ``high``] at ``confidence``."""

    inside: int
    trials: int
    probability: float
    low: float
    high: float
    confidence: float


def estimate_yield(inside: BoolArray, confidence: float = 0.95) -> YieldEstimate:
    """Yield from per-sample pass flags (n,), with the Wilson score interval
    (``scipy.stats.binomtest(...).proportion_ci``)."""
    trials = int(inside.size)
    if trials == 0:
        raise InputError('estimate_yield: no samples')
    if not 0.0 < confidence < 1.0:
        raise InputError(f'confidence = {confidence!r}: must lie in (0, 1)')
    k = int(np.count_nonzero(inside))
    ci = binomtest(k, trials).proportion_ci(confidence_level=confidence, method='wilson')
    return YieldEstimate(k, trials, k / trials, float(ci.low), float(ci.high), confidence)
