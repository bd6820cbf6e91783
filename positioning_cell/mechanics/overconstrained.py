"""Limb forces of over-constrained (statically indeterminate) parallel mechanisms, closed by
deformation compatibility (seed 002 §3), in space or in the plane.

The platform is held by k elastic limb wrench lines: unit wrenches W with stiffnesses k_j (N/m
for a force line, N·m/rad for a couple), moments about one reference point. Two spaces, told
apart by the width of W (or named by ``space``):

- spatial: W (k, 6) = (f_x, f_y, f_z, m_x, m_y, m_z), load w (6,), platform error
  δx = (δp m, δθ rad) (6,);
- planar (seed 002 §1: a platform moving in the OXY plane): W (k, 3) = (f_x, f_y, m_z), load
  w (3,), platform error δx = (δx m, δy m, δφ rad) (3,).

The limb forces f (k,) (N or N·m, positive along W_j on the platform) must satisfy

- equilibrium (seed 002 eq. 24): Wᵀ f + w = 0 for the load wrench w on the platform; when
  k > rank W this leaves k − rank unknowns free;
- compatibility (seed 002 eqs. 27-28): every limb deformation is the projection W_j·δx of one
  and the same small platform error δx. A limb's deformation is d_j = d0_j − f_j/k_j: its
  end force over its stiffness, plus ``initial`` d0_j, the deformation it has at zero end force
  (what a distributed load along it adds, seed 002 eq. 29 (:func:`axial_loading`); a length
  misfit; a preload), in the same sense as W_j·δx.

Both together give the stiffness method: (Wᵀ K W) δx = w + Wᵀ K d0, f = K (d0 − W δx). The
rigid-body pseudo-inverse f = −(Wᵀ)⁺ w satisfies equilibrium only.

Sign of W for a two-force link (the planar links of seed 002): the unit wrench of a tension
pulls the platform toward the link's other end, so with W_j = −l_j (l_j from the fixed end to
the platform end) f_j is the link's tension and W_j·δx = −ΔL_j its shortening.
"""

from __future__ import annotations

import math
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError
from positioning_cell.mechanics.screw import UpsUpp, line, moved, rank

FloatArray = NDArray[np.float64]

#: The two spaces of wrench lines: the plane (f_x, f_y, m_z) and space (f; m).
Space = Literal['planar', 'spatial']

#: Width of a wrench row in each space.
WRENCH_WIDTH: dict[str, int] = {'planar': 3, 'spatial': 6}
_SPACES: dict[str, Space] = {'planar': 'planar', 'spatial': 'spatial'}


class ElasticLimbs(NamedTuple):
    """Unit wrench lines (k, 6) (or (k, 3) in the plane) with moments about ``reference``
    ((3,) or (2,), m), stiffnesses (k,) and a name per line."""

    wrenches: FloatArray
    stiffness: FloatArray
    names: tuple[str, ...]
    reference: FloatArray


class StaticSolution(NamedTuple):
    """Limb forces (k,) in N or N·m and the platform's error δx ((6,) spatial: m, rad;
    (3,) planar: δx m, δy m, δφ rad; None for a solution that is not built from one)."""

    forces: FloatArray
    deflection: FloatArray | None


def space_of(wrenches: ArrayLike, space: str | None = None) -> Space:
    """The space of wrench lines (k, 3) (``'planar'``) or (k, 6) (``'spatial'``), or the named
    ``space`` checked against their width. InputError for any other width or name."""
    w = np.asarray(wrenches, dtype=float)
    width = int(w.shape[-1]) if w.ndim >= 1 else 0
    if space is None:
        if width == 3:
            return 'planar'
        if width == 6:
            return 'spatial'
        raise InputError(f'wrenches of shape {w.shape}: expected (k, 3) (planar: f_x, f_y, '
                         'm_z) or (k, 6) (spatial)')
    named = _SPACES.get(space) if isinstance(space, str) else None
    if named is None:
        raise InputError(f'space = {space!r}: expected \'planar\' or \'spatial\'')
    if width != WRENCH_WIDTH[named]:
        raise InputError(f'{named} wrenches must be (k, {WRENCH_WIDTH[named]}), got {w.shape}')
    return named


def _checked(wrenches: ArrayLike, load: ArrayLike,
             space: str | None) -> tuple[FloatArray, FloatArray, Space]:
    w = np.atleast_2d(np.asarray(wrenches, dtype=float))
    name = space_of(w, space)
    n = WRENCH_WIDTH[name]
    f = np.asarray(load, dtype=float).reshape(-1)
    if w.ndim != 2 or f.shape != (n,):
        raise InputError(f'{name} wrenches must be (k, {n}) and load ({n},), got {w.shape}, '
                         f'{f.shape}')
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(f))):
        raise InputError('wrenches and load must be finite')
    return w, f, name


