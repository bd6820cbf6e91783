"""Seed 000's effective-length clearance model, eq. (9): the U-joint eccentricity r_a and the
S-joint offset r_b, each with two direction angles per leg, change each leg's effective length
by Δl_i(φ_i, θ_i). It cannot produce lateral errors (see :mod:`.vector` for the exact model).
All lengths in m, angles in rad."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance.model import ModelInputs
from positioning_cell.core.kinematics import (
    ForwardResult,
    InverseResult,
    forward,
    home_phis,
    inverse,
)
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import Triple, triple
from positioning_cell.errors import ConfigError, ConvergenceError
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]

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
        return cls(r_a, r_b, *(triple(row) for row in d))

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
        """l_cmd = l_ideal − Δl(φ_ideal, θ_ideal) (docs/conventions/kinematics.md): exact, because
        the
        platform then sits where φ = φ_ideal."""
        ideal = inverse(mech, position, quaternion)
        delta = self.length_delta(ideal.phis, ideal.thetas)
        return InverseResult(ideal.lengths - delta, ideal.thetas, ideal.phis)



@dataclass(frozen=True)
class EffectiveLengthParameters:
    """The ``clearance.effective_length`` block: the direction angles δ of eq. (9) per leg;
    those not given are drawn uniformly in [0, 2π)."""

    delta_a1: Triple | None = setting(
        None, "U-joint direction angle δ_a' per leg (unset: drawn)", 'rad')
    delta_a2: Triple | None = setting(
        None, "U-joint direction angle δ_a'' per leg (unset: drawn)", 'rad')
    delta_b1: Triple | None = setting(
        None, "S-joint direction angle δ_b' per leg (unset: drawn)", 'rad')
    delta_b2: Triple | None = setting(
        None, "S-joint direction angle δ_b'' per leg (unset: drawn)", 'rad')

    def __post_init__(self) -> None:
        check_fields(self)

    def model(self, inputs: ModelInputs) -> EffectiveLengthClearance:
        """The model these parameters give with clearances r_a, r_b."""
        names = ('delta_a1', 'delta_a2', 'delta_b1', 'delta_b2')
        given = [getattr(self, n) for n in names]
        if any(g is None for g in given):
            drawn = EffectiveLengthClearance.random(inputs.r_a, inputs.r_b, inputs.generator(
                'effective_length'))
            given = [g if g is not None else getattr(drawn, n)
                     for g, n in zip(given, names, strict=True)]
        return EffectiveLengthClearance(inputs.r_a, inputs.r_b, *given)
