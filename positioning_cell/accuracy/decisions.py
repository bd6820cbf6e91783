"""Conformity decisions that account for the measurement's own uncertainty (issue 25): a
measured value against its specification limits by the decision rule of ISO 14253-1:2017
(conforms, does not conform, or neither can be shown), simple acceptance selectable for
comparison; and the expanded uncertainty U (coverage factor k) of a measured position error's
norm |Δp|, by the GUM's law of propagation where the norm is nearly linear in Δp (JCGM
100:2008 eq. 10) and by its Monte Carlo method where it is not (JCGM 101:2008). SI units
throughout (m for positions, whatever unit the limits use for the rest).

The monitor's verdicts use them (:mod:`positioning_cell.accuracy.verdicts`, each settled
visit's covariance from its readings': docs/howto/verdicts.md); ``cell watch``, the live view
and the fleet trends do not yet.
"""

from __future__ import annotations

import functools
import math
import threading
from enum import Enum
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: The coverage factor of an expanded uncertainty unless told otherwise (GUM §6.3: k = 2,
#: about 95 % for a normal distribution; ISO 14253-1 states U with it).
COVERAGE_FACTOR = 2.0

#: |Δp| at least this many times the largest standard deviation of Δp (along any direction):
#: the norm's law of propagation is used; below, its Monte Carlo. Measured against the Monte
#: Carlo (10^5 draws; 400 random covariances with sigmas up to 1:4 and random directions, ad
#: hoc): at 10 sigma the propagated U (second-order term included) was 0.2 % below to 1.9 %
#: above it, 0.8 % above on average (first order alone: up to 2.2 % below); at 5 sigma up to
#: 5.5 % above, at 3 up to 14 % (test_decisions checks -1 % to +3 % at 10).
LINEAR_FROM_SIGMAS = 10.0

#: Monte Carlo draws per norm (JCGM 101 §7.2: 10^4 for a 95 % interval to about one
#: significant digit; 10^5 here for two).
MONTE_CARLO_DRAWS = 100_000

#: Rows evaluated at once by the Monte Carlo (bounds its memory: 8 × 10^5 doubles, 6 MB, beside
#: the draws' 10^5 × 9 monomials, 7 MB).
MONTE_CARLO_ROWS = 8


class Decision(Enum):
    """What a measurement shows of a value against its limits (ISO 14253-1:2017 §5):
    conformity proven (inside the specification zone reduced by U), non-conformity proven
    (outside the specification zone widened by U), or neither: the value lies within U of a
    limit and the measurement cannot tell."""

    CONFORMS = 'conforms'
    INDETERMINATE = 'indeterminate'
    DOES_NOT_CONFORM = 'does not conform'


class DecisionRule(Enum):
    """ISO_14253_1: the default rule of ISO 14253-1:2017 (guard bands of width U at each
    limit, three outcomes). SIMPLE_ACCEPTANCE: U is ignored, a value inside the specification
    zone conforms and any other does not (shared risk, ILAC-G8; what the monitor's verdicts
    did until issue 25), for comparison."""

    ISO_14253_1 = 'iso_14253_1'
    SIMPLE_ACCEPTANCE = 'simple_acceptance'


#: The decisions as :func:`decisions` codes them, in code order.
DECISION_CODES = (Decision.CONFORMS, Decision.INDETERMINATE, Decision.DOES_NOT_CONFORM)


def decisions(values: ArrayLike, expanded_uncertainty: ArrayLike, upper: float,
              lower: float | None = None,
              rule: DecisionRule = DecisionRule.ISO_14253_1) -> NDArray[np.int8]:
    """The decision on each measured value y (any shape) with its expanded uncertainty U
    (broadcast against y) against the specification zone [lower, upper] (``lower`` None: an
    upper limit only, as for |Δp| ≤ tolerance), coded as the index into
    :data:`DECISION_CODES` (0 conforms, 1 indeterminate, 2 does not conform).

    ISO 14253-1:2017 §5.2-5.3, limits included in the zone they bound (a value equal to its
    tolerance passes, as the monitor's verdicts have it): conforms when
    lower + U ≤ y ≤ upper − U; does not conform when y > upper + U or y < lower − U;
    indeterminate otherwise (also everywhere in the zone when 2U exceeds its width).
    Simple acceptance: conforms when lower ≤ y ≤ upper, else does not conform.

    InputError: a NaN or infinite value or U, a negative U, a NaN limit, lower > upper."""
    y = np.asarray(values, dtype=float)
    u = np.asarray(expanded_uncertainty, dtype=float)
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(u))):
        raise InputError('decisions: every measured value and its expanded uncertainty U must '
                         'be finite (a value whose uncertainty is unknown cannot be decided on)')
    if np.any(u < 0.0):
        raise InputError(f'decisions: an expanded uncertainty U is negative ({float(u.min())})')
    low = -math.inf if lower is None else float(lower)
    high = float(upper)
    if math.isnan(high) or math.isnan(low) or low > high:
        raise InputError(f'decisions: the specification zone [{lower}, {upper}] is not one')
    try:
        y, u = np.broadcast_arrays(y, u)
    except ValueError as err:
        raise InputError(f'decisions: U of shape {u.shape} does not go with the values of '
                         f'shape {y.shape}') from err
    if rule is DecisionRule.SIMPLE_ACCEPTANCE:
        inside = (y >= low) & (y <= high)
        return np.where(inside, 0, 2).astype(np.int8)
    conforms = (y >= low + u) & (y <= high - u)
    refuted = (y > high + u) | (y < low - u)
    return np.where(conforms, 0, np.where(refuted, 2, 1)).astype(np.int8)


