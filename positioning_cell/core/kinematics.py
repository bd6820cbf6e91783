"""Inverse and forward kinematics and the velocity Jacobian of the 3-UPS positioner.

Conventions (docs/conventions/kinematics.md): leg i leaves its U-joint centre A_i along
u_i(φ_i, θ_i) = cos θ_i (sin φ_i e_r,i + cos φ_i e_z) + sin θ_i e_t,i, so the S-joint centre is
B_i = A_i + l_i u_i. Actuated: l_i (m) and θ_i (rad); passive: φ_i (rad). Poses are the platform
frame in the base frame: position (N, 3) in m, unit quaternion (N, 4) x, y, z, w.
Every function works on batches; a single pose is a batch of one.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core import compiled
from positioning_cell.core.compiled import kernel, kernel_array
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import (
    as_pose_batch,
    as_vectors,
    matrix_from_quaternion,
    quaternion_from_matrix,
)
from positioning_cell.core.vectors import cross
from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Leg pairs (i, j) of the platform-triangle closure equations, seed 000 eq. (14).
PAIRS_I = np.array([0, 1, 2])
PAIRS_J = np.array([1, 2, 0])

#: Side-length residual (m) below which forward kinematics counts as converged.
FK_TOLERANCE = 1e-14
#: Largest Newton step in tan(φ/2): keeps the iteration on the branch it starts on.
_MAX_STEP = 0.15
#: Batches of at least this many poses run the compiled kernel (numba loaded for them) in a
#: process that is not sealed; smaller ones, and every batch in a sealed process without numba
#: (a node, one pose at a time: ~0.1 ms), run the kernel's own Python source, uncompiled.
COMPILED_BATCH = 256


class InverseResult(NamedTuple):
    """Joint values of N poses, (N, 3) each: lengths l_i (m), actuated θ_i, passive φ_i (rad)."""

    lengths: FloatArray
    thetas: FloatArray
    phis: FloatArray


class ForwardResult(NamedTuple):
    """Platform poses from joint values.

    position (N, 3) m and quaternion (N, 4) are NaN where ``converged`` is False; phis (N, 3) rad
    are the passive angles of the solution (the start for branch continuity on the next call).
    """

    position: FloatArray
    quaternion: FloatArray
    phis: FloatArray
    converged: BoolArray


class JacobianResult(NamedTuple):
    """matrix (N, 6, 6): actuated rates (l̇1..3 m/s, θ̇1..3 rad/s) → platform twist (v m/s, ω rad/s),
    both in the base frame; conditioning (N,): reciprocal condition number of the inverse
    Jacobian with rotations scaled by R_B, in [0, 1], 0 at a singularity."""

    matrix: FloatArray
    conditioning: FloatArray


def leg_directions(mech: Mechanism, phis: FloatArray, thetas: FloatArray) -> FloatArray:
    """Unit leg vectors u_i (N, 3 legs, 3) from φ, θ (N, 3) in rad."""
    ct, st = np.cos(thetas)[..., None], np.sin(thetas)[..., None]
    cp, sp = np.cos(phis)[..., None], np.sin(phis)[..., None]
    ez = np.array([0.0, 0.0, 1.0])
    u: FloatArray = ct * (sp * mech.radial + cp * ez) + st * mech.tangential
    return u


def joint_points(mech: Mechanism, lengths: FloatArray, thetas: FloatArray,
                 phis: FloatArray) -> FloatArray:
    """S-joint centres B_i = A_i + l_i u_i in the base frame, (N, 3 legs, 3), m."""
    return mech.base_joints + lengths[..., None] * leg_directions(mech, phis, thetas)


def platform_points(mech: Mechanism, position: FloatArray, quaternion: FloatArray) -> FloatArray:
    """S-joint centres B_i = p + R b_i of validated poses, (N, 3 legs, 3), m."""
    rot = matrix_from_quaternion(quaternion)
    points: FloatArray = position[:, None, :] + np.einsum('nij,kj->nki', rot, mech.platform_joints)
    return points


def inverse(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike) -> InverseResult:
    """Joint values for poses, closed form (kinematics.md): l = |B − A|, θ = asin(u·e_t),
    φ = atan2(u·e_r, u·e_z).

    position (N, 3) or (3,) in m, quaternion (N, 4) or (4,) x, y, z, w. Raises InputError for
    wrong shapes, non-finite numbers and zero or non-unit quaternions. Limits are not checked
    here: see :func:`positioning_cell.core.limits.check_poses`.
    """
    p, q = as_pose_batch(position, quaternion)
    return _inverse_validated(mech, p, q)


def _inverse_validated(mech: Mechanism, p: FloatArray, q: FloatArray) -> InverseResult:
    d = platform_points(mech, p, q) - mech.base_joints
    lengths = np.linalg.norm(d, axis=2)
    u = d / lengths[..., None]
    thetas = np.arcsin(np.clip(np.einsum('nkj,kj->nk', u, mech.tangential), -1.0, 1.0))
    phis = np.arctan2(np.einsum('nkj,kj->nk', u, mech.radial), u[..., 2])
    return InverseResult(lengths, thetas, phis)


def home_phis(mech: Mechanism) -> FloatArray:
    """Passive angles φ (3,) at the home pose, rad."""
    phis: FloatArray = _home_phis(mech).copy()
    return phis


@functools.lru_cache(maxsize=64)
def _home_phis(mech: Mechanism) -> FloatArray:
    home = _inverse_validated(mech, mech.home_position[None], mech.home_quaternion[None])
    phis: FloatArray = home.phis[0]
    phis.setflags(write=False)
    return phis


def forward(mech: Mechanism, lengths: ArrayLike, thetas: ArrayLike,
            phi0: ArrayLike | None = None, *, tolerance: float = FK_TOLERANCE,
            max_iterations: int = 40) -> ForwardResult:
    """Platform poses from actuated joints: lengths (N, 3) m, thetas (N, 3) rad.

    Solves the closure equations |B_i(φ_i) − B_j(φ_j)|² = |b_i − b_j|² (seed 000 eq. 14) for the
    passive φ by Newton with the analytic Jacobian, started from ``phi0`` ((3,) or (N, 3) rad;
    branch continuity) or from home, to ``tolerance`` in side length (m). The pose follows from
    the three B_i by an exact rigid construction. A pose that does not converge, or lands on the
    mirrored assembly branch, has converged = False and NaN position and quaternion: it is never
    returned as a pose. Where numba is loaded, or for :data:`COMPILED_BATCH` poses and more in a
    process not sealed, the compiled kernel runs; otherwise its Python source, uncompiled (the
    same operations; a node solves one pose at a time and never loads numba).
    """
    lengths_arr = as_vectors(lengths, 3, 'lengths')
    thetas_arr = as_vectors(thetas, 3, 'thetas')
    n = lengths_arr.shape[0]
    if thetas_arr.shape[0] != n:
        raise InputError(f'lengths has {n} rows but thetas has {thetas_arr.shape[0]}')
    if np.any(lengths_arr <= 0.0):
        i = int(np.flatnonzero((lengths_arr <= 0.0).any(axis=1))[0])
        raise InputError(f'lengths[{i}] = {lengths_arr[i].tolist()}: leg lengths must be > 0 m')
    if not (np.isfinite(tolerance) and tolerance > 0.0):
        raise InputError(f'tolerance = {tolerance!r}: must be a finite number > 0 m')
    if max_iterations < 1:
        raise InputError(f'max_iterations = {max_iterations}: must be >= 1')
    if phi0 is None:
        start = _home_phis(mech)[None]
    else:
        start = as_vectors(phi0, 3, 'phi0')
        if start.shape[0] not in (1, n):
            raise InputError(f'phi0 has {start.shape[0]} rows, expected 1 or {n}')
    constants = _closure_constants(mech)
    phis = np.empty((n, 3))
    position = np.empty((n, 3))
    rot = np.empty((n, 3, 3))
    converged = np.empty(n, dtype=bool)
    compiled_run = compiled.loaded() or (n >= COMPILED_BATCH and not compiled.sealed())
    solve = _forward_kernel if compiled_run else compiled.source(_forward_kernel)
    solve(kernel_array(lengths_arr), kernel_array(thetas_arr), kernel_array(start), *constants,
          float(tolerance), int(max_iterations), phis, position, rot, converged)
    if converged.all():
        quaternion = quaternion_from_matrix(rot, orthonormal=True)
    else:
        quaternion = np.full((n, 4), np.nan)
        quaternion[converged] = quaternion_from_matrix(rot[converged], orthonormal=True)
    return ForwardResult(position, quaternion, phis, converged)


def warm_up() -> None:
    """Load numba and compile the forward-kinematics kernel now, or load it from numba's
    on-disk cache (several seconds the first time on a machine, about 0.3 s after): ``make
    setup`` fills the cache this way, and batch work may call it before it is timed. Nodes do
    not: they run :func:`forward` uncompiled, one pose at a time."""
    compiled.load()  # numba loaded: forward() takes the kernel from here on, for any batch
    mech = Mechanism.default()
    home = _inverse_validated(mech, mech.home_position[None], mech.home_quaternion[None])
    forward(mech, home.lengths, home.thetas)


@functools.lru_cache(maxsize=64)
def _closure_constants(mech: Mechanism) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray,
                                                  FloatArray, FloatArray]:
    """What the forward kernel needs of a mechanism, as contiguous arrays: A_i, e_r,i, e_t,i
    (3, 3) m and unit, squared platform side lengths |b_i − b_{i+1}|² (3,) m², and the
    centroid (3,) m and frame (3, 3) of the platform's S-joint triangle."""
    b = mech.platform_joints
    side_sq = np.sum((b - np.roll(b, -1, axis=0)) ** 2, axis=1)
    body_centroid, body_frame = (a[0] for a in _triangle_frames(b[None]))
    base, radial, tangential, body_centroid, body_frame = (
        kernel_array(a) for a in (mech.base_joints, mech.radial, mech.tangential, body_centroid,
                                  body_frame))
    return base, radial, tangential, side_sq, body_centroid, body_frame


