"""Pose batches: validation at the library boundary and rotation conversions.

A pose is (p, q): position in the base frame (m) and unit quaternion x, y, z, w. Batches are
(N, 3) and (N, 4); a single pose (3,), (4,) is promoted to N = 1.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation, Slerp

FloatArray = NDArray[np.float64]
#: Rotations as three angles about the fixed axes x, then y, then z: R = Rz·Ry·Rx (scipy's
#: extrinsic 'xyz'); ISO 9283's a, b, c and the operator's Rx, Ry, Rz.
EULER_SEQUENCE = 'xyz'
Triple = tuple[float, float, float]
Quad = tuple[float, float, float, float]

#: Largest accepted | |q| − 1 |; within it the quaternion is normalised.
QUATERNION_UNIT_TOLERANCE = 1e-6


def scipy_rotation() -> type[Rotation]:
    """scipy's :class:`~scipy.spatial.transform.Rotation`, imported at the first call, by
    every module that rotates: importing scipy.spatial loads its k-d tree, qhull, distance and
    sparse modules too, ~0.2 s of a node's 0.6-0.9 s start (issue 24), which the recorder and
    the bag player never need; the other nodes import it in a thread of its own as they start
    to spin, so that no callback pauses for a whole import
    (positioning_cell.ros.spin.SCIPY_MODULES)."""
    from scipy.spatial.transform import Rotation

    rotation_class: type[Rotation] = Rotation  # scipy is untyped here: Any
    return rotation_class


def scipy_slerp() -> type[Slerp]:
    """scipy's :class:`~scipy.spatial.transform.Slerp`, imported at the first call (see
    :func:`scipy_rotation`)."""
    from scipy.spatial.transform import Slerp

    slerp_class: type[Slerp] = Slerp
    return slerp_class


def as_number(value: object, name: str) -> float:
    """``value`` as a float; InputError ``'<name> = <value>: expected a number'`` for a bool,
    text or anything else float() refuses (range and finiteness are the caller's rule)."""
    if isinstance(value, bool):
        raise InputError(f'{name} = {value!r}: expected a number')
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as err:
        raise InputError(f'{name} = {value!r}: expected a number') from err


def as_vectors(value: ArrayLike, width: int, name: str, *, finite: bool = True) -> FloatArray:
    """``value`` as a float array (N, width), every value finite unless ``finite`` is False;
    a single (width,) row becomes N = 1."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise InputError(f'{name}: expected numbers, got {value!r}') from err
    if arr.ndim == 1:
        arr = arr[np.newaxis]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise InputError(
            f'{name}: expected shape ({width},) or (N, {width}), got {np.shape(value)}')
    bad = ~np.isfinite(arr).all(axis=1) if finite else np.zeros(0, dtype=bool)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f'{name}[{i}] = {arr[i].tolist()} is not finite (NaN or infinite)')
    return arr


def as_unit_quaternions(quaternion: ArrayLike, name: str = 'quaternion') -> FloatArray:
    """Quaternions (N, 4) x, y, z, w, normalised; zero or off unit length by > 1e-6 raise."""
    q = as_vectors(quaternion, 4, name)
    norm = np.linalg.norm(q, axis=1)
    off = np.abs(norm - 1.0) > QUATERNION_UNIT_TOLERANCE
    if off.any():
        i = int(np.flatnonzero(off)[0])
        what = 'is zero' if norm[i] == 0.0 else f'has norm {norm[i]:.9g}, not 1 (tolerance 1e-6)'
        raise InputError(f'{name}[{i}] = {q[i].tolist()} {what}')
    unit: FloatArray = q / norm[:, np.newaxis]
    return unit


def as_pose_batch(position: ArrayLike, quaternion: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Validated (N, 3) positions (m) and (N, 4) unit quaternions of equal N."""
    p = as_vectors(position, 3, 'position')
    q = as_unit_quaternions(quaternion)
    if p.shape[0] != q.shape[0]:
        raise InputError(f'position has {p.shape[0]} poses but quaternion has {q.shape[0]}')
    return p, q


def matrix_from_quaternion(quaternion: FloatArray) -> FloatArray:
    """Rotation matrices (N, 3, 3) from quaternions (N, 4) x, y, z, w, normalised as scipy's
    ``Rotation.from_quat(q).as_matrix()`` does (R = I + 2w[v]ₓ + 2[v]ₓ² over |q|², the
    Euler-Rodrigues form). Elementwise numpy, not scipy: every node's build computes a pose
    (the leg driver's and the positioner's inverse kinematics, the tracker's registration),
    and scipy.spatial would cost each ~0.2 s of its start (issue 24); test_kinematics checks it
    against scipy. One quaternion (the nodes' case: the simulated machine's truth calls this
    ~80 times per pose) in Python floats: the same operations in the same order, so the same
    values to the bit, in 5 µs instead of 44."""
    q = np.asarray(quaternion, dtype=float)
    if q.size == 4:
        x, y, z, w = q.ravel().tolist()
        s = 2.0 / (x * x + y * y + z * z + w * w)
        return np.array([1.0 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w),
                         s * (x * y + z * w), 1.0 - s * (x * x + z * z), s * (y * z - x * w),
                         s * (x * z - y * w), s * (y * z + x * w), 1.0 - s * (x * x + y * y)]
                        ).reshape(q.shape[:-1] + (3, 3))
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    s = 2.0 / (x * x + y * y + z * z + w * w)
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1.0 - s * (y * y + z * z)
    out[..., 0, 1] = s * (x * y - z * w)
    out[..., 0, 2] = s * (x * z + y * w)
    out[..., 1, 0] = s * (x * y + z * w)
    out[..., 1, 1] = 1.0 - s * (x * x + z * z)
    out[..., 1, 2] = s * (y * z - x * w)
    out[..., 2, 0] = s * (x * z - y * w)
    out[..., 2, 1] = s * (y * z + x * w)
    out[..., 2, 2] = 1.0 - s * (x * x + y * y)
    return out


