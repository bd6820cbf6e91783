"""Compliance of the real machine under its load: each leg yields axially to its force, each
θ drive to its torque, and each U and S joint radially to the force it carries (seed 002 §3,
eq. 28: δq = −K⁻¹τ). The efforts and joint forces are the statics of the pose, the payload
and the machine's parts (:mod:`positioning_cell.mechanics.statics`), so the deflection changes
with pose and payload.

Stiffnesses are the machine's own (``truth.compliance.*``), not the cell's nominal
``structure.leg_stiffness`` / ``theta_stiffness``: a real nut's preload and a real gear's
stiffness differ from the catalogue. Per leg: the length between the joint centres is
l − F/k_l (F > 0 pushes: the leg shortens), θ − τ/k_θ; the U centre moves by F_A/k_U along
the force the leg exerts on the base (base frame), the ball centre by F_B/k_S along the force
it exerts on the platform (platform frame), the sign convention of
:class:`positioning_cell.clearance.load.LoadAwareClearance`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import matrix_from_quaternion
from positioning_cell.mechanics.statics import (
    JointForces,
    Payload,
    Structure,
    actuator_efforts,
    joint_forces,
)
from positioning_cell.parameters import check_fields, setting

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ComplianceParameters:
    """The ``truth.compliance`` block: the machine's own stiffnesses (module docstring).
    Defaults: a leg 16 % softer axially than the cell's nominal 5e7 N/m (nut preload below
    catalogue, THK/NSK preloaded-nut rigidity data), a θ drive 30 % stiffer than the nominal
    4e4 N·m/rad (a size-25 strain-wave gear stiffens with torque: at the ~40 N·m the lower
    legs hold it works in its K2-K3 region, Harmonic Drive CSF catalogue, while the cell's
    figure is the low-torque K1 order), joints with preloaded bearings radially 1-1.5e8 N/m
    (INA needle roller and spherical plain bearing data)."""

    enabled: bool = setting(False, 'simulate the machine\'s compliance')
    leg_stiffness: float = setting(4.2e7, 'axial stiffness of each real leg', 'N/m', low=0.0,
                                   low_open=True)
    theta_stiffness: float = setting(5.2e4, 'torsional stiffness of each real theta drive',
                                     'N m/rad', low=0.0, low_open=True)
    u_radial_stiffness: float = setting(1.5e8, 'radial stiffness of a U joint', 'N/m',
                                        low=0.0, low_open=True)
    s_radial_stiffness: float = setting(1.0e8, 'radial stiffness of an S joint', 'N/m',
                                        low=0.0, low_open=True)

    def __post_init__(self) -> None:
        check_fields(self)


class Yield(NamedTuple):
    """How the loaded machine yields at N poses: joint deformations (N, 6) m, rad that the
    drives must add to stand where the rigid machine would (F/k_l, τ/k_θ), the U-centre
    offsets (N, 3, 3) m, base frame, and the ball-centre offsets (N, 3, 3) m, platform
    frame; ``forces``: the joint forces that load them (the statics, which a load-driven
    clearance of the same payload closes its joints with too)."""

    joints: FloatArray
    u_offsets: FloatArray
    s_offsets: FloatArray
    forces: JointForces


def yielding(params: ComplianceParameters, mech: Mechanism, position: FloatArray,
             quaternion: FloatArray, payload: Payload, structure: Structure) -> Yield:
    """The machine's yield (module docstring) at poses (N, 3) m, (N, 4) x, y, z, w."""
    efforts = actuator_efforts(mech, position, quaternion, payload, structure)
    forces = joint_forces(mech, position, quaternion, payload, structure, efforts)
    stiffness = np.r_[[params.leg_stiffness] * 3, [params.theta_stiffness] * 3]
    rot = matrix_from_quaternion(quaternion)
    s_off = np.einsum('nji,nkj->nki', rot, forces.at_platform) / params.s_radial_stiffness
    return Yield(efforts / stiffness, forces.at_base / params.u_radial_stiffness, s_off,
                 forces)