def _triangle_frames(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Centroids (N, 3) and orthonormal frames (N, 3, 3) (columns x, y, z) of N triangles
    (N, 3, 3) m: x along P3 − P2, y toward P1 in the triangle's plane (seed 000 eqs. 15-18;
    per triangle inside :func:`_forward_kernel`)."""
    centroid = points.mean(axis=1)
    x = points[:, 2] - points[:, 1]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    v = points[:, 0] - centroid
    y = v - np.sum(v * x, axis=1, keepdims=True) * x
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    return centroid, np.stack([x, y, cross(x, y)], axis=2)


@kernel
def _forward_kernel(lengths: FloatArray, thetas: FloatArray, start: FloatArray,
                    base: FloatArray, radial: FloatArray, tangential: FloatArray,
                    side_sq: FloatArray, body_centroid: FloatArray, body_frame: FloatArray,
                    tolerance: float, max_iterations: int, phis: FloatArray,
                    position: FloatArray, rot: FloatArray, converged: BoolArray) -> None:
    """Forward kinematics of N poses into ``phis`` (N, 3), ``position`` (N, 3), ``rot``
    (N, 3, 3), ``converged`` (N,); ``start`` holds one or N rows of starting φ (rad)."""
    n = lengths.shape[0]
    one_start = start.shape[0] == 1
    tau, w, lc, lcc, lcs = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    fixed, points = np.empty((3, 3)), np.empty((3, 3))
    residual, limit, a, c = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    centroid, frame = np.empty(3), np.empty((3, 3))
    for k in range(3):
        limit[k] = 2.0 * np.sqrt(side_sq[k]) * tolerance
    tau_start = np.tan(0.5 * start[0])
    for s in range(n):
        if not one_start:
            for i in range(3):
                tau_start[i] = np.tan(0.5 * start[s, i])
        # The unknown is the half-angle tangent τ = tan(φ/2): cos φ and sin φ are rational in τ,
        # no trigonometry inside the iteration. B_i = A_i + l sinθ e_t + l cosθ (sinφ e_r +
        # cosφ e_z) (docs/conventions/kinematics.md); the first two terms do not change while
        # iterating.
        for i in range(3):
            tau[i] = tau_start[i]
            lc[i] = lengths[s, i] * np.cos(thetas[s, i])
            ls = lengths[s, i] * np.sin(thetas[s, i])
            for x in range(3):
                fixed[i, x] = base[i, x] + ls * tangential[i, x]
        solved = False
        for iteration in range(max_iterations + 1):
            for i in range(3):
                t2 = tau[i] * tau[i]
                w[i] = 1.0 / (1.0 + t2)  # dφ/dτ = 2w
                lw = lc[i] * w[i]
                lcc[i] = lw - lw * t2  # l cosθ cos φ
                lcs[i] = 2.0 * tau[i] * lw  # l cosθ sin φ
                for x in range(3):
                    points[i, x] = fixed[i, x] + lcs[i] * radial[i, x]
                points[i, 2] += lcc[i]
            solved = True
            for k in range(3):
                j = (k + 1) % 3
                dx = points[k, 0] - points[j, 0]
                dy = points[k, 1] - points[j, 1]
                dz = points[k, 2] - points[j, 2]
                residual[k] = dx * dx + dy * dy + dz * dz - side_sq[k]
                solved = solved and abs(residual[k]) <= limit[k]
                # Jacobian row k of the closure (seed 000 eq. 14): +a_k at column k, −c_k at
                # column k+1, a_k = 2 D_k·∂B_k/∂τ_k, c_k = 2 D_k·∂B_{k+1}/∂τ_{k+1}, D_k = B_k −
                # B_{k+1}, ∂B_i/∂τ_i = (l cosθ cos φ e_r − l cosθ sin φ e_z)·2/(1 + τ_i²).
                a[k] = 4.0 * w[k] * (
                    lcc[k] * (dx * radial[k, 0] + dy * radial[k, 1] + dz * radial[k, 2])
                    - lcs[k] * dz)
                c[k] = 4.0 * w[j] * (
                    lcc[j] * (dx * radial[j, 0] + dy * radial[j, 1] + dz * radial[j, 2])
                    - lcs[j] * dz)
            if solved or iteration == max_iterations:
                break
            # a_k x_k − c_k x_{k+1} = −residual_k, k cyclic: closed form (Cramer's rule).
            inv_det = 1.0 / (a[0] * a[1] * a[2] - c[0] * c[1] * c[2])
            r0, r1, r2 = -residual[0], -residual[1], -residual[2]
            step0 = (r0 * a[1] * a[2] + c[0] * r1 * a[2] + c[0] * c[1] * r2) * inv_det
            step1 = (r1 * a[2] * a[0] + c[1] * r2 * a[0] + c[1] * c[2] * r0) * inv_det
            step2 = (r2 * a[0] * a[1] + c[2] * r0 * a[1] + c[2] * c[0] * r1) * inv_det
            # Bounded steps keep the iteration on the branch it starts on; a NaN step (singular
            # Jacobian) or |φ| beyond π/2 ends it unsolved.
            tau[0] += min(max(step0, -_MAX_STEP), _MAX_STEP)
            tau[1] += min(max(step1, -_MAX_STEP), _MAX_STEP)
            tau[2] += min(max(step2, -_MAX_STEP), _MAX_STEP)
            if not (abs(tau[0]) < 1.0 and abs(tau[1]) < 1.0 and abs(tau[2]) < 1.0):
                break
        for i in range(3):
            phis[s, i] = 2.0 * np.arctan(tau[i])
        if solved:
            # Centroid and frame (columns x, y, z) of the S-joint triangle: x along P3 − P2, y
            # toward P1 in its plane (seed 000 eqs. 15-18; :func:`_triangle_frames`), inline so
            # that the kernel calls no other and its Python source runs without numba.
            for i in range(3):
                centroid[i] = (points[0, i] + points[1, i] + points[2, i]) / 3.0
            x0 = points[2, 0] - points[1, 0]
            x1 = points[2, 1] - points[1, 1]
            x2 = points[2, 2] - points[1, 2]
            norm = np.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
            x0, x1, x2 = x0 / norm, x1 / norm, x2 / norm
            v0 = points[0, 0] - centroid[0]
            v1 = points[0, 1] - centroid[1]
            v2 = points[0, 2] - centroid[2]
            along = v0 * x0 + v1 * x1 + v2 * x2
            y0, y1, y2 = v0 - along * x0, v1 - along * x1, v2 - along * x2
            norm = np.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
            y0, y1, y2 = y0 / norm, y1 / norm, y2 / norm
            frame[0, 0], frame[1, 0], frame[2, 0] = x0, x1, x2
            frame[0, 1], frame[1, 1], frame[2, 1] = y0, y1, y2
            frame[0, 2] = x1 * y2 - x2 * y1
            frame[1, 2] = x2 * y0 - x0 * y2
            frame[2, 2] = x0 * y1 - x1 * y0
            # R = F_base·F_bodyᵀ maps the body triangle's frame onto the base one; p = c − R·c_b.
            for x in range(3):
                for y in range(3):
                    rot[s, x, y] = (frame[x, 0] * body_frame[y, 0]
                                    + frame[x, 1] * body_frame[y, 1]
                                    + frame[x, 2] * body_frame[y, 2])
            for x in range(3):
                position[s, x] = centroid[x] - (rot[s, x, 0] * body_centroid[0]
                                                + rot[s, x, 1] * body_centroid[1]
                                                + rot[s, x, 2] * body_centroid[2])
            # The closure fixes the triangle up to a mirror image: keep the branch whose
            # platform normal points away from the base, as at home.
            solved = rot[s, 2, 2] > 0.0
        converged[s] = solved
        if not solved:
            position[s] = np.nan
            rot[s] = np.nan


def inverse_jacobian(mech: Mechanism, position: ArrayLike,
                     quaternion: ArrayLike) -> FloatArray:
    """(N, 6, 6) map from platform twist (v m/s, ω rad/s; base frame) to actuated rates.

    Row l_i: [u_iᵀ, (r_i × u_i)ᵀ] with r_i = R b_i; row θ_i: [w_iᵀ, (r_i × w_i)ᵀ] with
    w_i = (I − u_i u_iᵀ) e_t,i / (l_i cos θ_i), from differentiating θ_i = asin(u_i · e_t,i).
    """
    p, q = as_pose_batch(position, quaternion)
    return _inverse_jacobian(mech, p, q)


def _inverse_jacobian(mech: Mechanism, p: FloatArray, q: FloatArray) -> FloatArray:
    points = platform_points(mech, p, q)
    r = points - p[:, None, :]
    d = points - mech.base_joints
    lengths = np.linalg.norm(d, axis=2)
    u = d / lengths[..., None]
    ut = np.einsum('nkj,kj->nk', u, mech.tangential)
    cos_theta = np.sqrt(np.clip(1.0 - ut**2, 0.0, None))
    w = (mech.tangential - ut[..., None] * u) / (lengths * cos_theta)[..., None]
    rows_l = np.concatenate([u, cross(r, u)], axis=2)
    rows_t = np.concatenate([w, cross(r, w)], axis=2)
    return np.concatenate([rows_l, rows_t], axis=1)


def conditioning(mech: Mechanism, inverse_jac: FloatArray) -> FloatArray:
    """Reciprocal condition number (N,) of inverse Jacobians (N, 6, 6), rotations scaled by R_B."""
    scale = np.array([1.0, 1.0, 1.0] + [mech.characteristic_length] * 3)
    scaled = scale[:, None] * inverse_jac / scale[None, :]
    sv = np.linalg.svd(scaled, compute_uv=False)
    return sv[:, -1] / sv[:, 0]


def jacobian(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike) -> JacobianResult:
    """Velocity Jacobian (N, 6, 6) at poses, and its conditioning (see :class:`JacobianResult`).

    Near a singularity the matrix is ill-conditioned or infinite; callers refuse poses whose
    conditioning is below ``Mechanism.min_conditioning``.
    """
    p, q = as_pose_batch(position, quaternion)
    jinv = _inverse_jacobian(mech, p, q)
    cond = conditioning(mech, jinv)
    matrix = np.full_like(jinv, np.inf)
    ok = cond > 1e-12
    matrix[ok] = np.linalg.inv(jinv[ok])
    return JacobianResult(matrix, cond)
