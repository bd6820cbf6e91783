"""Pose stabilisation time and pose overshoot (ISO 9283:1998 §7.4, §7.5) of one visit, from
the readings of its segment, with their expanded uncertainty U (k = 2).

The readings of a visit are the tracker's measured positions p_j (m, base frame) at times t_j
(s) from its segment's start (the target took effect) to the end of its settle window
(:class:`positioning_cell.accuracy.settle.Visit`), and x the visit's attained position. With
d_j = |p_j − x| and a limit band b (the manufacturer's limit; the monitor's
``stabilisation.band``):

- the *first entry* is the first reading with d_j ≤ b, the *final entry* the first reading of
  the run of readings with d_j ≤ b that lasts to the end of the window;
- the stabilisation time is t(final entry) − t(first entry) (0 when the position entered the
  band once and stayed: no oscillation, damped or otherwise, to wait out);
- the overshoot is how far the position went past the attained one from the first entry on:
  the largest (p_j − x)·a with a the unit direction of approach (from the segment's first
  reading to x), 0 when it never passed x (a step response's overshoot, in the direction it
  moved).

A visit whose readings never entered the band, or left it at the last reading, has neither
(NaN); one whose first reading lay within the band already (no move) has no overshoot.

Given the segment's start (the target took effect: the move began), the visit's positioning
time (ISO 9283 §9, :mod:`positioning_cell.accuracy.positioning_time`) is t(final entry) −
start: the time to the stabilised state.

U (k = 2): the figures are not linear in the readings (thresholds, a maximum), so each U is
a bound that holds, with at least the coverage probability p of k (95.45 %), whatever the
motion, from the readings' stated covariances Σ_j, the attained position's Σ_x and the
readings' spacing. All n errors lie within c = Φ⁻¹(1 − (1 − p)/(2n)) of their standard
deviations together with probability ≥ p, whatever their correlation (Bonferroni:
:func:`within_all`); a Monte Carlo of the same (JCGM 101) took 400 draws of every reading
of every visit, 2.8 ms a visit, and was the analysis's largest cost on a long recording.

- The time: each reading's true distance from x lies within c·σ_j of the measured one, σ_j
  the standard deviation of its error and the attained position's along its direction from
  x (first order: an entry happens some 50 µm out, the errors are µm). The earliest and
  latest first and final entries those intervals allow, each entry anywhere in the interval
  before the reading that sees it (the readings sample the motion), bound the true time; U
  is its larger departure from the estimate. None (NaN) when the readings might not stay in
  the band. The positioning time's U likewise from the earliest and latest final entries
  (the start is the target's stamp, taken as exact).
- The overshoot: with e_j the readings' errors and e_x the attained position's,
  |max_j (p_j − x)·a − max_j (p_j,true − x_true)·a| ≤ max_j |e_j·a| + |e_x·a| (each term
  moves by at most that; the clamp at 0 too), within c·(max_j σ_j,a + σ_x,a) over the
  readings from the one before the first entry on (n + 1 errors); plus half the step
  between the readings beside the furthest one (the motion's furthest point may lie between
  them, a path within half its chord of its readings).

When the position moved more than the band between two readings after the first entry, the
readings may have missed an excursion out of the band altogether: the figures are stated as
not resolved, without U (a faster tracker, or slower moves, resolve them).

Test: test/test_stabilisation.py (hand-worked figures; a damped approach sampled at the
tracker's rate with its noise against the same motion sampled finely, in ≥ 95 % of seeded
runs within U)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.decisions import COVERAGE_FACTOR
from positioning_cell.errors import InputError
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]

#: Default limit band (m): the monitor's default position tolerance, well above the tracker's
#: noise per reading (about 9 µm RMS).
BAND = 50e-6


@dataclass(frozen=True)
class StabilisationSettings:
    """The limit band of pose stabilisation and overshoot (the monitor's ``stabilisation:``
    block, read-only: the same band must be used offline to get the same figures)."""

    band: float = setting(BAND, 'limit band around the attained position (ISO 9283 7.4, 7.5)',
                          'm', low=0.0, low_open=True, high=0.01)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class Stabilisation:
    """A visit's stabilisation ``time`` (s) and ``overshoot`` (m) with their expanded
    uncertainties (k = 2; NaN: a reading stated no covariance), and how many ``readings``
    they came from. NaN figures: the readings never entered the band or did not stay."""

    time: float
    overshoot: float
    time_u: float
    overshoot_u: float
    readings: int
    #: False: the position moved more than the band between two readings after the first
    #: entry, so the readings may have missed an excursion out of the band; no U is stated.
    resolved: bool = True
    #: The positioning time (s, ISO 9283 §9): from the segment's start to the final entry,
    #: and its U (k = 2); NaN without a start, or without an entry that stayed.
    positioning_time: float = math.nan
    positioning_time_u: float = math.nan

    @staticmethod
    def none(readings: int = 0) -> Stabilisation:
        """No figure (no readings, or none that entered the band and stayed)."""
        return Stabilisation(math.nan, math.nan, math.nan, math.nan, readings)

    def to_dict(self) -> dict[str, float | int | bool | None]:
        """JSON-able (SI; NaN as null)."""
        return plain(self.__dict__)


def plain(values: dict[str, float | int | bool]) -> dict[str, float | int | bool | None]:
    """``values`` with NaN as None (JSON has no NaN)."""
    return {name: (None if isinstance(value, float) and not math.isfinite(value) else value)
            for name, value in values.items()}


def _entries(time: FloatArray, distance: FloatArray,
             band: float) -> tuple[FloatArray, NDArray[np.intp], NDArray[np.intp]]:
    """Stabilisation times (D,) of D rows of distances (D, n) at ``time`` (n,) (NaN where a
    row never entered the band or did not stay) and the indices (D,) of each row's first and
    final entries."""
    n = distance.shape[1]
    inside = distance <= band
    first = np.argmax(inside, axis=1)
    final = np.max(np.where(inside, -1, np.arange(n)), axis=1) + 1  # after the last outside
    ok = inside.any(axis=1) & (final < n)
    final = np.minimum(final, n - 1)
    t_first, t_final = time[first], time[final]
    stays = final > first  # entered, left and came back: else it stayed from the first entry
    return np.where(ok, np.where(stays, t_final - t_first, 0.0), math.nan), first, final


def stabilisation_values(figure: Stabilisation) -> dict[str, str]:
    """A visit's :class:`Stabilisation` as diagnostic values (s and m; ``nan``: none)."""
    return {'stabilisation_time': f'{figure.time:.3f}',
            'stabilisation_time_u': f'{figure.time_u:.3f}',
            'overshoot': f'{figure.overshoot:.7f}', 'overshoot_u': f'{figure.overshoot_u:.7f}',
            'stabilisation_resolved': str(figure.resolved).lower(),
            'positioning_time': f'{figure.positioning_time:.3f}',
            'positioning_time_u': f'{figure.positioning_time_u:.3f}'}


