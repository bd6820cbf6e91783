"""Screw theory of parallel mechanisms: joints as unit twists, limbs as twist systems, constraint
wrenches as reciprocal screws, the mechanism's mobility and its kind (seed 001 §3).

Conventions (seed 001 eq. 1-9, Plücker coordinates in the base frame, about the base origin):

- twist $ = (s; s0): a revolute about unit axis s through point r is (s; r × s), a prismatic
  joint along unit s is (0; s). Read as (ω; v_O): angular velocity and the velocity of the
  body point at the origin.
- wrench $r = (f; m_O): a unit force along s through r is (s; r × s), a unit couple about s is
  (0; s).
- reciprocal product $ ∘ $r = s·m_O + s0·f: the power of the wrench on the twist. A wrench is a
  constraint of a limb when it is reciprocal to every twist of the limb.

Arrays are (k, 6) rows of screws; lengths in m. The 4-UPS/UPP mechanism of seed 001 (§3.3,
Fig. 4) is defined here too, with the 3-UPS positioner's limbs at a pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.kinematics import inverse, leg_directions
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import scipy_rotation
from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Singular values below this fraction of the largest count as zero (rank decisions).
RANK_TOLERANCE = 1e-9

_AXIS_NAMES = ('x', 'y', 'z')


# -- joints as unit twists --------------------------------------------------------------------
def _unit(v: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(v, dtype=float).reshape(-1)
    norm = float(np.linalg.norm(arr)) if arr.shape == (3,) else 0.0
    if arr.shape != (3,) or not math.isfinite(norm) or norm < 1e-12:
        raise InputError(f'{name} = {v!r}: expected a finite non-zero 3-vector')
    unit: FloatArray = arr / norm
    return unit


def _point(r: ArrayLike, name: str) -> FloatArray:
    arr = np.asarray(r, dtype=float).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise InputError(f'{name} = {r!r}: expected a finite 3-vector (m)')
    return arr


def line(direction: ArrayLike, point: ArrayLike) -> FloatArray:
    """Unit line screw (s; r × s) (6,): a revolute twist, or a unit force wrench, about the
    line through ``point`` (m, base frame) along ``direction``."""
    s = _unit(direction, 'direction')
    return np.concatenate([s, np.cross(_point(point, 'point'), s)])


def free_vector(direction: ArrayLike) -> FloatArray:
    """Screw of infinite pitch (0; s) (6,): a prismatic twist, or a unit couple wrench."""
    return np.concatenate([np.zeros(3), _unit(direction, 'direction')])


def revolute(axis: ArrayLike, point: ArrayLike) -> FloatArray:
    """R joint: one unit twist (1, 6) about ``axis`` through ``point``."""
    return line(axis, point)[None]


def prismatic(direction: ArrayLike) -> FloatArray:
    """P joint: one unit twist (1, 6) of translation along ``direction``."""
    return free_vector(direction)[None]


def universal(axis1: ArrayLike, axis2: ArrayLike, centre: ArrayLike) -> FloatArray:
    """U joint = two revolutes with intersecting axes through ``centre``: twists (2, 6)."""
    return np.stack([line(axis1, centre), line(axis2, centre)])


def spherical(centre: ArrayLike) -> FloatArray:
    """S joint = three revolutes about x, y, z through ``centre``: twists (3, 6)."""
    return np.stack([line(e, centre) for e in np.eye(3)])


def cylindrical(axis: ArrayLike, point: ArrayLike) -> FloatArray:
    """C joint = a revolute and a prismatic on the same axis: twists (2, 6)."""
    return np.stack([line(axis, point), free_vector(axis)])


# -- reciprocity --------------------------------------------------------------------------------
def reciprocal_product(twists: ArrayLike, wrenches: ArrayLike) -> FloatArray:
    """Matrix (k, m) of reciprocal products s·m_O + s0·f of twists (k, 6) with wrenches (m, 6)."""
    t = np.atleast_2d(np.asarray(twists, dtype=float))
    w = np.atleast_2d(np.asarray(wrenches, dtype=float))
    product: FloatArray = t[:, :3] @ w[:, 3:].T + t[:, 3:] @ w[:, :3].T
    return product


def null_space_rows(a: FloatArray) -> FloatArray:
    """Orthonormal basis (rows) of the null space of ``a``: its right singular vectors whose
    singular values are at most RANK_TOLERANCE times the largest, which is what
    ``scipy.linalg.null_space(a, rcond=RANK_TOLERANCE).T`` returns (the same LAPACK SVD,
    gesdd; test_screw compares the two; on the 190 matrices of the coordinator's start they
    were equal to the last bit). numpy's SVD rather than scipy's: importing scipy.linalg was
    0.2-0.3 s of the coordinator's start, which builds its force watch's pair map with it
    (issue 24)."""
    _, singular, vh = np.linalg.svd(a, full_matrices=True)
    independent = int(np.sum(singular > RANK_TOLERANCE * np.amax(singular, initial=0.0)))
    basis: FloatArray = vh[independent:]
    return basis


def reciprocal_screws(screws: ArrayLike) -> FloatArray:
    """Basis (m, 6) of the screws reciprocal to every row of ``screws`` (k, 6) (seed 001
    eq. 2): orthonormal rows (:func:`null_space_rows`). For a limb's twist system these are
    its constraint wrenches; m = 6 − rank."""
    s = np.atleast_2d(np.asarray(screws, dtype=float))
    if s.size == 0:
        return np.eye(6)
    swapped = np.hstack([s[:, 3:], s[:, :3]])  # s ∘ w = swapped(s) · w
    basis: FloatArray = null_space_rows(swapped)
    return basis


def rank(screws: ArrayLike) -> int:
    """Numerical rank of a screw system (k, 6) (or of any (k, m) block), rotations and
    translations on equal footing."""
    s = np.atleast_2d(np.asarray(screws, dtype=float))
    if s.size == 0:
        return 0
    sv = np.linalg.svd(s, compute_uv=False)
    return int(np.sum(sv > RANK_TOLERANCE * max(float(sv[0]), 1e-300)))


def span_contains(basis: ArrayLike, screws: ArrayLike) -> bool:
    """Whether every row of ``screws`` (m, 6) lies in the span of the rows of ``basis`` (k, 6)."""
    b = np.atleast_2d(np.asarray(basis, dtype=float))
    return rank(np.vstack([b, np.atleast_2d(np.asarray(screws, dtype=float))])) == rank(b)


def normalised(wrenches: ArrayLike) -> FloatArray:
    """Wrenches (…, 6) scaled to unit force, or to unit couple where the force is zero."""
    w = np.asarray(wrenches, dtype=float)
    force = np.linalg.norm(w[..., :3], axis=-1, keepdims=True)
    couple = np.linalg.norm(w[..., 3:], axis=-1, keepdims=True)
    scale = np.where(force > 1e-9 * np.maximum(couple, 1e-300), force, couple)
    out: FloatArray = w / scale
    return out


def moved(screws: ArrayLike, point: ArrayLike) -> FloatArray:
    """Screws (…, 6) about the base origin re-expressed about ``point`` (…, 3):
    moment' = moment − point × direction."""
    s = np.asarray(screws, dtype=float)
    r = np.asarray(point, dtype=float)
    out = s.copy()
    out[..., 3:] = s[..., 3:] - np.cross(r, s[..., :3])
    return out


