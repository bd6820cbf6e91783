"""The expanded uncertainty U (k = 2) of ISO 9283 position figures from the covariances the
measurement states for each attained position (issue 25; the pattern of ISO/TR 230-9 for
ISO 230-2): a commanded pose's pose accuracy AP_p (§7.2.1) and repeatability RP_l (§7.2.2)
below, the angles' AP_a..c and RP_a..c in :func:`orientation_figure_uncertainty`, the
multi-directional variation vAP_p (§7.2.3) in :func:`multidirectional_uncertainty`, the
distance accuracy and repeatability AD_p, RD_p (§7.3) between two poses in
:func:`distance_figure_uncertainty`.

Each attained position x_j (n visits) was measured with covariance Σ_j (3, 3) m², the mean of
its settle window's readings (:meth:`positioning_cell.accuracy.monitor.Readings.covariance_of`):
the readings' noise averaged down and a part every reading shares (the tracker's
registration) that is not. That split is not carried per visit, so each figure takes the side
that cannot understate it:

- AP_p = |x̄ − x_c| depends on the barycentre x̄. Its covariance is taken as the mean of the Σ_j,
  the visits' errors fully correlated (a common part shifts every visit alike and does not
  average over them); for independent errors that is at most √n too wide. U of the norm by
  :func:`~positioning_cell.accuracy.decisions.norm_expanded_uncertainty` (JCGM 100 with the
  second-order term, JCGM 101 near zero).
- RP_l = l̄ + 3·S_l depends on the spread about x̄, which a common error does not change, and
  measurement errors e_j inflate it (they add to the machine's own spread in quadrature, so
  the measured RP_l lies above the machine's by an amount that depends on the unknown truth).
  A bound that holds whatever the truth: with D_j = x_j − x̄ the deviations and l_j = |D_j|,
  D(t + e) = D(t) + D(e), so |l_j(t + e) − l_j(t)| ≤ l_j(e) (triangle inequality), hence
  |l̄(t + e) − l̄(t)| ≤ l̄(e), and, centring being a projection,
  |S_l(t + e) − S_l(t)| ≤ ‖l(t + e) − l(t)‖/√(n − 1) ≤ √(Σ l_j(e)²/(n − 1)). So
  |RP_l(measured) − RP_l(machine)| ≤ B(e) = l̄(e) + 3·√(Σ l_j(e)²/(n − 1)), and U is the
  quantile of B(e) at the coverage probability of k (95.45 % for k = 2) over draws of the
  errors, independent and each N(0, Σ_j) (JCGM 101:2008's adaptive Monte Carlo, at most
  :data:`DRAWS` draws: :func:`adaptive_quantiles`): the
  machine's RP_l lies within U of the measured one with at least that probability. It is
  conservative where the machine's spread is much larger than the errors (there the errors
  change RP_l by less than B): U then says what the measurement could hide, never less.

Test: test/test_figure_uncertainty.py (the figures of seeded simulated machines from their
true poses lie within U of those from their measurements in ≥ 95 % of runs)."""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.decisions import (
    COVERAGE_FACTOR,
    covariance_checks,
    norm_expanded_uncertainty,
)
from positioning_cell.accuracy.iso9283 import orientation_angles
from positioning_cell.core.poses import as_unit_quaternions, as_vectors
from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: The Monte Carlo of a bound (U of RP_l, RP_a..c, RD_p) draws the visits' errors in batches
#: (JCGM 101:2008 §7.9's adaptive procedure) of at most this many draws, at most
#: :data:`MAX_BATCHES` of them: 10⁴ draws, §7.2's figure for a 95 % interval to about two
#: significant digits. A batch holds at most :data:`BATCH_ERRORS` visits' errors (fewer draws
#: for more visits: the bound narrows as they grow, and the procedure's stopping rule still
#: holds the quantile to :data:`RELATIVE_TOLERANCE`): a pose visited 700 times in a tiled
#: `make run` bag of 250 k messages took 1.7 s and 335 MiB of peak memory when 10⁴ draws of
#: all its visits were taken at once.
BATCH = 1_000
MAX_BATCHES = 10
BATCH_ERRORS = 200_000
#: The adaptive procedure stops once twice the standard deviation of the mean of the batches'
#: quantiles is at most this share of it (after two batches at least).
RELATIVE_TOLERANCE = 0.01