def _approach(position: FloatArray, attained: FloatArray, band: float) -> FloatArray | None:
    """The unit direction of approach (3,): from the segment's first reading to the attained
    position; None when they lie within the band (no move to overshoot)."""
    way = attained - position[0]
    length = float(np.linalg.norm(way))
    return way / length if length > band else None


def stabilisation_figures(time: ArrayLike, position: ArrayLike, attained: ArrayLike,
                          band: float) -> tuple[float, float]:
    """Stabilisation time (s) and overshoot (m) of readings at ``time`` (n,) s, positions
    (n, 3) m, against the ``attained`` position (3,) m and the limit ``band`` (m), as the
    module docstring defines them (ISO 9283:1998 §7.4, §7.5); NaN when the readings never
    entered the band or did not stay (the overshoot also when they began within the band)."""
    t, p, x = _checked(time, position, attained, band)
    if t.size == 0:
        return math.nan, math.nan
    s, first, _ = _entries(t, np.linalg.norm(p - x, axis=1)[None], band)
    approach = _approach(p, x, band)
    if math.isnan(s[0]) or approach is None:
        return float(s[0]), math.nan
    return float(s[0]), max(0.0, float(np.max((p[first[0]:] - x) @ approach)))


def _checked(time: ArrayLike, position: ArrayLike, attained: ArrayLike,
             band: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The inputs as arrays, InputError naming what is wrong."""
    t = np.asarray(time, dtype=float)
    p = np.asarray(position, dtype=float)
    x = np.asarray(attained, dtype=float)
    if t.ndim != 1 or p.shape != (t.size, 3) or x.shape != (3,):
        raise InputError(f'readings need times (n,), positions (n, 3) and an attained '
                         f'position (3,), got {t.shape}, {p.shape}, {x.shape}')
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p)) and np.all(np.isfinite(x))):
        raise InputError('readings and the attained position must be finite')
    if t.size > 1 and np.any(np.diff(t) < 0.0):
        raise InputError('reading times must not decrease')
    if not (math.isfinite(band) and band > 0.0):
        raise InputError(f'the limit band must be a finite length > 0 m, got {band!r}')
    return t, p, x


def within_all(count: int, k: float = COVERAGE_FACTOR) -> float:
    """The multiple c of their standard deviations within which ``count`` normal errors all
    lie with at least the coverage probability p of k (95.45 % for k = 2), whatever their
    correlation: Φ⁻¹(1 − (1 − p)/(2·count)) (Bonferroni)."""
    p = math.erf(k / math.sqrt(2.0))
    # (the standard library's inverse: the nodes load no scipy, test_numba_isolation)
    return NormalDist().inv_cdf(1.0 - (1.0 - p) / (2.0 * max(count, 1)))


def stabilisation(time: ArrayLike, position: ArrayLike, covariance: ArrayLike,
                  attained: ArrayLike, attained_covariance: ArrayLike,
                  band: float, start: float = math.nan) -> Stabilisation:
    """The :class:`Stabilisation` of one visit: readings at ``time`` (n,) s, positions (n, 3)
    m in base, each with its stated position covariance ``covariance`` (n, 3, 3) m² (NaN: not
    stated), against its ``attained`` position (3,) m of covariance ``attained_covariance``
    (3, 3) m², with the limit ``band`` (m); the positioning time from ``start`` s (the
    segment's start; NaN: none); U as the module docstring says."""
    t, p, x = _checked(time, position, attained, band)
    cov = np.asarray(covariance, dtype=float)
    cov_x = np.asarray(attained_covariance, dtype=float)
    if cov.shape != (t.size, 3, 3) or cov_x.shape != (3, 3):
        raise InputError(f'covariances (n, 3, 3) and (3, 3) needed, got {cov.shape}, '
                         f'{cov_x.shape}')
    if t.size == 0:
        return Stabilisation.none()
    offset = p - x
    distance = np.linalg.norm(offset, axis=1)
    times, firsts, finals = _entries(t, distance[None], band)
    s, first = float(times[0]), int(firsts[0])
    if math.isnan(s):
        return Stabilisation.none(t.size)
    reached = float(t[finals[0]])  # the final entry
    positioning = reached - start
    approach = _approach(p, x, band)
    past = offset @ approach if approach is not None else np.full(t.size, math.nan)
    ov = max(0.0, float(np.max(past[first:]))) if approach is not None else math.nan
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)  # step[j]: reading j to j + 1
    if np.any(step[first:] > band):
        return Stabilisation(s, ov, math.nan, math.nan, t.size, False, positioning)
    if not (np.all(np.isfinite(cov)) and np.all(np.isfinite(cov_x))):
        return Stabilisation(s, ov, math.nan, math.nan, t.size, True, positioning)
    # each reading's distance moves by its error along its own direction from x (first
    # order: an entry happens some 50 µm out, errors are µm), the attained position's error
    # with it; all n within c of their sigma together
    radial = offset / np.maximum(distance, np.finfo(float).tiny)[:, None]
    sigma = np.sqrt(np.maximum(np.einsum('ni,nij,nj->n', radial, cov + cov_x, radial), 0.0))
    c = within_all(t.size)
    low, high = distance - c * sigma, distance + c * sigma
    u_time = _time_bound(t, low, high, band, s)
    u_positioning = (_final_bound(t, low, high, band, reached, start)
                     if math.isfinite(positioning) else math.nan)
    if approach is None:
        return Stabilisation(s, ov, u_time, math.nan, t.size, True, positioning, u_positioning)
    # |max_j (p_j - x)·a - max_j (p_j,true - x_true)·a| <= max_j |e_j·a| + |e_x·a| whatever
    # the motion (the clamp at 0 keeps it): all within c' of their sigma, from the reading
    # before the first entry on (an error may enter there)
    kept = slice(max(first - 1, 0), None)
    along = np.sqrt(np.maximum(np.einsum('i,nij,j->n', approach, cov[kept], approach), 0.0))
    along_x = math.sqrt(max(float(approach @ cov_x @ approach), 0.0))
    u_noise = within_all(along.size + 1) * (float(along.max()) + along_x)
    # the motion's furthest point may lie between the readings beside the furthest one: up to
    # half the step between them further (a path within half its chord of its readings)
    top = first + int(np.argmax(past[first:]))
    beside = np.abs(np.diff(past))[max(top - 1, first):top + 1]  # (none before the entry)
    return Stabilisation(s, ov, u_time, u_noise + 0.5 * float(beside.max(initial=0.0)),
                         t.size, True, positioning, u_positioning)


def _time_bound(time: FloatArray, low: FloatArray, high: FloatArray, band: float,
                estimate: float) -> float:
    """U of a stabilisation time ``estimate`` (s) when each reading's true distance lies in
    [``low``, ``high``] (m) and each entry somewhere in the interval before the reading that
    sees it: the largest departure of the times these allow from the estimate (module
    docstring)."""
    n = time.size
    interval = np.diff(time, prepend=time[0])
    first_early, first_late = _first_in(low, band), _first_in(high, band)
    final_early, final_late = _final_in(low, band), _final_in(high, band)
    if final_late >= n:  # the readings may not stay in the band: no bound
        return math.nan
    longest = (time[final_late] - (time[first_early] - interval[first_early])
               if final_late > first_early else 0.0)
    shortest = (time[final_early] - interval[final_early] - time[first_late]
                if final_early > first_late else 0.0)
    return float(max(longest - estimate, estimate - max(shortest, 0.0), 0.0))


def _first_in(distance: FloatArray, band: float) -> int:
    """The first reading within the band (the last reading when none is)."""
    inside = np.flatnonzero(distance <= band)
    return int(inside[0]) if inside.size else distance.size - 1


def _final_in(distance: FloatArray, band: float) -> int:
    """The first reading of the run within the band that lasts to the end (the number of
    readings when the last is outside)."""
    outside = np.flatnonzero(distance > band)
    return int(outside[-1]) + 1 if outside.size else 0


def _final_bound(time: FloatArray, low: FloatArray, high: FloatArray, band: float,
                 estimate: float, start: float) -> float:
    """U of the time ``estimate`` (s) of the final entry when each reading's true distance
    lies in [``low``, ``high``] (m) and the entry somewhere in the interval before the reading
    that sees it, or since ``start`` (s) when that is the first reading (NaN when the readings
    may not stay in the band)."""
    early, late = _final_in(low, band), _final_in(high, band)
    if late >= time.size:
        return math.nan
    earliest = time[early - 1] if early > 0 else min(start, float(time[0]))
    return float(max(time[late] - estimate, estimate - earliest, 0.0))


@dataclass(frozen=True)
class StabilisationFigures:
    """A commanded pose's stabilisation time (s) and overshoot (m) over its visits (its
    cycles): the ``mean`` and the largest of each over the visits that have the figure, U
    (k = 2) of each mean (the mean of its visits' U: their errors taken as fully correlated,
    the side that cannot understate it; NaN when a visit stated none), how many visits gave
    the time (``cycles``) and how many the readings did not resolve (``unresolved``)."""

    time_mean: float
    time_max: float
    time_u: float
    overshoot_mean: float
    overshoot_max: float
    overshoot_u: float
    cycles: int
    unresolved: int

    def to_dict(self) -> dict[str, float | int | bool | None]:
        """JSON-able (SI; NaN as null)."""
        return plain(self.__dict__)


def stabilisation_figures_of(visits: list[Stabilisation]) -> StabilisationFigures | None:
    """The :class:`StabilisationFigures` of one commanded pose's visits (None: no visit has a
    stabilisation time)."""
    timed = [v for v in visits if math.isfinite(v.time)]
    if not timed:
        return None
    time = np.array([v.time for v in timed])
    time_u = np.array([v.time_u if v.resolved else math.nan for v in timed])
    over = np.array([v.overshoot for v in timed if math.isfinite(v.overshoot)])
    over_u = np.array([v.overshoot_u if v.resolved else math.nan
                       for v in timed if math.isfinite(v.overshoot)])
    return StabilisationFigures(
        float(time.mean()), float(time.max()), float(time_u.mean()),
        float(over.mean()) if over.size else math.nan,
        float(over.max()) if over.size else math.nan,
        float(over_u.mean()) if over.size else math.nan,
        len(timed), sum(not v.resolved for v in timed))
