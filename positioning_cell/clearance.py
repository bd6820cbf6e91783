"""Joint-clearance models of the 3-UPS positioner and model-based compensation.

Two models (design/kinematics.md, seed 000 §1-2):

- :class:`EffectiveLengthClearance`: the paper's effective-length model, eq. (9): the U-joint
  eccentricity r_a and the S-joint offset r_b, each with two direction angles per leg, change
  each leg's effective length by Δl_i(φ_i, θ_i).
- :class:`VectorClearance`: the exact model: 3-D offset vectors of the U centre (base frame,
  |e_a| ≤ r_a) and of the ball centre (platform frame, |e_b| ≤ r_b), solved by the same forward
  kinematics on the displaced joint centres.

``None`` stands for a machine without clearance. All lengths in m, angles in rad.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, TypeAlias

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import ConfigError, ConvergenceError
from positioning_cell.kinematics import ForwardResult, InverseResult, forward, home_phis, inverse
from positioning_cell.mechanism import Mechanism
from positioning_cell.poses import as_pose_batch, pose_error

FloatArray = NDArray[np.float64]
Triple = tuple[float, float, float]

#: Fixed-point tolerance on Δl (m) when solving forward kinematics under eq. (9).
_DELTA_TOLERANCE = 1e-15


@dataclass(frozen=True)
class EffectiveLengthClearance:
    """Seed 000 eq. (9): Δl_i = r_b[cos(φ_i + δ_b,i') + cos(θ_i + δ_b,i'')]
    − r_a[cos(φ_i + δ_a,i') + cos(θ_i + δ_a,i'')]. r_a, r_b in m, δ per leg in rad."""

    r_a: float
    r_b: float
    delta_a1: Triple
    delta_a2: Triple
    delta_b1: Triple
    delta_b2: Triple

    def __post_init__(self) -> None:
        for name in ('r_a', 'r_b'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f'clearance.{name} = {value!r}: must be a finite length >= 0 m')
        for name in ('delta_a1', 'delta_a2', 'delta_b1', 'delta_b2'):
            value = getattr(self, name)
            if len(value) != 3 or not all(math.isfinite(v) for v in value):
                raise ConfigError(f'clearance.{name} = {value!r}: expected 3 finite angles (rad)')

    @classmethod
    def random(cls, r_a: float, r_b: float, rng: np.random.Generator) -> EffectiveLengthClearance:
        """Direction angles drawn uniformly in [0, 2π) per joint (seed 000, Table 1)."""
        d = rng.uniform(0.0, 2.0 * math.pi, size=(4, 3))
        return cls(r_a, r_b, *(_triple(row) for row in d))

    def length_delta(self, phis: FloatArray, thetas: FloatArray) -> FloatArray:
        """Δl (N, 3) in m at passive angles φ and actuated angles θ (N, 3) rad; eq. (9)."""
        da1, da2, db1, db2 = (np.asarray(v) for v in (self.delta_a1, self.delta_a2,
                                                      self.delta_b1, self.delta_b2))
        return (self.r_b * (np.cos(phis + db1) + np.cos(thetas + db2))  # type: ignore[no-any-return]
                - self.r_a * (np.cos(phis + da1) + np.cos(thetas + da2)))

    def attained_pose(self, mech: Mechanism, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """FK with l_eff = l + Δl(φ, θ); since Δl depends on the φ it produces, iterated to a
        fixed point (|ΔΔl| ≤ 1e-15 m; each pass one warm-started FK)."""
        lengths_arr = np.asarray(lengths, dtype=float).reshape(-1, 3)
        thetas_arr = np.asarray(thetas, dtype=float).reshape(-1, 3)
        # Start from Δl at the warm-start φ (or none): near the solution that leaves one or
        # two passes.
        delta = (np.zeros_like(lengths_arr) if phi0 is None else
                 self.length_delta(np.broadcast_to(np.asarray(phi0, dtype=float),
                                                   lengths_arr.shape), thetas_arr))
        result = forward(mech, lengths_arr + delta, thetas_arr, phi0)
        for _ in range(20):
            phis = np.where(np.isfinite(result.phis), result.phis, home_phis(mech))
            new_delta = self.length_delta(phis, thetas_arr)
            change = np.max(np.abs(new_delta - delta), initial=0.0)
            delta = new_delta
            result = forward(mech, lengths_arr + delta, thetas_arr, phis)
            if change <= _DELTA_TOLERANCE:
                return result
        raise ConvergenceError('clearance fixed point (seed 000 eq. 9) did not converge')

    def compensate(self, mech: Mechanism, position: ArrayLike,
                   quaternion: ArrayLike) -> InverseResult:
        """l_cmd = l_ideal − Δl(φ_ideal, θ_ideal) (design/kinematics.md): exact, because the
        platform then sits where φ = φ_ideal."""
        ideal = inverse(mech, position, quaternion)
        delta = self.length_delta(ideal.phis, ideal.thetas)
        return InverseResult(ideal.lengths - delta, ideal.thetas, ideal.phis)


@dataclass(frozen=True)
class VectorClearance:
    """Exact clearance: U-centre offsets e_a (3 legs × 3, base frame) and ball-centre offsets
    e_b (3 legs × 3, platform frame), in m."""

    u_offsets: tuple[Triple, Triple, Triple]
    s_offsets: tuple[Triple, Triple, Triple]

    def __post_init__(self) -> None:
        for name in ('u_offsets', 's_offsets'):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
                raise ConfigError(f'clearance.{name}: expected 3 x 3 finite lengths (m)')

    @classmethod
    def random(cls, r_a: float, r_b: float, rng: np.random.Generator) -> VectorClearance:
        """Offsets of full magnitude r_a, r_b in directions uniform on the sphere."""
        def on_sphere(r: float) -> tuple[Triple, Triple, Triple]:
            v = rng.normal(size=(3, 3))
            v *= r / np.linalg.norm(v, axis=1, keepdims=True)
            return (_triple(v[0]), _triple(v[1]), _triple(v[2]))
        return cls(on_sphere(r_a), on_sphere(r_b))

    def mechanism(self, mech: Mechanism) -> Mechanism:
        """The machine with its joint centres displaced by the offsets."""
        return mech.with_offsets(np.asarray(mech.base_offsets) + np.asarray(self.u_offsets),
                                 np.asarray(mech.platform_offsets) + np.asarray(self.s_offsets))

    def attained_pose(self, mech: Mechanism, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """FK of the machine with displaced joint centres."""
        return forward(self.mechanism(mech), lengths, thetas, phi0)

    def compensate(self, mech: Mechanism, position: ArrayLike,
                   quaternion: ArrayLike) -> InverseResult:
        """IK of the machine with displaced joint centres (closed form, exact)."""
        return inverse(self.mechanism(mech), position, quaternion)


class ClearanceLike(Protocol):
    """What a clearance model provides: where the platform goes for commanded joints, and the
    joint commands that put it on a desired pose."""

    def attained_pose(self, mech: Mechanism, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """Attained platform poses for commanded lengths (N, 3) m and thetas (N, 3) rad."""
        ...

    def compensate(self, mech: Mechanism, position: ArrayLike,
                   quaternion: ArrayLike) -> InverseResult:
        """Joint commands for desired poses (N, 3) m, (N, 4) x, y, z, w."""
        ...


#: A clearance model, or None for a machine without clearance.
ClearanceModel: TypeAlias = ClearanceLike | None


def _triple(v: Any) -> Triple:
    return (float(v[0]), float(v[1]), float(v[2]))


def attained_pose(mech: Mechanism, model: ClearanceModel, lengths: ArrayLike,
                  thetas: ArrayLike, phi0: ArrayLike | None = None) -> ForwardResult:
    """Where a machine with clearance ``model`` really puts the platform for commanded joints
    lengths (N, 3) m and thetas (N, 3) rad (None: nominal forward kinematics)."""
    if model is None:
        return forward(mech, lengths, thetas, phi0)
    return model.attained_pose(mech, lengths, thetas, phi0)


def compensate(mech: Mechanism, model: ClearanceModel, position: ArrayLike,
               quaternion: ArrayLike) -> InverseResult:
    """Joint commands that put a machine with clearance ``model`` on the given poses (None:
    nominal inverse kinematics). Returned phis are the passive angles the machine will show."""
    if model is None:
        return inverse(mech, position, quaternion)
    return model.compensate(mech, position, quaternion)


def model_from_params(params: Mapping[str, Any], mech: Mechanism,
                      rng: np.random.Generator | None = None) -> ClearanceModel:
    """A clearance model from a parameter block (nested or dotted keys, prefix ``clearance.``).

    Keys: ``model`` ('none' | 'effective_length' | 'vector' | 'load'); r_a, r_b (m; default the
    mechanism's joint clearance); for effective_length delta_a1, delta_a2, delta_b1, delta_b2
    (3 angles each, rad); for vector u_offsets, s_offsets (9 numbers each, m). Directions not
    given are drawn from ``rng`` (required then). For ``model: load`` seating_force (N) and
    the ``payload`` and ``structure`` blocks, nested or dotted (defaults: config/cell.yaml);
    see :class:`positioning_cell.load_clearance.LoadAwareClearance`. Bad values raise
    ConfigError naming the key.
    """
    flat = {k.removeprefix('clearance.'): v for k, v in params.items()}
    kind = str(flat.get('model', 'effective_length'))
    known = {'model', 'r_a', 'r_b', 'delta_a1', 'delta_a2', 'delta_b1', 'delta_b2',
             'u_offsets', 's_offsets', 'seed', 'seating_force', 'payload', 'structure'}
    for key in flat:
        if key not in known and key.split('.')[0] not in ('payload', 'structure'):
            raise ConfigError(f'clearance: unknown parameter {key!r}')
    if kind == 'none':
        return None
    r_a = _length(flat, 'r_a', mech.joint_clearance_u)
    r_b = _length(flat, 'r_b', mech.joint_clearance_s)

    def need_rng() -> np.random.Generator:
        if rng is None:
            raise ConfigError(f'clearance ({kind}): directions not given and no random seed')
        return rng

    if kind == 'effective_length':
        names = ('delta_a1', 'delta_a2', 'delta_b1', 'delta_b2')
        given = [_angles(flat, k) for k in names]
        if any(g is None for g in given):
            drawn = EffectiveLengthClearance.random(r_a, r_b, need_rng())
            given = [g if g is not None else getattr(drawn, k)
                     for g, k in zip(given, names, strict=True)]
        return EffectiveLengthClearance(r_a, r_b, *given)  # type: ignore[arg-type]
    if kind == 'vector':
        u = _offsets(flat, 'u_offsets', r_a)
        s = _offsets(flat, 's_offsets', r_b)
        if u is None or s is None:
            drawn_v = VectorClearance.random(r_a, r_b, need_rng())
            u = u if u is not None else drawn_v.u_offsets
            s = s if s is not None else drawn_v.s_offsets
        return VectorClearance(u, s)
    if kind == 'load':  # closed by the joint forces (positioning_cell.load_clearance)
        from positioning_cell.load_clearance import LoadAwareClearance
        return LoadAwareClearance.from_params(flat, r_a, r_b)
    raise ConfigError(
        f'clearance.model = {kind!r}: expected one of none, effective_length, vector, load')


def _length(flat: Mapping[str, Any], key: str, default: float) -> float:
    value = flat.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value >= 0.0):
        raise ConfigError(f'clearance.{key} = {value!r}: expected a length >= 0 m')
    return float(value)


def _angles(flat: Mapping[str, Any], key: str) -> Triple | None:
    value = flat.get(key)
    if value is None or (hasattr(value, '__len__') and len(value) == 0):
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise ConfigError(f'clearance.{key} = {value!r}: expected 3 angles (rad)') from err
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f'clearance.{key} = {value!r}: expected 3 finite angles (rad)')
    return _triple(arr)


def _offsets(flat: Mapping[str, Any], key: str,
             bound: float) -> tuple[Triple, Triple, Triple] | None:
    value = flat.get(key)
    if value is None or (hasattr(value, '__len__') and len(value) == 0):
        return None
    try:
        arr = np.asarray(value, dtype=float).reshape(3, 3)
    except (TypeError, ValueError) as err:
        raise ConfigError(f'clearance.{key} = {value!r}: expected 9 numbers (m)') from err
    if not np.all(np.isfinite(arr)) or np.any(np.linalg.norm(arr, axis=1) > bound * (1 + 1e-9)):
        raise ConfigError(
            f'clearance.{key} = {value!r}: each offset must be finite with length <= {bound} m')
    return (_triple(arr[0]), _triple(arr[1]), _triple(arr[2]))


def monte_carlo_pose_errors(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                            r_a: float, r_b: float, samples: int, rng: np.random.Generator,
                            kind: str = 'effective_length') -> FloatArray:
    """Pose errors (samples, N, 6) of an uncompensated machine whose clearance directions are
    drawn uniformly (seed 000 Table 1: δ in [0, 2π); vector model: directions on the sphere).

    Each sample commands the nominal inverse kinematics of the N poses and records attained
    − commanded: Δp (m, base frame) and the rotation vector of R_cmdᵀ·R_att (rad).
    """
    p, q = as_pose_batch(position, quaternion)
    cmd = inverse(mech, p, q)
    makers: dict[str, Callable[[float, float, np.random.Generator], ClearanceLike]] = {
        'effective_length': EffectiveLengthClearance.random, 'vector': VectorClearance.random}
    make = makers.get(kind)
    if make is None:
        raise ConfigError(f'kind = {kind!r}: expected effective_length or vector')
    out = np.empty((samples, p.shape[0], 6))
    for s in range(samples):  # one clearance draw per sample; each is a batched FK over poses
        att = make(r_a, r_b, rng).attained_pose(mech, cmd.lengths, cmd.thetas, cmd.phis)
        dp, dr = pose_error(att.position, att.quaternion, p, q)
        out[s, :, :3], out[s, :, 3:] = dp, dr
    return out
