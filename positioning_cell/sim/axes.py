"""The six drive axes of the legs, in ``JOINT_NAMES`` order (docs/conventions/kinematics.md):
three linear
leg drives l_1..l_3 (m) and three rotary drives θ_1..θ_3 on the second U axes (rad)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.mechanism import JOINT_NAMES

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

AXES = len(JOINT_NAMES)

#: True for the linear axes (m), False for the rotary ones (rad), in JOINT_NAMES order.
LINEAR_AXES: BoolArray = np.array([name.endswith('_length') for name in JOINT_NAMES])

def per_axis(linear: float, rotary: float) -> FloatArray:
    """A (6,) vector holding ``linear`` on the length axes and ``rotary`` on the θ axes."""
    return np.where(LINEAR_AXES, float(linear), float(rotary))


def unit_of(axis: int, per_second: int = 0) -> str:
    """SI unit of ``axis`` (m or rad), per second ``per_second`` times ('m/s', 'rad/s^2')."""
    base = 'm' if LINEAR_AXES[axis] else 'rad'
    return base + ('' if per_second == 0 else '/s' if per_second == 1 else f'/s^{per_second}')
