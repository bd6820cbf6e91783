"""Inverse and forward kinematics and the velocity Jacobian of the 3-UPS positioner.

Conventions (design/kinematics.md): leg i leaves its U-joint centre A_i along
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

from positioning_cell.errors import InputError
from positioning_cell.mechanism import Mechanism
from positioning_cell.poses import (
    as_pose_batch,
    as_vectors,
    matrix_from_quaternion,
    quaternion_from_matrix,
)

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Leg pairs (i, j) of the platform-triangle closure equations, seed 000 eq. (14).
PAIRS_I = np.array([0, 1, 2])
PAIRS_J = np.array([1, 2, 0])

#: Side-length residual (m) below which forward kinematics counts as converged.
FK_TOLERANCE = 1e-14
#: Largest Newton step in tan(φ/2): keeps the iteration on the branch it starts on.
_MAX_STEP = 0.15


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
    here: see :func:`positioning_cell.limits.check_poses`.
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
    passive φ by batched Newton with the analytic Jacobian, started from ``phi0`` ((3,) or
    (N, 3) rad; branch continuity) or from home, to ``tolerance`` in side length (m). The pose
    follows from the three B_i by an exact rigid construction. A pose that does not converge,
    or lands on the mirrored assembly branch, has converged = False and NaN position and
    quaternion: it is never returned as a pose.
    """
    lengths_arr = as_vectors(lengths, 3, 'lengths')
    thetas_arr = as_vectors(thetas, 3, 'thetas')
    n = lengths_arr.shape[0]
    if thetas_arr.shape[0] != n:
        raise InputError(f'lengths has {n} rows but thetas has {thetas_arr.shape[0]}')
    if np.any(lengths_arr <= 0.0):
        i = int(np.flatnonzero((lengths_arr <= 0.0).any(axis=1))[0])
        raise InputError(f'lengths[{i}] = {lengths_arr[i].tolist()}: leg lengths must be > 0 m')
    if phi0 is None:
        start = np.broadcast_to(_home_phis(mech), (n, 3))
    else:
        start = as_vectors(phi0, 3, 'phi0')
        if start.shape[0] not in (1, n):
            raise InputError(f'phi0 has {start.shape[0]} rows, expected 1 or {n}')
        start = np.broadcast_to(start, (n, 3))
    phis, points, converged = solve_passive_angles(
        mech, lengths_arr, thetas_arr, start, tolerance=tolerance, max_iterations=max_iterations)
    position, rot = _place(_body_frame(mech), points)
    # The closure equations fix the triangle up to a mirror image: keep the branch whose platform
    # normal points away from the base, as at home.
    with np.errstate(invalid='ignore'):
        converged &= rot[:, 2, 2] > 0.0
    quaternion = np.full((n, 4), np.nan)
    quaternion[converged] = quaternion_from_matrix(rot[converged], orthonormal=True)
    position[~converged] = np.nan
    return ForwardResult(position, quaternion, phis, converged)


