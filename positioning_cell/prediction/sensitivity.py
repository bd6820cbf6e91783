"""First-order sensitivity of the platform pose to the error sources (seed 004 eqs. 7-15).

Closure equations (the seed's closed vector loops, eq. 5), one per leg, base frame:

    h_i = p + R·b_i − A_i − l_i·u_i(φ_i, θ_i) = 0,   i = 1, 2, 3   (9 scalar equations)

The "assembly dimensions" u of the seed are the pose deviation (δp, δρ) and the passive angles
δφ (9 unknowns); R = R_nom·exp([δρ]×), so δρ is the rotation vector of R_nomᵀ·R, as
:func:`positioning_cell.core.poses.pose_error` gives. The open loop (eq. 6) is the pose itself,
Gap = (δp, δρ), so C = 0 and D = [I₆ 0]. With U = ∂h/∂(δp, δρ, δφ) and A = ∂h/∂x the sources,
eq. (14) gives T = C − D·U⁻¹·A = −[I₆ 0]·U⁻¹·A, a (6 × S) matrix: rows δp_x, δp_y, δp_z (m) and
δρ_x, δρ_y, δρ_z (rad), columns the sources (m or rad) of :mod:`.sources`.

A is built in two steps: ∂h/∂(24 primitive perturbations) — δl (3), δθ (3), δA_i (9, base
frame), δb_i (9, platform frame) — times the map from sources to primitives (clearances enter
as gap connectors along their direction, :class:`.sources.GapModel`, or, in the ``any`` model,
as the three components of the joint's offset vector, like a joint-centre error).

Worst case (eq. 15) over box sources |x_i| ≤ t_i and, in the ``any`` model, clearance balls
|e_j| ≤ r_j: per pose coordinate c, max (T·x)_c = Σ_i |T_ci|·t_i + Σ_j r_j·‖T_c,j‖₂ (T_c,j the
three columns of ball j), exact for the linear model (:func:`worst_case`); the largest |Δp| and
rotation angle over the same set: :func:`positioning_cell.prediction.extremes.worst_norm`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.kinematics import inverse, leg_directions
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, matrix_from_quaternion
from positioning_cell.prediction.sources import GapModel, ToleranceSpec
from positioning_cell.tolerance.linear import sensitivity
from positioning_cell.tolerance.stackup import root_sum_square, worst_case

FloatArray = NDArray[np.float64]

#: Primitive perturbations: leg lengths, θ, U centres (base), S centres (platform).
N_PRIMITIVES = 24
_L, _T, _A, _B = 0, 3, 6, 15
#: Pose-coordinate labels, the rows of T.
COORDINATES = ('x', 'y', 'z', 'rx', 'ry', 'rz')
#: The closure's equations (rows of U): leg i's x, y, z; and its unknowns (columns).
CLOSURE_EQUATIONS = tuple(f'leg {i} {c}' for i in (1, 2, 3) for c in 'xyz')
CLOSURE_UNKNOWNS = (*(f'd{c}' for c in COORDINATES), 'dphi1', 'dphi2', 'dphi3')

__all__ = ['COORDINATES', 'Linearisation', 'closure_jacobians', 'gap_directions',
           'kind_variances', 'linearise', 'root_sum_square', 'skew', 'source_map',
           'split_norms', 'worst_case']
_EZ = np.array([0.0, 0.0, 1.0])


class Linearisation(NamedTuple):
    """The first-order model at N poses.

    position (N, 3) m, quaternion (N, 4) x, y, z, w (nominal poses); closure (N, 9, 9) = U,
    ∂h/∂(δp, δρ, δφ); primitives (N, 9, 24) = ∂h/∂(δl, δθ, δA, δb); source_map (N, 24, S);
    matrix (N, 6, S) = T, seed 004 eq. (14), in m/m, m/rad, rad/m, rad/rad.
    """

    position: FloatArray
    quaternion: FloatArray
    closure: FloatArray
    primitives: FloatArray
    source_map: FloatArray
    matrix: FloatArray


def skew(v: FloatArray) -> FloatArray:
    """Cross-product matrices [v]× (..., 3, 3) of vectors (..., 3)."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1),
                     np.stack([-y, x, z], -1)], -2)


