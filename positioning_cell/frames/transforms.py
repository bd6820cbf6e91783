"""Rigid transforms and the six-number form of a pose.

A :class:`Transform` T_a_b is the pose of frame b in frame a: position ``p`` (3,) m of b's
origin in a, rotation ``R`` (3, 3) whose columns are b's axes in a; it maps b coordinates to
a coordinates, x_a = R·x_b + p, and composes as T_a_c = T_a_b @ T_b_c.

Six numbers for a pose (Symétrie controller semantics): Tx, Ty, Tz, Rx, Ry, Rz with
R = Rz(Rz)·Ry(Ry)·Rx(Rx), rotations about the fixed axes x, then y, then z (scipy's extrinsic
``'xyz'``; the ISO 9283 angles a, b, c of :mod:`positioning_cell.accuracy.iso9283`). Two unit
systems: ``pose6`` is SI (m, rad), the one on the wire and in the library; ``human`` is mm and
degrees, the one for people (CLI, reports). Angles come back as Rx, Rz in [−π, π],
Ry in [−π/2, π/2]; at Ry = ±π/2 (gimbal lock) only Rx ∓ Rz is defined and Rz is set to 0.
Conversions are vectorised over leading axes: (..., 6) ↔ (..., 3), (..., 4); quaternions are
x, y, z, w and come back with w ≥ 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell.core.poses import (
    EULER_SEQUENCE,
    FloatArray,
    as_pose_batch,
    as_unit_quaternions,
    as_vectors,
    canonical_quaternions,
    euler_xyz_from_quaternion,
    matrix_from_quaternion,
    quaternion_from_euler_xyz,
    quaternion_from_matrix,
    quaternion_product,
    rotation_angle,
)
from positioning_cell.errors import InputError

#: Millimetres per metre: the translation of the human form.
MM_PER_M = 1000.0
#: Largest accepted deviation of RᵀR from the identity (and of det R from 1).
ROTATION_TOLERANCE = 1e-9

__all__ = [
    'EULER_SEQUENCE',
    'MM_PER_M',
    'ROTATION_TOLERANCE',
    'Transform',
    'compose_poses',
    'distance',
    'format_human',
    'human_from_pose6',
    'pose6_from_human',
    'pose6_from_pq',
    'pq_from_pose6',
]


# -- validation of (..., width) batches ----------------------------------------------------------
def _as_last(value: ArrayLike, width: int, name: str) -> FloatArray:
    """``value`` as a finite float array (..., width) of its own shape; InputError otherwise."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise InputError(f'{name}: expected numbers, got {value!r}') from err
    if arr.ndim == 0 or arr.shape[-1] != width:
        raise InputError(f'{name}: expected shape (..., {width}), got {arr.shape}')
    return as_vectors(arr.reshape(-1, width), width, name).reshape(arr.shape)


def _as_quaternions(value: ArrayLike, name: str) -> FloatArray:
    """Unit quaternions (..., 4) x, y, z, w, normalised (InputError as as_unit_quaternions)."""
    arr = _as_last(value, 4, name)
    return as_unit_quaternions(arr.reshape(-1, 4), name).reshape(arr.shape)


# -- six numbers ---------------------------------------------------------------------------------
def pose6_from_pq(position: ArrayLike, quaternion: ArrayLike) -> FloatArray:
    """SI six numbers (..., 6): tx, ty, tz m and rx, ry, rz rad (R = Rz·Ry·Rx) of poses
    ``position`` (..., 3) m and unit ``quaternion`` (..., 4) x, y, z, w (same leading shape)."""
    p = _as_last(position, 3, 'position')
    q = _as_quaternions(quaternion, 'quaternion')
    if p.shape[:-1] != q.shape[:-1]:
        raise InputError(f'position {p.shape} and quaternion {q.shape} differ in batch shape')
    angles = euler_xyz_from_quaternion(q.reshape(-1, 4)).reshape(p.shape)
    return np.concatenate([p, angles], axis=-1)


