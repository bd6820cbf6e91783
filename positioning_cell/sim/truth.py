"""The simulated machine as it really is: the nominal mechanism with geometric errors of its
joint centres and its joint clearance. Only the simulators read it; the cell judges itself
against it in reports and tests, never works from it."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from positioning_cell.clearance import (
    ClearanceModel,
    ClearanceParameters,
    attained_pose,
    build,
)
from positioning_cell.config import flatten
from positioning_cell.core.kinematics import ForwardResult
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import Triple
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.parameters import (
    ParameterError,
    block,
    check_fields,
    group,
    parse,
    setting,
)

_ZERO = ((0.0, 0.0, 0.0),) * 3


@dataclass(frozen=True)
class TruthParameters:
    """The simulator's ``truth:`` block (read-only): the clearance (directions not given drawn
    from ``clearance.seed``) and geometric errors of the U and S joint centres, added to the
    nominal mechanism's own offsets, 3 legs × (x, y, z) m."""

    clearance: ClearanceParameters = group(
        ClearanceParameters, 'the machine\'s joint clearance',
        default=lambda: ClearanceParameters(seed=0))
    base_offsets: tuple[Triple, ...] = setting(
        _ZERO, 'geometric errors of the U centres, 3 legs x (x, y, z), base frame', 'm',
        length=9)
    platform_offsets: tuple[Triple, ...] = setting(
        _ZERO, 'geometric errors of the S centres, 3 legs x (x, y, z), platform frame', 'm',
        length=9)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class Truth:
    """The simulated machine: ``mechanism`` with its joint-centre geometric errors, and its
    joint ``clearance`` (None: none)."""

    mechanism: Mechanism = field(default_factory=Mechanism.default)
    clearance: ClearanceModel = None

    @classmethod
    def from_parameters(cls, params: TruthParameters, mech: Mechanism,
                        payload: Payload | None = None,
                        structure: Structure | None = None) -> Truth:
        """The truth ``params`` describe over the nominal machine ``mech`` (ConfigError naming
        the ``truth.*`` key when it cannot be built)."""
        try:
            model = build(params.clearance, mech, payload, structure)
        except ParameterError as err:
            raise err.within('truth.') from None
        real = mech.with_offsets(np.asarray(mech.base_offsets) + np.asarray(params.base_offsets),
                                 np.asarray(mech.platform_offsets)
                                 + np.asarray(params.platform_offsets))
        return cls(real, model)

    def attained_pose(self, lengths: ArrayLike, thetas: ArrayLike,
                      phi0: ArrayLike | None = None) -> ForwardResult:
        """True platform poses for actual joints: lengths (N, 3) m, thetas (N, 3) rad;
        ``phi0`` the previous passive angles (branch continuity), see clearance.attained_pose."""
        return attained_pose(self.mechanism, self.clearance, lengths, thetas, phi0)


def truth_from_params(params: Mapping[str, Any], mech: Mechanism,
                      payload: Payload | None = None,
                      structure: Structure | None = None) -> Truth:
    """The truth from a ``truth:`` block (nested or dotted keys, relative to it or prefixed
    ``truth.``) over the nominal ``mech`` (:class:`TruthParameters`); ConfigError names a bad
    key."""
    flat = flatten(params)
    if any(k.startswith('truth.') for k in flat):
        flat = block(flat, 'truth')
    return Truth.from_parameters(parse(TruthParameters, flat, 'truth.'), mech, payload,
                                 structure)