#: At most this many draws in all (:data:`BATCH` × :data:`MAX_BATCHES`).
DRAWS = BATCH * MAX_BATCHES


class FigureUncertainty(NamedTuple):
    """U (k as asked, m) of AP_p and of RP_l; NaN where not stated (a visit without a
    covariance; RP_l below two visits)."""

    ap_p: float
    rp_l: float


def pose_figure_uncertainty(commanded_position: ArrayLike, attained_position: ArrayLike,
                            covariance: ArrayLike, k: float = COVERAGE_FACTOR,
                            rng: np.random.Generator | None = None) -> FigureUncertainty:
    """U of AP_p and RP_l (module docstring) of one commanded position (3,) m from its n
    attained positions (n, 3) m and the covariance (n, 3, 3) m² each was measured with;
    ``rng``: the Monte Carlo's generator (default: seeded, the same figure on every run).
    A covariance with a NaN: not stated (U NaN). InputError: wrong shapes, positions not
    finite, a covariance not symmetric positive semi-definite, k ≤ 0."""
    commanded = as_vectors(commanded_position, 3, 'commanded_position')
    if commanded.shape[0] != 1:
        raise InputError(f'one commanded position, got {commanded.shape[0]}')
    x = as_vectors(attained_position, 3, 'attained_position')
    cov = np.asarray(covariance, dtype=float)
    n = x.shape[0]
    if cov.shape != (n, 3, 3):
        raise InputError(f'covariance: expected shape ({n}, 3, 3) for the {n} attained '
                         f'positions, got {cov.shape}')
    _check_k(k)
    if not np.all(np.isfinite(cov)):
        return FigureUncertainty(math.nan, math.nan)
    _check_covariances(cov)
    ap = x.mean(axis=0) - commanded[0]
    u_ap = float(norm_expanded_uncertainty(ap[None], cov.mean(axis=0)[None], k)[0])
    if n < 2:
        return FigureUncertainty(u_ap, math.nan)
    spread = spread_uncertainty(cov[None], np.zeros((1, n, 3, 3)), k, rng)
    return FigureUncertainty(u_ap, float(spread[0, 0]))


class DistanceUncertainty(NamedTuple):
    """U (k as asked, m) of AD_p and of RD_p (ISO 9283 §7.3); NaN where not stated."""

    ad_p: float
    rd_p: float


def distance_figure_uncertainty(attained_first: ArrayLike, attained_second: ArrayLike,
                                covariance_first: ArrayLike, covariance_second: ArrayLike,
                                k: float = COVERAGE_FACTOR,
                                rng: np.random.Generator | None = None) -> DistanceUncertainty:
    """U of AD_p and RD_p (:func:`~positioning_cell.accuracy.iso9283.distance_figures`) from
    the n pairs of attained positions (n, 3) m and the covariance (n, 3, 3) m² each was
    measured with. A part common to both positions of a pair (the registration) cancels in
    their distance, so the errors are taken as independent: the side that cannot understate.

    - AD_p = D̄ − D_c, D_j = |P_1j − P_2j| of millimetres against errors of micrometres: the
      law of propagation (JCGM 100 eq. 10), D_j's sensitivity the unit vector u_j along
      P_1j − P_2j: u(D̄)² = Σ u_jᵀ(Σ_1j + Σ_2j)u_j / n².
    - RD_p = 3·S_D: as RP_l's bound (module docstring), |δD_j| ≤ |e_1j − e_2j|, so
      |RD_p(measured) − RD_p(machine)| ≤ 3·√(Σ|e_1j − e_2j|²/(n − 1)), its quantile
      (:func:`adaptive_quantiles`; NaN below two pairs).

    InputError as :func:`pose_figure_uncertainty`'s."""
    first = as_vectors(attained_first, 3, 'attained_first')
    second = as_vectors(attained_second, 3, 'attained_second')
    n = first.shape[0]
    cov = [np.asarray(c, dtype=float) for c in (covariance_first, covariance_second)]
    if second.shape != first.shape or any(c.shape != (n, 3, 3) for c in cov):
        raise InputError(f'expected {n} pairs of positions (n, 3) and covariances (n, 3, 3), '
                         f'got {second.shape}, {cov[0].shape} and {cov[1].shape}')
    _check_k(k)
    if not all(np.all(np.isfinite(c)) for c in cov):
        return DistanceUncertainty(math.nan, math.nan)
    _check_covariances(np.concatenate(cov))
    along = first - second
    along /= np.maximum(np.linalg.norm(along, axis=1, keepdims=True), np.finfo(float).tiny)
    variance = np.einsum('ni,nij,nj->', along, cov[0] + cov[1], along) / n**2
    u_ad = k * math.sqrt(max(float(variance), 0.0))
    if n < 2:
        return DistanceUncertainty(u_ad, math.nan)
    source: NormalSource = rng if rng is not None else SeededDraws()

    def bounds(draws: int) -> FloatArray:
        difference = drawn_errors(cov[0], source, draws) - drawn_errors(cov[1], source, draws)
        bound: FloatArray = 3.0 * np.sqrt((difference ** 2).sum(axis=(0, 2)) / (n - 1))
        return bound[:, None]

    return DistanceUncertainty(u_ad, float(adaptive_quantiles(bounds, k, 2 * n)[0]))


