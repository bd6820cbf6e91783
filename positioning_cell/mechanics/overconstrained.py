"""Limb forces of over-constrained (statically indeterminate) parallel mechanisms, closed by
deformation compatibility (seed 002 §3).

The platform is held by k elastic limb wrench lines: unit wrenches W (k, 6) (force N /
moment N·m about one reference point, base frame) with stiffnesses k_j (N/m for a force line,
N·m/rad for a couple). The limb forces f (k,) (N or N·m, positive along W_j on the platform)
must satisfy

- equilibrium (seed 002 eq. 24): Wᵀ f + w = 0 for the load wrench w on the platform; when
  k > rank W this leaves k − rank unknowns free;
- compatibility (seed 002 eqs. 27-28): every limb deformation −f_j/k_j is the projection
  W_j·δx of one and the same small platform pose error δx (m, rad).

Both together give the stiffness method: (Wᵀ K W) δx = w, f = −K W δx. The rigid-body
pseudo-inverse f = −(Wᵀ)⁺ w satisfies equilibrium only.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError
from positioning_cell.mechanics.screw import UpsUpp, line, moved, rank

FloatArray = NDArray[np.float64]


class ElasticLimbs(NamedTuple):
    """Unit wrench lines (k, 6) (moments about ``reference`` (3,), m), stiffnesses (k,) and a
    name per line."""

    wrenches: FloatArray
    stiffness: FloatArray
    names: tuple[str, ...]
    reference: FloatArray


class StaticSolution(NamedTuple):
    """Limb forces (k,) in N or N·m and the platform's pose error δx (6,) (m, rad; None for a
    solution that is not built from one)."""

    forces: FloatArray
    deflection: FloatArray | None


def _checked(wrenches: ArrayLike, load: ArrayLike) -> tuple[FloatArray, FloatArray]:
    w = np.atleast_2d(np.asarray(wrenches, dtype=float))
    f = np.asarray(load, dtype=float).reshape(-1)
    if w.ndim != 2 or w.shape[1] != 6 or f.shape != (6,):
        raise InputError(f'wrenches must be (k, 6) and load (6,), got {w.shape}, {f.shape}')
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(f))):
        raise InputError('wrenches and load must be finite')
    return w, f


def _stiffness(stiffness: ArrayLike, k: int) -> FloatArray:
    s = np.asarray(stiffness, dtype=float).reshape(-1)
    if s.shape != (k,) or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
        raise InputError(f'stiffness = {stiffness!r}: expected {k} finite values > 0')
    return s


def static_indeterminacy(wrenches: ArrayLike) -> int:
    """Degree of static indeterminacy: number of limb forces minus the rank of their wrenches
    (0: equilibrium alone fixes the forces)."""
    w = np.atleast_2d(np.asarray(wrenches, dtype=float))
    return int(w.shape[0] - rank(w))


def solve_compatible(wrenches: ArrayLike, stiffness: ArrayLike,
                     load: ArrayLike) -> StaticSolution:
    """Limb forces satisfying equilibrium and deformation compatibility (seed 002 §3):
    δx = (Wᵀ K W)⁻¹ w, f = −K W δx. Raises InputError when the limbs cannot hold every load
    (rank W < 6)."""
    w, load_arr = _checked(wrenches, load)
    k = _stiffness(stiffness, w.shape[0])
    if rank(w) < 6:
        raise InputError(f'the limbs span rank {rank(w)} < 6: the platform is not held')
    stiff = w.T @ (k[:, None] * w)
    dx = np.asarray(np.linalg.solve(stiff, load_arr), dtype=float)
    return StaticSolution(-k * (w @ dx), dx)


def solve_pseudo_inverse(wrenches: ArrayLike, load: ArrayLike) -> StaticSolution:
    """The rigid-body answer f = −(Wᵀ)⁺ w: minimum-norm forces in equilibrium, blind to the
    limbs' stiffness (and to the units that mix N and N·m)."""
    w, load_arr = _checked(wrenches, load)
    return StaticSolution(-np.linalg.pinv(w.T) @ load_arr, None)


def equilibrium_residual(wrenches: ArrayLike, forces: ArrayLike, load: ArrayLike) -> float:
    """|Wᵀ f + w| / |w|: relative force-and-moment imbalance of the platform."""
    w, load_arr = _checked(wrenches, load)
    f = np.asarray(forces, dtype=float).reshape(-1)
    return _ratio(float(np.linalg.norm(w.T @ f + load_arr)), float(np.linalg.norm(load_arr)))


def compatibility_residual(wrenches: ArrayLike, stiffness: ArrayLike,
                           forces: ArrayLike) -> float:
    """How far the limb deformations d = −f/k are from those of one rigid platform
    displacement, as a fraction of their strain energy: with δx* the stiffness-weighted
    least-squares fit of W δx ≈ d, sqrt(Σ k (d − W δx*)²) / sqrt(Σ k d²). 0 = compatible."""
    w = np.atleast_2d(np.asarray(wrenches, dtype=float))
    k = _stiffness(stiffness, w.shape[0])
    d = -np.asarray(forces, dtype=float).reshape(-1) / k
    root = np.sqrt(k)
    fit, *_ = np.linalg.lstsq(root[:, None] * w, root * d, rcond=None)
    misfit = root * (d - w @ fit)
    return _ratio(float(np.linalg.norm(misfit)), float(np.linalg.norm(root * d)))


def _ratio(num: float, den: float) -> float:
    return num / den if den > 0.0 else num


def ups_upp_elastic_limbs(mech: UpsUpp, leg_stiffness: float = 5.0e7,
                          column_stiffness: float = 2.0e8, torsion_stiffness: float = 2.0e6,
                          slide_stiffness: float = 2.0e7) -> ElasticLimbs:
    """The wrench lines of the n-UPS/UPP (seed 001) at its reference configuration, moments
    about the platform centre: one force along each UPS leg (k_leg, N/m); the UPP's force along
    the platform normal through the U centre (k_column, N/m) and couple about it (k_torsion,
    N·m/rad); with the slides braked also forces along the two slide axes through the U centre
    (k_slide, N/m). These span the limbs' screw-theory transmitted wrenches
    (:attr:`positioning_cell.mechanics.screw.Limb.transmitted_wrenches`)."""
    base, plat = mech.attachment_points()
    centre, rot = mech.pose()
    origin = np.zeros(3)
    rows = [line(plat[i] - base[i], base[i]) for i in range(mech.n_ups)]
    stiff = [leg_stiffness] * mech.n_ups
    names = [f'UPS{i + 1} force' for i in range(mech.n_ups)]
    rows += [line(rot[:, 2], origin), np.concatenate([np.zeros(3), rot[:, 2]])]
    stiff += [column_stiffness, torsion_stiffness]
    names += ['UPP force (normal)', 'UPP couple (normal)']
    if mech.lock_centre_prismatics:
        rows += [line(rot[:, 0], origin), line(rot[:, 1], origin)]
        stiff += [slide_stiffness, slide_stiffness]
        names += ['UPP force (slide x)', 'UPP force (slide y)']
    for value in stiff:
        if not (math.isfinite(value) and value > 0.0):
            raise InputError(f'stiffness {value!r}: must be finite and > 0')
    return ElasticLimbs(moved(np.array(rows), centre), np.array(stiff), tuple(names), centre)
