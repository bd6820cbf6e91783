"""ISO 9283:1998 pose accuracy (§7.2.1) and repeatability (§7.2.2) of a commanded pose from its
attained poses, distance accuracy and repeatability (§7.3) between two commanded poses, and
the orientation angles the standard uses. SI: m and rad."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import (
    Quad,
    Triple,
    as_pose_batch,
    as_unit_quaternions,
    as_vectors,
    euler_xyz_from_quaternion,
    quad,
    triple,
)
from positioning_cell.errors import InputError
from positioning_cell.records import plain_fields

FloatArray = NDArray[np.float64]


def orientation_angles(quaternion: ArrayLike) -> FloatArray:
    """ISO 9283 orientation angles a, b, c (N, 3) rad of unit quaternions (N, 4): roll, pitch,
    yaw about the fixed base axes x, y, z (R = Rz(c)·Ry(b)·Rx(a)); a, c in [−π, π],
    b in [−π/2, π/2]. Near b = ±π/2 (gimbal lock) a and c are not separable."""
    return euler_xyz_from_quaternion(as_unit_quaternions(quaternion))

def wrap_angle(angle: ArrayLike) -> FloatArray:
    """Angles wrapped into [−π, π) rad."""
    return np.asarray((np.asarray(angle, dtype=float) + math.pi) % (2.0 * math.pi) - math.pi)

# -- ISO 9283 --------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseFigures:
    """ISO 9283:1998 pose accuracy (§7.2.1) and repeatability (§7.2.2) of one commanded pose
    from its n attained poses. SI: m and rad; angles a, b, c per
    :data:`~positioning_cell.core.poses.EULER_SEQUENCE`.

    ``barycentre`` (x̄, ȳ, z̄); AP_x = x̄ − x_c, AP_y, AP_z; AP_p = √(AP_x² + AP_y² + AP_z²);
    AP_a = ā − a_c, AP_b, AP_c with each a_j taken as a_c + wrap(a_j − a_c) (no jump at ±π).
    l_j = |P_j − barycentre|, l̄ their mean, S_l = √(Σ(l_j − l̄)²/(n−1)), RP_l = l̄ + 3·S_l;
    S_a = √(Σ(a_j − ā)²/(n−1)), RP_a = ±3·S_a (the half-width is stored), RP_b, RP_c.
    The S and RP terms are None when n < 2.
    """

    key: int
    n: int
    commanded_position: Triple
    commanded_quaternion: Quad
    commanded_angles: Triple
    barycentre: Triple
    ap_x: float
    ap_y: float
    ap_z: float
    ap_p: float
    ap_a: float
    ap_b: float
    ap_c: float
    l_mean: float
    s_l: float | None
    rp_l: float | None
    s_a: float | None
    s_b: float | None
    s_c: float | None
    rp_a: float | None
    rp_b: float | None
    rp_c: float | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples as lists; None for undefined terms)."""
        return plain_fields(self)

    def for_people(self) -> dict[str, str]:
        """The figures formatted for people: µm and degrees ('n/a' where undefined)."""
        def um(v: float | None) -> str:
            return 'n/a' if v is None else f'{v * 1e6:.1f}'

        def deg(v: float | None) -> str:
            return 'n/a' if v is None else f'{math.degrees(v):.4f}'

        return {'n': str(self.n), 'AP_p_um': um(self.ap_p), 'RP_l_um': um(self.rp_l),
                'AP_a_deg': deg(self.ap_a), 'AP_b_deg': deg(self.ap_b),
                'AP_c_deg': deg(self.ap_c), 'RP_a_deg': deg(self.rp_a),
                'RP_b_deg': deg(self.rp_b), 'RP_c_deg': deg(self.rp_c)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PoseFigures:
        """Inverse of :meth:`to_dict`; missing or unknown keys raise InputError."""
        names = [f.name for f in fields(cls)]
        if set(data) != set(names):
            raise InputError(f'PoseFigures: expected keys {names}, got {sorted(data)}')
        values: dict[str, Any] = {
            k: (tuple(float(x) for x in v) if isinstance(v, list) else v)
            for k, v in data.items()}
        return cls(**values)

def iso9283(commanded_position: ArrayLike, commanded_quaternion: ArrayLike,
            attained_position: ArrayLike, attained_quaternion: ArrayLike,
            key: int = 0) -> PoseFigures:
    """ISO 9283:1998 §7.2.1 (AP) and §7.2.2 (RP) of one commanded pose (3,), (4,) from its n
    attained poses (n, 3) m, (n, 4), in visit order. See :class:`PoseFigures` for the formulas."""
    pc, qc = as_pose_batch(commanded_position, commanded_quaternion)
    if pc.shape[0] != 1:
        raise InputError(f'iso9283 takes one commanded pose, got {pc.shape[0]}')
    pa, qa = as_pose_batch(attained_position, attained_quaternion)
    n = pa.shape[0]
    barycentre = pa.mean(axis=0)
    ap = barycentre - pc[0]
    l_j = np.sqrt(((pa - barycentre) ** 2).sum(axis=1))
    angles_c = orientation_angles(qc)[0]
    deviation = wrap_angle(orientation_angles(qa) - angles_c)
    ap_abc = deviation.mean(axis=0)
    s_l: float | None = None
    s_abc: list[float | None] = [None, None, None]
    rp_abc: list[float | None] = [None, None, None]
    if n >= 2:
        s_l = float(l_j.std(ddof=1))
        s = deviation.std(axis=0, ddof=1)
        s_abc = [float(v) for v in s]
        rp_abc = [3.0 * float(v) for v in s]
    return PoseFigures(
        key=int(key), n=n, commanded_position=triple(pc[0]),
        commanded_quaternion=quad(qc[0]), commanded_angles=triple(angles_c),
        barycentre=triple(barycentre), ap_x=float(ap[0]), ap_y=float(ap[1]),
        ap_z=float(ap[2]), ap_p=float(np.sqrt((ap ** 2).sum())), ap_a=float(ap_abc[0]),
        ap_b=float(ap_abc[1]), ap_c=float(ap_abc[2]), l_mean=float(l_j.mean()), s_l=s_l,
        rp_l=None if s_l is None else float(l_j.mean()) + 3.0 * s_l,
        s_a=s_abc[0], s_b=s_abc[1], s_c=s_abc[2], rp_a=rp_abc[0], rp_b=rp_abc[1],
        rp_c=rp_abc[2])


@dataclass(frozen=True)
class DistanceFigures:
    """ISO 9283:1998 distance accuracy AD (§7.3.1) and distance repeatability RD (§7.3.2) of
    the position between two commanded poses, from n pairs of attained positions (cycle j
    reached the first pose at P_1j and the second at P_2j). SI: m.

    D_c = |P_c1 − P_c2|, D_j = |P_1j − P_2j|, D̄ their mean; AD_p = D̄ − D_c;
    S_D = √(Σ(D_j − D̄)²/(n − 1)), RD_p = ±3·S_D (the half-width is stored; None when
    n < 2)."""

    n: int
    commanded_distance: float
    mean_distance: float
    ad_p: float
    s_d: float | None
    rd_p: float | None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (None for undefined terms)."""
        return plain_fields(self)


def distance_figures(commanded_first: ArrayLike, commanded_second: ArrayLike,
                     attained_first: ArrayLike, attained_second: ArrayLike) -> DistanceFigures:
    """ISO 9283 §7.3 AD_p and RD_p (:class:`DistanceFigures`) between two commanded positions
    (3,) m from the n pairs of attained positions (n, 3), (n, 3) m, pair j of cycle j.
    InputError: not finite, or not as many of each."""
    c = as_vectors(np.vstack([np.reshape(np.asarray(commanded_first, dtype=float), (-1, 3)),
                              np.reshape(np.asarray(commanded_second, dtype=float), (-1, 3))]),
                   3, 'commanded positions')
    first = as_vectors(attained_first, 3, 'attained_first')
    second = as_vectors(attained_second, 3, 'attained_second')
    if c.shape[0] != 2 or first.shape != second.shape:
        raise InputError(f'distance figures take two commanded positions and as many attained '
                         f'of each; got {c.shape[0]}, {first.shape[0]} and {second.shape[0]}')
    n = first.shape[0]
    distance = np.sqrt(((first - second) ** 2).sum(axis=1))
    commanded = float(np.linalg.norm(c[0] - c[1]))
    s_d = float(distance.std(ddof=1)) if n >= 2 else None
    return DistanceFigures(n, commanded, float(distance.mean()),
                           float(distance.mean()) - commanded, s_d,
                           None if s_d is None else 3.0 * s_d)


#: Approach directions closer than this angle (rad) are one direction of ISO 9283 §7.2.3.
APPROACH_ANGLE = math.radians(30.0)


@dataclass(frozen=True)
class MultiDirectionalFigures:
    """ISO 9283:1998 multi-directional pose accuracy variation (§7.2.3) of one commanded pose
    approached from ``directions`` directions (h = 1 … ``directions``; n visits with a known
    approach): the largest distance between the barycentres of the attained positions of two
    directions, vAP_p = max |x̄_h − x̄_k| (m), and of their mean angles, vAP_a = max
    |ā_h − ā_k| (rad; b, c likewise). ``approaches`` (directions, 3) the unit direction of
    each (the first visit's of it), base frame. SI."""

    n: int
    directions: int
    approaches: tuple[Triple, ...]
    vap_p: float
    vap_a: float
    vap_b: float
    vap_c: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict."""
        return plain_fields(self)


def approach_groups(approach: ArrayLike, angle: float = APPROACH_ANGLE) -> NDArray[np.intp]:
    """The direction index (n,) of each approach vector (n, 3) (any length > 0): the first
    earlier direction within ``angle`` rad of it, else a new one (numbered in order of first
    appearance). InputError: a zero or non-finite vector."""
    v = as_vectors(approach, 3, 'approach')
    length = np.linalg.norm(v, axis=1)
    if np.any(length <= 0.0):
        raise InputError('approach: a zero vector has no direction')
    unit = v / length[:, None]
    group = np.empty(len(unit), dtype=np.intp)
    representative: list[FloatArray] = []
    for i, u in enumerate(unit):  # over visits of one pose, not samples
        close = [k for k, r in enumerate(representative) if float(u @ r) >= math.cos(angle)]
        if close:
            group[i] = close[0]
        else:
            group[i] = len(representative)
            representative.append(u)
    return group


def multidirectional_figures(commanded_quaternion: ArrayLike, attained_position: ArrayLike,
                             attained_quaternion: ArrayLike, approach: ArrayLike,
                             angle: float = APPROACH_ANGLE) -> MultiDirectionalFigures | None:
    """ISO 9283 §7.2.3 vAP (:class:`MultiDirectionalFigures`) of one commanded pose from its n
    attained poses (n, 3) m, (n, 4) and the direction (n, 3) each was approached from (the
    motion that reached it, base frame), grouped by :func:`approach_groups`; angles as
    :func:`iso9283`'s (each a_j taken as a_c + wrap(a_j − a_c)). None below two directions."""
    _, qc = as_pose_batch(np.zeros(3), commanded_quaternion)
    pa, qa = as_pose_batch(attained_position, attained_quaternion)
    group = approach_groups(approach, angle)
    if pa.shape[0] != group.size:
        raise InputError(f'{pa.shape[0]} attained poses for {group.size} approach directions')
    count = int(group.max()) + 1 if group.size else 0
    if count < 2:
        return None
    angles = wrap_angle(orientation_angles(qa) - orientation_angles(qc)[0])
    barycentres = np.array([pa[group == h].mean(axis=0) for h in range(count)])
    means = np.array([angles[group == h].mean(axis=0) for h in range(count)])
    span_p = np.sqrt(((barycentres[:, None] - barycentres[None]) ** 2).sum(axis=2)).max()
    span_abc = np.abs(means[:, None] - means[None]).max(axis=(0, 1))
    v = as_vectors(approach, 3, 'approach')
    first = [int(np.flatnonzero(group == h)[0]) for h in range(count)]
    unit = v[first] / np.linalg.norm(v[first], axis=1)[:, None]
    return MultiDirectionalFigures(int(pa.shape[0]), count, tuple(triple(u) for u in unit),
                                   float(span_p), *(float(x) for x in span_abc))
