"""Monte Carlo of the pose error with the full nonlinear closure model (seed 004 §3.2, last step).

For each sample of the sources (:func:`.sources.draw_sources`) the closure equations

    h_i = p + R·(b_i + δb_i) − (A_i + δA_i) − (l_i + δl_i)·u_i(φ_i + δφ_i, θ_i + δθ_i) = 0

are solved exactly for the pose deviation (δp, δρ) and the passive angles δφ, every sample with
its own joint centres. :func:`positioning_cell.kinematics.forward` takes one geometry for the
whole batch, so the batch is solved here by a chord (simplified Newton) iteration that reuses
the nominal closure Jacobian U of :mod:`.sensitivity` for all samples: each step is one
vectorised residual evaluation and one (9 × 9) product, no per-sample solve. The tests check it
against ``forward(mech.with_offsets(...))`` sample by sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import binomtest

from positioning_cell.errors import InputError
from positioning_cell.kinematics import forward, inverse
from positioning_cell.mechanism import Mechanism
from positioning_cell.poses import matrix_from_quaternion, pose_error
from positioning_cell.prediction.sensitivity import (
    COORDINATES,
    Linearisation,
    linearise,
    root_sum_square,
    worst_case,
)
from positioning_cell.prediction.sources import Requirement, ToleranceSpec, draw_sources

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Closure residual (m) below which a sample counts as solved: 10 pm, five orders of magnitude
#: below the smallest tolerance worth predicting.
CLOSURE_TOLERANCE = 1e-11
#: Samples per vectorised chunk (bounds memory: ~30 doubles per sample and source).
CHUNK = 1 << 14


@dataclass(frozen=True)
class MonteCarloResult:
    """Sampled pose deviations at one pose: ``deviations`` (n, 6) from the nonlinear model and
    ``linear`` (n, 6) = T·x from the same samples, m and rad (rows of
    :data:`.sensitivity.COORDINATES`); ``converged`` (n,) False where the closure was not
    solved (deviations NaN there)."""

    deviations: FloatArray
    linear: FloatArray
    converged: BoolArray


@dataclass(frozen=True)
class YieldEstimate:
    """Probability that the pose meets the requirement: ``inside`` of ``trials`` samples,
    estimate ``probability`` and its Wilson interval [``low``, ``high``] at ``confidence``."""

    inside: int
    trials: int
    probability: float
    low: float
    high: float
    confidence: float


@dataclass(frozen=True)
class Comparison:
    """Per pose coordinate (6,), m and rad: the first-order worst case (seed 004 eq. 15), the
    RSS of the tolerance contributions, the linear-model 3σ, and from the Monte Carlo the
    largest |deviation|, 3 × standard deviation and the 99.73 % quantile of |deviation|."""

    worst_case: FloatArray
    rss: FloatArray
    linear_3sigma: FloatArray
    mc_max: FloatArray
    mc_3sigma: FloatArray
    mc_q9973: FloatArray


def solve_closure(mech: Mechanism, lin: Linearisation, primitives: FloatArray, *,
                  tolerance: float = CLOSURE_TOLERANCE,
                  max_iterations: int = 12) -> tuple[FloatArray, BoolArray]:
    """Exact pose deviations (n, 6) (δp m, δρ rad) for primitive perturbations (n, 24)
    (δl m, δθ rad, δA m base frame, δb m platform frame) at the single pose of ``lin``.

    Chord iteration z ← z − U⁻¹·h(z), z = (δp, δρ, δφ), from the first-order solution
    z = −U⁻¹·∂h/∂prim·prim, until max |h| ≤ ``tolerance`` m for every sample or
    ``max_iterations``. Returns the deviations (NaN where not converged) and converged (n,).
    A transposed view of a (24, n) C array avoids a copy.
    """
    if lin.position.shape[0] != 1:
        raise InputError(f'solve_closure: expected one pose, got {lin.position.shape[0]}')
    if primitives.ndim != 2 or primitives.shape[1] != lin.primitives.shape[2]:
        raise InputError(f'primitives: expected shape (n, 24), got {primitives.shape}')
    joints = inverse(mech, lin.position, lin.quaternion)
    rot = matrix_from_quaternion(lin.quaternion)[0]
    closure_inv = np.linalg.inv(lin.closure[0])
    # Leg-major (component or leg, sample) rows, as in kinematics.solve_passive_angles: every
    # operation runs over contiguous rows of n samples; the leg is written out,
    # l·u = l cos θ (sin φ e_r + cos φ e_z) + l sin θ e_t (design/kinematics.md), with the terms
    # that do not change while iterating computed once.
    prim = np.ascontiguousarray(primitives.T)
    n = prim.shape[1]
    lengths = joints.lengths[0][:, None] + prim[0:3]
    thetas = joints.thetas[0][:, None] + prim[3:6]
    lc, ls = lengths * np.cos(thetas), lengths * np.sin(thetas)
    body = mech.platform_joints[:, :, None] + prim[15:24].reshape(3, 3, n)  # (leg, xyz, n)
    body = np.einsum('ij,kjn->ikn', rot, body)  # R_nom·b, (xyz, leg, n)
    # p − A − l sin θ e_t, (xyz, leg, n)
    centre = (lin.position[0][:, None, None] - mech.base_joints.T[:, :, None]
              - prim[6:15].reshape(3, 3, n).transpose(1, 0, 2)
              - ls[None] * mech.tangential.T[:, :, None])
    erx, ery = mech.radial[:, 0, None], mech.radial[:, 1, None]
    phi0 = joints.phis[0][:, None]
    z = -closure_inv @ (lin.primitives[0] @ prim)
    residual = np.empty((3, 3, n))  # (leg, xyz, n): the rows of U
    for iteration in range(max_iterations + 1):
        # R = R_nom·exp([δρ]×) = exp([R_nom·δρ]×)·R_nom
        spin = np.ascontiguousarray(
            Rotation.from_rotvec((rot @ z[3:6]).T).as_matrix().reshape(n, 9).T)
        phi = phi0 + z[6:9]
        lcs, lcc = lc * np.sin(phi), lc * np.cos(phi)
        for i, (radial, point) in enumerate(((erx, lcs), (ery, lcs), (None, lcc))):
            moved = spin[3 * i] * body[0] + spin[3 * i + 1] * body[1] + spin[3 * i + 2] * body[2]
            leg = point * radial if radial is not None else point
            residual[:, i] = centre[i] + z[i] + moved - leg
        flat = residual.reshape(9, n)
        done = np.max(np.abs(flat), axis=0) <= tolerance
        if iteration == max_iterations or done.all():
            break
        z -= closure_inv @ flat
    deviations = z[:6].T.copy()
    deviations[~done] = np.nan
    return deviations, done


def monte_carlo(mech: Mechanism, spec: ToleranceSpec, position: ArrayLike,
                quaternion: ArrayLike, n_samples: int, rng: np.random.Generator, *,
                chunk: int = CHUNK) -> MonteCarloResult:
    """Pose deviations of ``n_samples`` machines drawn from ``spec`` at one pose ((3,) m,
    (4,) x, y, z, w), nonlinear and linear, processed in chunks of ``chunk`` samples."""
    if n_samples < 1:
        raise InputError(f'n_samples = {n_samples}: need at least 1 sample')
    if chunk < 1:
        raise InputError(f'chunk = {chunk}: must be >= 1')
    lin = linearise(mech, spec, position, quaternion)
    if lin.position.shape[0] != 1:
        raise InputError(f'monte_carlo: expected one pose, got {lin.position.shape[0]}')
    deviations = np.empty((n_samples, 6))
    linear = np.empty((n_samples, 6))
    converged = np.empty(n_samples, dtype=bool)
    for start in range(0, n_samples, chunk):
        stop = min(start + chunk, n_samples)
        x = draw_sources(spec, stop - start, rng).T  # (S, n)
        deviations[start:stop], converged[start:stop] = solve_closure(
            mech, lin, (lin.source_map[0] @ x).T)
        linear[start:stop] = (lin.matrix[0] @ x).T
    return MonteCarloResult(deviations, linear, converged)


def inside_requirement(deviations: FloatArray, requirement: Requirement) -> BoolArray:
    """(n,) True where |Δp| ≤ requirement.position and |δρ| ≤ requirement.orientation
    (deviations (n, 6) m, rad); NaN rows (unsolved) count as outside."""
    pos = np.linalg.norm(deviations[:, :3], axis=1)
    ang = np.linalg.norm(deviations[:, 3:], axis=1)
    with np.errstate(invalid='ignore'):
        inside: BoolArray = (pos <= requirement.position) & (ang <= requirement.orientation)
    return inside


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


def compare(lin: Linearisation, spec: ToleranceSpec, result: MonteCarloResult) -> Comparison:
    """Worst case, RSS and linear 3σ at the (single) pose of ``lin`` next to the Monte Carlo
    statistics of ``result`` (converged samples only)."""
    matrix = lin.matrix[0]
    dev = np.abs(result.deviations[result.converged])
    if dev.shape[0] == 0:
        raise InputError('compare: no converged Monte Carlo samples')
    return Comparison(
        worst_case=worst_case(matrix, spec.bounds),
        rss=root_sum_square(matrix, spec.bounds),
        linear_3sigma=3.0 * root_sum_square(matrix, spec.stds),
        mc_max=dev.max(axis=0),
        mc_3sigma=3.0 * result.deviations[result.converged].std(axis=0),
        mc_q9973=np.quantile(dev, 0.9973, axis=0),
    )


__all__ = ['COORDINATES', 'Comparison', 'MonteCarloResult', 'YieldEstimate', 'compare',
           'estimate_yield', 'inside_requirement', 'monte_carlo', 'solve_closure']


def per_sample_deviations(mech: Mechanism, spec: ToleranceSpec, position: ArrayLike,
                          quaternion: ArrayLike, samples: ArrayLike) -> FloatArray:
    """Reference: pose deviations (n, 6) (m, rad) for source samples (n, S), one
    :func:`positioning_cell.kinematics.forward` per sample on the displaced mechanism. Slow and
    independent of :func:`solve_closure`: what tests check it against and the benchmark's
    baseline."""
    p = np.asarray(position, dtype=float).reshape(3)
    q = np.asarray(quaternion, dtype=float).reshape(4)
    x = np.asarray(samples, dtype=float)
    lin = linearise(mech, spec, p, q)
    joints = inverse(mech, p, q)
    out = np.empty((x.shape[0], 6))
    for k, xs in enumerate(x):  # deliberately one pose at a time
        prim = lin.source_map[0] @ xs
        displaced = mech.with_offsets(prim[6:15].reshape(3, 3), prim[15:24].reshape(3, 3))
        r = forward(displaced, joints.lengths + prim[0:3], joints.thetas + prim[3:6],
                    joints.phis)
        dp, drot = pose_error(r.position, r.quaternion, p[None], q[None])
        out[k] = np.concatenate([dp[0], drot[0]])
    return out
