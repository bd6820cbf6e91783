"""The identified parameters of a machine model, as one vector: names, scales, and the
:class:`~positioning_cell.calibration.machine.MachineModel` a vector describes.

Order (26): for each leg i = 1..3 the U-centre error (x, y, z; base frame, m), then for each leg
the S-centre error (x, y, z; platform frame, m), the leg zero offsets δl (m), the θ zero
offsets δθ (rad), and the load-driven clearances r_a, r_b (m) of the load model
(:mod:`positioning_cell.clearance.load`). The scales are the expected sizes of each kind (a
machine built to drawing: ~0.1 mm per coordinate, ~0.3 mrad, the design clearance): the
identification works in units of them, so that singular values and information compare kinds.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from positioning_cell.calibration.machine import MachineModel
from positioning_cell.clearance import LoadAwareClearance
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.mechanics.statics import Payload, Structure

FloatArray = NDArray[np.float64]

_AXES = ('x', 'y', 'z')
_LEGS = (1, 2, 3)

#: Every parameter's name, in vector order (module docstring).
PARAMETER_NAMES: tuple[str, ...] = (
    *(f'leg{i}.base_offset.{a}' for i in _LEGS for a in _AXES),
    *(f'leg{i}.platform_offset.{a}' for i in _LEGS for a in _AXES),
    *(f'leg{i}.length_offset' for i in _LEGS),
    *(f'leg{i}.theta_offset' for i in _LEGS),
    'clearance.r_a', 'clearance.r_b',
)
COUNT = len(PARAMETER_NAMES)

#: Slices of the kinds in the vector.
BASE = slice(0, 9)
PLATFORM = slice(9, 18)
LENGTH = slice(18, 21)
THETA = slice(21, 24)
R_A, R_B = 24, 25

#: Units of the parameters, in vector order.
UNITS: tuple[str, ...] = ('m',) * 21 + ('rad',) * 3 + ('m', 'm')


def scales(mech: Mechanism, joint_centre: float = 1e-4, length: float = 1e-4,
           theta: float = 3e-4) -> FloatArray:
    """Expected size of each parameter (COUNT,): m, m, m, rad, and the design clearances."""
    out = np.empty(COUNT)
    out[BASE] = out[PLATFORM] = joint_centre
    out[LENGTH] = length
    out[THETA] = theta
    out[R_A], out[R_B] = mech.joint_clearance_u, mech.joint_clearance_s
    return out


def machine_model(x: FloatArray, nominal: Mechanism, payload: Payload,
                  structure: Structure, seating_force: float = 1.0) -> MachineModel:
    """The machine the vector ``x`` (COUNT,) describes over the nominal mechanism, carrying
    ``payload`` (negative clearances are taken as 0: a gap cannot be negative)."""
    real = nominal.with_offsets(np.asarray(nominal.base_offsets) + x[BASE].reshape(3, 3),
                                np.asarray(nominal.platform_offsets)
                                + x[PLATFORM].reshape(3, 3))
    clearance = LoadAwareClearance(max(float(x[R_A]), 0.0), max(float(x[R_B]), 0.0), payload,
                                   structure, seating_force)
    return MachineModel(real, clearance, x[LENGTH], x[THETA])


def vector_of(model: MachineModel, nominal: Mechanism) -> FloatArray:
    """The vector (COUNT,) of a machine whose clearance is a load model (or none) over
    ``nominal``: the inverse of :func:`machine_model` (used to judge a calibration against a
    simulated truth)."""
    x = np.zeros(COUNT)
    x[BASE] = (np.asarray(model.mechanism.base_offsets)
               - np.asarray(nominal.base_offsets)).ravel()
    x[PLATFORM] = (np.asarray(model.mechanism.platform_offsets)
                   - np.asarray(nominal.platform_offsets)).ravel()
    x[LENGTH], x[THETA] = model.length_offsets, model.theta_offsets
    if isinstance(model.clearance, LoadAwareClearance):
        x[R_A], x[R_B] = model.clearance.r_a, model.clearance.r_b
    return x