def gap_directions(mech: Mechanism, gap: GapModel, position: FloatArray,
                   quaternion: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Unit gap-connector directions of the U and S joints (N, 3 legs, 3), base frame, at
    validated poses (N, 3) m, (N, 4); see :class:`.sources.GapModel` (seed 004 eqs. 2-3). The
    ``any`` model has no fixed direction: the leg axis is returned (unused by its sources)."""
    joints = inverse(mech, position, quaternion)
    u = leg_directions(mech, joints.phis, joints.thetas)
    if gap.mode != 'motion':
        return u, u
    rot = matrix_from_quaternion(quaternion)
    r = np.einsum('nij,kj->nki', rot, mech.platform_joints)
    twist = np.asarray(gap.twist)
    v_ball = twist[:3] + np.cross(twist[3:], r)
    v_normal = v_ball - np.sum(v_ball * u, axis=-1, keepdims=True) * u
    return _unit_or(v_normal, u), _unit_or(v_ball, u)


def _unit_or(v: FloatArray, fallback: FloatArray) -> FloatArray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    small = norm < 1e-9 * max(1.0, float(np.max(norm, initial=0.0)))
    out: FloatArray = np.where(small, fallback, v / np.where(small, 1.0, norm))
    return out


def closure_jacobians(mech: Mechanism, position: FloatArray,
                      quaternion: FloatArray) -> tuple[FloatArray, FloatArray]:
    """U = ∂h/∂(δp, δρ, δφ) (N, 9, 9) and ∂h/∂(δl, δθ, δA, δb) (N, 9, 24) of the closure
    equations at validated poses (seed 004 eq. 9, [A][δx] + [U][δu] = 0)."""
    joints = inverse(mech, position, quaternion)
    n = position.shape[0]
    ct, st = np.cos(joints.thetas)[..., None], np.sin(joints.thetas)[..., None]
    cp, sp = np.cos(joints.phis)[..., None], np.sin(joints.phis)[..., None]
    du_dphi = ct * (cp * mech.radial - sp * _EZ)
    du_dtheta = -st * (sp * mech.radial + cp * _EZ) + ct * mech.tangential
    u = leg_directions(mech, joints.phis, joints.thetas)
    lengths = joints.lengths[..., None]
    rot = matrix_from_quaternion(quaternion)
    closure = np.zeros((n, 9, 9))
    prim = np.zeros((n, 9, N_PRIMITIVES))
    eye = np.eye(3)
    for i in range(3):
        rows = slice(3 * i, 3 * i + 3)
        closure[:, rows, 0:3] = eye
        closure[:, rows, 3:6] = -rot @ skew(mech.platform_joints[i])
        closure[:, rows, 6 + i] = -lengths[:, i] * du_dphi[:, i]
        prim[:, rows, _L + i] = -u[:, i]
        prim[:, rows, _T + i] = -lengths[:, i] * du_dtheta[:, i]
        prim[:, rows, _A + 3 * i:_A + 3 * i + 3] = -eye
        prim[:, rows, _B + 3 * i:_B + 3 * i + 3] = rot
    return closure, prim


def source_map(spec: ToleranceSpec, rotation: FloatArray, gap_u: FloatArray,
               gap_s: FloatArray) -> FloatArray:
    """Map (N, 24, S) from sources to primitive perturbations (δl, δθ, δA base, δb platform)
    at poses with rotations (N, 3, 3) and gap directions (N, 3 legs, 3) in the base frame.
    A clearance component (``any`` model: ``axis`` set) is one coordinate of δA_i (base) or
    δb_i (platform), as :class:`positioning_cell.clearance.VectorClearance` offsets."""
    n = rotation.shape[0]
    out = np.zeros((n, N_PRIMITIVES, len(spec.sources)))
    gap_s_platform = np.einsum('nji,nkj->nki', rotation, gap_s)
    for j, src in enumerate(spec.sources):
        i = src.leg - 1
        axis = 'xyz'.index(src.axis) if src.axis else 0
        if src.kind in ('leg_length', 'encoder_length'):
            out[:, _L + i, j] = 1.0
        elif src.kind == 'encoder_theta':
            out[:, _T + i, j] = 1.0
        elif src.kind == 'u_centre' or (src.kind == 'u_clearance' and src.axis):
            out[:, _A + 3 * i + axis, j] = 1.0
        elif src.kind == 's_centre' or (src.kind == 's_clearance' and src.axis):
            out[:, _B + 3 * i + axis, j] = 1.0
        elif src.kind == 'u_clearance':
            out[:, _A + 3 * i:_A + 3 * i + 3, j] = gap_u[:, i]
        else:  # s_clearance: the ball centre moves by x·d (base) = x·Rᵀd in the platform
            out[:, _B + 3 * i:_B + 3 * i + 3, j] = gap_s_platform[:, i]
    return out


def linearise(mech: Mechanism, spec: ToleranceSpec, position: ArrayLike,
              quaternion: ArrayLike) -> Linearisation:
    """Sensitivity T = −[I₆ 0]·U⁻¹·A (seed 004 eq. 14) at poses (N, 3) m, (N, 4) x, y, z, w.

    Columns follow ``spec.sources``; rows :data:`COORDINATES`. Raises InputError for malformed
    poses, and SingularLoopsError (an InputError) where U is singular or ill-conditioned (a
    singular pose of the mechanism).
    """
    p, q = as_pose_batch(position, quaternion)
    closure, prim = closure_jacobians(mech, p, q)
    gap_u, gap_s = gap_directions(mech, spec.gap, p, q)
    smap = source_map(spec, matrix_from_quaternion(q), gap_u, gap_s)
    n, sources = p.shape[0], len(spec.sources)
    # The open loop is the pose itself: Gap = (δp, δρ), C = 0, D = [I₆ 0].
    gap_of_unknowns = np.broadcast_to(np.eye(6, 9), (n, 6, 9))
    matrix = sensitivity(prim @ smap, closure, np.zeros((n, 6, sources)), gap_of_unknowns,
                         equations=CLOSURE_EQUATIONS, unknowns=CLOSURE_UNKNOWNS)
    return Linearisation(p, q, closure, prim, smap, matrix)


def split_norms(per_coordinate: FloatArray) -> FloatArray:
    """(..., 6) per-coordinate values → (..., 2): Euclidean norm of the position part (m) and of
    the rotation part (rad). Of worst cases, an upper bound of the worst |Δp| and angle."""
    out: FloatArray = np.stack([np.linalg.norm(per_coordinate[..., :3], axis=-1),
                                np.linalg.norm(per_coordinate[..., 3:], axis=-1)], axis=-1)
    return out


def kind_variances(matrix: FloatArray, spec: ToleranceSpec) -> tuple[tuple[str, ...], FloatArray]:
    """Variance each kind of source adds to |Δp|² (m²) and to |δρ|² (rad²) under the linear
    model: (kinds, (..., 2, K))."""
    kinds = tuple(dict.fromkeys(spec.kinds))
    contrib = (matrix * spec.stds) ** 2
    pos, rot = contrib[..., :3, :].sum(axis=-2), contrib[..., 3:, :].sum(axis=-2)
    member = np.array([[k == kind for k in spec.kinds] for kind in kinds], dtype=float)
    return kinds, np.stack([pos @ member.T, rot @ member.T], axis=-2)
