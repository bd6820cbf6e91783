"""The clearance models by name, and building one from its parameter block.

:class:`ClearanceParameters` is the ``clearance:`` block of a node (the simulator's
``truth.clearance``, the positioner's ``compensation.clearance``): the model's name, the
clearances, the seed of directions not given, and one group per model with what only that
model reads. The groups of :class:`Models` are the registry: a new model is one module (its
class and its parameters, with a ``model(inputs)`` method) and one line there.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, Protocol

from positioning_cell.clearance.effective_length import EffectiveLengthParameters
from positioning_cell.clearance.load import LoadParameters
from positioning_cell.clearance.model import ClearanceLike, ClearanceModel, ModelInputs
from positioning_cell.clearance.vector import VectorParameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.parameters import ParameterError, check_fields, group, parse, setting


class ModelParameters(Protocol):
    """A model's parameter group: it builds the model."""

    def model(self, inputs: ModelInputs) -> ClearanceLike:
        """The model these parameters describe."""
        ...


@dataclass(frozen=True)
class Models:
    """The registry: one group per clearance model, named as ``clearance.model`` names it."""

    effective_length: EffectiveLengthParameters = group(
        EffectiveLengthParameters, 'seed 000 eq. 9 (effective leg length)')
    vector: VectorParameters = group(VectorParameters, 'exact model: displaced joint centres')
    load: LoadParameters = group(LoadParameters, 'vector model closed by the joint forces')


#: Names ``clearance.model`` accepts: 'none' and every registered model.
MODEL_NAMES: tuple[str, ...] = ('none', *(f.name for f in fields(Models)))


@dataclass(frozen=True)
class ClearanceParameters(Models):
    """The ``clearance:`` block (see the module docstring)."""

    model: str = setting('effective_length', 'clearance model', choices=MODEL_NAMES)
    r_a: float | None = setting(None, 'U-joint clearance (unset: mechanism.joint_clearance_u)',
                                'm', low=0.0, high=0.01)
    r_b: float | None = setting(None, 'S-joint clearance (unset: mechanism.joint_clearance_s)',
                                'm', low=0.0, high=0.01)
    seed: int = setting(-1, 'seed of the directions not given (-1: all must be given)',
                        low=-1, high=2**31 - 1)

    def __post_init__(self) -> None:
        check_fields(self)


def build(params: ClearanceParameters, mech: Mechanism, payload: Payload | None = None,
          structure: Structure | None = None) -> ClearanceModel:
    """The clearance model ``params`` describe on machine ``mech`` (None for 'none');
    ParameterError naming the key when it cannot be built."""
    if params.model == 'none':
        return None
    inputs = ModelInputs(mech.joint_clearance_u if params.r_a is None else params.r_a,
                         mech.joint_clearance_s if params.r_b is None else params.r_b,
                         params.seed, payload or Payload(), structure or Structure())
    chosen: ModelParameters = getattr(params, params.model)
    try:
        return chosen.model(inputs)
    except ParameterError as err:
        raise err.within('clearance.') from None


def model_from_params(params: Mapping[str, Any], mech: Mechanism,
                      payload: Payload | None = None,
                      structure: Structure | None = None) -> ClearanceModel:
    """A clearance model from a ``clearance:`` block (nested or dotted keys relative to it;
    :class:`ClearanceParameters`). ConfigError names a bad key (``clearance.r_a``)."""
    return build(parse(ClearanceParameters, params, 'clearance.'), mech, payload, structure)