# -- limbs and mechanisms -----------------------------------------------------------------------
@dataclass(frozen=True)
class Limb:
    """A serial limb at one configuration: unit twists (n, 6) of its joint freedoms from base to
    platform, which of them are actuated (n,), a name, and the joint kinds for people."""

    name: str
    twists: FloatArray
    actuated: BoolArray
    joints: str = ''

    def __post_init__(self) -> None:
        if self.twists.ndim != 2 or self.twists.shape[1] != 6:
            raise InputError(f'limb {self.name}: twists must be (n, 6), got {self.twists.shape}')
        if self.actuated.shape != (self.twists.shape[0],):
            raise InputError(f'limb {self.name}: one actuated flag per twist')

    @classmethod
    def from_joints(cls, name: str, joints: Sequence[tuple[str, FloatArray, bool]]) -> Limb:
        """Limb from (kind, twists (k, 6), actuated) per joint, base to platform; ``actuated``
        marks every freedom of that joint."""
        twists = np.vstack([t for _, t, _ in joints])
        flags = np.concatenate([np.full(t.shape[0], a) for _, t, a in joints])
        return cls(name, twists, flags.astype(bool), ''.join(k for k, _, _ in joints))

    @property
    def constraint_wrenches(self) -> FloatArray:
        """Constraint wrenches (m, 6) the limb imposes on the platform: the reciprocal screws of
        its twist system (seed 001 eq. 2, 9)."""
        return reciprocal_screws(self.twists)

    @property
    def transmitted_wrenches(self) -> FloatArray:
        """Wrenches (m', 6) the limb can carry with its actuators locked: reciprocal to its
        passive twists only (constraint wrenches plus actuation wrenches)."""
        return reciprocal_screws(self.twists[~self.actuated])

    def actuation_wrenches(self) -> FloatArray:
        """One normalised wrench (a, 6) per actuated freedom: reciprocal to every other twist of
        the limb and not a constraint, i.e. what the actuator transmits (Joshi & Tsai)."""
        constraints = self.constraint_wrenches
        out = []
        for j in np.flatnonzero(self.actuated):
            others = np.delete(self.twists, j, axis=0)
            candidates = reciprocal_screws(others)
            if constraints.shape[0]:
                q, _ = np.linalg.qr(constraints.T)
                candidates = candidates - (candidates @ q) @ q.T
            best = candidates[np.argmax(np.linalg.norm(candidates, axis=1))]
            out.append(best)
        return normalised(np.array(out).reshape(-1, 6))