def solve_passive_angles(mech: Mechanism, lengths: FloatArray, thetas: FloatArray,
                         phi_start: FloatArray, *, tolerance: float = FK_TOLERANCE,
                         max_iterations: int = 40) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Newton on the closure equations (seed 000 eq. 14) for the passive angles.

    lengths, thetas, phi_start (N, 3) in m and rad. Returns φ (N, 3) rad, the S-joint centres
    B (N, 3 legs, 3) m at that φ, and converged (N,) (side-length residual ≤ ``tolerance`` m).
    """
    side_sq = np.sum((mech.platform_joints[PAIRS_I] - mech.platform_joints[PAIRS_J]) ** 2, axis=1)
    limit = (2.0 * np.sqrt(side_sq) * tolerance)[:, None]
    side_sq = side_sq[:, None]
    n = lengths.shape[0]
    # Leg-major (3 legs, N) so that every operation runs over contiguous rows; the unknown is
    # the half-angle tangent τ = tan(φ/2), which makes cos φ and sin φ rational in τ (no trig
    # inside the loop). B_i = A_i + l sinθ e_t + l cosθ (sin φ e_r + cos φ e_z): the first two
    # terms do not change while iterating.
    tau_all = np.tan(0.5 * np.asarray(phi_start, dtype=float)).T.copy()
    lc_all = (lengths * np.cos(thetas)).T.copy()
    ls = (lengths * np.sin(thetas)).T
    erx, ery = mech.radial[:, 0, None], mech.radial[:, 1, None]
    cx_all = mech.base_joints[:, 0, None] + ls * mech.tangential[:, 0, None]
    cy_all = mech.base_joints[:, 1, None] + ls * mech.tangential[:, 1, None]
    az = mech.base_joints[:, 2, None]
    erx_j, ery_j = erx[PAIRS_J], ery[PAIRS_J]
    points = np.full((3, 3, n), np.nan)  # (xyz, leg, pose)
    converged = np.zeros(n, dtype=bool)
    active = np.arange(n)
    tau, lc, cx, cy = tau_all, lc_all, cx_all, cy_all
    for _ in range(max_iterations):
        t2 = tau * tau
        w = 1.0 / (1.0 + t2)
        lw = lc * w
        lcc = lw - lw * t2  # l cosθ cos φ
        lcs = 2.0 * tau * lw  # l cosθ sin φ
        bx = cx + lcs * erx
        by = cy + lcs * ery
        bz = az + lcc
        dx, dy, dz = bx - bx[PAIRS_J], by - by[PAIRS_J], bz - bz[PAIRS_J]
        residual = dx * dx + dy * dy + dz * dz - side_sq
        done = np.all(np.abs(residual) <= limit, axis=0)
        if done.any():
            idx = active[done]
            converged[idx] = True
            tau_all[:, idx] = tau[:, done]
            points[:, :, idx] = np.stack([bx[:, done], by[:, done], bz[:, done]])
            keep = ~done
            active = active[keep]
            if active.size == 0:
                break
            tau, lc, cx, cy, lcc, lcs, w = (v[:, keep] for v in (tau, lc, cx, cy, lcc, lcs, w))
            dx, dy, dz, residual = dx[:, keep], dy[:, keep], dz[:, keep], residual[:, keep]
        # ∂B_i/∂τ_i = (l cosθ cos φ e_r − l cosθ sin φ e_z)·dφ/dτ with dφ/dτ = 2/(1 + τ²).
        # Row k of the Jacobian holds +a_k at column k and −c_k at column k+1, where
        # a_k = 2 D_k·∂B_k and c_k = 2 D_k·∂B_{k+1}, D_k = B_k − B_{k+1}.
        w4 = 4.0 * w
        gr, gz = lcc * w4, lcs * w4
        a = gr * (dx * erx + dy * ery) - gz * dz
        c = gr[PAIRS_J] * (dx * erx_j + dy * ery_j) - gz[PAIRS_J] * dz
        step = _solve_cyclic(a, c, -residual)
        np.minimum(step, _MAX_STEP, out=step)
        np.maximum(step, -_MAX_STEP, out=step)
        tau = tau + step
        # Drop what diverged (NaN step at a singular Jacobian, or |φ| beyond π/2).
        lost = ~(np.abs(tau) < 1.0).all(axis=0)
        if lost.any():
            tau_all[:, active[lost]] = tau[:, lost]
            keep = ~lost
            active = active[keep]
            tau, lc, cx, cy = tau[:, keep], lc[:, keep], cx[:, keep], cy[:, keep]
    else:
        tau_all[:, active] = tau
    phis = 2.0 * np.arctan(tau_all.T)
    return phis, points.transpose(2, 1, 0), converged


def _solve_cyclic(a: FloatArray, c: FloatArray, r: FloatArray) -> FloatArray:
    """Solve a_k x_k − c_k x_{k+1} = r_k (k cyclic mod 3) for x, batched (3, N), closed form."""
    a0, a1, a2 = a
    c0, c1, c2 = c
    r0, r1, r2 = r
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        inv_det = 1.0 / (a0 * a1 * a2 - c0 * c1 * c2)
        x0 = (r0 * a1 * a2 + c0 * r1 * a2 + c0 * c1 * r2) * inv_det
        x1 = (r1 * a2 * a0 + c1 * r2 * a0 + c1 * c2 * r0) * inv_det
        x2 = (r2 * a0 * a1 + c2 * r0 * a1 + c2 * c0 * r1) * inv_det
    return np.stack([x0, x1, x2])


def _triangle_frame(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Centroid (..., 3) and orthonormal frame (..., 3, 3) (columns x, y, z) of three points
    (..., 3, 3): x along P3 − P2, y toward P1 in the triangle's plane."""
    centroid = points.mean(axis=-2)
    x = points[..., 2, :] - points[..., 1, :]
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    v = points[..., 0, :] - centroid
    y = v - np.sum(v * x, axis=-1, keepdims=True) * x
    y = y / np.linalg.norm(y, axis=-1, keepdims=True)
    return centroid, np.stack([x, y, np.cross(x, y)], axis=-1)


def rigid_pose_from_points(body_points: FloatArray,
                           base_points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Position (N, 3) and rotation (N, 3, 3) placing three body-frame points (3, 3) on their
    base-frame images (N, 3, 3); exact for congruent triangles (seed 000 eqs. 15-18)."""
    return _place(_triangle_frame(body_points), base_points)


@functools.lru_cache(maxsize=64)
def _body_frame(mech: Mechanism) -> tuple[FloatArray, FloatArray]:
    """Centroid and frame of the platform's S-joint triangle (constant per mechanism)."""
    return _triangle_frame(mech.platform_joints)


def _place(body: tuple[FloatArray, FloatArray],
           base_points: FloatArray) -> tuple[FloatArray, FloatArray]:
    c_body, f_body = body
    c_base, f_base = _triangle_frame(base_points)
    rot = f_base @ f_body.T
    return c_base - rot @ c_body, rot


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
    rows_l = np.concatenate([u, np.cross(r, u)], axis=2)
    rows_t = np.concatenate([w, np.cross(r, w)], axis=2)
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
