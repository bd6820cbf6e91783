"""The exact clearance model: 3-D offset vectors of each U centre (base frame, |e_a| ≤ r_a) and
ball centre (platform frame, |e_b| ≤ r_b), solved by the same kinematics on the displaced joint
centres (docs/conventions/kinematics.md). All lengths in m."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance.model import ModelInputs
from positioning_cell.core.kinematics import ForwardResult, InverseResult, forward, inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import Triple, triple
from positioning_cell.errors import ConfigError
from positioning_cell.parameters import ParameterError, check_fields, setting

FloatArray = NDArray[np.float64]
Offsets = tuple[Triple, Triple, Triple]


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
            return (triple(v[0]), triple(v[1]), triple(v[2]))
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



@dataclass(frozen=True)
class VectorParameters:
    """The ``clearance.vector`` block: the offsets, 3 legs × (x, y, z); those not given are
    drawn with full magnitude in directions uniform on the sphere."""

    u_offsets: tuple[Triple, ...] | None = setting(
        None, 'U-centre offsets, 3 legs x (x, y, z), base frame, each |e| <= r_a (unset: drawn)',
        'm', length=9)
    s_offsets: tuple[Triple, ...] | None = setting(
        None, 'ball-centre offsets, 3 legs x (x, y, z), platform frame, each |e| <= r_b (unset: '
        'drawn)', 'm', length=9)

    def __post_init__(self) -> None:
        check_fields(self)

    def model(self, inputs: ModelInputs) -> VectorClearance:
        """The model these parameters give with clearances r_a, r_b."""
        u, s = self.u_offsets, self.s_offsets
        for name, value, bound in (('u_offsets', u, inputs.r_a), ('s_offsets', s, inputs.r_b)):
            if value is not None and np.any(np.linalg.norm(value, axis=1) > bound * (1 + 1e-9)):
                raise ParameterError(f'vector.{name}', value,
                                     f'each offset must have length <= {bound} m')
        if u is None or s is None:
            drawn = VectorClearance.random(inputs.r_a, inputs.r_b, inputs.generator('vector'))
            u = u if u is not None else drawn.u_offsets
            s = s if s is not None else drawn.s_offsets
        return VectorClearance(u, s)  # type: ignore[arg-type]
