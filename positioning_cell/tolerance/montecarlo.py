"""Monte Carlo of a mechanism's assembly dimensions with the nonlinear loop closure (seed 004
§3.2, last step): per sample of the sources, the closed loops h(x, u) = 0 are solved for the
unknowns by Newton from the first-order solution u0 − U⁻¹·A·δx, then the open loops give the
assembly dimensions; the linear model T·δx of the same sample rides along.

One kernel (:mod:`positioning_cell.core.compiled`, compiled once and cached on disk) serves
every mechanism: it interprets the trigonometric normal form (:class:`.loops.TrigForm`) as
arrays. Per sample it forms the *features*, everything that depends on the sources alone
(each shared angle's source part, the amplitudes' source parts, the affine part, the
first-order unknowns and T·δx), as nominal + F·δx with F sparse (CSR); then the angles that
do not involve an unknown get their cos/sin once, the others once per Newton step; each step
is one E × E solve (Gaussian elimination with partial pivoting). A sample counts as solved when
the error of its unknowns, estimated from the residual as U⁻¹·h (U at the nominal), is below
:data:`UNKNOWN_TOLERANCE` of each unknown's scale (1 rad; the mechanism's size for a length)
within ``max_iterations`` steps (a residual criterion alone, in m, would let a small linkage's
angles off by 1e-10 rad); an unsolved sample is NaN and flagged.

:func:`solve_with_scipy` is the reference (and the benchmark's baseline): the same closure per
sample with ``scipy.optimize.root``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import root
from scipy.sparse import csr_array

from positioning_cell.core.compiled import kernel, kernel_array
from positioning_cell.errors import InputError
from positioning_cell.tolerance.loops import (
    Form,
    Linearisation,
    TrigForm,
    linearise,
)
from positioning_cell.tolerance.model import Mechanism, parse_mechanism
from positioning_cell.tolerance.sampling import draw

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
IntArray = NDArray[np.int64]

#: Samples per chunk of draws (S × 16384 doubles: a few hundred kB per source set).
CHUNK = 1 << 14
#: Newton steps per sample before it counts as unsolved.
MAX_ITERATIONS = 20
#: A sample is solved when |U⁻¹·h| of every unknown is below this share of its scale.
UNKNOWN_TOLERANCE = 1e-12


@dataclass(frozen=True)
class MonteCarloResult:
    """Per sample (n rows), SI: ``unknowns`` (n, E) u − u0 and ``outputs`` (n, G) the assembly
    dimensions' deviations Gap − Gap0 from the nonlinear closure (NaN where unsolved),
    ``linear`` (n, G) T·δx of the same samples, ``converged`` (n,), ``iterations`` (n,) the
    Newton steps taken."""

    unknowns: FloatArray
    outputs: FloatArray
    linear: FloatArray
    converged: BoolArray
    iterations: NDArray[np.int32]

    @property
    def unsolved(self) -> int:
        """Samples whose loops did not close."""
        return int(self.converged.size - np.count_nonzero(self.converged))


@dataclass(frozen=True)
class KernelProblem:
    """What the kernel needs of one mechanism at its nominal, as contiguous arrays (module
    docstring), sparse lists throughout (a mechanism's rows touch few angles and unknowns).

    Angles: G = ``n_free`` angles free of unknowns, then the bound ones. A *pair* is an angle
    and a row its amplitudes enter: ``group_ptr`` (G + 1) into ``group_rows`` (P pairs' rows,
    ascending per angle), ``group_split`` (G,) each angle's first assembly-dimension pair.
    Features (F = G + 2P + R + E + (R − E)): CSR (indptr, indices, data: F × S sources) and
    nominal values (F,): each angle's source part, the pairs' cos then sin amplitudes' source
    parts, the affine rows, the first-order unknowns u0 − U⁻¹·A·δx, T·δx. The unknowns' part:
    of the bound angles (``angle_ptr`` (Gb + 1), ``angle_idx``, ``angle_val``), of each pair's
    amplitudes (``amp_ptr`` (P + 1), ``amp_idx``, ``amp_cos``, ``amp_sin``), of the affine rows
    (``lin_ptr`` (R + 1), ``lin_idx``, ``lin_val``; and dense ``jac0`` (E, E) for the closure
    rows); u0 (E,), Gap0 (R − E,); U⁻¹ at the nominal (E, E) and the tolerance on U⁻¹·h per
    unknown (E,) (m or rad: :data:`UNKNOWN_TOLERANCE` of its scale); the Newton step
    limit."""

    indptr: IntArray
    indices: IntArray
    data: FloatArray
    nominal: FloatArray
    n_sources: int
    n_free: int
    n_rows: int
    n_closure: int
    group_ptr: IntArray
    group_rows: IntArray
    group_split: IntArray
    angle_ptr: IntArray
    angle_idx: IntArray
    angle_val: FloatArray
    amp_ptr: IntArray
    amp_idx: IntArray
    amp_cos: FloatArray
    amp_sin: FloatArray
    lin_ptr: IntArray
    lin_idx: IntArray
    lin_val: FloatArray
    jac0: FloatArray
    u0: FloatArray
    gap0: FloatArray
    closure_inv: FloatArray
    tolerance: FloatArray
    max_iterations: int

    @classmethod
    def build(cls, form: Form, lin: Linearisation, *, tolerance: float = UNKNOWN_TOLERANCE,
              max_iterations: int = MAX_ITERATIONS) -> KernelProblem:
        """The problem of ``form`` linearised as ``lin``; ``tolerance`` the share of each
        unknown's scale (:attr:`.loops.Form.scales`) its estimated error must be below."""
        trig = TrigForm.from_form(form)
        s, e = form.n_sources, form.n_closure
        bound = (np.any(trig.angles[:, s:] != 0.0, axis=1)
                 | np.any(trig.cos_amp[:, :, s:] != 0.0, axis=(1, 2))
                 | np.any(trig.sin_amp[:, :, s:] != 0.0, axis=(1, 2)))
        order = np.concatenate([np.flatnonzero(~bound), np.flatnonzero(bound)])
        angles, cos_amp, sin_amp = trig.angles[order], trig.cos_amp[order], trig.sin_amp[order]
        cos0, sin0 = trig.cos0[order], trig.sin0[order]
        x0 = lin.x0
        g, r = angles.shape[0], trig.linear.shape[0]
        used = (np.any(cos_amp != 0.0, axis=2) | np.any(sin_amp != 0.0, axis=2)
                | (cos0 != 0.0) | (sin0 != 0.0))   # (G, R): the rows each angle enters
        rows = [np.flatnonzero(u) for u in used]
        group_ptr = np.cumsum([0, *(len(x) for x in rows)])
        group_rows = np.concatenate([*rows, np.zeros(0, dtype=np.int64)])
        split = np.array([group_ptr[k] + np.searchsorted(x, e) for k, x in enumerate(rows)],
                         dtype=np.int64)
        pg = np.repeat(np.arange(g), np.diff(group_ptr))   # each pair's angle
        pc, ps = cos_amp[pg, group_rows], sin_amp[pg, group_rows]   # (P, N)
        features = np.concatenate([angles[:, :s], pc[:, :s], ps[:, :s], trig.linear[:, :s],
                                   lin.first_order, lin.T])
        nominal = np.concatenate([
            angles[:, :s] @ x0, pc[:, :s] @ x0 + cos0[pg, group_rows],
            ps[:, :s] @ x0 + sin0[pg, group_rows], trig.linear[:, :s] @ x0 + trig.linear0,
            lin.u0, np.zeros(lin.T.shape[0])])
        nb = int(bound.sum())
        sparse, ang_u = csr_array(features), csr_array(angles[g - nb:, s:])
        amp_u, lin_u = csr_array(pc[:, s:] != 0.0) + csr_array(ps[:, s:] != 0.0), csr_array(
            trig.linear[:, s:])
        amp_u = csr_array(amp_u)
        amp_u.sort_indices()
        amp_rows = np.repeat(np.arange(pc.shape[0]), np.diff(amp_u.indptr))
        c = kernel_array
        return cls(c(sparse.indptr, np.int64), c(sparse.indices, np.int64), c(sparse.data),
                   c(nominal), s, g - nb, r, e, c(group_ptr, np.int64), c(group_rows, np.int64),
                   c(split, np.int64), c(ang_u.indptr, np.int64), c(ang_u.indices, np.int64),
                   c(ang_u.data), c(amp_u.indptr, np.int64), c(amp_u.indices, np.int64),
                   c(pc[amp_rows, s + amp_u.indices]), c(ps[amp_rows, s + amp_u.indices]),
                   c(lin_u.indptr, np.int64), c(lin_u.indices, np.int64), c(lin_u.data),
                   c(trig.linear[:e, s:]), c(lin.u0), c(lin.gap0), c(np.linalg.inv(lin.U)),
                   c(tolerance * form.scales[s:]), int(max_iterations))


def solve_samples(problem: KernelProblem, deviations: FloatArray) -> MonteCarloResult:
    """The nonlinear closure of samples ``deviations`` (S, n) δx (SI) in the kernel."""
    if deviations.ndim != 2 or deviations.shape[0] != problem.n_sources:
        raise InputError(f'deviations: expected ({problem.n_sources}, n), got shape '
                         f'{deviations.shape}')
    n = deviations.shape[1]
    e, g = problem.n_closure, problem.n_rows - problem.n_closure
    out = MonteCarloResult(np.empty((n, e)), np.empty((n, g)), np.empty((n, g)),
                           np.empty(n, dtype=bool), np.empty(n, dtype=np.int32))
    p = problem
    _closure_kernel(kernel_array(deviations), p.indptr, p.indices, p.data, p.nominal, p.n_free,
                    p.n_rows, p.n_closure, p.group_ptr, p.group_rows, p.group_split,
                    p.angle_ptr, p.angle_idx, p.angle_val, p.amp_ptr, p.amp_idx, p.amp_cos,
                    p.amp_sin, p.lin_ptr, p.lin_idx, p.lin_val, p.jac0, p.u0, p.gap0,
                    p.closure_inv, p.tolerance, p.max_iterations, out.unknowns, out.outputs,
                    out.linear, out.converged, out.iterations)
    return out


def monte_carlo(mech: Mechanism, n: int, rng: np.random.Generator, *,
                lin: Linearisation | None = None, chunk: int = CHUNK) -> MonteCarloResult:
    """n samples of the sources (:func:`.sampling.draw`) through the nonlinear closure and the
    linear model (linearised here unless ``lin`` is given). The draws are made ``chunk``
    samples at a time: the same generator state and chunk give the same samples."""
    if n < 1 or chunk < 1:
        raise InputError(f'n = {n}, chunk = {chunk}: both must be >= 1')
    form = Form.from_mechanism(mech)
    lin = linearise(form) if lin is None else lin
    problem = KernelProblem.build(form, lin)
    e, g = form.n_closure, len(form.rows) - form.n_closure
    out = MonteCarloResult(np.empty((n, e)), np.empty((n, g)), np.empty((n, g)),
                           np.empty(n, dtype=bool), np.empty(n, dtype=np.int32))
    for start in range(0, n, chunk):
        stop = min(n, start + chunk)
        part = solve_samples(problem, draw(mech.sources, stop - start, rng))
        out.unknowns[start:stop] = part.unknowns
        out.outputs[start:stop] = part.outputs
        out.linear[start:stop] = part.linear
        out.converged[start:stop] = part.converged
        out.iterations[start:stop] = part.iterations
    return out


def solve_with_scipy(form: Form, lin: Linearisation, deviations: FloatArray, *,
                     xtol: float = 1e-13) -> MonteCarloResult:
    """The reference: each sample (column of ``deviations`` (S, n)) closed by
    ``scipy.optimize.root`` (MINPACK hybrd with the exact Jacobian) from the nominal u0; a
    sample is solved when max |h| ≤ 1e-9 (m or rad) at root's answer (hybrd may report that
    ``xtol`` is too small for further progress once it is there)."""
    e, s = form.n_closure, form.n_sources
    n = deviations.shape[1]
    g = len(form.rows) - e
    out = MonteCarloResult(np.full((n, e), np.nan), np.full((n, g), np.nan),
                           (lin.T @ deviations).T.copy(), np.zeros(n, dtype=bool),
                           np.zeros(n, dtype=np.int32))
    for i in range(n):
        x = lin.x0 + deviations[:, i]

        def residual(u: FloatArray, x: FloatArray = x) -> FloatArray:
            h: FloatArray = form.evaluate(form.point(x, u))[:e]
            return h

        def jacobian(u: FloatArray, x: FloatArray = x) -> FloatArray:
            jac: FloatArray = form.jacobian(form.point(x, u))[:e, s:]
            return jac

        sol = root(residual, lin.u0, jac=jacobian, method='hybr', options={'xtol': xtol})
        point = form.point(x, sol.x)
        rows = form.evaluate(point)
        out.iterations[i] = int(sol.nfev)
        if np.max(np.abs(rows[:e])) <= 1e-9:
            out.converged[i] = True
            out.unknowns[i] = sol.x - lin.u0
            out.outputs[i] = rows[e:] - lin.gap0
    return out


# -- the kernel ---------------------------------------------------------------------------
#: Samples whose features the kernel forms together (vectorised over the samples).
BLOCK = 256


@kernel
def _closure_kernel(deviations: FloatArray, indptr: IntArray, indices: IntArray,
                    data: FloatArray, nominal: FloatArray, n_free: int, n_rows: int,
                    n_closure: int, group_ptr: IntArray, group_rows: IntArray,
                    group_split: IntArray, angle_ptr: IntArray, angle_idx: IntArray,
                    angle_val: FloatArray, amp_ptr: IntArray, amp_idx: IntArray,
                    amp_cos: FloatArray, amp_sin: FloatArray, lin_ptr: IntArray,
                    lin_idx: IntArray, lin_val: FloatArray, jac0: FloatArray, u0: FloatArray,
                    gap0: FloatArray, closure_inv: FloatArray, tolerance: FloatArray,
                    max_iterations: int,
                    unknowns: FloatArray, outputs: FloatArray, linear: FloatArray,
                    converged: BoolArray, iterations: NDArray[np.int32]) -> None:
    """Per sample (column of ``deviations``): the features (formed :data:`BLOCK` samples at a
    time), the free angles' terms, Newton on the closure rows from the first-order unknowns
    (the step by Gaussian elimination with partial pivoting; a singular Jacobian gives NaN and
    an unsolved sample), then the assembly dimensions with the last step's cos/sin (module
    docstring); writes deviations from u0 and Gap0. All in one function: no call, no array
    view on the per-sample path."""
    n = deviations.shape[1]
    n_feat, n_bound, e = nominal.shape[0], angle_ptr.shape[0] - 1, n_closure
    n_pairs = group_rows.shape[0]
    off_p = n_free + n_bound
    off_q = off_p + n_pairs
    off_l = off_q + n_pairs
    off_f = off_l + n_rows
    off_o = off_f + e
    feats = np.empty((n_feat, BLOCK))
    f, base, vals = np.empty(n_feat), np.empty(n_rows), np.empty(n_rows)
    u = np.empty(e)
    jac = np.empty((e, e))
    cb, sb = np.empty(n_bound), np.empty(n_bound)
    amp_c, amp_s = np.empty(n_pairs), np.empty(n_pairs)
    for start in range(0, n, BLOCK):
        m = min(BLOCK, n - start)
        for k in range(n_feat):   # feature k of the block: nominal + Σ F_kj·δx_j
            row = feats[k]
            v0 = nominal[k]
            for i in range(m):
                row[i] = v0
            for p in range(indptr[k], indptr[k + 1]):
                d = data[p]
                src = deviations[indices[p]]
                for i in range(m):
                    row[i] += d * src[start + i]
        for i in range(m):
            s = start + i
            for k in range(n_feat):
                f[k] = feats[k, i]
            for r in range(n_rows):
                base[r] = f[off_l + r]
            for g in range(n_free):
                c, sn = math.cos(f[g]), math.sin(f[g])
                for q in range(group_ptr[g], group_ptr[g + 1]):
                    base[group_rows[q]] += f[off_p + q] * c + f[off_q + q] * sn
            for j in range(e):
                u[j] = f[off_f + j]
            ok = False
            step = 0
            lo, hi = 0, e   # rows evaluated: the closure while iterating, then the rest
            while True:
                if not ok:
                    for b in range(n_bound):
                        theta = f[n_free + b]
                        for t in range(angle_ptr[b], angle_ptr[b + 1]):
                            theta += angle_val[t] * u[angle_idx[t]]
                        cb[b], sb[b] = math.cos(theta), math.sin(theta)
                for r in range(lo, hi):
                    acc = base[r]
                    for t in range(lin_ptr[r], lin_ptr[r + 1]):
                        acc += lin_val[t] * u[lin_idx[t]]
                    vals[r] = acc
                for b in range(n_bound):
                    g = n_free + b
                    first = group_ptr[g] if lo == 0 else group_split[g]
                    last = group_split[g] if lo == 0 else group_ptr[g + 1]
                    for q in range(first, last):
                        a, bq = f[off_p + q], f[off_q + q]
                        for t in range(amp_ptr[q], amp_ptr[q + 1]):
                            a += amp_cos[t] * u[amp_idx[t]]
                            bq += amp_sin[t] * u[amp_idx[t]]
                        amp_c[q], amp_s[q] = a, bq
                        vals[group_rows[q]] += a * cb[b] + bq * sb[b]
                if ok:
                    break
                # Solved when the unknowns' error estimated as U⁻¹·h is within the tolerance.
                within, finite = True, True
                for j in range(e):
                    est = 0.0
                    for r in range(e):
                        est += closure_inv[j, r] * vals[r]
                    est = abs(est)
                    if not est < math.inf:   # NaN or inf
                        finite = False
                    elif est > tolerance[j]:
                        within = False
                if finite and within:
                    ok = True
                    lo, hi = e, n_rows
                    continue
                if not finite or step >= max_iterations:
                    break
                # The Jacobian of the closure rows, ∂h/∂u.
                for r in range(e):
                    for j in range(e):
                        jac[r, j] = jac0[r, j]
                for b in range(n_bound):
                    g = n_free + b
                    for q in range(group_ptr[g], group_split[g]):
                        r = group_rows[q]
                        turn = amp_s[q] * cb[b] - amp_c[q] * sb[b]
                        for t in range(angle_ptr[b], angle_ptr[b + 1]):
                            jac[r, angle_idx[t]] += turn * angle_val[t]
                        for t in range(amp_ptr[q], amp_ptr[q + 1]):
                            jac[r, amp_idx[t]] += amp_cos[t] * cb[b] + amp_sin[t] * sb[b]
                # vals[:e] ← jac⁻¹·vals[:e]: elimination with partial pivoting, back substitution.
                for col in range(e):
                    piv, best = col, abs(jac[col, col])
                    for r in range(col + 1, e):
                        if abs(jac[r, col]) > best:
                            piv, best = r, abs(jac[r, col])
                    if piv != col:
                        for j in range(col, e):
                            jac[col, j], jac[piv, j] = jac[piv, j], jac[col, j]
                        vals[col], vals[piv] = vals[piv], vals[col]
                    for r in range(col + 1, e):
                        factor = jac[r, col] / jac[col, col]
                        for j in range(col, e):
                            jac[r, j] -= factor * jac[col, j]
                        vals[r] -= factor * vals[col]
                for col in range(e - 1, -1, -1):
                    acc = vals[col]
                    for j in range(col + 1, e):
                        acc -= jac[col, j] * vals[j]
                    u[col] -= acc / jac[col, col]
                    vals[col] = acc / jac[col, col]
                step += 1
            converged[s] = ok
            iterations[s] = step
            for j in range(e):
                unknowns[s, j] = u[j] - u0[j] if ok else math.nan
            for o in range(n_rows - e):
                outputs[s, o] = vals[e + o] - gap0[o] if ok else math.nan
                linear[s, o] = f[off_o + o]


_WARM_UP = {
    'units': {'length': 'mm'}, 'inputs': {'t2': '60 deg'},
    'sources': {'r1': {'nominal': 100, 'tolerance': 0.1}, 'r2': {'nominal': 40, 'tolerance': 0.1},
                'r3': {'nominal': 90, 'tolerance': 0.1}, 'r4': {'nominal': 70, 'tolerance': 0.1},
                'g': {'nominal': '0 deg', 'tolerance': '0.1 deg'}},
    'unknowns': {'t3': '20 deg', 't4': '80 deg'},
    'closed_loops': {'loop': {'vectors': [
        {'length': 'r2', 'angle': 't2'}, {'length': 'r3', 'angle': 't3'},
        {'length': '-r4', 'angle': 't4'}, {'length': '-r1', 'angle': 'g'}]}},
    'open_loops': {'t4': {'expression': 't4'}}}


def warm_up() -> None:
    """Compile the kernel now, or load it from numba's on-disk cache (setup calls this: no
    command waits for the compiler later)."""
    monte_carlo(parse_mechanism(_WARM_UP, 'warm-up four-bar'), 16, np.random.default_rng(0))
