"""The loop equations of a :class:`~.model.Mechanism` as arrays, their derivatives, the nominal
solution and the first-order model (seed 004 §3.2, eqs. 5-14).

Symbols s = (x, u): the S sources then the E unknowns, SI (m, rad); inputs are substituted.
Rows: the E closure equations h (eq. 5; a loop's x, y (, z) sums and its scalar equations),
then the G assembly dimensions Gap (eq. 6). With every vector k's length L_k, azimuth a_k and
elevation e_k affine in s,

    row_r(s) = Σ_k Σ_c w_rck · L_k·d_c(a_k, e_k) + W_r·s + w_r,
    d = (cos e·cos a, cos e·sin a, sin e)        (planar: e = 0, d = (cos φ, sin φ))

(:class:`Form`). Its Jacobian is exact and cheap: ∂(L·d)/∂s = d·∂L/∂s + L·∂d/∂a·∂a/∂s +
L·∂d/∂e·∂e/∂s (:meth:`Form.jacobian`), so A = ∂h/∂x, U = ∂h/∂u, C = ∂Gap/∂x, D = ∂Gap/∂u
(eqs. 11-12) are its blocks; :meth:`Form.jacobian_fd` gives the same by central differences.

The same rows in *trigonometric normal form* (:class:`TrigForm`): angles that differ only by a
constant and a sign share one cos/sin (cos(−θ + k), sin(θ + k) are mixtures of cos θ, sin θ;
cos e·cos a = ½[cos(a − e) + cos(a + e)] in space), so

    row_r(s) = Σ_g [(P_gr·s + p_gr)·cos θ_g + (Q_gr·s + q_gr)·sin θ_g] + W_r·s + w_r,
    θ_g = c_g·s,

one angle θ_g per distinct direction of variation: what the Monte Carlo kernel
(:mod:`positioning_cell.tolerance.montecarlo`) interprets per sample, for any mechanism, with
no code generated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import ConvergenceError, InputError
from positioning_cell.tolerance.expressions import LENGTH, Affine
from positioning_cell.tolerance.linear import check_closure, sensitivity
from positioning_cell.tolerance.model import Mechanism, Vector

FloatArray = NDArray[np.float64]

#: Closure residual (m or rad) below which the loops count as closed: 10 pm, 10 prad.
CLOSURE_TOLERANCE = 1e-11
#: Relative step of the central differences (times the symbol's scale).
FD_STEP = 1e-6
_AXIS = {'x': 0, 'y': 1, 'z': 2}


@dataclass(frozen=True)
class Form:
    """A mechanism's rows as arrays over the symbols (module docstring): K vectors with
    ``length``, ``azimuth``, ``elevation`` (K, N) coefficient rows and (K,) constants;
    ``weights`` (R, 3, K) which component of which vector each row sums; ``linear`` (R, N) and
    ``linear0`` (R,) the affine part. ``x0`` (S,) the sources' nominals, ``guess`` (E,) the
    unknowns' starting values, SI."""

    symbols: tuple[str, ...]
    dimensions: tuple[str, ...]
    n_sources: int
    rows: tuple[str, ...]
    row_dimensions: tuple[str, ...]
    n_closure: int
    length: FloatArray
    length0: FloatArray
    azimuth: FloatArray
    azimuth0: FloatArray
    elevation: FloatArray
    elevation0: FloatArray
    weights: FloatArray
    linear: FloatArray
    linear0: FloatArray
    x0: FloatArray
    guess: FloatArray

    @classmethod
    def from_mechanism(cls, mech: Mechanism) -> Form:
        """The arrays of ``mech`` at its inputs' values."""
        symbols = mech.source_names + mech.unknown_names
        dims = tuple(s.dimension for s in mech.sources) + tuple(
            u.dimension for u in mech.unknowns)
        index = {name: i for i, name in enumerate(symbols)}
        inputs = {i.name: i.value for i in mech.inputs}
        n = len(symbols)

        def row(expr: Affine) -> tuple[FloatArray, float]:
            out = np.zeros(n)
            const = expr.constant
            for name, c in expr.terms:
                if name in inputs:
                    const += c * inputs[name]
                else:
                    out[index[name]] += c
            return out, const

        vectors: list[Vector] = []
        members: list[list[tuple[int, int]]] = []   # per row: (component, vector index)
        linear: list[Affine | None] = []
        names: list[str] = []
        row_dims: list[str] = []
        for loop in mech.closed_loops:
            first = len(vectors)
            vectors.extend(loop.vectors)
            span = range(first, len(vectors))
            for comp, name in zip(loop.components, loop.equation_names, strict=False):
                members.append([(_AXIS[comp], k) for k in span])
                linear.append(None)
                names.append(name)
                row_dims.append(LENGTH)
            for eq in loop.equations:
                members.append([])
                linear.append(eq.expression)
                names.append(f'{loop.name}: {eq.name}')
                row_dims.append(eq.expression.dimension)
        for open_loop in mech.open_loops:
            first = len(vectors)
            vectors.extend(open_loop.vectors)
            axis = _AXIS[open_loop.component] if open_loop.component else 0
            members.append([(axis, k) for k in range(first, len(vectors))])
            linear.append(open_loop.linear)
            names.append(open_loop.name)
            row_dims.append(open_loop.dimension)
        k_count, r_count = len(vectors), len(names)
        arrays = {key: (np.zeros((k_count, n)), np.zeros(k_count))
                  for key in ('length', 'azimuth', 'elevation')}
        for k, v in enumerate(vectors):
            for key, expr in (('length', v.length), ('azimuth', v.azimuth),
                              ('elevation', v.elevation)):
                arrays[key][0][k], arrays[key][1][k] = row(expr)
        weights = np.zeros((r_count, 3, k_count))
        lin, lin0 = np.zeros((r_count, n)), np.zeros(r_count)
        for r, (member, affine) in enumerate(zip(members, linear, strict=True)):
            for axis, k in member:
                weights[r, axis, k] += 1.0
            if affine is not None:
                lin[r], lin0[r] = row(affine)
        x0 = np.array([s.nominal for s in mech.sources])
        guess = np.array([u.guess for u in mech.unknowns])
        return cls(symbols, dims, len(mech.sources), tuple(names), tuple(row_dims),
                   len(mech.equation_names), *arrays['length'], *arrays['azimuth'],
                   *arrays['elevation'], weights, lin, lin0, x0, guess)

    @property
    def n_unknowns(self) -> int:
        """E, the number of unknowns (= closure equations)."""
        return len(self.symbols) - self.n_sources

    def point(self, x: ArrayLike | None = None, u: ArrayLike | None = None) -> FloatArray:
        """s = (x, u) (..., N); the nominal sources and the guess where not given."""
        xa = self.x0 if x is None else np.asarray(x, dtype=float)
        ua = self.guess if u is None else np.asarray(u, dtype=float)
        shape = np.broadcast_shapes(xa.shape[:-1], ua.shape[:-1])
        return np.concatenate([np.broadcast_to(xa, (*shape, xa.shape[-1])),
                               np.broadcast_to(ua, (*shape, ua.shape[-1]))], axis=-1)

    def _vectors(self, s: FloatArray) -> tuple[FloatArray, ...]:
        length = s @ self.length.T + self.length0
        a = s @ self.azimuth.T + self.azimuth0
        e = s @ self.elevation.T + self.elevation0
        return length, np.cos(a), np.sin(a), np.cos(e), np.sin(e)

    def evaluate(self, s: ArrayLike) -> FloatArray:
        """Every row (..., R) at s (..., N): closure residuals h (m or rad), then the assembly
        dimensions (SI), straight from the vectors."""
        s = np.asarray(s, dtype=float)
        length, ca, sa, ce, se = self._vectors(s)
        comps = np.stack([length * ce * ca, length * ce * sa, length * se], axis=-2)
        out: FloatArray = (np.einsum('...ck,rck->...r', comps, self.weights)
                           + s @ self.linear.T + self.linear0)
        return out

    def jacobian(self, s: ArrayLike) -> FloatArray:
        """∂row/∂s (..., R, N), exact (module docstring)."""
        s = np.asarray(s, dtype=float)
        length, ca, sa, ce, se = self._vectors(s)
        dl, da, de = self.length, self.azimuth, self.elevation
        lk = length[..., :, None]

        def d(c: FloatArray) -> FloatArray:
            return c[..., :, None]

        dx = d(ce * ca) * dl - lk * d(se * ca) * de - lk * d(ce * sa) * da
        dy = d(ce * sa) * dl - lk * d(se * sa) * de + lk * d(ce * ca) * da
        dz = d(se) * dl + lk * d(ce) * de
        dcomps = np.stack([dx, dy, dz], axis=-3)
        out: FloatArray = np.einsum('rck,...ckn->...rn', self.weights, dcomps) + self.linear
        return out

    @cached_property
    def scales(self) -> FloatArray:
        """A typical magnitude per symbol (N,): the largest nominal length of the mechanism
        for lengths (at least 1 mm), 1 rad for angles; the finite-difference steps scale
        with it."""
        point = self.point()
        lengths = [abs(v) for v, d in zip(point, self.dimensions, strict=True) if d == LENGTH]
        size = max([1e-3, *lengths, *np.abs(self.length0)])
        return np.array([size if d == LENGTH else 1.0 for d in self.dimensions])

    def jacobian_fd(self, s: ArrayLike, step: float = FD_STEP) -> FloatArray:
        """∂row/∂s (R, N) at one point s (N,) by central differences of :meth:`evaluate`, step
        ``step``·max(|s_j|, scale_j)."""
        s = np.asarray(s, dtype=float)
        if s.ndim != 1 or s.size != len(self.symbols):
            raise InputError(f'jacobian_fd: expected one point of {len(self.symbols)} '
                             f'symbols, got shape {s.shape}')
        h = step * np.maximum(np.abs(s), self.scales)
        shifts = np.diag(h)
        out: FloatArray = ((self.evaluate(s + shifts) - self.evaluate(s - shifts))
                           / (2.0 * h)[:, None]).T
        return out