def decision(value: float, expanded_uncertainty: float, upper: float,
             lower: float | None = None,
             rule: DecisionRule = DecisionRule.ISO_14253_1) -> Decision:
    """:func:`decisions` of one value."""
    code = decisions(value, expanded_uncertainty, upper, lower, rule)
    return DECISION_CODES[int(code)]


class CovarianceChecks(NamedTuple):
    """Per covariance (N,): every entry ``finite``; ``symmetric`` to 1e-9 of its largest
    entry; ``semidefinite``: no eigenvalue below −1e-9 of it (rows not finite: False)."""

    finite: NDArray[np.bool_]
    symmetric: NDArray[np.bool_]
    semidefinite: NDArray[np.bool_]

    @property
    def usable(self) -> NDArray[np.bool_]:
        """A covariance: finite, symmetric and positive semi-definite."""
        return self.finite & self.symmetric & self.semidefinite


def covariance_checks(covariance: ArrayLike) -> CovarianceChecks:
    """:class:`CovarianceChecks` of N square covariances (N, n, n), each to its own scale."""
    cov = np.asarray(covariance, dtype=float)
    finite: NDArray[np.bool_] = np.all(np.isfinite(cov), axis=(1, 2))
    symmetric, semidefinite = np.zeros_like(finite), np.zeros_like(finite)
    if np.any(finite):
        c = cov[finite]
        scale = np.maximum(np.abs(c).max(axis=(1, 2)), np.finfo(float).tiny)
        symmetric[finite] = np.all(
            np.abs(c - np.swapaxes(c, 1, 2)) <= 1e-9 * scale[:, None, None], axis=(1, 2))
        lowest = np.linalg.eigvalsh(0.5 * (c + np.swapaxes(c, 1, 2)))[:, 0]
        semidefinite[finite] = lowest >= -1e-9 * scale
    return CovarianceChecks(finite, symmetric, semidefinite)


