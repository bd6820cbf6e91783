"""The first-order model of a mechanism's vector loops (seed 004 §3.2, eqs. 7-14).

Closed loops h(x, u) = 0 tie the E unknowns u (the assembly dimensions: joint variables, a
pose) to the S sources x (dimensions, form, clearances); the open loops give the G assembly
dimensions Gap(x, u) the requirement is on. Expanded to first order at the nominal state:

    A·δx + U·δu = 0          A = ∂h/∂x (E, S), U = ∂h/∂u (E, E)          (eqs. 9, 11)
    δGap = C·δx + D·δu       C = ∂Gap/∂x (G, S), D = ∂Gap/∂u (G, E)      (eqs. 10, 12)

so δu = −U⁻¹·A·δx (eq. 13) and δGap = T·δx with the sensitivity T = C − D·U⁻¹·A (eq. 14).

U must be invertible: a singular U means the loops do not fix the unknowns (a combination of
unknowns the equations do not see: the right null space of U) and some equations repeat
others (the left null space: dependent loops). :func:`sensitivity` refuses such a U, and one
whose condition number exceeds :data:`MAX_CONDITION` (its inverse would amplify rounding into
the result), with both null spaces named.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: The largest condition number of U accepted: beyond it U⁻¹·A loses more than 4 of the 16
#: significant digits of a float64 (seed 004's printed U has about 1e18).
MAX_CONDITION = 1e12
#: A null-space vector's component counts (names its unknown or equation) above this share of
#: its largest component.
NULL_SHARE = 1e-8


class SingularLoopsError(InputError):
    """U = ∂h/∂u is singular or ill-conditioned: ``condition`` its condition number (inf when
    exactly singular), ``unknowns`` groups of unknowns the loops cannot tell apart (each group
    a right null vector's support), ``equations`` groups of dependent equations (a left null
    vector's support)."""

    def __init__(self, condition: float, unknowns: tuple[tuple[str, ...], ...],
                 equations: tuple[tuple[str, ...], ...], where: str = '') -> None:
        what = [f'U = dh/du is singular or ill-conditioned{where} (condition number '
                f'{condition:.3g} > {MAX_CONDITION:.0e}): the closed loops do not fix the '
                'unknowns']
        what += [f'unknowns {", ".join(g)} enter only in a fixed combination' for g in unknowns]
        what += [f'equations {", ".join(g)} are dependent' for g in equations]
        super().__init__('; '.join(what))
        self.condition = condition
        self.unknowns = unknowns
        self.equations = equations


def _supports(vectors: FloatArray, names: Sequence[str]) -> tuple[tuple[str, ...], ...]:
    """The names of the non-negligible components of each null vector (rows of ``vectors``)."""
    out = []
    for v in vectors:
        big = np.abs(v) > NULL_SHARE * np.abs(v).max()
        out.append(tuple(names[int(i)] for i in np.flatnonzero(big)))
    return tuple(out)


def check_closure(U: FloatArray, equations: Sequence[str] = (), unknowns: Sequence[str] = (),
                  where: str = '') -> float:
    """The condition number of one U (E, E); SingularLoopsError naming the dependent unknowns
    and equations when it exceeds :data:`MAX_CONDITION`. Unnamed rows/columns are numbered."""
    e = U.shape[0]
    if U.shape != (e, e) or not np.isfinite(U).all():
        raise InputError(f'U must be a finite square matrix, got shape {U.shape}')
    s = np.linalg.svd(U, compute_uv=False)
    condition = float(s[0] / s[-1]) if s[-1] > 0.0 else float('inf')
    if condition <= MAX_CONDITION:
        return condition
    left, sv, right = np.linalg.svd(U)
    small = sv <= sv[0] / MAX_CONDITION
    eq_names = list(equations) or [f'equation {i + 1}' for i in range(e)]
    un_names = list(unknowns) or [f'unknown {i + 1}' for i in range(e)]
    raise SingularLoopsError(condition, _supports(right[small], un_names),
                             _supports(left[:, small].T, eq_names), where)


def sensitivity(A: ArrayLike, U: ArrayLike, C: ArrayLike, D: ArrayLike, *,
                equations: Sequence[str] = (), unknowns: Sequence[str] = (),
                check: bool = True) -> FloatArray:
    """T = C − D·U⁻¹·A (seed 004 eq. 14) of one state or a batch: A (..., E, S), U (..., E, E),
    C (..., G, S), D (..., G, E) → T (..., G, S), in the units of Gap per unit of each source.
    With ``check`` every U is first checked (:func:`check_closure`; ``equations`` and
    ``unknowns`` name its rows and columns in the error)."""
    a, u, c, d = (np.asarray(m, dtype=float) for m in (A, U, C, D))
    if check:
        flat = u.reshape(-1, *u.shape[-2:])
        for k, single in enumerate(flat):
            check_closure(single, equations, unknowns,
                          f' at state {k}' if flat.shape[0] > 1 else '')
    out: FloatArray = -(d @ np.linalg.solve(u, a) - c)  # −(D·U⁻¹·A − C): −0.0 where 0 − 0
    return out