def _check_k(k: float) -> None:
    if not (math.isfinite(k) and k > 0.0):
        raise InputError(f'the coverage factor k must be > 0, got {k}')


def _check_covariances(cov: FloatArray) -> None:
    checks = covariance_checks(cov)
    if not np.all(checks.symmetric & checks.semidefinite):
        raise InputError('covariance: each must be symmetric positive semi-definite')


class NormalSource(Protocol):
    """What the Monte Carlos draw from: a numpy Generator, or :class:`SeededDraws`."""

    def standard_normal(self, size: tuple[int, ...]) -> Any:
        """Standard normal numbers of shape ``size``."""


#: The seed of the Monte Carlos when the caller gives no generator.
SEED = 0
#: The blocks of :class:`SeededDraws` kept once drawn, at most this many bytes in all (the
#: least recently used dropped first).
KEPT_BYTES = 48 * 2**20


class SeededDraws:
    """The generator of a Monte Carlo whose caller gives none: its b-th block of shape s is
    the same standard normals in every call and process (seeded by ``(SEED, b, *s)``), so
    the same inputs give the same U. The analysis of a recording draws the same shapes for
    every pose, path and mode of the same cycles, and drawing them was half of each Monte
    Carlo's time: blocks are kept once drawn (:data:`KEPT_BYTES`), read-only."""

    #: (shape, block) → block, least recently used first; shared by the process's threads
    #: (a Dask worker may run several analyses at once), under :attr:`_lock`.
    _kept: ClassVar[OrderedDict[tuple[tuple[int, ...], int], FloatArray]] = OrderedDict()
    _kept_bytes: ClassVar[int] = 0
    _lock: ClassVar[threading.Lock] = threading.Lock()

    def __init__(self) -> None:
        self._block = 0

    def standard_normal(self, size: tuple[int, ...]) -> FloatArray:
        """The next block of standard normals of shape ``size`` (read-only)."""
        key = (tuple(size), self._block)
        self._block += 1
        kept = SeededDraws._kept
        with SeededDraws._lock:
            if key in kept:
                kept.move_to_end(key)
                return kept[key]
        out: FloatArray = np.random.default_rng((SEED, key[1], *key[0])).standard_normal(size)
        out.setflags(write=False)
        if out.nbytes <= KEPT_BYTES // 4:
            with SeededDraws._lock:
                if key not in kept:
                    kept[key] = out
                    SeededDraws._kept_bytes += out.nbytes
                while SeededDraws._kept_bytes > KEPT_BYTES:
                    SeededDraws._kept_bytes -= kept.popitem(last=False)[1].nbytes
        return out