def quaternion_from_euler_xyz(angles: FloatArray) -> FloatArray:
    """Quaternions (N, 4) x, y, z, w of R = Rz(γ)·Ry(β)·Rx(α) from angles (N, 3) α, β, γ rad
    (extrinsic x, y, z, :data:`EULER_SEQUENCE`: scipy's ``Rotation.from_euler('xyz',
    angles).as_quat()``), as the product q_z ⊗ q_y ⊗ q_x of the half-angle quaternions
    written out. Elementwise numpy, not scipy, for the positioner's build (its factory box),
    where scipy.spatial would cost ~0.2 s of its start (issue 24); test_kinematics checks it
    against scipy."""
    half = 0.5 * np.asarray(angles, dtype=float)
    c, s = np.cos(half), np.sin(half)
    cx, cy, cz = c[..., 0], c[..., 1], c[..., 2]
    sx, sy, sz = s[..., 0], s[..., 1], s[..., 2]
    return np.stack([sx * cy * cz - cx * sy * sz,
                     cx * sy * cz + sx * cy * sz,
                     cx * cy * sz - sx * sy * cz,
                     cx * cy * cz + sx * sy * sz], axis=-1)


#: How close (rad) the middle angle of :func:`euler_xyz_from_quaternion` may come to ±π/2
#: before the rotation is taken as gimbal-locked (scipy's threshold).
GIMBAL_LOCK = 1e-7


def euler_xyz_from_quaternion(quaternion: FloatArray) -> FloatArray:
    """Angles (N, 3) α, β, γ rad of R = Rz(γ)·Ry(β)·Rx(α) (extrinsic x, y, z,
    :data:`EULER_SEQUENCE`) of quaternions (N, 4) x, y, z, w, any norm or sign: α, γ in
    [−π, π], β in [−π/2, π/2]. What scipy's ``Rotation.from_quat(q).as_euler('xyz')`` gives
    (an angle of exactly ±π may come with the other sign), by the same method: Bernardes and
    Viollet 2022, "Quaternion to Euler angles conversion: a direct, general and
    computationally efficient method", for a Tait-Bryan sequence. At gimbal lock, β within
    :data:`GIMBAL_LOCK` of ±π/2, γ = 0 and α takes the whole rotation about the locked axis,
    without scipy's warning. Elementwise numpy: the inverse of
    :func:`quaternion_from_euler_xyz` without scipy.spatial, whose import costs a command
    line ~0.3 s (``cell watch``'s first table, issue 24); test_kinematics checks it against
    scipy."""
    q = np.asarray(quaternion, dtype=float)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    # the paper's step 1 for i, j, k = x, y, z (an even permutation: sign +1)
    a, b, c, d = w - y, x + z, y + w, z - x
    middle = 2.0 * np.arctan2(np.hypot(c, d), np.hypot(a, b))  # β + π/2, in [0, π]
    half_sum, half_diff = np.arctan2(b, a), np.arctan2(d, c)
    at_zero, at_pi = np.abs(middle) <= GIMBAL_LOCK, np.abs(middle - np.pi) <= GIMBAL_LOCK
    first = np.where(at_zero, 2.0 * half_sum,
                     np.where(at_pi, -2.0 * half_diff, half_sum - half_diff))
    third = np.where(at_zero | at_pi, 0.0, half_sum + half_diff)
    angles = np.stack([first, middle - 0.5 * np.pi, third], axis=-1)
    wrapped: FloatArray = np.where(angles < -np.pi, angles + 2.0 * np.pi,
                                   np.where(angles > np.pi, angles - 2.0 * np.pi, angles))
    return wrapped