def pq_from_pose6(pose6: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Positions (..., 3) m and unit quaternions (..., 4) x, y, z, w (w ≥ 0) of SI six numbers
    (..., 6): tx, ty, tz m and rx, ry, rz rad (R = Rz·Ry·Rx)."""
    v = _as_last(pose6, 6, 'pose6')
    q = canonical_quaternions(quaternion_from_euler_xyz(v.reshape(-1, 6)[:, 3:]))
    return v[..., :3].copy(), q.reshape(v.shape[:-1] + (4,))


def human_from_pose6(pose6: ArrayLike) -> FloatArray:
    """Human six numbers (..., 6): Tx, Ty, Tz mm and Rx, Ry, Rz deg, of SI ones (m, rad)."""
    v = _as_last(pose6, 6, 'pose6')
    return np.concatenate([v[..., :3] * MM_PER_M, np.degrees(v[..., 3:])], axis=-1)


def pose6_from_human(human: ArrayLike) -> FloatArray:
    """SI six numbers (..., 6): tx, ty, tz m and rx, ry, rz rad, of human ones (mm, deg)."""
    v = _as_last(human, 6, 'human pose')
    return np.concatenate([v[..., :3] / MM_PER_M, np.radians(v[..., 3:])], axis=-1)


def format_human(human: ArrayLike, decimals: int = 6) -> str:
    """One pose's human six numbers (6,) as text: ``'Tx Ty Tz mm Rx Ry Rz deg'``."""
    v = _as_last(human, 6, 'human pose')
    if v.shape != (6,):
        raise InputError(f'human pose: expected shape (6,), got {v.shape}')
    t = ' '.join(f'{x:.{decimals}f}' for x in v[:3])
    r = ' '.join(f'{x:.{decimals}f}' for x in v[3:])
    return f'{t} mm {r} deg'


# -- rigid transforms ----------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Transform:
    """Rigid transform T_a_b: frame b in frame a (module docstring). ``p`` (3,) m, ``R``
    (3, 3) proper rotation (orthonormal within :data:`ROTATION_TOLERANCE`, det +1); both are
    stored as read-only copies. Equal when ``p`` and ``R`` are bit for bit equal."""

    p: FloatArray
    R: FloatArray

    def __post_init__(self) -> None:
        p = _as_last(self.p, 3, 'transform position')
        if p.shape != (3,):
            raise InputError(f'transform position: expected shape (3,), got {p.shape}')
        try:
            r = np.array(self.R, dtype=float)
        except (TypeError, ValueError) as err:
            raise InputError(f'transform rotation: expected numbers, got {self.R!r}') from err
        if r.shape != (3, 3):
            raise InputError(f'transform rotation: expected shape (3, 3), got {r.shape}')
        if not np.isfinite(r).all():
            raise InputError(f'transform rotation {r.tolist()} is not finite (NaN or infinite)')
        off = float(np.abs(r.T @ r - np.eye(3)).max())
        if off > ROTATION_TOLERANCE or np.linalg.det(r) < 0.0:
            raise InputError(f'transform rotation {r.tolist()} is not a proper rotation '
                             f'(|RᵀR − I| = {off:.3g}, det = {np.linalg.det(r):.9g})')
        p = p.copy()
        p.setflags(write=False)
        r.setflags(write=False)
        object.__setattr__(self, 'p', p)
        object.__setattr__(self, 'R', r)

    # -- construction ----------------------------------------------------------------------
    @classmethod
    def identity(cls) -> Transform:
        """The identity: frame b is frame a."""
        return cls(np.zeros(3), np.eye(3))

    @classmethod
    def from_pq(cls, position: ArrayLike, quaternion: ArrayLike) -> Transform:
        """From one position (3,) m and one unit quaternion (4,) x, y, z, w."""
        p, q = as_pose_batch(position, quaternion)
        if p.shape[0] != 1:
            raise InputError(f'expected one pose, got {p.shape[0]}')
        return cls(p[0], matrix_from_quaternion(q)[0])

    @classmethod
    def from_pose6(cls, pose6: ArrayLike) -> Transform:
        """From SI six numbers (6,): tx, ty, tz m, rx, ry, rz rad (R = Rz·Ry·Rx)."""
        v = _as_last(pose6, 6, 'pose6')
        if v.shape != (6,):
            raise InputError(f'pose6: expected shape (6,), got {v.shape}')
        return cls(v[:3], matrix_from_quaternion(quaternion_from_euler_xyz(v[3:])))

    @classmethod
    def from_human(cls, human: ArrayLike) -> Transform:
        """From human six numbers (6,): Tx, Ty, Tz mm, Rx, Ry, Rz deg (R = Rz·Ry·Rx)."""
        return cls.from_pose6(pose6_from_human(human))

    # -- conversion ------------------------------------------------------------------------
    @property
    def q(self) -> FloatArray:
        """The rotation as a unit quaternion (4,) x, y, z, w with w ≥ 0."""
        q: FloatArray = quaternion_from_matrix(self.R[np.newaxis], orthonormal=True)[0]
        return q

    def to_pq(self) -> tuple[FloatArray, FloatArray]:
        """Position (3,) m and unit quaternion (4,) x, y, z, w (w ≥ 0)."""
        return np.array(self.p), self.q

    def to_pose6(self) -> FloatArray:
        """SI six numbers (6,): tx, ty, tz m, rx, ry, rz rad (R = Rz·Ry·Rx)."""
        return np.concatenate([self.p, euler_xyz_from_quaternion(self.q[np.newaxis])[0]])

    def to_human(self) -> FloatArray:
        """Human six numbers (6,): Tx, Ty, Tz mm, Rx, Ry, Rz deg (R = Rz·Ry·Rx)."""
        return human_from_pose6(self.to_pose6())

    # -- algebra ---------------------------------------------------------------------------
    def __matmul__(self, other: Transform) -> Transform:
        """T_a_c = T_a_b @ T_b_c."""
        if not isinstance(other, Transform):
            return NotImplemented
        return Transform(self.p + self.R @ other.p, self.R @ other.R)

    def inverse(self) -> Transform:
        """T_b_a of T_a_b: (−Rᵀ·p, Rᵀ)."""
        return Transform(-(self.R.T @ self.p), self.R.T)

    def apply(self, points: ArrayLike) -> FloatArray:
        """Points (..., 3) given in frame b, expressed in frame a (m): R·x + p."""
        x = _as_last(points, 3, 'points')
        return np.asarray(x @ self.R.T + self.p)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Transform):
            return NotImplemented
        return bool(np.array_equal(self.p, other.p) and np.array_equal(self.R, other.R))

    def __hash__(self) -> int:
        return hash((self.p.tobytes(), self.R.tobytes()))

    def __repr__(self) -> str:
        return f'Transform.from_human([{", ".join(repr(float(v)) for v in self.to_human())}])'

    def __str__(self) -> str:
        return format_human(self.to_human())


def compose_poses(left: Transform, position: ArrayLike, quaternion: ArrayLike,
                  right: Transform) -> tuple[FloatArray, FloatArray]:
    """left · T_i · right for a batch of poses T_i = (``position`` (N, 3) m, unit
    ``quaternion`` (N, 4) x, y, z, w): positions (N, 3) m, quaternions (N, 4) with w ≥ 0."""
    p, q = as_pose_batch(position, quaternion)
    out_p = (p + matrix_from_quaternion(q) @ right.p) @ left.R.T + left.p
    # as quaternions, in numpy at any batch size (the positioner checks a move's every sample
    # against a user box through this, and imports no scipy: ros.spin)
    out_q = quaternion_product(quaternion_product(left.q, q), right.q)
    return np.asarray(out_p), canonical_quaternions(out_q)


def distance(a: Transform, b: Transform) -> tuple[float, float]:
    """How far ``b`` is from ``a``: |p_b − p_a| m and the rotation angle of R_aᵀ·R_b rad."""
    angle = rotation_angle(quaternion_from_matrix((a.R.T @ b.R)[np.newaxis], orthonormal=True))[0]
    return float(np.linalg.norm(b.p - a.p)), float(angle)
