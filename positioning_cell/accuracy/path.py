"""Path accuracy and path repeatability (ISO 9283:1998 §8.2) of the cell's straight-line moves,
from the tracker's readings during the moves, with their expanded uncertainty U (k = 2).
SI: m, s; positions in the base frame.

A move's commanded path is the straight line from the commanded position it started from
(the visit before it) to its own (:mod:`positioning_cell.moves.trajectory` plans every move
so). The standard takes the attained path's points in planes normal to the commanded path:
here :data:`PLANE_FRACTIONS` of its length L, each plane i through c_i = a + f_i·L·u (a the
start, u the unit direction). A cycle's point x_ij in plane i is where its readings first
cross the plane (:func:`path_crossings`: linear between the two readings either side, the
readings sampling the motion at the tracker's rate; a straight path lies on its chords).
Planes near the ends are left out: the platform starts where the previous move left it, off
the commanded start by its pose error, and a plane close to the start may lie behind it.

Over the n cycles of one path (the same start and end commanded), per plane: the barycentre
x̄_i, AT_i = |x̄_i − c_i|, l_ij = |x_ij − x̄_i|, RT_i = l̄_i + 3·S_li (S_li the standard
deviation of the l_ij, n − 1); the path's AT_p = max_i AT_i and RT_l = max_i RT_i
(:func:`path_figures`), over the planes every cycle crossed. The orientation's path figures
(AT_a..c, RT_a..c) are not taken: the cell's moves turn by SLERP and its programs keep the
orientation, so they would restate the pose figures.

U (k = 2), as the pose figures' (:mod:`positioning_cell.accuracy.figure_uncertainty`), from
the covariances the tracker states, each crossing's the readings' weighted as the crossing
is (an upper bound of the interpolated error's: the shared part does not average), in the
plane (an error along the path moves the crossing along it):

- AT: each plane's U_i of AT_i, the barycentre's covariance the mean of its crossings' (their
  errors fully correlated), by
  :func:`~positioning_cell.accuracy.decisions.norm_expanded_uncertainty` with the coverage
  factor raised so that all planes' errors lie within their U_i together
  with the coverage probability of k whatever their correlation (Bonferroni,
  :func:`~positioning_cell.accuracy.stabilisation.within_all`). Then
  |max_i AT_i − max_i AT_i,true| ≤ max_i |AT_i − AT_i,true| ≤ max_i U_i = U.
- RT: each plane's RT_i moves by at most the bound B_i of RP_l's U (the crossings' errors
  drawn independent, N(0, Σ_ij)); U is the quantile of max_i B_i over the draws, one JCGM
  101 adaptive Monte Carlo for all planes (:func:`adaptive_quantiles`). Planes drawn
  independent give the maximum a wider spread than correlated ones would: U cannot
  understate.

Test: test/test_path.py (a hand-worked path; the figures of seeded simulated paths from
their true points lie within U of those from their readings in ≥ 95 % of runs)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.decisions import COVERAGE_FACTOR, norm_expanded_uncertainty
from positioning_cell.accuracy.figure_uncertainty import (
    NormalSource,
    SeededDraws,
    adaptive_quantiles,
    drawn_errors,
)
from positioning_cell.accuracy.stabilisation import within_all
from positioning_cell.core.poses import Triple, as_vectors, triple
from positioning_cell.errors import InputError
from positioning_cell.records import plain_fields

FloatArray = NDArray[np.float64]

#: Where the normal planes lie along the commanded path, as fractions of its length.
PLANE_FRACTIONS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)

#: The shortest commanded path (m) whose crossings are taken: a pose commanded again, or a
#: step of a millimetre, has no path to speak of.
PATH_LEAST = 1e-3


@dataclass(frozen=True)
class PathCrossings:
    """One move's attained path in the normal planes of its commanded path: commanded
    ``start`` and ``end`` (m), the crossing ``points`` (P, 3) m (NaN rows: the readings did
    not cross that plane), their ``covariance`` (P, 3, 3) m² (NaN: not stated) and ``time``
    (P,) s, one per :data:`PLANE_FRACTIONS`."""

    start: Triple
    end: Triple
    points: FloatArray
    covariance: FloatArray
    time: FloatArray

    @property
    def crossed(self) -> NDArray[np.bool_]:
        """Which planes (P,) the readings crossed."""
        return np.asarray(np.all(np.isfinite(self.points), axis=1))

    def deviation(self) -> float:
        """The largest distance (m) of a crossing from the commanded point of its plane: this
        one cycle's AT_p (NaN: no plane crossed), what the live monitor says of a visit."""
        a, b = np.asarray(self.start), np.asarray(self.end)
        commanded = a + np.outer(PLANE_FRACTIONS, b - a)
        crossed = self.crossed
        if not crossed.any():
            return math.nan
        return float(np.linalg.norm(self.points[crossed] - commanded[crossed], axis=1).max())


