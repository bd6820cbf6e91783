"""Joint-clearance models of the 3-UPS positioner and model-based compensation.

- :mod:`.model`: the protocol every model implements; :func:`attained_pose` (where a machine
  with that clearance puts the platform) and :func:`compensate` (the joint commands that cancel
  it). ``None`` stands for a machine without clearance.
- :mod:`.effective_length`: seed 000's eq. (9) model; :mod:`.vector`: the exact model of
  displaced joint centres; :mod:`.load`: the vector model closed by the joint forces.
- :mod:`.registry`: the models by name and the ``clearance:`` parameter block that builds one.
- :mod:`.sampling`: pose errors of an uncompensated machine over random clearance directions.

All lengths in m, angles in rad.
"""

from positioning_cell.clearance.effective_length import (
    EffectiveLengthClearance,
    EffectiveLengthParameters,
)
from positioning_cell.clearance.load import LoadAwareClearance, LoadParameters
from positioning_cell.clearance.model import (
    ClearanceLike,
    ClearanceModel,
    ModelInputs,
    attained_pose,
    compensate,
)
from positioning_cell.clearance.registry import (
    MODEL_NAMES,
    ClearanceParameters,
    Models,
    build,
    model_from_params,
)
from positioning_cell.clearance.sampling import monte_carlo_pose_errors
from positioning_cell.clearance.vector import VectorClearance, VectorParameters

__all__ = [
    'MODEL_NAMES',
    'ClearanceLike',
    'ClearanceModel',
    'ClearanceParameters',
    'EffectiveLengthClearance',
    'EffectiveLengthParameters',
    'LoadAwareClearance',
    'LoadParameters',
    'ModelInputs',
    'Models',
    'VectorClearance',
    'VectorParameters',
    'attained_pose',
    'build',
    'compensate',
    'model_from_params',
    'monte_carlo_pose_errors',
]
