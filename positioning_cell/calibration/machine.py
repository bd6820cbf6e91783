"""A real machine as the cell models it: the nominal mechanism with geometric errors of its
joint centres, zero offsets of its encoders and joint clearance. The simulator's truth is one
such machine; a calibration identifies another from measurements.

Joints: the drives report the encoder values l_enc, θ_enc; the machine's real leg length and
second U angle are l = l_enc + δl and θ = θ_enc + δθ (``length_offsets`` δl in m,
``theta_offsets`` δθ in rad, per leg). The joint centres are the mechanism's own
(``Mechanism.base_offsets`` / ``platform_offsets``), the clearance any model of
:mod:`positioning_cell.clearance` over that mechanism.

A :class:`MachineModel` is also a :class:`positioning_cell.clearance.ClearanceLike`: the mover
uses it in place of a clearance model (it ignores the nominal mechanism it is handed and uses
its own geometry), so every mode works on the calibrated machine unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance import ClearanceModel, attained_pose, compensate
from positioning_cell.core.kinematics import ForwardResult, InverseResult
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_vectors

FloatArray = NDArray[np.float64]


def _zeros() -> FloatArray:
    return np.zeros(3)


@dataclass(frozen=True)
class MachineModel:
    """``mechanism`` (with its joint-centre offsets), ``clearance`` over it (None: none), and
    the encoder zero offsets ``length_offsets`` (3,) m and ``theta_offsets`` (3,) rad (module
    docstring)."""

    mechanism: Mechanism = field(default_factory=Mechanism.default)
    clearance: ClearanceModel = None
    length_offsets: FloatArray = field(default_factory=_zeros)
    theta_offsets: FloatArray = field(default_factory=_zeros)

    def __post_init__(self) -> None:
        for name in ('length_offsets', 'theta_offsets'):
            value = as_vectors(getattr(self, name), 3, name)
            if value.shape != (1, 3):
                raise ValueError(f'{name} must hold 3 numbers, one per leg')
            object.__setattr__(self, name, value[0].copy())

    def with_clearance(self, clearance: ClearanceModel) -> MachineModel:
        """The same geometry and offsets with another clearance (e.g. a new payload)."""
        return replace(self, clearance=clearance)

    # -- the two uses of a machine model ----------------------------------------------------
    def poses(self, lengths: ArrayLike, thetas: ArrayLike,
              phi0: ArrayLike | None = None) -> ForwardResult:
        """Where this machine puts the platform when its encoders read lengths (N, 3) m and
        thetas (N, 3) rad (``phi0``: previous passive angles, branch continuity)."""
        real_l = as_vectors(lengths, 3, 'lengths') + self.length_offsets
        real_t = as_vectors(thetas, 3, 'thetas') + self.theta_offsets
        return attained_pose(self.mechanism, self.clearance, real_l, real_t, phi0)

    def commands(self, position: ArrayLike, quaternion: ArrayLike) -> InverseResult:
        """Encoder values (lengths m, thetas rad) that put this machine on poses (N, 3) m,
        (N, 4) x, y, z, w in ``base``; phis are the passive angles the machine shows."""
        real = compensate(self.mechanism, self.clearance, position, quaternion)
        return InverseResult(real.lengths - self.length_offsets,
                             real.thetas - self.theta_offsets, real.phis)

    # -- ClearanceLike (the mover's compensation model) -------------------------------------
    def attained_pose(self, mech: Mechanism, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """:meth:`poses` (``mech``, the nominal machine, is not used)."""
        return self.poses(lengths, thetas, phi0)

    def compensate(self, mech: Mechanism, position: ArrayLike,
                   quaternion: ArrayLike) -> InverseResult:
        """:meth:`commands` (``mech``, the nominal machine, is not used)."""
        return self.commands(position, quaternion)