def _stiffness(stiffness: ArrayLike, k: int) -> FloatArray:
    s = np.asarray(stiffness, dtype=float).reshape(-1)
    if s.shape != (k,) or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
        raise InputError(f'stiffness = {stiffness!r}: expected {k} finite values > 0')
    return s


def _initial(initial: ArrayLike | None, k: int) -> FloatArray:
    if initial is None:
        return np.zeros(k)
    d0 = np.asarray(initial, dtype=float).reshape(-1)
    if d0.shape != (k,) or not np.all(np.isfinite(d0)):
        raise InputError(f'initial = {initial!r}: expected {k} finite deformations (m or rad)')
    return d0


def static_indeterminacy(wrenches: ArrayLike, space: str | None = None) -> int:
    """Degree of static indeterminacy: number of limb forces minus the rank of their wrenches
    (0: equilibrium alone fixes the forces). Wrenches (k, 6) or (k, 3) (planar)."""
    w = np.atleast_2d(np.asarray(wrenches, dtype=float))
    space_of(w, space)
    return int(w.shape[0] - rank(w))


def planar_line(direction: ArrayLike, point: ArrayLike,
                reference: ArrayLike = (0.0, 0.0)) -> FloatArray:
    """Unit planar force line (s_x, s_y, m_z) (3,) along ``direction`` (2,) through ``point``
    (2,) (m), its moment m_z = ((point − reference) × s)_z about ``reference`` (m)."""
    s = np.asarray(direction, dtype=float).reshape(-1)
    p = np.asarray(point, dtype=float).reshape(-1) - np.asarray(reference, dtype=float)
    norm = float(np.linalg.norm(s)) if s.shape == (2,) else 0.0
    if p.shape != (2,) or not np.all(np.isfinite(p)) or not (math.isfinite(norm)
                                                             and norm > 1e-12):
        raise InputError(f'direction = {direction!r}, point = {point!r}: expected a finite '
                         'non-zero 2-vector and a finite 2-vector (m)')
    s = s / norm
    return np.array([s[0], s[1], p[0] * s[1] - p[1] * s[0]])


def solve_compatible(wrenches: ArrayLike, stiffness: ArrayLike, load: ArrayLike,
                     initial: ArrayLike | None = None,
                     space: str | None = None) -> StaticSolution:
    """Limb forces satisfying equilibrium and deformation compatibility (seed 002 §3,
    eqs. 24 and 28): δx = (Wᵀ K W)⁻¹ (w + Wᵀ K d0), f = K (d0 − W δx), with ``initial`` d0
    (k,) (m or rad, default 0) the limbs' deformations at zero end force.

    Wrenches (k, 6) and load (6,) in space, (k, 3) and (3,) in the plane (``space`` decides,
    else the width). Raises InputError when the limbs cannot hold every load: rank W < 6
    (spatial) or < 3 (planar)."""
    w, load_arr, name = _checked(wrenches, load, space)
    k = _stiffness(stiffness, w.shape[0])
    d0 = _initial(initial, w.shape[0])
    needed = WRENCH_WIDTH[name]
    if rank(w) < needed:
        raise InputError(f'the limbs span rank {rank(w)} < {needed} ({name}): the platform is '
                         'not held')
    stiff = w.T @ (k[:, None] * w)
    dx = np.asarray(np.linalg.solve(stiff, load_arr + w.T @ (k * d0)), dtype=float)
    return StaticSolution(k * (d0 - w @ dx), dx)


def solve_pseudo_inverse(wrenches: ArrayLike, load: ArrayLike,
                         space: str | None = None) -> StaticSolution:
    """The rigid-body answer f = −(Wᵀ)⁺ w: minimum-norm forces in equilibrium, blind to the
    limbs' stiffness, to their initial deformations (and to the units that mix N and N·m).
    Wrenches (k, 6) / load (6,), or (k, 3) / (3,) in the plane."""
    w, load_arr, _ = _checked(wrenches, load, space)
    return StaticSolution(-np.linalg.pinv(w.T) @ load_arr, None)


def equilibrium_residual(wrenches: ArrayLike, forces: ArrayLike, load: ArrayLike,
                         space: str | None = None) -> float:
    """|Wᵀ f + w| / |w|: relative force-and-moment imbalance of the platform (seed 002 eq. 24),
    in space or in the plane."""
    w, load_arr, _ = _checked(wrenches, load, space)
    f = np.asarray(forces, dtype=float).reshape(-1)
    if f.shape != (w.shape[0],):
        raise InputError(f'forces of shape {f.shape}: expected ({w.shape[0]},)')
    return _ratio(float(np.linalg.norm(w.T @ f + load_arr)), float(np.linalg.norm(load_arr)))


