"""Monte Carlo of the pose error with the full nonlinear closure model (seed 004 §3.2, last step).

For each sample of the sources (:func:`.sources.draw_sources`) the closure equations

    h_i = p + R·(b_i + δb_i) − (A_i + δA_i) − (l_i + δl_i)·u_i(φ_i + δφ_i, θ_i + δθ_i) = 0

are solved exactly for the pose deviation (δp, δρ) and the passive angles δφ, every sample with
its own joint centres. :func:`positioning_cell.core.kinematics.forward` takes one geometry for the
whole batch, so each sample is solved here by a chord (simplified Newton) iteration that reuses
the nominal closure Jacobian U of :mod:`.sensitivity`: z ← z − U⁻¹·h(z) from the first-order
solution, each step one residual evaluation and one (9 × 9) product, in a compiled per-sample
kernel (:mod:`positioning_cell.core.compiled`). The tests check it against
``forward(mech.with_offsets(...))`` sample by sample.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import csr_array

from positioning_cell.core.compiled import available_cpus, kernel, kernel_array
from positioning_cell.core.kinematics import forward, inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import matrix_from_quaternion, pose_error
from positioning_cell.errors import InputError
from positioning_cell.prediction.sensitivity import (
    COORDINATES,
    Linearisation,
    linearise,
    root_sum_square,
    worst_case,
)
from positioning_cell.prediction.sources import Requirement, ToleranceSpec, draw_sources
from positioning_cell.tolerance.stackup import YieldEstimate, estimate_yield

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Closure residual (m) below which a sample counts as solved: 10 pm, five orders of magnitude
#: below the smallest tolerance worth predicting.
CLOSURE_TOLERANCE = 1e-11
#: Samples per chunk: its draws (S × 4096 doubles, about 1 MiB) stay in the core's cache.
CHUNK = 1 << 12


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
class Comparison:
    """Per pose coordinate (6,), m and rad: the first-order worst case (seed 004 eq. 15, over
    every clearance direction in the ``any`` gap model), the RSS of the tolerance contributions,
    the linear-model 3σ, and from the Monte Carlo the largest |deviation|, 3 × standard
    deviation and the 99.73 % quantile of |deviation|."""

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
    z = −U⁻¹·∂h/∂prim·prim, until max |h| ≤ ``tolerance`` m or ``max_iterations``. Returns the
    deviations (NaN where not converged) and converged (n,).
    """
    if lin.position.shape[0] != 1:
        raise InputError(f'solve_closure: expected one pose, got {lin.position.shape[0]}')
    if primitives.ndim != 2 or primitives.shape[1] != lin.primitives.shape[2]:
        raise InputError(f'primitives: expected shape (n, 24), got {primitives.shape}')
    identity = np.eye(primitives.shape[1])
    solved = _solve(_ClosureProblem.at(mech, lin, identity, tolerance, max_iterations),
                    kernel_array(primitives.T))
    return solved.deviations, solved.converged


class _ClosureProblem(NamedTuple):
    """What the closure kernel needs at one pose, as contiguous arrays: the source → primitive
    map in CSR form (indptr, indices, data); the first-order map −U⁻¹·∂h/∂prim and U⁻¹, both
    transposed ((24, 9), (9, 9)) for column-wise products; the nominal pose (3,) m and
    rotation (3, 3); nominal joints l, θ, φ (3,) each; the mechanism's A_i, e_r,i, e_t,i, b_i
    (3, 3); the tolerance (m) and the iteration limit."""

    indptr: NDArray[np.int64]
    indices: NDArray[np.int64]
    data: FloatArray
    first_order: FloatArray
    closure_inv: FloatArray
    position: FloatArray
    rot: FloatArray
    lengths: FloatArray
    thetas: FloatArray
    phis: FloatArray
    base: FloatArray
    radial: FloatArray
    tangential: FloatArray
    platform: FloatArray
    tolerance: float
    max_iterations: int

    @classmethod
    def at(cls, mech: Mechanism, lin: Linearisation, to_primitives: FloatArray,
           tolerance: float, max_iterations: int) -> _ClosureProblem:
        """The problem at the pose of ``lin`` for samples mapped to the 24 primitives by
        ``to_primitives`` (24, S)."""
        joints = inverse(mech, lin.position, lin.quaternion)
        closure_inv = np.linalg.inv(lin.closure[0])
        sparse = csr_array(to_primitives)
        c = kernel_array
        return cls(c(sparse.indptr, np.int64), c(sparse.indices, np.int64), c(sparse.data),
                   c((-closure_inv @ lin.primitives[0]).T), c(closure_inv.T),
                   c(lin.position[0]), c(matrix_from_quaternion(lin.quaternion)[0]),
                   c(joints.lengths[0]), c(joints.thetas[0]), c(joints.phis[0]),
                   c(mech.base_joints), c(mech.radial), c(mech.tangential),
                   c(mech.platform_joints), float(tolerance), int(max_iterations))


class _Solved(NamedTuple):
    linear: FloatArray
    deviations: FloatArray
    converged: BoolArray