def norm_expanded_uncertainty(delta: ArrayLike, covariance: ArrayLike,
                              k: float = COVERAGE_FACTOR,
                              rng: np.random.Generator | None = None,
                              draws: int = MONTE_CARLO_DRAWS) -> FloatArray:
    """The expanded uncertainty U (N,) of the norms |Δp| of N measured vectors ``delta``
    (N, 3), each with the covariance (N, 3, 3) of its measurement (same unit squared), for
    coverage factor ``k``.

    Where |Δp| ≥ :data:`LINEAR_FROM_SIGMAS` times Δp's largest standard deviation: the law of
    propagation of uncertainty (JCGM 100:2008 eq. 10) with the norm's sensitivities
    n = Δp / |Δp| and its second-order term (§5.1.2 note) with the norm's curvature
    H = (I − n nᵀ) / |Δp|: U = k · sqrt(nᵀ Σ n + ½ tr((H Σ)²)). Elsewhere the norm is far
    from linear (at Δp = 0 its derivative does not exist): JCGM 101:2008's Monte Carlo, Δp
    drawn from N(Δp, Σ)
    :data:`MONTE_CARLO_DRAWS` times, and U the half-width of the probabilistically symmetric
    coverage interval of |Δp| with the coverage probability k gives for a normal
    distribution (95.45 % for k = 2). ``rng``: the draws' generator (default: seeded, so a
    figure is the same on every run); ``draws``: their number (fewer for a live display).

    InputError: wrong shapes, NaN or infinite entries, a covariance that is not symmetric
    positive semi-definite, k ≤ 0."""
    d = np.asarray(delta, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    if d.ndim != 2 or d.shape[1] != 3 or cov.shape != (d.shape[0], 3, 3):
        raise InputError(f'norm_expanded_uncertainty: expected Δp (N, 3) and its covariance '
                         f'(N, 3, 3), got {d.shape} and {cov.shape}')
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(cov))):
        raise InputError('norm_expanded_uncertainty: Δp and its covariance must be finite')
    if not (math.isfinite(k) and k > 0.0):
        raise InputError(f'norm_expanded_uncertainty: the coverage factor k must be > 0, '
                         f'got {k}')
    if draws < 2:
        raise InputError(f'norm_expanded_uncertainty: draws must be >= 2, got {draws}')
    checks = covariance_checks(cov)
    if not np.all(checks.symmetric):
        raise InputError('norm_expanded_uncertainty: a covariance is not symmetric')
    if not np.all(checks.semidefinite):
        raise InputError('norm_expanded_uncertainty: a covariance is not positive '
                         'semi-definite')
    eigen = np.linalg.eigvalsh(cov)  # (N, 3), ascending
    norms = np.sqrt((d * d).sum(axis=1))
    # (|Δp| = 0 with an exact measurement: the Monte Carlo, whose draws all give 0)
    linear = (norms >= LINEAR_FROM_SIGMAS * np.sqrt(np.maximum(eigen[:, 2], 0.0))) & (norms > 0)
    out = np.empty(d.shape[0])
    n = d[linear] / norms[linear][:, None]
    first = np.einsum('ni,nij,nj->n', n, cov[linear], n)
    # The norm's curvature, H = (I - n nᵀ) / |Δp|: the second-order term of the propagation
    # for normal inputs, ½ tr((H Σ)²) (JCGM 100:2008 §5.1.2 note, eq. 11 with correlations).
    # It carries the variance across Δp into |Δp|: without it U came out up to 2.2 % below
    # the Monte Carlo's at 10 sigma (LINEAR_FROM_SIGMAS), with it never more than 0.2 %.
    hessian = (np.eye(3) - n[:, :, None] * n[:, None, :]) / norms[linear][:, None, None]
    h_cov = hessian @ cov[linear]
    second = 0.5 * np.einsum('nij,nji->n', h_cov, h_cov)
    out[linear] = k * np.sqrt(np.maximum(first + second, 0.0))
    if np.any(~linear):
        out[~linear] = _monte_carlo(d[~linear], cov[~linear], k,
                                    rng, draws)
    return out


