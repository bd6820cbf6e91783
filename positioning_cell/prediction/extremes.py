"""The largest position error |Δp| and rotation angle |δρ| over every admissible source vector,
clearance directions included (first-order model, seed 004 eq. 14).

The set is a product of boxes |x_i| ≤ t_i (scalar sources) and balls |e_j| ≤ r_j (a clearance's
offset vector in the ``any`` gap model, :attr:`.sources.ToleranceSpec.balls`). For three rows M
(3, S) of the sensitivity T (δp or δρ), |v| = max_{|w|=1} w·v turns the maximum of the convex
|M·x| over that set into the maximum over the unit sphere of its support function

    h(w) = Σ_box t_i·|w·m_i| + Σ_j r_j·‖M_jᵀ·w‖₂      (m_i a column of M, M_j a ball's 3 columns)

a two-dimensional problem. :func:`worst_norm` evaluates h on a cube-sphere grid, refines the
best grid directions by alternating maximisation (x ← argmax w·M·x, the box vertex and the ball
points r_j·M_jᵀw/‖M_jᵀw‖; w ← M·x/|M·x|: |M·x| never decreases) and returns

- ``attained``: |M·x*| at a feasible x*, a lower bound of the maximum (and its direction);
- ``bound``: a certified upper bound. h is a seminorm, so for the maximiser w* and the grid
  point g nearest to it, H = h(w*) ≤ h(g) + h(w* − g) ≤ max_grid h + δ·H, δ the grid's covering
  radius: H ≤ max_grid h / (1 − δ). The grid is the cells' centres of a k × k division of each
  cube face, projected on the sphere; the projection onto the unit ball is 1-Lipschitz, so
  δ = √2/k (the half-diagonal of a cell). The crude Σ_box t_i‖m_i‖ + Σ_j r_j‖M_j‖₂ bounds it
  too; ``bound`` is the smaller of the two.

Both in the unit of the rows (m for δp, rad for δρ).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np
from numpy.typing import NDArray

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: Cells per cube-face edge of the default grid: 6·64² = 24 576 directions, δ = 2.2 %.
RESOLUTION = 64
#: Grid directions refined by the alternating maximisation, and its iteration limit.
_STARTS = 8
_ITERATIONS = 200


@dataclass(frozen=True)
class WorstNorm:
    """The largest |M·x| over the admissible sources (see the module docstring): ``attained``
    at ``sources`` x* (S,) (m or rad; box sources at ±t_i, balls on their sphere), whose error
    M·x* points along the unit vector ``direction`` (3,); ``bound`` ≥ the true maximum ≥
    ``attained``, certified (the smaller of the grid certificate and ``simple_bound``);
    ``simple_bound`` = Σ_box t_i‖m_i‖ + Σ_j r_j‖M_j‖₂ (spectral norm),
    the crude bound, for comparison."""

    attained: float
    bound: float
    simple_bound: float
    sources: FloatArray
    direction: FloatArray


@cache
def sphere_grid(resolution: int = RESOLUTION) -> tuple[FloatArray, float]:
    """Unit directions (6·k², 3) of a cube-sphere grid with k = ``resolution`` cells per face
    edge, and its covering radius √2/k: every unit vector lies within it of a grid direction."""
    if resolution < 2:
        raise InputError(f'resolution = {resolution}: need at least 2 cells per cube edge')
    c = -1.0 + (2.0 * np.arange(resolution) + 1.0) / resolution
    u, v = (a.ravel() for a in np.meshgrid(c, c))
    one = np.ones_like(u)
    faces = [np.stack(f, axis=1) for s in (1.0, -1.0)
             for f in ((s * one, u, v), (u, s * one, v), (u, v, s * one))]
    grid = np.concatenate(faces)
    grid /= np.linalg.norm(grid, axis=1, keepdims=True)
    grid.setflags(write=False)
    return grid, math.sqrt(2.0) / resolution


def worst_norm(matrix: FloatArray, bounds: FloatArray, balls: tuple[tuple[int, int], ...] = (),
               resolution: int = RESOLUTION) -> WorstNorm:
    """Largest |M·x| for rows M (3, S) of T at one pose over |x_i| ≤ ``bounds`` (S,) and, for
    each index range of ``balls``, |x[first:stop]| ≤ bounds[first]: the attained value, its
    sources and direction, and a certified upper bound (module docstring)."""
    m = np.asarray(matrix, dtype=np.float64)
    if m.ndim != 2 or m.shape[0] != 3 or bounds.shape != (m.shape[1],):
        raise InputError(f'worst_norm: expected rows (3, S) and bounds (S,), got {m.shape} and '
                         f'{bounds.shape}')
    members = np.array([range(a, b) for a, b in balls], dtype=np.int64).reshape(-1, 3)
    box = np.ones(m.shape[1], dtype=bool)
    box[members.ravel()] = False
    radii = bounds[members[:, 0]]
    grid, delta = sphere_grid(resolution)

    def support(w: FloatArray) -> FloatArray:
        proj = w @ m
        out: FloatArray = (np.abs(proj[:, box]) @ bounds[box]
                           + np.linalg.norm(proj[:, members], axis=-1) @ radii)
        return out

    def maximiser(w: FloatArray) -> FloatArray:
        proj = w @ m
        x = np.where(proj >= 0.0, 1.0, -1.0) * bounds
        ball = proj[:, members]
        norm = np.linalg.norm(ball, axis=-1, keepdims=True)
        x[:, members] = np.where(norm > 0.0, ball / np.where(norm > 0.0, norm, 1.0), 0.0) \
            * radii[:, None]
        out: FloatArray = x
        return out

    h = support(grid)
    simple = float(np.linalg.norm(m[:, box], axis=0) @ bounds[box]
                   + (np.linalg.norm(m[:, members].transpose(1, 0, 2), ord=2, axis=(1, 2))
                      @ radii if members.size else 0.0))
    top = float(h.max(initial=0.0))
    if top <= 0.0:
        return WorstNorm(0.0, 0.0, simple, np.zeros(m.shape[1]), np.array([0.0, 0.0, 1.0]))
    w = grid[np.argsort(h)[-_STARTS:]]
    value = np.zeros(len(w))
    for _ in range(_ITERATIONS):
        x = maximiser(w)
        v = x @ m.T
        new = np.linalg.norm(v, axis=1)
        w = v / new[:, None]
        if np.all(new - value <= 1e-14 * new):
            value = new
            break
        value = new
    best = int(np.argmax(value))
    x_best = maximiser(w[best:best + 1])[0]
    v_best = m @ x_best
    attained = float(np.linalg.norm(v_best))
    # Both are upper bounds of the maximum; the ascent's value is below it, up to rounding.
    bound = max(min(top / (1.0 - delta), simple), attained)
    return WorstNorm(attained, bound, simple, x_best, v_best / attained)