def _solve(problem: _ClosureProblem, samples: FloatArray) -> _Solved:
    """First-order and exact deviations (n, 6) and converged (n,) for samples (S, n)."""
    n = samples.shape[1]
    out = _Solved(np.empty((n, 6)), np.empty((n, 6)), np.empty(n, dtype=bool))
    _closure_kernel(samples, *problem, *out)
    return out


@kernel
def _closure_kernel(samples: FloatArray, indptr: NDArray[np.int64], indices: NDArray[np.int64],
                    data: FloatArray, first_order: FloatArray, closure_inv: FloatArray,
                    position: FloatArray, rot: FloatArray, lengths: FloatArray,
                    thetas: FloatArray, phis: FloatArray, base: FloatArray, radial: FloatArray,
                    tangential: FloatArray, platform: FloatArray, tolerance: float,
                    max_iterations: int, linear: FloatArray, deviations: FloatArray,
                    converged: BoolArray) -> None:
    """Per sample (column of ``samples``): primitives, first-order z, then the chord iteration
    on the closure h (module docstring); writes the first-order and exact (δp, δρ)."""
    n = samples.shape[1]
    prim, z, h = np.empty(24), np.empty(9), np.empty(9)
    lc, sin_phi, cos_phi = np.empty(3), np.sin(phis), np.cos(phis)
    sin_theta, cos_theta = np.sin(thetas), np.cos(thetas)
    body, centre, spin = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    for s in range(n):
        for k in range(24):
            acc = 0.0
            for e in range(indptr[k], indptr[k + 1]):
                acc += data[e] * samples[indices[e], s]
            prim[k] = acc
        # z = first_order·prim, column by column: nine independent sums (no latency chain).
        z[:] = 0.0
        for m in range(24):
            pm = prim[m]
            for k in range(9):
                z[k] += first_order[m, k] * pm
        for k in range(6):
            linear[s, k] = z[k]
        # The leg, l·u = l cosθ (sinφ e_r + cosφ e_z) + l sinθ e_t
        # (docs/conventions/kinematics.md): what
        # does not change while iterating is computed once, h_i = centre_i + δp + R·b_i − l cosθ
        # (sinφ e_r + cosφ e_z) with centre_i = p − A_i − δA_i − l sinθ e_t and R·b_i =
        # exp([R_nom·δρ]×)·R_nom·(b_i + δb_i).
        for i in range(3):
            sin_d, cos_d = _sin_cos_small(prim[3 + i])
            length = lengths[i] + prim[i]
            lc[i] = length * (cos_theta[i] * cos_d - sin_theta[i] * sin_d)
            ls = length * (sin_theta[i] * cos_d + cos_theta[i] * sin_d)
            b0 = platform[i, 0] + prim[15 + 3 * i]
            b1 = platform[i, 1] + prim[16 + 3 * i]
            b2 = platform[i, 2] + prim[17 + 3 * i]
            for x in range(3):
                body[i, x] = rot[x, 0] * b0 + rot[x, 1] * b1 + rot[x, 2] * b2
                centre[i, x] = (position[x] - base[i, x] - prim[6 + 3 * i + x]
                                - ls * tangential[i, x])
        done = False
        for iteration in range(max_iterations + 1):
            _rotation_from_rotvec(rot[0, 0] * z[3] + rot[0, 1] * z[4] + rot[0, 2] * z[5],
                                  rot[1, 0] * z[3] + rot[1, 1] * z[4] + rot[1, 2] * z[5],
                                  rot[2, 0] * z[3] + rot[2, 1] * z[4] + rot[2, 2] * z[5], spin)
            done = True
            for i in range(3):
                sin_d, cos_d = _sin_cos_small(z[6 + i])
                lcs = lc[i] * (sin_phi[i] * cos_d + cos_phi[i] * sin_d)
                lcc = lc[i] * (cos_phi[i] * cos_d - sin_phi[i] * sin_d)
                for x in range(3):
                    r = (centre[i, x] + z[x] + spin[x, 0] * body[i, 0]
                         + spin[x, 1] * body[i, 1] + spin[x, 2] * body[i, 2]
                         - lcs * radial[i, x])
                    if x == 2:
                        r -= lcc
                    h[3 * i + x] = r
                    if not abs(r) <= tolerance:  # also false for NaN
                        done = False
            if done or iteration == max_iterations:
                break
            for m in range(9):
                hm = h[m]
                for k in range(9):
                    z[k] -= closure_inv[m, k] * hm
        converged[s] = done
        for k in range(6):
            deviations[s, k] = z[k] if done else np.nan


#: Below this |angle| (rad) the series of :func:`_sin_cos_small` and the small-angle branch of
#: :func:`_rotation_from_rotvec` are exact to double precision (next terms < 1e-20).
_SERIES_LIMIT = 0.05


@kernel
def _sin_cos_small(d: float) -> tuple[float, float]:
    """(sin d, cos d) of an angle d (rad): Taylor series up to d⁹ / d¹⁰ for |d| below
    :data:`_SERIES_LIMIT` (the increments of the closure iteration), libm beyond it."""
    if abs(d) >= _SERIES_LIMIT:
        return np.sin(d), np.cos(d)
    d2 = d * d
    sin_d = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0 * (1.0 - d2 / 72.0))))
    cos_d = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (1.0 - d2 / 56.0 * (
        1.0 - d2 / 90.0))))
    return sin_d, cos_d