def _monte_carlo(d: FloatArray, cov: FloatArray, k: float, rng: np.random.Generator | None,
                 draws: int = MONTE_CARLO_DRAWS) -> FloatArray:
    """JCGM 101:2008 §7 for Y = |X|, X ~ N(d, cov), rows at once: the half-width of the
    probabilistically symmetric coverage interval for probability erf(k / √2). ``rng`` None:
    the draws of the seeded default generator (:func:`_default_monomials`, drawn once).

    One set of ``draws`` standard normal draws z (M, 3) serves every row (a
    valid sample of each row's X = d + L z, L Lᵀ = cov; the rows' figures are then
    correlated, never biased), and |X|² = dᵀd + 2 (Lᵀd)·z + zᵀ(LᵀL)z is one matrix product
    of the draws' nine monomials with each row's nine coefficients: ~20 times faster than a
    draw per row (19 ms a row before), so that a replay of thousands of visits affords it.
    With the draws drawn once and only the tails partitioned (:func:`order_statistics`):
    0.52 ms a row of 10^5 draws, against 1.6-2.0 ms before (the largest share of a long replay,
    issue 24; the same half-widths). Double precision throughout, and the product always of
    a full chunk: a row's rounding must not depend on the rows beside it (in single
    precision, 0.42 ms a row, and with chunks of fewer rows on some processors it did, and
    the monitor's figures then on how its visits were grouped)."""
    p = math.erf(k / math.sqrt(2.0))
    # A symmetric positive semi-definite covariance's square root by its eigenvectors (a
    # Cholesky factor needs it definite: a reading may be exact along an axis).
    w, v = np.linalg.eigh(cov)
    root = v * np.sqrt(np.maximum(w, 0.0))[:, None, :]  # (N, 3, 3): root @ rootᵀ = cov
    monomials = (_default_monomials(draws) if rng is None
                 else _monomials(rng.standard_normal((draws, 3))))
    linear = 2.0 * np.einsum('nji,nj->ni', root, d)  # 2 Lᵀd (N, 3)
    quad = np.einsum('nki,nkj->nij', root, root)  # LᵀL (N, 3, 3)
    coefficients = np.column_stack([
        linear, quad[:, 0, 0], quad[:, 1, 1], quad[:, 2, 2],
        2.0 * quad[:, 0, 1], 2.0 * quad[:, 0, 2], 2.0 * quad[:, 1, 2]])  # (N, 9)
    constant = (d * d).sum(axis=1)
    # np.quantile's linear interpolation between the order statistics around (M - 1)·p, taken
    # from |X|² (the same order) and their roots only: no root of every draw.
    at = (draws - 1) * np.array([(1.0 - p) / 2.0, (1.0 + p) / 2.0])
    below = np.floor(at).astype(np.intp)
    share = at - below
    ranks = np.concatenate([below, np.minimum(below + 1, draws - 1)])
    out = np.empty(d.shape[0])
    scratch = _scratch(draws)
    for start in range(0, d.shape[0], MONTE_CARLO_ROWS):  # chunks of rows, not samples
        rows = slice(start, start + MONTE_CARLO_ROWS)
        # the product of a full chunk always (padded with zero rows): BLAS picks its kernel
        # by the shape, and a row's last bits must not depend on how many rows come with it
        # (the monitor's figures are the same however its visits are grouped)
        count = min(MONTE_CARLO_ROWS, d.shape[0] - start)
        chunk = np.zeros((MONTE_CARLO_ROWS, 9))
        chunk[:count] = coefficients[rows]
        np.matmul(chunk, monomials, out=scratch)
        squared = scratch[:count]
        squared += constant[rows, None]  # (rows, M)
        y = np.sqrt(np.maximum(order_statistics(squared, ranks), 0.0))  # low, high, +1, +1
        low_high = y[:, :2] + share * (y[:, 2:] - y[:, :2])
        out[rows] = (low_high[:, 1] - low_high[:, 0]) / 2.0
    return out


def _monomials(z: FloatArray) -> FloatArray:
    """The nine monomials (9, M) of draws z (M, 3) that |X|² is linear in: z₀, z₁, z₂, z₀²,
    z₁², z₂², z₀z₁, z₀z₂, z₁z₂."""
    return np.vstack([z.T, (z * z).T, z[:, 0] * z[:, 1], z[:, 0] * z[:, 2], z[:, 1] * z[:, 2]])