#: Up to this many matrices built orthonormal, :func:`quaternion_from_matrix` converts in numpy
#: (a node's build converts one or two: scipy.spatial would cost ~0.2 s of its start); above
#: it, in scipy (4.5× faster than this numpy form on 10⁵ matrices, ad hoc).
SMALL_BATCH = 16


def quaternion_from_matrix(matrix: FloatArray, *, orthonormal: bool = False) -> FloatArray:
    """Unit quaternions (N, 4) x, y, z, w from rotation matrices (N, 3, 3), canonical as scipy
    makes them (w > 0; w = 0: the first non-zero component > 0).

    ``orthonormal=True`` skips scipy's re-orthonormalisation for matrices built orthonormal;
    up to :data:`SMALL_BATCH` of them are converted in numpy by Shepperd's method (the
    quaternion from the largest of the trace and the diagonal, as scipy does; test_kinematics
    checks the two against each other).
    """
    m = np.asarray(matrix, dtype=float)
    if orthonormal and m.shape[:-2] and m.shape[0] <= SMALL_BATCH:
        return _quaternion_shepperd(m)
    rot = scipy_rotation().from_matrix(m, assume_valid=orthonormal)
    return np.asarray(rot.as_quat(canonical=True))


def _quaternion_shepperd(m: FloatArray) -> FloatArray:
    """Canonical unit quaternions (N, 4) of orthonormal matrices (N, 3, 3): of the four
    expressions of q (each exact for a rotation matrix), the one whose divisor, the largest
    of 1 + 2·R_ii − tr R and 1 + tr R, is largest (Shepperd 1978)."""
    m00, m01, m02 = m[:, 0, 0], m[:, 0, 1], m[:, 0, 2]
    m10, m11, m12 = m[:, 1, 0], m[:, 1, 1], m[:, 1, 2]
    m20, m21, m22 = m[:, 2, 0], m[:, 2, 1], m[:, 2, 2]
    trace = m00 + m11 + m22
    a, b, c = m10 + m01, m20 + m02, m21 + m12
    u, v, w = m21 - m12, m02 - m20, m10 - m01
    candidates = np.stack([np.stack([1 + 2 * m00 - trace, a, b, u], -1),
                           np.stack([a, 1 + 2 * m11 - trace, c, v], -1),
                           np.stack([b, c, 1 + 2 * m22 - trace, w], -1),
                           np.stack([u, v, w, 1 + trace], -1)], 1)
    choice = np.argmax(np.stack([m00, m11, m22, trace], -1), -1)
    q: FloatArray = candidates[np.arange(m.shape[0]), choice]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return _canonical(q)


def mean_quaternion(quaternion: FloatArray) -> FloatArray:
    """The chordal L2 mean (4,) x, y, z, w of unit quaternions (N, 4), canonical (w > 0; w = 0:
    the first non-zero component > 0): the eigenvector of the largest eigenvalue of the mean
    of q·qᵀ (Markley, Cheng, Crassidis and Oshman 2007, "Averaging quaternions"; either sign
    of each q gives the same mean). What scipy's ``Rotation.mean`` computes, the same way, in
    numpy: the monitor's means of tracker readings need no scipy.spatial, whose import would
    pause its callbacks for ~0.4 s (issue 24); test_kinematics checks the two against each
    other."""
    q = np.asarray(quaternion, dtype=float)
    _, vectors = np.linalg.eigh(np.einsum('ni,nj->ij', q, q) / len(q))
    mean: FloatArray = _canonical(vectors[:, -1][None])[0]
    return mean


def _canonical(q: FloatArray) -> FloatArray:
    """Quaternions (N, 4) x, y, z, w with the sign scipy's ``as_quat(canonical=True)`` picks:
    the first non-zero of w, x, y, z positive."""
    ordered = q[:, [3, 0, 1, 2]]
    lead = ordered[np.arange(q.shape[0]), np.argmax(ordered != 0.0, axis=-1)]
    out: FloatArray = q * np.where(lead < 0.0, -1.0, 1.0)[:, None]
    return out