@dataclass(frozen=True)
class Mobility:
    """Mobility of a platform from its limbs' constraint wrenches (seed 001 §3.3).

    dof = 6 − rank(constraints); ``rotations`` and ``translations`` count the kind (kRmT):
    rotations = rank of the angular part of the free twists, translations = dimension of the
    pure translations among them. ``rotation_axes`` (rotations, 3) and
    ``translation_directions`` (translations, 3) are orthonormal bases in the base frame.
    ``redundant_constraints`` = Σ limb constraints − rank: over-constraint count.
    """

    dof: int
    rotations: int
    translations: int
    free_twists: FloatArray
    constraint_wrenches: FloatArray
    rotation_axes: FloatArray
    translation_directions: FloatArray
    redundant_constraints: int
    limb_constraints: tuple[int, ...] = field(default=())

    @property
    def kind(self) -> str:
        """'3R3T', '2R2T', …"""
        return f'{self.rotations}R{self.translations}T'

    def describe(self) -> str:
        """Words for people: DOF, kind and the axes (named when along base axes)."""
        rot = _directions_in_words(self.rotation_axes)
        tra = _directions_in_words(self.translation_directions)
        return (f'{self.dof} DOF ({self.kind}): rotations about {rot}; translations along '
                f'{tra}; {self.redundant_constraints} redundant constraints')


def _directions_in_words(basis: FloatArray) -> str:
    if basis.shape[0] == 0:
        return 'none'
    named = [i for i in range(3)
             if np.linalg.norm(basis @ np.eye(3)[i]) > 1.0 - 1e-9]
    if len(named) == basis.shape[0]:
        return ', '.join(_AXIS_NAMES[i] for i in named)
    return ', '.join(np.array2string(v, precision=3) for v in basis)


def mobility(limbs: Sequence[Limb]) -> Mobility:
    """DOF and kind of a platform carried by ``limbs`` (one configuration, seed 001 §3.3)."""
    per_limb = [limb.constraint_wrenches for limb in limbs]
    all_c = np.vstack(per_limb) if per_limb else np.zeros((0, 6))
    r = rank(all_c)
    free = reciprocal_screws(all_c)
    omega = free[:, :3]
    n_rot = rank(omega) if free.size else 0
    if free.size:
        coeffs = null_space_rows(omega.T)
        trans = coeffs @ free[:, 3:]
        trans = _orthonormal_rows(trans)
        rot_axes = _orthonormal_rows(omega)
    else:
        trans = rot_axes = np.zeros((0, 3))
    constraints = _orthonormal_rows(all_c, width=6)
    return Mobility(6 - r, n_rot, free.shape[0] - n_rot, free, constraints, rot_axes, trans,
                    sum(c.shape[0] for c in per_limb) - r,
                    tuple(c.shape[0] for c in per_limb))


