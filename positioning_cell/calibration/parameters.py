"""The identified parameters of a machine model, as one vector: names, scales, and the
:class:`~positioning_cell.calibration.machine.MachineModel` a vector describes.

Order (43): for each leg i = 1..3 the U-centre error (x, y, z; base frame, m), then for each leg
the S-centre error (x, y, z; platform frame, m), the leg zero offsets δl (m), the θ zero
offsets δθ (rad), and the load-driven clearances r_a, r_b (m) of the load model
(:mod:`positioning_cell.clearance.load`) -- the 26 of calibration file format 1 -- then the
terms beyond geometry (:class:`~positioning_cell.calibration.machine.MachineTerms`): the legs'
axial compliances (m/N) and the θ drives' torsional compliances (rad/(N m)), the legs' and the
structure's thermal expansion (1/K), the legs' lead scales (1), and the reversal half-bands of
the legs (m) and θ axes (rad). :data:`CLASSES` names the slice of each class. The scales are
the expected sizes of each kind (a machine built to drawing: ~0.1 mm per coordinate, ~0.3 mrad,
the design clearance, the nominal compliance): the identification works in units of them, so
that singular values and information compare kinds.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from positioning_cell.calibration.conditions import STANDARD_TEMPERATURE
from positioning_cell.calibration.machine import MachineModel, MachineTerms
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
    *(f'leg{i}.compliance' for i in _LEGS),
    *(f'leg{i}.theta_compliance' for i in _LEGS),
    'thermal.leg_expansion', 'thermal.structure_expansion',
    *(f'leg{i}.lead_scale' for i in _LEGS),
    *(f'leg{i}.length_reversal' for i in _LEGS),
    *(f'leg{i}.theta_reversal' for i in _LEGS),
)
COUNT = len(PARAMETER_NAMES)
#: The parameters of calibration file format 1 (geometry, zero offsets, clearance).
FORMAT1_COUNT = 26

#: Slices of the kinds in the vector.
BASE = slice(0, 9)
PLATFORM = slice(9, 18)
LENGTH = slice(18, 21)
THETA = slice(21, 24)
R_A, R_B = 24, 25
CLEARANCE = slice(24, 26)
LEG_COMPLIANCE = slice(26, 29)
THETA_COMPLIANCE = slice(29, 32)
COMPLIANCE = slice(26, 32)
LEG_EXPANSION, STRUCTURE_EXPANSION = 32, 33
THERMAL = slice(32, 34)
LEAD = slice(34, 37)
REVERSAL = slice(37, 43)

#: The parameter classes: name -> slice of the vector. ``geometry`` and ``clearance`` are
#: always modelled; the others can be left out (IdentificationSettings.fit_*).
CLASSES: dict[str, slice] = {'geometry': slice(0, 24), 'clearance': CLEARANCE,
                             'compliance': COMPLIANCE, 'thermal': THERMAL, 'lead': LEAD,
                             'reversal': REVERSAL}
#: The classes beyond format 1 (the terms of :class:`MachineTerms`).
TERM_CLASSES = ('compliance', 'thermal', 'lead', 'reversal')

#: Units of the parameters, in vector order.
UNITS: tuple[str, ...] = (('m',) * 21 + ('rad',) * 3 + ('m', 'm') + ('m/N',) * 3
                          + ('rad/(N m)',) * 3 + ('1/K',) * 2 + ('1',) * 3 + ('m',) * 3
                          + ('rad',) * 3)

#: Expected sizes of the terms: expansion 1/K (steel 1.2e-5, aluminium 2.3e-5), lead scale
#: (a ground screw's lead error, ~50 µm/m), reversal half-band m, rad.
EXPANSION_SCALE = 1.5e-5
LEAD_SCALE = 5e-5
LENGTH_REVERSAL_SCALE = 2e-6
THETA_REVERSAL_SCALE = 2e-5


def _compliance(stiffness: float, fallback: float) -> float:
    return 1.0 / (stiffness if np.isfinite(stiffness) else fallback)


def scales(mech: Mechanism, joint_centre: float = 1e-4, length: float = 1e-4,
           theta: float = 3e-4, structure: Structure | None = None) -> FloatArray:
    """Expected size of each parameter (COUNT,): m, m, m, rad, the design clearances, the
    nominal compliances of ``structure`` (default :class:`Structure`; a rigid one: the
    default's), and the term scales above."""
    s, default = structure or Structure(), Structure()
    out = np.empty(COUNT)
    out[BASE] = out[PLATFORM] = joint_centre
    out[LENGTH] = length
    out[THETA] = theta
    out[R_A], out[R_B] = mech.joint_clearance_u, mech.joint_clearance_s
    out[LEG_COMPLIANCE] = _compliance(s.leg_stiffness, default.leg_stiffness)
    out[THETA_COMPLIANCE] = _compliance(s.theta_stiffness, default.theta_stiffness)
    out[THERMAL] = EXPANSION_SCALE
    out[LEAD] = LEAD_SCALE
    out[REVERSAL] = (LENGTH_REVERSAL_SCALE,) * 3 + (THETA_REVERSAL_SCALE,) * 3
    return out


def terms_of(x: FloatArray, reference_temperature: float = STANDARD_TEMPERATURE
             ) -> MachineTerms:
    """The :class:`MachineTerms` of the vector ``x`` (COUNT,)."""
    return MachineTerms(x[LEG_COMPLIANCE], x[THETA_COMPLIANCE], float(x[LEG_EXPANSION]),
                        float(x[STRUCTURE_EXPANSION]), reference_temperature, x[LEAD],
                        x[REVERSAL])


def machine_model(x: FloatArray, nominal: Mechanism, payload: Payload,
                  structure: Structure, seating_force: float = 1.0,
                  reference_temperature: float = STANDARD_TEMPERATURE) -> MachineModel:
    """The machine the vector ``x`` (COUNT,) describes over the nominal mechanism, carrying
    ``payload`` (negative clearances are taken as 0: a gap cannot be negative), its thermal
    terms about ``reference_temperature`` °C."""
    real = nominal.with_offsets(np.asarray(nominal.base_offsets) + x[BASE].reshape(3, 3),
                                np.asarray(nominal.platform_offsets)
                                + x[PLATFORM].reshape(3, 3))
    clearance = LoadAwareClearance(max(float(x[R_A]), 0.0), max(float(x[R_B]), 0.0), payload,
                                   structure, seating_force)
    return MachineModel(real, clearance, x[LENGTH], x[THETA],
                        terms_of(x, reference_temperature), payload, structure)


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
    t = model.terms
    x[LEG_COMPLIANCE], x[THETA_COMPLIANCE] = t.leg_compliance, t.theta_compliance
    x[LEG_EXPANSION], x[STRUCTURE_EXPANSION] = t.leg_expansion, t.structure_expansion
    x[LEAD], x[REVERSAL] = t.lead_scale, t.reversal
    return x
