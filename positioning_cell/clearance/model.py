"""What a clearance model is (the protocol every model implements), and the two uses of one:
where a machine with that clearance puts the platform, and the joint commands that compensate
it. ``None`` stands for a machine without clearance (nominal kinematics)."""

from __future__ import annotations

from typing import NamedTuple, Protocol, TypeAlias

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell.core.kinematics import ForwardResult, InverseResult, forward, inverse
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.parameters import ParameterError


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


class ModelInputs(NamedTuple):
    """What building a model from its parameter block may use besides the block itself: the
    clearances ``r_a``, ``r_b`` (m), the ``seed`` that draws directions not given (−1: none),
    and the ``payload`` and machine ``structure`` (for load-driven models)."""

    r_a: float
    r_b: float
    seed: int
    payload: Payload
    structure: Structure

    def generator(self, model: str) -> np.random.Generator:
        """The generator of the directions not given; ParameterError when there is no seed."""
        if self.seed < 0:
            raise ParameterError('seed', self.seed, f'the {model} model\'s directions are not '
                                 'all given: set clearance.seed >= 0 to draw them')
        return np.random.default_rng(self.seed)