def _orthonormal_rows(a: FloatArray, width: int = 3) -> FloatArray:
    if a.size == 0:
        return np.zeros((0, width))
    _, sv, vt = np.linalg.svd(a, full_matrices=False)
    keep = sv > RANK_TOLERANCE * max(float(sv[0]), 1e-300)
    basis: FloatArray = vt[keep]
    return basis


def governing_wrenches(limbs: Sequence[Limb]) -> FloatArray:
    """Constraint and actuation wrenches of all limbs, stacked (k, 6), normalised: the wrench
    system whose rank and conditioning decide singularity (rank < 6: the locked mechanism
    can move)."""
    rows = [normalised(limb.constraint_wrenches) for limb in limbs]
    rows += [limb.actuation_wrenches() for limb in limbs]
    return np.vstack([r for r in rows if r.size] or [np.zeros((0, 6))])


# -- the 3-UPS positioner -----------------------------------------------------------------------
def positioner_limbs(mech: Mechanism, position: ArrayLike,
                     quaternion: ArrayLike) -> tuple[Limb, ...]:
    """The three UPS limbs of the positioner at one pose: U at A_i (first axis e_t,i passive φ,
    second axis actuated θ), P along u_i (actuated l), S at B_i (passive)."""
    joints = inverse(mech, position, quaternion)
    if joints.lengths.shape[0] != 1:
        raise InputError('positioner_limbs takes one pose')
    u = leg_directions(mech, joints.phis, joints.thetas)[0]
    limbs = []
    for i in range(3):
        a, b = mech.base_joints[i], mech.base_joints[i] + joints.lengths[0, i] * u[i]
        second = np.cross(u[i], theta_rate_direction(mech.tangential[i], u[i]))
        limbs.append(Limb.from_joints(f'leg{i + 1}', [
            ('R', revolute(mech.tangential[i], a), False),
            ('R', revolute(second, a), True),
            ('P', prismatic(u[i]), True),
            ('S', spherical(b), False),
        ]))
    return tuple(limbs)


def theta_rate_direction(tangential: FloatArray, u: FloatArray) -> FloatArray:
    """∂u/∂θ = (e_t − (u·e_t) u)/cos θ: unit, ⊥ u, in the plane of u and e_t (…, 3)."""
    d = tangential - np.sum(u * tangential, axis=-1, keepdims=True) * u
    out: FloatArray = d / np.linalg.norm(d, axis=-1, keepdims=True)
    return out


def positioner_actuation_wrenches(mech: Mechanism, points: FloatArray,
                                  directions: FloatArray) -> FloatArray:
    """Actuation wrenches of the positioner in closed form, batched (N, 6, 6), about the base
    origin, unit forces: rows l_i = force along u_i through B_i, rows θ_i = force along
    ∂u_i/∂θ_i through B_i (reciprocal to the φ, P and S twists of leg i). points B (N, 3, 3) m,
    directions u (N, 3, 3)."""
    w = theta_rate_direction(mech.tangential, directions)
    rows_l = np.concatenate([directions, np.cross(points, directions)], axis=2)
    rows_t = np.concatenate([w, np.cross(points, w)], axis=2)
    return np.concatenate([rows_l, rows_t], axis=1)