def drawn_errors(cov: FloatArray, rng: NormalSource, draws: int) -> FloatArray:
    """``draws`` draws of independent errors, row j ~ N(0, cov[j]) (cov (n, d, d)), laid out
    by visit: (n, draws, d), element [j, m] the m-th draw of row j. The standard normals are
    drawn (draws, n, d) as ever (the same blocks of :class:`SeededDraws`, so the same
    errors); each visit's are one batched matmul (a tenth of einsum's time), left in the
    matmul's own layout: laying them out (draws, n, d) took longer than the matmul itself (a
    copy of the whole array), and the callers' sums over visits read them as they are."""
    d = cov.shape[-1]
    w, v = np.linalg.eigh(cov)
    root = v * np.sqrt(np.maximum(w, 0.0))[:, None, :]  # (n, d, d): root @ rootᵀ = cov[j]
    z = rng.standard_normal((draws, cov.shape[0], d))
    errors: FloatArray = np.matmul(z.transpose(1, 0, 2), root.transpose(0, 2, 1))
    return errors


def adaptive_quantiles(bounds_of: Callable[[int], FloatArray], k: float,
                       visits: int = 1) -> FloatArray:
    """The quantiles (q,) at the coverage probability of k for a normal distribution (95.45 %
    for k = 2) of q bounds drawn by ``bounds_of(m)`` (m draws, (m, q)) of ``visits`` visits'
    errors each, by JCGM 101:2008 §7.9's adaptive procedure: batches of :data:`BATCH` draws
    (fewer for many visits: :data:`BATCH_ERRORS`; 100 at least) until twice the standard
    deviation of the mean of the batches' quantiles is at most :data:`RELATIVE_TOLERANCE` of
    it (two batches at least, :data:`MAX_BATCHES` at most); the quantiles of all the draws."""
    p = math.erf(k / math.sqrt(2.0))
    size = max(100, min(BATCH, BATCH_ERRORS // max(visits, 1)))
    drawn: list[FloatArray] = []
    quantiles: list[FloatArray] = []
    for batch in range(1, MAX_BATCHES + 1):
        drawn.append(bounds_of(size))
        quantiles.append(np.quantile(drawn[-1], p, axis=0))
        if batch >= 2:
            q = np.array(quantiles)
            spread = 2.0 * q.std(axis=0, ddof=1) / math.sqrt(batch)
            if np.all(spread <= RELATIVE_TOLERANCE * np.abs(q.mean(axis=0))):
                break
    out: FloatArray = np.quantile(np.concatenate(drawn), p, axis=0)
    return out


class OrientationUncertainty(NamedTuple):
    """U (k as asked, rad) of AP_a, AP_b, AP_c and of the half-widths RP_a, RP_b, RP_c (ISO
    9283 §7.2.1, §7.2.2); NaN where not stated (RP below two visits)."""

    ap_a: float
    ap_b: float
    ap_c: float
    rp_a: float
    rp_b: float
    rp_c: float


def euler_rates_from_rotation(quaternion: ArrayLike) -> FloatArray:
    """The matrices (n, 3, 3) taking a small rotation δθ about the base axes, R' =
    exp([δθ]×)·R, to the change of ISO 9283's angles (a, b, c) of R = Rz(c)·Ry(b)·Rx(a): the
    inverse of J = [Rz(c)·Ry(b)·e_x, Rz(c)·e_y, e_z] (the base-frame rotation of each angle's
    change; singular at b = ±π/2, where a and c are not separable)."""
    angles = orientation_angles(quaternion)
    b, c = angles[:, 1], angles[:, 2]
    cb, sb, cc, sc = np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    jac = np.zeros((angles.shape[0], 3, 3))
    jac[:, :, 0] = np.stack([cc * cb, sc * cb, -sb], axis=1)  # Rz(c)·Ry(b)·e_x
    jac[:, :, 1] = np.stack([-sc, cc, np.zeros_like(c)], axis=1)  # Rz(c)·e_y
    jac[:, 2, 2] = 1.0  # e_z
    out: FloatArray = np.asarray(np.linalg.inv(jac), dtype=float)
    return out


def orientation_figure_uncertainty(attained_quaternion: ArrayLike, covariance: ArrayLike,
                                   k: float = COVERAGE_FACTOR,
                                   rng: np.random.Generator | None = None
                                   ) -> OrientationUncertainty:
    """U of AP_a, AP_b, AP_c and RP_a, RP_b, RP_c of one commanded pose from its n attained
    orientations (n, 4) and the covariance (n, 3, 3) rad² each was measured with (small
    rotations about the base axes, R' = exp([δθ]×)·R), taken to the angles by
    :func:`euler_rates_from_rotation`: C_j = M_j Σ_j M_jᵀ. As for the positions (module
    docstring): U of AP from the mean of the C_j (errors fully correlated, the linear law of
    propagation: the angles' means are linear in the errors); U of RP_x = 3·S_x the quantile
    of 3·‖e − ē‖/√(n − 1) (:func:`adaptive_quantiles`) of independent errors e_j ~ N(0, C_j)
    (|S(t + e) − S(t)| ≤ that, centring being a projection). InputError as
    :func:`pose_figure_uncertainty`'s."""
    _check_k(k)
    q = as_unit_quaternions(attained_quaternion)
    cov = np.asarray(covariance, dtype=float)
    n = q.shape[0]
    if cov.shape != (n, 3, 3):
        raise InputError(f'covariance: expected shape ({n}, 3, 3) for the {n} attained '
                         f'orientations, got {cov.shape}')
    if not np.all(np.isfinite(cov)):
        return OrientationUncertainty(*[math.nan] * 6)
    _check_covariances(cov)
    m = euler_rates_from_rotation(q)
    angles = m @ cov @ np.swapaxes(m, 1, 2)  # (n, 3, 3) of a, b, c
    u_ap = k * np.sqrt(np.maximum(np.diagonal(angles.mean(axis=0)), 0.0))
    if n < 2:
        return OrientationUncertainty(*u_ap.tolist(), *[math.nan] * 3)
    spread = spread_uncertainty(np.zeros((1, n, 3, 3)), angles[None], k, rng)
    return OrientationUncertainty(*u_ap.tolist(), *spread[0, 1:].tolist())


def spread_uncertainty(position_covariance: FloatArray, angle_covariance: FloatArray,
                       k: float = COVERAGE_FACTOR, rng: NormalSource | None = None
                       ) -> FloatArray:
    """U (g, 4) of RP_l and of RP_a, RP_b, RP_c (the module docstring's bounds; the angles'
    3·‖e − ē‖/√(n − 1)) of g commanded poses of n ≥ 2 visits each, from the covariances
    (g, n, 3, 3) of their positions (m²) and of their angles a, b, c (rad²,
    :func:`orientation_figure_uncertainty`'s C_j): one adaptive Monte Carlo for all of them
    (:func:`adaptive_quantiles`), each visit's position and angle errors drawn together,
    independent. ``rng``: default seeded (:class:`SeededDraws`). Covariances are taken as
    given (the callers check them); a pose whose covariances are all zero (exact: the
    simulation's truth) has U 0 without a draw."""
    exact = ~(np.any(position_covariance != 0.0, axis=(1, 2, 3))
              | np.any(angle_covariance != 0.0, axis=(1, 2, 3)))
    out = np.zeros((position_covariance.shape[0], 4))
    if not exact.all():
        out[~exact] = _spread_quantiles(position_covariance[~exact],
                                        angle_covariance[~exact], k, rng)
    return out


def _spread_quantiles(position_covariance: FloatArray, angle_covariance: FloatArray,
                      k: float, rng: NormalSource | None) -> FloatArray:
    """:func:`spread_uncertainty`'s Monte Carlo."""
    g, n = position_covariance.shape[:2]
    cov = np.zeros((g * n, 6, 6))
    cov[:, :3, :3] = position_covariance.reshape(g * n, 3, 3)
    cov[:, 3:, 3:] = angle_covariance.reshape(g * n, 3, 3)
    source: NormalSource = rng if rng is not None else SeededDraws()

    def bounds(draws: int) -> FloatArray:
        squared = drawn_errors(cov, source, draws).reshape(g, n, draws, 6)  # its own
        squared -= squared.mean(axis=1, keepdims=True)  # centred on each pose's mean,
        np.square(squared, out=squared)  # then squared, in place (no copy of the draws)
        distance2 = squared[..., 0] + squared[..., 1] + squared[..., 2]  # (g, n, draws)
        out = np.empty((draws, g, 4))
        out[..., 0] = (np.sqrt(distance2).mean(axis=1) + 3.0 * np.sqrt(
            distance2.sum(axis=1) / (n - 1))).T
        out[..., 1:] = (3.0 * np.sqrt(squared[..., 3:].sum(axis=1) / (n - 1))).transpose(1, 0, 2)
        return out.reshape(draws, g * 4)

    return adaptive_quantiles(bounds, k, g * n).reshape(g, 4)


def pose_uncertainties(commanded_position: ArrayLike, attained_position: ArrayLike,
                       attained_quaternion: ArrayLike, covariance: ArrayLike,
                       k: float = COVERAGE_FACTOR, rng: NormalSource | None = None
                       ) -> list[tuple[FigureUncertainty, OrientationUncertainty]]:
    """:func:`pose_figure_uncertainty` and :func:`orientation_figure_uncertainty` of g
    commanded poses (g, 3) m of n visits each, attained at (g, n, 3) m, (g, n, 4), measured
    with covariances (g, n, 6, 6) (position m², then small rotations about the base axes
    rad²; a NaN: that pose's U not stated): the same figures, the RP parts of every pose
    from one Monte Carlo (:func:`spread_uncertainty`), as the analysis of a long recording
    takes them for each mode's poses. InputError as theirs."""
    _check_k(k)
    commanded = as_vectors(commanded_position, 3, 'commanded_position')
    x = np.asarray(attained_position, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    g = commanded.shape[0]
    if x.ndim != 3 or x.shape[0] != g or x.shape[2] != 3:
        raise InputError(f'attained_position: expected shape ({g}, n, 3), got {x.shape}')
    n = x.shape[1]
    q = as_unit_quaternions(np.reshape(attained_quaternion, (-1, 4)))
    if q.shape[0] != g * n or cov.shape != (g, n, 6, 6):
        raise InputError(f'attained_quaternion, covariance: expected ({g}, {n}, 4) and '
                         f'({g}, {n}, 6, 6), got {np.shape(attained_quaternion)} and '
                         f'{cov.shape}')
    as_vectors(x.reshape(-1, 3), 3, 'attained_position')  # finite
    stated = np.all(np.isfinite(cov), axis=(1, 2, 3))
    m = euler_rates_from_rotation(q).reshape(g, n, 3, 3)
    angles = m @ cov[..., 3:, 3:] @ np.swapaxes(m, 2, 3)  # (g, n, 3, 3) of a, b, c
    u_ap = np.full(g, math.nan)
    u_rp = np.full((g, 4), math.nan)
    if stated.any():
        _check_covariances(cov[stated].reshape(-1, 6, 6))
        u_ap[stated] = norm_expanded_uncertainty(
            x[stated].mean(axis=1) - commanded[stated], cov[stated, :, :3, :3].mean(axis=1),
            k)
        if n >= 2:
            u_rp[stated] = spread_uncertainty(cov[stated, :, :3, :3], angles[stated], k, rng)
    u_angles = k * np.sqrt(np.maximum(np.diagonal(angles.mean(axis=1), axis1=1, axis2=2), 0.0))
    return [(FigureUncertainty(float(u_ap[i]), float(u_rp[i, 0])),
             OrientationUncertainty(*u_angles[i].tolist(), *u_rp[i, 1:].tolist()))
            for i in range(g)]


def _by_direction(n: int, covariance: ArrayLike, direction: ArrayLike
                  ) -> tuple[FloatArray, NDArray[np.intp], int] | None:
    """The covariances (n, 3, 3) and approach directions (n,) of n visits, and how many
    directions; None below two directions or with a covariance not stated (NaN). InputError:
    wrong shapes, a covariance not symmetric positive semi-definite."""
    cov = np.asarray(covariance, dtype=float)
    group = np.asarray(direction, dtype=np.intp)
    if cov.shape != (n, 3, 3) or group.shape != (n,):
        raise InputError(f'expected {n} covariances (n, 3, 3) and directions (n,), got '
                         f'{cov.shape} and {group.shape}')
    count = int(group.max()) + 1 if n else 0
    if count < 2 or not np.all(np.isfinite(cov)):
        return None
    _check_covariances(cov)
    return cov, group, count


def multidirectional_uncertainty(attained_position: ArrayLike, covariance: ArrayLike,
                                 direction: ArrayLike, k: float = COVERAGE_FACTOR) -> float:
    """U (m) of vAP_p (ISO 9283 §7.2.3) from the n attained positions (n, 3) m, the covariance
    (n, 3, 3) m² each was measured with and the approach direction (n,) each belongs to
    (:func:`~positioning_cell.accuracy.iso9283.approach_groups`); NaN when a covariance is not
    stated or below two directions.

    Each direction's barycentre x̄_h is taken with the mean of its visits' covariances Σ̄_h (its
    errors fully correlated); the difference of two barycentres, whatever the correlation
    between them, has a covariance below 2(Σ̄_h + Σ̄_k) (Var(a − b) ≤ 2 Var a + 2 Var b), and
    U_hk of its norm follows (:func:`norm_expanded_uncertainty`). vAP_p is the largest |d_hk|:
    the machine's lies between the largest |d_hk| − U_hk and the largest |d_hk| + U_hk, and U
    is the larger distance from the measured vAP_p to either."""
    _check_k(k)
    x = as_vectors(attained_position, 3, 'attained_position')
    grouped = _by_direction(x.shape[0], covariance, direction)
    if grouped is None:
        return math.nan
    cov, group, count = grouped
    centre = np.array([x[group == h].mean(axis=0) for h in range(count)])
    spread = np.array([cov[group == h].mean(axis=0) for h in range(count)])
    h, j = np.triu_indices(count, 1)
    d = centre[h] - centre[j]
    u = norm_expanded_uncertainty(d, 2.0 * (spread[h] + spread[j]), k)
    norm = np.linalg.norm(d, axis=1)
    measured = float(norm.max())
    return float(max(float((norm + u).max()) - measured,
                     measured - float((norm - u).max())))



def multidirectional_angle_uncertainty(attained_quaternion: ArrayLike, covariance: ArrayLike,
                                       direction: ArrayLike,
                                       k: float = COVERAGE_FACTOR) -> tuple[float, float, float]:
    """U (rad) of vAP_a, vAP_b, vAP_c (ISO 9283 §7.2.3) from the n attained orientations
    (n, 4), the covariance (n, 3, 3) rad² each was measured with (small rotations about the
    base axes, as :func:`orientation_figure_uncertainty` takes them) and the approach
    direction (n,) each belongs to; NaN when a covariance is not stated or below two
    directions.

    Each angle's direction mean ā_h is taken with the mean of its visits' variances (errors
    fully correlated, as for AP); the difference of two means, whatever their correlation,
    has a variance below 2(σ̄_h² + σ̄_k²). |·| moves by at most the error, so the machine's
    |ā_h − ā_k| lies within k·σ_hk of the measured one (the linear law of propagation, which
    near zero only widens the interval), and U is the larger distance from the measured vAP
    to the largest bound above or below, as for vAP_p (:func:`multidirectional_uncertainty`)."""
    _check_k(k)
    q = as_unit_quaternions(attained_quaternion)
    grouped = _by_direction(q.shape[0], covariance, direction)
    if grouped is None:
        return (math.nan, math.nan, math.nan)
    cov, group, count = grouped
    m = euler_rates_from_rotation(q)
    variance = np.diagonal(m @ cov @ np.swapaxes(m, 1, 2), axis1=1, axis2=2)  # (n, 3)
    angles = orientation_angles(q)
    # each angle about the first visit's (no wrap across ±π between the directions' means)
    angles = angles[0] + np.angle(np.exp(1j * (angles - angles[0])))
    means = np.array([angles[group == h].mean(axis=0) for h in range(count)])
    spread = np.array([variance[group == h].mean(axis=0) for h in range(count)])
    h, j = np.triu_indices(count, 1)
    gap = np.abs(means[h] - means[j])  # (pairs, 3)
    u = k * np.sqrt(np.maximum(2.0 * (spread[h] + spread[j]), 0.0))
    measured = gap.max(axis=0)
    out = np.maximum((gap + u).max(axis=0) - measured,
                     measured - np.maximum(gap - u, 0.0).max(axis=0))
    return (float(out[0]), float(out[1]), float(out[2]))