@dataclass(frozen=True)
class TrigForm:
    """The rows in trigonometric normal form (module docstring): ``angles`` (G, N) the
    coefficient rows c_g; ``cos_amp``, ``sin_amp`` (G, R, N) and ``cos0``, ``sin0`` (G, R) the
    amplitudes' rows and constants; ``linear`` (R, N), ``linear0`` (R,) what no angle
    varies."""

    angles: FloatArray
    cos_amp: FloatArray
    cos0: FloatArray
    sin_amp: FloatArray
    sin0: FloatArray
    linear: FloatArray
    linear0: FloatArray

    @classmethod
    def from_form(cls, form: Form) -> TrigForm:
        """Group the vectors' terms of ``form`` by angle."""
        r_count, n = form.linear.shape
        keys: dict[tuple[float, ...], int] = {}
        cos_amp: list[FloatArray] = []
        cos0: list[FloatArray] = []
        sin_amp: list[FloatArray] = []
        sin0: list[FloatArray] = []
        linear, linear0 = form.linear.copy(), form.linear0.copy()

        def add(r: int, amp: FloatArray, amp0: float, ang: FloatArray, ang0: float,
                trig: str) -> None:
            if not amp.any() and amp0 == 0.0:
                return
            if not ang.any():   # a constant angle: an affine term
                t = math.cos(ang0) if trig == 'cos' else math.sin(ang0)
                linear[r] += t * amp
                linear0[r] += t * amp0
                return
            sign = float(np.sign(ang[np.flatnonzero(ang)[0]]))
            key = tuple(float(v) for v in sign * ang)
            if key not in keys:
                keys[key] = len(keys)
                for lst, shape in ((cos_amp, (r_count, n)), (cos0, (r_count,)),
                                   (sin_amp, (r_count, n)), (sin0, (r_count,))):
                    lst.append(np.zeros(shape))
            g = keys[key]
            ck, sk = math.cos(ang0), math.sin(ang0)
            # cos(σθ + k) = cos k·cos θ − σ sin k·sin θ; sin(σθ + k) = sin k·cos θ + σ cos k·sin θ
            alpha, beta = (ck, -sign * sk) if trig == 'cos' else (sk, sign * ck)
            cos_amp[g][r] += alpha * amp
            cos0[g][r] += alpha * amp0
            sin_amp[g][r] += beta * amp
            sin0[g][r] += beta * amp0

        for r in range(r_count):
            for axis in range(3):
                for k in np.flatnonzero(form.weights[r, axis]):
                    w = form.weights[r, axis, k]
                    amp, amp0 = w * form.length[k], w * form.length0[k]
                    a, a0 = form.azimuth[k], form.azimuth0[k]
                    e, e0 = form.elevation[k], form.elevation0[k]
                    if not e.any():   # constant elevation: L·cos e0·(cos a, sin a), L·sin e0
                        ce, se = math.cos(e0), math.sin(e0)
                        if axis == 2:   # e is the zero row: an affine term
                            add(r, amp * se, amp0 * se, e, 0.0, 'cos')
                        else:
                            add(r, amp * ce, amp0 * ce, a, a0, 'cos' if axis == 0 else 'sin')
                        continue
                    if axis == 2:
                        add(r, amp, amp0, e, e0, 'sin')
                        continue
                    trig = 'cos' if axis == 0 else 'sin'
                    add(r, 0.5 * amp, 0.5 * amp0, a + e, a0 + e0, trig)
                    add(r, 0.5 * amp, 0.5 * amp0, a - e, a0 - e0, trig)
        g_count = len(keys)

        def stack(lst: list[FloatArray], shape: tuple[int, ...]) -> FloatArray:
            return np.array(lst) if lst else np.zeros((0, *shape))

        angles = np.array(list(keys)) if keys else np.zeros((0, n))
        return cls(angles.reshape(g_count, n), stack(cos_amp, (r_count, n)),
                   stack(cos0, (r_count,)), stack(sin_amp, (r_count, n)),
                   stack(sin0, (r_count,)), linear, linear0)

    def evaluate(self, s: ArrayLike) -> FloatArray:
        """Every row (..., R) at s (..., N), from the normal form."""
        s = np.asarray(s, dtype=float)
        theta = s @ self.angles.T
        pa = np.einsum('grn,...n->...gr', self.cos_amp, s) + self.cos0
        qa = np.einsum('grn,...n->...gr', self.sin_amp, s) + self.sin0
        out: FloatArray = (np.einsum('...gr,...g->...r', pa, np.cos(theta))
                           + np.einsum('...gr,...g->...r', qa, np.sin(theta))
                           + s @ self.linear.T + self.linear0)
        return out