def path_crossings(start: ArrayLike, end: ArrayLike, time: ArrayLike, position: ArrayLike,
                   covariance: ArrayLike | None = None) -> PathCrossings | None:
    """The crossings (module docstring) of the readings (times (k,) s, increasing; positions
    (k, 3) m; covariances (k, 3, 3) m², None: not stated) of a move commanded from ``start``
    to ``end`` (3,) m; None for a path shorter than :data:`PATH_LEAST`. Vectorised over the
    readings and the planes. InputError: wrong shapes, a value not finite."""
    a = as_vectors(start, 3, 'start')[0]
    b = as_vectors(end, 3, 'end')[0]
    x = np.asarray(position, dtype=float).reshape(-1, 3)
    t = np.asarray(time, dtype=float)
    k = x.shape[0]
    cov = (np.full((k, 3, 3), math.nan) if covariance is None
           else np.asarray(covariance, dtype=float))
    if t.shape != (k,) or cov.shape != (k, 3, 3):
        raise InputError(f'path_crossings: {k} positions need {k} times and ({k}, 3, 3) '
                         f'covariances, got {t.shape} and {cov.shape}')
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(t))):
        raise InputError('path_crossings: the readings\' times and positions must be finite')
    length = float(np.linalg.norm(b - a))
    if length < PATH_LEAST:
        return None
    u = (b - a) / length
    planes = np.asarray(PLANE_FRACTIONS) * length  # (P,) along the path from a
    along = (x - a) @ u  # (k,)
    # reading j and j + 1 either side of plane i: the first such pair
    cross = (along[None, :-1] < planes[:, None]) & (along[None, 1:] >= planes[:, None])
    has = cross.any(axis=1) if k >= 2 else np.zeros(planes.size, dtype=bool)
    j = cross.argmax(axis=1) if k >= 2 else np.zeros(planes.size, dtype=np.intp)
    j1 = np.minimum(j + 1, k - 1)
    w = np.where(has, (planes - along[j]) / np.where(has, along[j1] - along[j], 1.0), 0.0)
    points = x[j] + w[:, None] * (x[j1] - x[j]) if k else np.zeros((planes.size, 3))
    crossing_cov = ((1.0 - w)[:, None, None] * cov[j] + w[:, None, None] * cov[j1] if k
                    else np.zeros((planes.size, 3, 3)))
    times = t[j] + w * (t[j1] - t[j]) if k else np.zeros(planes.size)
    points[~has] = math.nan
    crossing_cov[~has] = math.nan
    times = np.where(has, times, math.nan)
    return PathCrossings(triple(a), triple(b), points, crossing_cov, times)


