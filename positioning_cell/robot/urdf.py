"""The URDF of the 3-UPS positioner (docs/conventions/robot-description.md).

URDF describes trees, and the machine is a closed chain: the tree here follows each leg from
the base through its U joint (``leg<i>_phi`` about e_t,i, then ``leg<i>_theta`` about the
rotated −e_r,i), its prismatic joint ``leg<i>_length`` (the whole leg length l_i, so that the
joint value is the one on /legs/joint_states) and its S joint (three revolute joints
``leg<i>_s_x``, ``_s_y``, ``_s_z``: R_rod,iᵀ·R = Rx·Ry·Rz, :mod:`.joints`), and hangs the
platform from leg 1's S joint; the chain is cut at the S joints of legs 2 and 3, whose last
links take the platform's orientation at the S-joint centre B_i. With the joint values of
:func:`positioning_cell.robot.joints.joint_positions`, every link lies where the kinematics puts
it (seed 000 eqs. 1-3; kinematics.md), and a standard robot_state_publisher fed /joint_states
and this description gives the transforms the cell publishes on /tf.

Lengths in m, angles in rad; the joint centres include the mechanism's offsets (a calibrated
machine's identified geometry). Visuals are primitives (discs, cylinders, spheres).
"""

from __future__ import annotations

import numpy as np

from positioning_cell import names
from positioning_cell.core.mechanism import LEG_AZIMUTHS, PASSIVE_JOINT_NAMES, Mechanism

#: The robot's name in the description.
ROBOT_NAME = 'positioning_cell_3ups'
#: The tree's root link: the ``base`` frame of kinematics.md.
ROOT_LINK = names.BASE_FRAME
#: The link of the platform frame (a child of leg 1's S joint).
PLATFORM_LINK = names.PLATFORM_FRAME
#: The legs, 1-based as in the joint names.
LEGS = (1, 2, 3)
#: The S joint's three revolute joints of each leg (axes x, y, z of the leg's rod frame).
S_JOINT_NAMES = tuple(f'leg{i}_s_{axis}' for axis in 'xyz' for i in LEGS)
#: Every joint of the tree that moves, in the order of the cell's /joint_states: the actuated
#: joints (names.JOINT_NAMES), the U joints' passive angles, then the S joints' angles.
MOVING_JOINT_NAMES = (*names.JOINT_NAMES, *PASSIVE_JOINT_NAMES, *S_JOINT_NAMES)
#: The fixed joint that hangs the platform from leg 1's S joint.
PLATFORM_JOINT = 'leg1_s_platform'

#: Sizes of the visuals (m): drawing only, no part of the model.
_BASE_DISC = (0.03, 0.010)  # margin beyond R_A, thickness
_PLATFORM_DISC = (0.02, 0.008)  # margin beyond R_B, thickness
_CYLINDER_RADIUS, _ROD_RADIUS, _BALL_RADIUS, _CROSS = 0.012, 0.006, 0.010, 0.018
_COLOURS = {'frame': '0.55 0.57 0.60 1', 'leg': '0.20 0.60 0.90 1', 'rod': '0.85 0.85 0.88 1',
            'joint': '0.95 0.65 0.15 1', 'platform': '0.25 0.35 0.85 0.9'}


def link_names(leg: int) -> tuple[str, str, str, str, str, str]:
    """The links of leg ``leg`` (1-3) from the base outward: the U joint's cross (after φ), the
    cylinder (after θ; z along the leg), the rod (after the length; origin at the S-joint
    centre B_i), the S joint's two inner links, and its ball (the platform's orientation)."""
    return (f'leg{leg}_u', f'leg{leg}_cylinder', f'leg{leg}_rod', f'leg{leg}_s_x_link',
            f'leg{leg}_s_y_link', f'leg{leg}_s')


def _numbers(values: object) -> str:
    """Numbers as URDF writes them, each exactly (the shortest text that reads back equal)."""
    return ' '.join(repr(float(v)) for v in np.ravel(np.asarray(values, dtype=float)))


def _visual(geometry: str, xyz: tuple[float, float, float], colour: str) -> str:
    return (f'    <visual><origin xyz="{_numbers(xyz)}" rpy="0 0 0"/>'
            f'<geometry>{geometry}</geometry><material name="{colour}"/></visual>\n')


def _link(name: str, visual: str = '') -> str:
    if not visual:
        return f'  <link name="{name}"/>\n'
    return f'  <link name="{name}">\n{visual}  </link>\n'