# -- the 4-UPS/UPP mechanism of seed 001 ----------------------------------------------------
@dataclass(frozen=True)
class UpsUpp:
    """The n-UPS/UPP posture-adjustment mechanism of seed 001 (Fig. 4; n = 4 there).

    n UPS limbs (P actuated) from base points at radius ``base_radius`` (azimuths 360°·k/n)
    to platform points at radius ``platform_radius``, azimuths turned by ``twist`` (rad) so
    that the leg lines are skew (with twist = 0 all leg lines and the centre force meet in one
    point: singular). The centre UPP limb: U at the base origin (first axis base x, second axis
    y of the U body), two prismatic joints along x and y of the U body, carrying the platform
    at ``column`` (m) along the U body's z. ``lock_centre_prismatics``: the UPP slides are
    braked (they then carry force). Lengths in m.

    The first half of the legs is turned by +``twist``, the rest by −``twist``
    (``symmetric=False``). With every leg turned alike (``symmetric=True``) each pair of opposite
    legs sums to the UPP's own constraint wrenches at the reference configuration, so the
    actuation and constraint wrench system has rank 4 there: a singularity.
    """

    n_ups: int = 4
    base_radius: float = 0.5
    platform_radius: float = 0.3
    column: float = 0.6
    twist: float = math.pi / 4
    symmetric: bool = False
    lock_centre_prismatics: bool = False

    def __post_init__(self) -> None:
        if self.n_ups < 1:
            raise InputError(f'n_ups = {self.n_ups!r}: need at least one UPS limb')
        for name in ('base_radius', 'platform_radius', 'column'):
            if not getattr(self, name) > 0.0:
                raise InputError(f'{name} = {getattr(self, name)!r}: must be > 0 m')

    def centre_rotation(self, alpha: float, beta: float) -> FloatArray:
        """Rotation (3, 3) of the U body (= platform): about base x by α, then body y by β."""
        rot = scipy_rotation().from_euler('XY', [alpha, beta])
        return np.asarray(rot.as_matrix(), dtype=float)

    def pose(self, alpha: float = 0.0, beta: float = 0.0, slide_x: float = 0.0,
             slide_y: float = 0.0) -> tuple[FloatArray, FloatArray]:
        """Platform position (3,) m and rotation (3, 3) for the UPP joint values (rad, m)."""
        rot = self.centre_rotation(alpha, beta)
        return rot @ np.array([slide_x, slide_y, self.column]), rot

    def attachment_points(self, alpha: float = 0.0, beta: float = 0.0, slide_x: float = 0.0,
                          slide_y: float = 0.0) -> tuple[FloatArray, FloatArray]:
        """UPS base points A (n, 3) and platform points B (n, 3), base frame, m."""
        az = 2.0 * math.pi * np.arange(self.n_ups) / self.n_ups
        radial = np.stack([np.cos(az), np.sin(az), np.zeros_like(az)], axis=1)
        first_half = np.arange(self.n_ups) < self.n_ups / 2
        turn = az + np.where(first_half | self.symmetric, self.twist, -self.twist)
        turned = np.stack([np.cos(turn), np.sin(turn), np.zeros_like(az)], axis=1)
        p, rot = self.pose(alpha, beta, slide_x, slide_y)
        return self.base_radius * radial, p + self.platform_radius * turned @ rot.T

    def limbs(self, alpha: float = 0.0, beta: float = 0.0, slide_x: float = 0.0,
              slide_y: float = 0.0) -> tuple[Limb, ...]:
        """UPS limbs then the UPP limb at a configuration (twists about the base origin)."""
        base, plat = self.attachment_points(alpha, beta, slide_x, slide_y)
        az = 2.0 * math.pi * np.arange(self.n_ups) / self.n_ups
        out = []
        for k in range(self.n_ups):
            u = plat[k] - base[k]
            first = np.array([-math.sin(az[k]), math.cos(az[k]), 0.0])
            out.append(Limb.from_joints(f'UPS{k + 1}', [
                ('U', universal(first, np.cross(first, u), base[k]), False),
                ('P', prismatic(u), True),
                ('S', spherical(plat[k]), False),
            ]))
        rot = self.centre_rotation(alpha, beta)
        x_axis = np.array([1.0, 0.0, 0.0])
        out.append(Limb.from_joints('UPP', [
            ('U', universal(x_axis, self.centre_rotation(alpha, 0.0)[:, 1], np.zeros(3)), False),
            ('P', prismatic(rot[:, 0]), self.lock_centre_prismatics),
            ('P', prismatic(rot[:, 1]), self.lock_centre_prismatics),
        ]))
        return tuple(out)