@dataclass(frozen=True)
class PathFigures:
    """ISO 9283 §8.2 of one commanded path over ``n`` cycles (module docstring): its
    ``length`` (m), the planes every cycle crossed (``planes``: their fractions), AT_i and
    RT_i of each (m; RT NaN below two cycles), AT_p and RT_l (their maxima; RT_l None below
    two cycles) and U (k = 2) of each (NaN: not stated)."""

    n: int
    length: float
    planes: tuple[float, ...]
    at_planes: tuple[float, ...]
    rt_planes: tuple[float, ...]
    at_p: float
    rt_l: float | None
    u_at_p: float = math.nan
    u_rt_l: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; None where undefined or, for a U, not stated)."""
        out = plain_fields(self)
        for key in ('at_planes', 'rt_planes'):
            out[key] = [v if math.isfinite(v) else None for v in out[key]]
        for key in ('u_at_p', 'u_rt_l'):
            out[key] = out[key] if math.isfinite(out[key]) else None
        return out


def path_figures(crossings: Sequence[PathCrossings], k: float = COVERAGE_FACTOR,
                 rng: np.random.Generator | None = None) -> PathFigures | None:
    """AT_p and RT_l (module docstring) of the cycles ``crossings`` of one commanded path
    (each cycle's, the same start and end); None when no plane was crossed by every cycle.
    ``rng``: the Monte Carlo's generator (default: seeded). InputError: no cycles, or cycles
    of different paths."""
    if not crossings:
        raise InputError('path_figures needs the crossings of one cycle at least')
    first = crossings[0]
    for c in crossings[1:]:
        if not (np.allclose(c.start, first.start, rtol=0.0, atol=1e-9)
                and np.allclose(c.end, first.end, rtol=0.0, atol=1e-9)):
            raise InputError('path_figures: the cycles are of different commanded paths')
    used = np.all([c.crossed for c in crossings], axis=0)  # (P,)
    if not used.any():
        return None
    a, b = np.asarray(first.start), np.asarray(first.end)
    length = float(np.linalg.norm(b - a))
    u = (b - a) / length
    fractions = np.asarray(PLANE_FRACTIONS)[used]
    commanded = a + fractions[:, None] * length * u  # (P', 3)
    x = np.array([c.points[used] for c in crossings])  # (n, P', 3)
    n, planes = x.shape[0], x.shape[1]
    barycentre = x.mean(axis=0)
    at = np.linalg.norm(barycentre - commanded, axis=1)
    distance = np.linalg.norm(x - barycentre, axis=2)  # (n, P')
    rt = (distance.mean(axis=0) + 3.0 * distance.std(axis=0, ddof=1) if n >= 2
          else np.full(planes, math.nan))
    normal = np.eye(3) - np.outer(u, u)  # the projection into the normal planes
    cov = normal @ np.array([c.covariance[used] for c in crossings]) @ normal  # (n, P', 3, 3)
    u_at, u_rt = math.nan, math.nan
    if np.all(np.isfinite(cov)):
        k_all = within_all(planes, k)
        u_at = float(norm_expanded_uncertainty(barycentre - commanded, cov.mean(axis=0),
                                               k_all).max())
        if n >= 2:
            in_plane = np.linalg.svd(normal)[0][:, :2]  # (3, 2): an orthonormal basis
            u_rt = _rt_uncertainty(in_plane.T @ cov @ in_plane, k,
                                   rng if rng is not None else SeededDraws())
    return PathFigures(n, length, tuple(float(f) for f in fractions), tuple(at.tolist()),
                       tuple(rt.tolist()), float(at.max()),
                       float(rt.max()) if n >= 2 else None, u_at, u_rt)


def _rt_uncertainty(cov: FloatArray, k: float, rng: NormalSource) -> float:
    """U of RT_l: the quantile of max_i B_i (module docstring) of crossings' errors drawn
    independent with covariances ``cov`` (n, P, 2, 2) in their planes' coordinates."""
    n, planes = cov.shape[:2]

    def bounds(draws: int) -> FloatArray:
        centred = drawn_errors(cov.reshape(n * planes, 2, 2), rng, draws).reshape(
            n, planes, draws, 2)
        centred -= centred.mean(axis=0, keepdims=True)  # in place: the draws are its own
        squared = centred[..., 0] ** 2 + centred[..., 1] ** 2  # (n, P, draws)
        bound = np.sqrt(squared).mean(axis=0) + 3.0 * np.sqrt(squared.sum(axis=0) / (n - 1))
        out: FloatArray = bound.max(axis=0)[:, None]
        return out

    return float(adaptive_quantiles(bounds, k, n * planes)[0])


__all__ = ['PATH_LEAST', 'PLANE_FRACTIONS', 'PathCrossings', 'PathFigures', 'path_crossings',
           'path_figures']