@dataclass(frozen=True)
class Linearisation:
    """The first-order model at the nominal solution (seed 004 eqs. 9-14), SI.

    ``x0`` (S,) nominal sources, ``u0`` (E,) the unknowns solved from ``guess`` (E,) in
    ``iterations`` Newton steps (``guess_residual`` (E,): h at the guess, m or rad),
    ``gap0`` (G,) the assembly dimensions there; A (E, S), U (E, E), C (G, S), D (G, E) and
    T = C − D·U⁻¹·A (G, S); ``condition`` of U; ``method`` of the derivatives."""

    sources: tuple[str, ...]
    unknowns: tuple[str, ...]
    equations: tuple[str, ...]
    open_loops: tuple[str, ...]
    x0: FloatArray
    guess: FloatArray
    guess_residual: FloatArray
    u0: FloatArray
    iterations: int
    gap0: FloatArray
    A: FloatArray
    U: FloatArray
    C: FloatArray
    D: FloatArray
    T: FloatArray
    condition: float
    method: str

    @property
    def first_order(self) -> FloatArray:
        """−U⁻¹·A (E, S): δu to first order per source deviation (eq. 13)."""
        out: FloatArray = -np.linalg.solve(self.U, self.A).astype(np.float64)
        return out


@dataclass(frozen=True)
class Blocks:
    """A, U, C, D of one Jacobian (seed 004 eqs. 11-12)."""

    A: FloatArray
    U: FloatArray
    C: FloatArray
    D: FloatArray