def compatibility_residual(wrenches: ArrayLike, stiffness: ArrayLike, forces: ArrayLike,
                           initial: ArrayLike | None = None,
                           space: str | None = None) -> float:
    """How far the limb deformations d = d0 − f/k (``initial`` d0, default 0) are from those
    of one rigid platform displacement (seed 002 eq. 28), as a fraction of their strain energy:
    with δx* the stiffness-weighted least-squares fit of W δx ≈ d,
    sqrt(Σ k (d − W δx*)²) / sqrt(Σ k d²). 0 = compatible. Spatial or planar wrenches."""
    w = np.atleast_2d(np.asarray(wrenches, dtype=float))
    space_of(w, space)
    k = _stiffness(stiffness, w.shape[0])
    d = _initial(initial, w.shape[0]) - np.asarray(forces, dtype=float).reshape(-1) / k
    root = np.sqrt(k)
    fit, *_ = np.linalg.lstsq(root[:, None] * w, root * d, rcond=None)
    misfit = root * (d - w @ fit)
    return _ratio(float(np.linalg.norm(misfit)), float(np.linalg.norm(root * d)))


def _ratio(num: float, den: float) -> float:
    return num / den if den > 0.0 else num


# -- a bar under an end force and a uniform axial load (seed 002 eq. 29) -----------------------
class AxialLoading(NamedTuple):
    """A uniform bar's axial state (seed 002 eq. 29), tension positive: the axial force at
    x = 0 (N(0) = f + w·L) and at x = L (N(L) = f), both N, and its elongation ΔL (m)."""

    force_at_start: FloatArray
    force_at_end: FloatArray
    elongation: FloatArray


def _bar(end_force: ArrayLike, distributed_load: ArrayLike,
         length: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    f = np.asarray(end_force, dtype=float)
    w = np.asarray(distributed_load, dtype=float)
    length_arr = np.asarray(length, dtype=float)
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(w))):
        raise InputError(f'end_force = {end_force!r}, distributed_load = {distributed_load!r}: '
                         'must be finite (N, N/m)')
    if not (np.all(np.isfinite(length_arr)) and np.all(length_arr > 0.0)):
        raise InputError(f'length = {length!r}: must be finite and > 0 (m)')
    return f, w, length_arr


def axial_force(x: ArrayLike, end_force: ArrayLike, distributed_load: ArrayLike,
                length: ArrayLike) -> FloatArray:
    """Axial force N(x) = f + w·(L − x) (N, tension positive) of a bar of length L (m) at
    x ∈ [0, L] (m) (seed 002 eq. 29).

    Conventions: x runs along the bar's unit axis e from its start (x = 0) to its end (x = L);
    ``end_force`` f (N) is the tension at the end x = L (in seed 002: x measured from the slider
    joint B_i, so that the end is the platform joint A_i where f_i acts); ``distributed_load``
    w (N/m) is the axial component along +e of the uniform load per unit length (seed 002:
    w = (p_i + q_i)·l_i, weight p_i = m_i·g/L and inertia q_i = −m_i·a_Ci/L). Broadcasts."""
    f, w, length_arr = _bar(end_force, distributed_load, length)
    xs = np.asarray(x, dtype=float)
    if not (np.all(np.isfinite(xs)) and np.all(xs >= 0.0) and np.all(xs <= length_arr)):
        raise InputError(f'x = {x!r}: must lie in [0, L = {length!r}] (m)')
    out: FloatArray = f + w * (length_arr - xs)
    return out


def axial_loading(end_force: ArrayLike, distributed_load: ArrayLike, length: ArrayLike,
                  axial_rigidity: ArrayLike) -> AxialLoading:
    """The bar of :func:`axial_force` with axial rigidity E·S (N; stiffness E·S/L): the axial
    force at each end and the elongation ΔL = ∫₀ᴸ N(x)/(E·S) dx = f·L/(E·S) + w·L²/(2·E·S)
    (m, lengthening positive), seed 002 eq. 29 integrated. The second term is what the
    distributed load adds to the end force's f/k: the ``initial`` deformation of
    :func:`solve_compatible` (with the sign of W_j·δx). Broadcasts."""
    f, w, length_arr = _bar(end_force, distributed_load, length)
    rigidity = np.asarray(axial_rigidity, dtype=float)
    if not (np.all(np.isfinite(rigidity)) and np.all(rigidity > 0.0)):
        raise InputError(f'axial_rigidity = {axial_rigidity!r}: must be finite and > 0 (N)')
    shape = np.broadcast_shapes(f.shape, w.shape, length_arr.shape, rigidity.shape)
    elongation = (f * length_arr + 0.5 * w * length_arr**2) / rigidity
    return AxialLoading(np.broadcast_to(f + w * length_arr, shape).astype(float),
                        np.broadcast_to(f, shape).astype(float),
                        np.broadcast_to(elongation, shape).astype(float))


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
