"""The simulated machine as it really is: the nominal mechanism with geometric errors of its
joint centres, zero offsets of its encoders and its joint clearance. Only the simulators read
it; the cell judges itself against it in reports and tests, never works from it."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell.calibration.machine import MachineModel
from positioning_cell.clearance import ClearanceParameters, build
from positioning_cell.config import flatten
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

FloatArray = NDArray[np.float64]

_ZERO = ((0.0, 0.0, 0.0),) * 3


@dataclass(frozen=True)
class TruthParameters:
    """The simulator's ``truth:`` block (read-only): the clearance (directions not given drawn
    from ``clearance.seed``) and the geometric errors: the U and S joint-centre offsets (added
    to the nominal mechanism's own, 3 legs × (x, y, z) m) and the encoders' zero offsets. Each
    error is the given value plus, when ``geometry_seed`` >= 0, a normal draw of its ``*_sigma``
    (one seeded machine per seed)."""

    clearance: ClearanceParameters = group(
        ClearanceParameters, 'the machine\'s joint clearance',
        default=lambda: ClearanceParameters(seed=0))
    base_offsets: tuple[Triple, ...] = setting(
        _ZERO, 'geometric errors of the U centres, 3 legs x (x, y, z), base frame', 'm',
        length=9)
    platform_offsets: tuple[Triple, ...] = setting(
        _ZERO, 'geometric errors of the S centres, 3 legs x (x, y, z), platform frame', 'm',
        length=9)
    length_offsets: Triple = setting(
        (0.0, 0.0, 0.0), 'encoder zero offsets of the legs: real length = reading + offset',
        'm')
    theta_offsets: Triple = setting(
        (0.0, 0.0, 0.0), 'encoder zero offsets of the theta axes: real = reading + offset',
        'rad')
    geometry_seed: int = setting(-1, 'seed of the drawn geometric errors (-1: none drawn)',
                                 low=-1, high=2**31 - 1)
    joint_centre_sigma: float = setting(1e-4, 'sigma of a drawn joint-centre coordinate', 'm',
                                        low=0.0, high=0.01)
    length_offset_sigma: float = setting(1e-4, 'sigma of a drawn leg zero offset', 'm',
                                         low=0.0, high=0.01)
    theta_offset_sigma: float = setting(3e-4, 'sigma of a drawn theta zero offset', 'rad',
                                        low=0.0, high=0.1)

    def __post_init__(self) -> None:
        check_fields(self)

    def geometric_errors(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(base offsets (3, 3) m, platform offsets (3, 3) m, length offsets (3,) m, theta
        offsets (3,) rad): the given values plus the seeded draws."""
        base = np.asarray(self.base_offsets, dtype=float)
        platform = np.asarray(self.platform_offsets, dtype=float)
        lengths = np.asarray(self.length_offsets, dtype=float)
        thetas = np.asarray(self.theta_offsets, dtype=float)
        if self.geometry_seed >= 0:
            rng = np.random.default_rng(self.geometry_seed)
            base = base + rng.normal(0.0, self.joint_centre_sigma, (3, 3))
            platform = platform + rng.normal(0.0, self.joint_centre_sigma, (3, 3))
            lengths = lengths + rng.normal(0.0, self.length_offset_sigma, 3)
            thetas = thetas + rng.normal(0.0, self.theta_offset_sigma, 3)
        return base, platform, lengths, thetas


class Truth(MachineModel):
    """The simulated machine (a :class:`~positioning_cell.calibration.machine.MachineModel`):
    ``mechanism`` with its joint-centre geometric errors, its ``clearance`` (None: none) and
    its encoders' zero offsets."""

    @classmethod
    def from_parameters(cls, params: TruthParameters, mech: Mechanism,
                        payload: Payload | None = None,
                        structure: Structure | None = None) -> Truth:
        """The truth ``params`` describe over the nominal machine ``mech`` (ConfigError naming
        the ``truth.*`` key when it cannot be built)."""
        base, platform, lengths, thetas = params.geometric_errors()
        real = mech.with_offsets(np.asarray(mech.base_offsets) + base,
                                 np.asarray(mech.platform_offsets) + platform)
        try:
            model = build(params.clearance, real, payload, structure)
        except ParameterError as err:
            raise err.within('truth.') from None
        return cls(real, model, lengths, thetas)


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