def blocks(form: Form, jac: FloatArray) -> Blocks:
    """Split a Jacobian (R, N) of ``form`` into A, U, C, D."""
    e, s = form.n_closure, form.n_sources
    return Blocks(jac[:e, :s], jac[:e, s:], jac[e:, :s], jac[e:, s:])


def solve_nominal(form: Form, *, tolerance: float = CLOSURE_TOLERANCE,
                  max_iterations: int = 50) -> tuple[FloatArray, int]:
    """The unknowns (E,) closing the loops at the nominal sources, by Newton from the guess
    (step halved while it does not reduce max |h|; once within ``tolerance``, polished while
    a step still reduces it), and the steps taken. SingularLoopsError
    when U is singular at the guess or on the way; ConvergenceError when the loops do not
    close within ``max_iterations``."""
    e, s = form.n_closure, form.n_sources
    names = (form.rows[:e], form.symbols[s:])
    u = form.guess.copy()
    h = form.evaluate(form.point(u=u))[:e]
    check_closure(form.jacobian(form.point(u=u))[:e, s:], *names, ' at the given nominal')
    for iteration in range(max_iterations + 1):
        worst = float(np.max(np.abs(h)))
        if worst <= tolerance:
            return _polish(form, u, h), iteration
        if iteration == max_iterations:
            break
        jac = form.jacobian(form.point(u=u))[:e, s:]
        check_closure(jac, *names, f' at Newton step {iteration + 1} of the nominal solve')
        step = np.linalg.solve(jac, h)
        for _ in range(30):
            trial = u - step
            h_trial = form.evaluate(form.point(u=trial))[:e]
            if np.all(np.isfinite(h_trial)) and np.max(np.abs(h_trial)) < worst:
                break
            step = step / 2.0
        u, h = trial, h_trial
    detail = ', '.join(f'{n} = {v:.3g}' for n, v in zip(form.rows[:e], h, strict=True))
    raise ConvergenceError(f'the closed loops do not close near the given nominal unknowns: '
                           f'after {max_iterations} Newton steps the residuals are {detail} '
                           '(m or rad)')