@functools.lru_cache(maxsize=2)
def _default_monomials(draws: int) -> FloatArray:
    """:func:`_monomials` of ``draws`` draws of the default generator (seed 0), the same on
    every call: drawn once per process, not per call (8.5 ms of each call's 20 ms for 10^5
    draws; 7 MB kept), read-only."""
    out = _monomials(np.random.default_rng(0).standard_normal((draws, 3)))
    out.setflags(write=False)
    return out


_SCRATCH = threading.local()


def _scratch(draws: int) -> FloatArray:
    """This thread's working array (:data:`MONTE_CARLO_ROWS`, ``draws``) for the Monte
    Carlo's |X|², kept between calls (6.4 MB for 10^5 draws): allocated afresh, it was mapped
    and its pages faulted in at every chunk where large allocations are mapped apart from the
    heap (the analysis: :mod:`positioning_cell.analysis.heap`), 0.9-1.3 ms a row against
    0.5-0.6 ms."""
    buffer: FloatArray | None = getattr(_SCRATCH, 'buffer', None)
    if buffer is None or buffer.shape[1] != draws:
        buffer = _SCRATCH.buffer = np.empty((MONTE_CARLO_ROWS, draws))
    return buffer


#: :func:`order_statistics` finds its thresholds in the first this many values of each row.
PILOT = 4_096


def order_statistics(values: FloatArray, ranks: NDArray[np.intp]) -> FloatArray:
    """The order statistics (rows, r) of each row of ``values`` (rows, M) at ``ranks`` (r,),
    0-based: exactly ``np.partition(values, ranks, axis=1)[:, ranks]``, in about a quarter of
    its time when the ranks lie in the tails (the Monte Carlo's 2.3 % and 97.7 %: 2.7 ms for
    8 rows of 10^5 values, 9.9 ms partitioned whole). A threshold per row and tail, taken
    from the first :data:`PILOT` values with a margin, leaves only the values beyond it to
    partition; a row whose threshold did not leave enough of them (the pilot not
    representative: values in drawn order are) is partitioned whole, so the result never
    depends on the pilot."""
    rows, m = values.shape
    ranks = np.asarray(ranks, dtype=np.intp)
    low, high = ranks[ranks < m // 2], ranks[ranks >= m // 2]
    # how far into each tail the ranks reach, as a share of M, with a margin for the pilot's
    # own scatter (4 binomial sigmas and 2 values, at the pilot's size)
    reach = (int(low.max()) + 1 if low.size else 0, m - int(high.min()) if high.size else 0)
    if m < 4 * PILOT or max(reach) > m // 8:
        return np.partition(values, ranks, axis=1)[:, ranks]
    pilot_ranks = [min(PILOT - 1, math.ceil(r * PILOT / m + 4.0 * math.sqrt(r * PILOT / m)) + 2)
                   for r in reach]
    pilot = np.partition(values[:, :PILOT], [pilot_ranks[0], PILOT - 1 - pilot_ranks[1]],
                         axis=1)
    out = np.empty((rows, ranks.size))
    order = np.concatenate([np.flatnonzero(ranks < m // 2), np.flatnonzero(ranks >= m // 2)])
    for row in range(rows):  # rows, not values
        v = values[row]
        below = v[v <= pilot[row, pilot_ranks[0]]] if low.size else v[:0]
        above = v[v >= pilot[row, PILOT - 1 - pilot_ranks[1]]] if high.size else v[:0]
        if below.size < reach[0] or above.size < reach[1]:
            out[row] = np.partition(v, ranks)[ranks]
            continue
        # the below set holds the smallest values (rank r is its rank r), the above set the
        # largest (rank r is its rank r - (M - size))
        low_at = np.partition(below, low)[low] if low.size else below[:0]
        high_in = high - (m - above.size)
        high_at = np.partition(above, high_in)[high_in] if high.size else above[:0]
        out[row, order] = np.concatenate([low_at, high_at])
    return out


__all__ = ['COVERAGE_FACTOR', 'DECISION_CODES', 'CovarianceChecks', 'Decision', 'DecisionRule',
           'covariance_checks', 'decision', 'decisions', 'norm_expanded_uncertainty']