def interpolated_pose(times: ArrayLike, positions: ArrayLike, quaternions: ArrayLike,
                      t: float) -> tuple[FloatArray, FloatArray]:
    """The pose at ``t`` s of a stamped series: ``times`` (M,) s increasing, ``positions``
    (M, 3) m, ``quaternions`` (M, 4) x, y, z, w; held at its ends. The position is linear
    between the two samples around ``t``; the quaternion their normalised linear blend (the
    shorter way round), within 1e-9 rad of the slerp for samples a control period apart."""
    p, q = interpolated_poses(times, positions, quaternions, [float(t)])
    return p[0], q[0]


def interpolated_poses(times: ArrayLike, positions: ArrayLike, quaternions: ArrayLike,
                       t: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """:func:`interpolated_pose` at each of the times ``t`` (K,) s: positions (K, 3) m and
    quaternions (K, 4)."""
    stamps = np.asarray(times, dtype=float)
    p_all, q_all = np.asarray(positions, dtype=float), np.asarray(quaternions, dtype=float)
    at = np.atleast_1d(np.asarray(t, dtype=float))
    if stamps.size == 1:
        return np.tile(p_all[0], (at.size, 1)), np.tile(q_all[0], (at.size, 1))
    at = np.clip(at, stamps[0], stamps[-1])
    k = np.clip(np.searchsorted(stamps, at, side='right') - 1, 0, stamps.size - 2)
    span = stamps[k + 1] - stamps[k]
    w = np.where(span > 0.0, (at - stamps[k]) / np.where(span > 0.0, span, 1.0), 0.0)[:, None]
    p = (1.0 - w) * p_all[k] + w * p_all[k + 1]
    q0, q1 = q_all[k], q_all[k + 1]
    q = (1.0 - w) * q0 + w * np.where((np.sum(q0 * q1, axis=1) >= 0.0)[:, None], q1, -q1)
    return p, q / np.linalg.norm(q, axis=1)[:, None]


def pose_error(position: FloatArray, quaternion: FloatArray, position_ref: FloatArray,
               quaternion_ref: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Pose minus reference: Δp (N, 3) in m, base frame; rotation vector of R_refᵀ·R (N, 3) rad.

    Either side may be one pose (1, 3), (1, 4) against N. The rotation is the quaternion
    product q_ref* ⊗ q (both normalised, x, y, z, w) as :func:`rotation_vector` takes it
    (angle in [0, π]; exact to the last bits for small angles, where |v| ≈ angle/2).
    Elementwise numpy: a row's result does not depend on the batch it is in."""
    q = np.asarray(quaternion, dtype=float)
    r = np.asarray(quaternion_ref, dtype=float)
    q = q / np.sqrt((q * q).sum(axis=-1))[..., np.newaxis]
    r = r / np.sqrt((r * r).sum(axis=-1))[..., np.newaxis]
    return (np.asarray(position, dtype=float) - np.asarray(position_ref, dtype=float),
            rotation_vector(quaternion_product(quaternion_inverse(r), q)))


# -- rotations as quaternions, in numpy ---------------------------------------------------------
# What scipy's Rotation computes for the positioner's moves, corrections and status, by the same
# formulas, so that a node rotating poses needs no scipy.spatial (its import: ~0.35 CPU-s and
# ~30 MB of every start that pays it, issue 24); test_kinematics checks each against scipy.

def quaternion_product(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Hamilton products a ⊗ b (..., 4) of quaternions (..., 4) x, y, z, w (broadcast): for
    unit ones the rotation R_a·R_b (scipy's ``Rotation.__mul__``, the same formula)."""
    p, q = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    x1, y1, z1, w1 = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    x2, y2, z2, w2 = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
                     w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2], axis=-1)


def quaternion_inverse(quaternion: ArrayLike) -> FloatArray:
    """Conjugates (..., 4) of unit quaternions (..., 4) x, y, z, w: the inverse rotations."""
    q = np.asarray(quaternion, dtype=float)
    return np.concatenate([-q[..., :3], q[..., 3:]], axis=-1)


def rotation_vector(quaternion: ArrayLike) -> FloatArray:
    """Rotation vectors (..., 3) rad (angle · unit axis, angle in [0, π]) of unit quaternions
    (..., 4) x, y, z, w, either sign: 2·atan2(|v|, w)·v/|v| with q of scipy's canonical sign
    (``as_rotvec``: w > 0; at exactly π, w = 0, the first non-zero of x, y, z positive, which
    sets the way round a slerp goes; atan2 keeps small angles exact to the last bits, where
    |v| ≈ angle/2)."""
    q = np.asarray(quaternion, dtype=float)
    v, w = q[..., :3], q[..., 3]
    sign = np.where(w < 0.0, -1.0, 1.0)
    at_pi = w == 0.0
    if at_pi.any():
        first = np.take_along_axis(v, np.argmax(v != 0.0, axis=-1)[..., None], axis=-1)[..., 0]
        sign = np.where(at_pi & (first < 0.0), -1.0, sign)
    w = w * sign
    norm = np.sqrt((v * v).sum(axis=-1))
    safe = np.where(norm > 0.0, norm, 1.0)
    scale = np.where(norm > 0.0, 2.0 * np.arctan2(norm, w) / safe, 0.0) * sign
    out: FloatArray = v * scale[..., np.newaxis]
    return out


def quaternion_from_rotation_vector(rotvec: ArrayLike) -> FloatArray:
    """Unit quaternions (..., 4) x, y, z, w (w ≥ 0 for angles up to π) of rotation vectors
    (..., 3) rad: [sin(θ/2)·v/θ, cos(θ/2)], θ = |v|, with scipy's series for θ ≤ 1e-3
    (``Rotation.from_rotvec``)."""
    v = np.asarray(rotvec, dtype=float)
    angle = np.sqrt((v * v).sum(axis=-1))
    small = angle <= 1e-3
    safe = np.where(small, 1.0, angle)
    scale = np.where(small, 0.5 - angle ** 2 / 48.0 + angle ** 4 / 3840.0,
                     np.sin(0.5 * safe) / safe)
    return np.concatenate([v * scale[..., np.newaxis], np.cos(0.5 * angle)[..., np.newaxis]],
                          axis=-1)


def rotate(quaternion: ArrayLike, vectors: ArrayLike) -> FloatArray:
    """R(q)·v (..., 3) for quaternions (..., 4) x, y, z, w and vectors (..., 3), broadcast
    (scipy's ``Rotation.apply``: the matrix of :func:`matrix_from_quaternion` times v)."""
    m = matrix_from_quaternion(np.asarray(quaternion, dtype=float))
    out: FloatArray = np.einsum('...ij,...j->...i', m, np.asarray(vectors, dtype=float))
    return out


def slerp(start: ArrayLike, end: ArrayLike, fractions: ArrayLike) -> FloatArray:
    """Quaternions (K, 4) x, y, z, w at ``fractions`` (K,) of the way from the unit quaternion
    ``start`` (4,) to ``end`` (4,), at constant angular rate about one axis, the shorter way:
    q₀ ⊗ exp(s·log(q₀* ⊗ q₁)) (scipy's ``Slerp`` between key times 0 and 1, the same
    formula)."""
    q0 = np.asarray(start, dtype=float).reshape(4)
    turn = rotation_vector(quaternion_product(quaternion_inverse(q0), end))
    s = np.asarray(fractions, dtype=float).reshape(-1, 1)
    return quaternion_product(q0, quaternion_from_rotation_vector(s * turn))


def rotation_angle(quaternion: ArrayLike) -> FloatArray:
    """Rotation angles (...,) rad in [0, π] of unit quaternions (..., 4) x, y, z, w:
    2·atan2(|v|, |w|) (scipy's ``Rotation.magnitude``)."""
    q = np.asarray(quaternion, dtype=float)
    angle: FloatArray = 2.0 * np.arctan2(np.sqrt((q[..., :3] ** 2).sum(axis=-1)),
                                         np.abs(q[..., 3]))
    return angle


def canonical_quaternions(quaternion: ArrayLike) -> FloatArray:
    """Quaternions (N, 4) x, y, z, w with scipy's canonical sign (``as_quat(canonical=True)``:
    the first non-zero of w, x, y, z positive)."""
    return _canonical(np.asarray(quaternion, dtype=float).reshape(-1, 4))


def triple(v: ArrayLike) -> Triple:
    """The first three numbers of ``v`` as a tuple of floats (a position, a vector)."""
    a = np.asarray(v, dtype=float).ravel()
    return (float(a[0]), float(a[1]), float(a[2]))


def quad(v: ArrayLike) -> Quad:
    """The first four numbers of ``v`` as a tuple of floats (a quaternion x, y, z, w)."""
    a = np.asarray(v, dtype=float).ravel()
    return (float(a[0]), float(a[1]), float(a[2]), float(a[3]))


def row_norms(d: FloatArray) -> FloatArray:
    """Euclidean norms (M,) of the rows of (M, 3): one expression wherever two code paths must
    give bit-identical figures (the batch and streaming monitor)."""
    return np.asarray(np.sqrt((d * d).sum(axis=1)))