def _polish(form: Form, u: FloatArray, h: FloatArray, steps: int = 3) -> FloatArray:
    """Newton steps past the tolerance while they reduce max |h|: the nominal to the last
    digit (it is the reference of every deviation)."""
    e, s = form.n_closure, form.n_sources
    worst = float(np.max(np.abs(h)))
    for _ in range(steps):
        if worst == 0.0:
            break
        trial = u - np.linalg.solve(form.jacobian(form.point(u=u))[:e, s:], h)
        h_trial = form.evaluate(form.point(u=trial))[:e]
        if not np.max(np.abs(h_trial)) < worst:
            break
        u, h, worst = trial, h_trial, float(np.max(np.abs(h_trial)))
    return u


def linearise(mech: Mechanism | Form, *, method: str = 'analytic',
              tolerance: float = CLOSURE_TOLERANCE) -> Linearisation:
    """The first-order model of ``mech`` at its nominal solution (:func:`solve_nominal`):
    A, U, C, D by the exact derivatives (``method='analytic'``) or central differences
    (``'fd'``), T by :func:`.linear.sensitivity`. SingularLoopsError (an InputError) names
    the dependent loops' equations and the unknowns when U is singular or ill-conditioned."""
    if method not in ('analytic', 'fd'):
        raise InputError(f'method = {method!r}: expected analytic or fd')
    form = mech if isinstance(mech, Form) else Form.from_mechanism(mech)
    e, s = form.n_closure, form.n_sources
    guess_residual = form.evaluate(form.point())[:e]
    u0, iterations = solve_nominal(form, tolerance=tolerance)
    point = form.point(u=u0)
    jac = form.jacobian(point) if method == 'analytic' else form.jacobian_fd(point)
    b = blocks(form, jac)
    equations, unknowns = form.rows[:e], form.symbols[s:]
    condition = check_closure(b.U, equations, unknowns, ' at the nominal solution')
    t = sensitivity(b.A, b.U, b.C, b.D, check=False)
    gap0 = form.evaluate(point)[e:]
    return Linearisation(form.symbols[:s], unknowns, equations, form.rows[e:], form.x0.copy(),
                         form.guess.copy(), guess_residual, u0, iterations, gap0, b.A, b.U,
                         b.C, b.D, t, condition, method)


@dataclass(frozen=True)
class DerivativeCheck:
    """Analytic against central-difference Jacobian at one point: the largest absolute
    difference (SI) and the largest relative one (|Δ| / max(|J|, 1e-9·max|J| of its row)),
    with the row and symbol where it occurs."""

    max_abs: float
    max_rel: float
    row: str
    symbol: str


def check_derivatives(form: Form, s: ArrayLike | None = None) -> DerivativeCheck:
    """Compare :meth:`Form.jacobian` with :meth:`Form.jacobian_fd` at ``s`` (default: the
    nominal sources and the guess)."""
    point = form.point() if s is None else np.asarray(s, dtype=float)
    exact, approx = form.jacobian(point), form.jacobian_fd(point)
    diff = np.abs(exact - approx)
    floor = 1e-9 * np.maximum(np.abs(exact).max(axis=1, keepdims=True), 1e-300)
    rel = diff / np.maximum(np.abs(exact), floor)
    r, n = np.unravel_index(int(np.argmax(rel)), rel.shape)
    return DerivativeCheck(float(diff.max(initial=0.0)), float(rel.max(initial=0.0)),
                           form.rows[r], form.symbols[n])