def _joint(name: str, kind: str, parent: str, child: str, *, xyz: object = (0.0, 0.0, 0.0),
           rpy: object = (0.0, 0.0, 0.0), axis: object | None = None,
           limits: tuple[float, float] | None = None) -> str:
    lines = [f'  <joint name="{name}" type="{kind}">',
             f'    <parent link="{parent}"/><child link="{child}"/>',
             f'    <origin xyz="{_numbers(xyz)}" rpy="{_numbers(rpy)}"/>']
    if axis is not None:
        lines.append(f'    <axis xyz="{_numbers(axis)}"/>')
    if limits is not None:  # effort and velocity are not modelled: URDF requires them, 0
        lines.append(f'    <limit lower="{float(limits[0])!r}" upper="{float(limits[1])!r}" '
                     'effort="0" velocity="0"/>')
    return '\n'.join(lines) + '\n  </joint>\n'


def _cylinder(radius: float, length: float) -> str:
    return f'<cylinder radius="{radius:.6g}" length="{length:.6g}"/>'


def machine_urdf(mech: Mechanism) -> str:
    """The URDF (XML text) of the machine ``mech``: joint origins at its U-joint centres A_i
    and, for the platform, its S-joint centre b_1 (offsets included); joint limits its
    stroke, its U angles and its S-joint tilt (``tilt_max`` bounds each of ``s_x`` and
    ``s_y``; ``s_z``, the spin of the ball, is continuous)."""
    a, b = mech.base_joints, mech.platform_joints
    cylinder = 0.55 * mech.length_min
    rod = 0.55 * mech.length_max
    parts = ['<?xml version="1.0"?>\n',
             f'<robot name="{ROBOT_NAME}">\n',
             *(f'  <material name="{k}"><color rgba="{v}"/></material>\n'
               for k, v in _COLOURS.items()),
             _link(ROOT_LINK, _visual(_cylinder(mech.base_radius + _BASE_DISC[0], _BASE_DISC[1]),
                                      (0.0, 0.0, -0.5 * _BASE_DISC[1]), 'frame'))]
    for i, (leg, gamma) in enumerate(zip(LEGS, LEG_AZIMUTHS, strict=True)):
        u, cyl, rod_link, s_x, s_y, ball = link_names(leg)
        parts += [
            _joint(f'leg{leg}_phi', 'revolute', ROOT_LINK, u, xyz=a[i], rpy=(0.0, 0.0, gamma),
                   axis=(0.0, 1.0, 0.0), limits=(mech.phi_min, mech.phi_max)),
            _link(u, _visual(f'<box size="{_CROSS} {_CROSS} {_CROSS}"/>', (0.0, 0.0, 0.0),
                             'joint')),
            _joint(f'leg{leg}_theta', 'revolute', u, cyl, axis=(-1.0, 0.0, 0.0),
                   limits=(mech.theta_min, mech.theta_max)),
            _link(cyl, _visual(_cylinder(_CYLINDER_RADIUS, cylinder), (0.0, 0.0, 0.5 * cylinder),
                               'leg')),
            _joint(f'leg{leg}_length', 'prismatic', cyl, rod_link, axis=(0.0, 0.0, 1.0),
                   limits=(mech.length_min, mech.length_max)),
            _link(rod_link, _visual(_cylinder(_ROD_RADIUS, rod), (0.0, 0.0, -0.5 * rod), 'rod')),
            _joint(f'leg{leg}_s_x', 'revolute', rod_link, s_x, axis=(1.0, 0.0, 0.0),
                   limits=(-mech.tilt_max, mech.tilt_max)),
            _link(s_x),
            _joint(f'leg{leg}_s_y', 'revolute', s_x, s_y, axis=(0.0, 1.0, 0.0),
                   limits=(-mech.tilt_max, mech.tilt_max)),
            _link(s_y),
            _joint(f'leg{leg}_s_z', 'continuous', s_y, ball, axis=(0.0, 0.0, 1.0)),
            _link(ball, _visual(f'<sphere radius="{_BALL_RADIUS}"/>', (0.0, 0.0, 0.0), 'joint')),
        ]
    parts += [_joint(PLATFORM_JOINT, 'fixed', link_names(1)[-1], PLATFORM_LINK, xyz=-b[0]),
              _link(PLATFORM_LINK, _visual(
                  _cylinder(mech.platform_radius + _PLATFORM_DISC[0], _PLATFORM_DISC[1]),
                  (0.0, 0.0, -0.5 * _PLATFORM_DISC[1]), 'platform')),
              '</robot>\n']
    return ''.join(parts)