@kernel
def _rotation_from_rotvec(w0: float, w1: float, w2: float, out: FloatArray) -> None:
    """Rotation matrix (3, 3) of the rotation vector w (rad), Rodrigues' formula
    R = I + a·[w]× + b·[w]×², a = sin t / t, b = (1 − cos t) / t², t = |w|. Written out because
    compiled code cannot call scipy; the tests check it against scipy's Rotation.from_rotvec."""
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    if t2 < _SERIES_LIMIT * _SERIES_LIMIT:
        a = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)))
        b = 0.5 * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0 * (1.0 - t2 / 90.0))))
    else:
        t = np.sqrt(t2)
        a = np.sin(t) / t
        half = np.sin(0.5 * t) / t
        b = 2.0 * half * half
    out[0, 0] = 1.0 - b * (w1 * w1 + w2 * w2)
    out[1, 1] = 1.0 - b * (w0 * w0 + w2 * w2)
    out[2, 2] = 1.0 - b * (w0 * w0 + w1 * w1)
    out[0, 1] = b * w0 * w1 - a * w2
    out[1, 0] = b * w0 * w1 + a * w2
    out[0, 2] = b * w0 * w2 + a * w1
    out[2, 0] = b * w0 * w2 - a * w1
    out[1, 2] = b * w1 * w2 - a * w0
    out[2, 1] = b * w1 * w2 + a * w0


def monte_carlo(mech: Mechanism, spec: ToleranceSpec, position: ArrayLike,
                quaternion: ArrayLike, n_samples: int, rng: np.random.Generator, *,
                chunk: int = CHUNK, workers: int | None = None) -> MonteCarloResult:
    """Pose deviations of ``n_samples`` machines drawn from ``spec`` at one pose ((3,) m,
    (4,) x, y, z, w), nonlinear and linear.

    Samples are processed in chunks of ``chunk``, chunk k drawn from the k-th generator
    spawned from ``rng``, on ``workers`` threads (default: the CPUs this process may use): the
    result depends on ``rng`` and ``chunk``, never on ``workers``.
    """
    if n_samples < 1:
        raise InputError(f'n_samples = {n_samples}: need at least 1 sample')
    if chunk < 1:
        raise InputError(f'chunk = {chunk}: must be >= 1')
    if workers is not None and workers < 1:
        raise InputError(f'workers = {workers}: must be >= 1')
    lin = linearise(mech, spec, position, quaternion)
    if lin.position.shape[0] != 1:
        raise InputError(f'monte_carlo: expected one pose, got {lin.position.shape[0]}')
    problem = _ClosureProblem.at(mech, lin, lin.source_map[0], CLOSURE_TOLERANCE, 12)
    starts = range(0, n_samples, chunk)
    streams = rng.spawn(len(starts))
    result = MonteCarloResult(np.empty((n_samples, 6)), np.empty((n_samples, 6)),
                              np.empty(n_samples, dtype=bool))

    def run(k: int) -> None:
        start = starts[k]
        stop = min(start + chunk, n_samples)
        solved = _solve(problem, draw_sources(spec, stop - start, streams[k]).T)
        result.linear[start:stop] = solved.linear
        result.deviations[start:stop] = solved.deviations
        result.converged[start:stop] = solved.converged

    # The kernel and numpy's generators release the GIL: threads run chunks in parallel.
    with ThreadPoolExecutor(max_workers=workers or available_cpus()) as pool:
        for _ in pool.map(run, range(len(starts))):
            pass
    return result


def inside_requirement(deviations: FloatArray, requirement: Requirement) -> BoolArray:
    """(n,) True where |Δp| ≤ requirement.position and |δρ| ≤ requirement.orientation
    (deviations (n, 6) m, rad); NaN rows (unsolved) count as outside."""
    pos = np.linalg.norm(deviations[:, :3], axis=1)
    ang = np.linalg.norm(deviations[:, 3:], axis=1)
    with np.errstate(invalid='ignore'):
        inside: BoolArray = (pos <= requirement.position) & (ang <= requirement.orientation)
    return inside


def compare(lin: Linearisation, spec: ToleranceSpec, result: MonteCarloResult) -> Comparison:
    """Worst case, RSS and linear 3σ at the (single) pose of ``lin`` next to the Monte Carlo
    statistics of ``result`` (converged samples only)."""
    matrix = lin.matrix[0]
    dev = np.abs(result.deviations[result.converged])
    if dev.shape[0] == 0:
        raise InputError('compare: no converged Monte Carlo samples')
    return Comparison(
        worst_case=worst_case(matrix, spec.bounds, spec.balls),
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
    :func:`positioning_cell.core.kinematics.forward` per sample on the displaced mechanism.
    Slow and independent of :func:`solve_closure`: what tests check it against and the
    benchmark's baseline."""
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
