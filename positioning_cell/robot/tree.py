"""A URDF's kinematic tree and its transforms, as robot_state_publisher makes them: each
joint's parent → child transform for joint values (moving joints on /tf, fixed joints once on
/tf_static), and the pose of any link in the root, composed along the tree.

URDF semantics (wiki.ros.org/urdf/XML/joint): a joint's child frame is its origin (xyz, then
rpy as fixed-axis roll about x, pitch about y, yaw about z: R = Rz·Ry·Rx) followed by the
joint's motion: a rotation by q about ``axis`` (revolute, continuous) or a translation q·axis
(prismatic), axis in the joint frame. Fixed joints do not move; floating and planar joints are
refused (the cell's description has none). Lengths m, angles rad.

Numpy only: a node turns one joint state into transforms in some 0.1 ms, with no scipy.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.core.poses import quaternion_from_euler_xyz
from positioning_cell.errors import InputError

FloatArray = NDArray[np.float64]

#: Joint types the tree moves, and the fixed one.
REVOLUTE_TYPES = ('revolute', 'continuous')
PRISMATIC = 'prismatic'
FIXED = 'fixed'


@dataclass(frozen=True)
class UrdfJoint:
    """One joint of a URDF: ``xyz`` (3,) m and ``quaternion`` (4,) x, y, z, w of its origin in
    the parent link's frame, ``axis`` (3,) unit, in the joint frame."""

    name: str
    kind: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    axis: tuple[float, float, float]


class Transforms(NamedTuple):
    """Parent → child transforms of several joints for N joint states: ``translation``
    (N, J, 3) m and ``quaternion`` (N, J, 4) x, y, z, w, the child frame in the parent's."""

    parents: tuple[str, ...]
    children: tuple[str, ...]
    translation: FloatArray
    quaternion: FloatArray


def _numbers(element: ET.Element | None, attribute: str, default: str, what: str) -> FloatArray:
    text = default if element is None else element.get(attribute, default)
    try:
        values = np.array([float(v) for v in text.split()])
    except ValueError as err:
        raise InputError(f'{what}: {attribute}={text!r} is not three numbers') from err
    if values.shape != (3,) or not np.isfinite(values).all():
        raise InputError(f'{what}: {attribute}={text!r} is not three finite numbers')
    return values


def _parse_joint(element: ET.Element) -> UrdfJoint:
    name, kind = element.get('name', ''), element.get('type', '')
    what = f'URDF joint {name!r}'
    if kind not in (*REVOLUTE_TYPES, PRISMATIC, FIXED):
        raise InputError(f'{what}: type {kind!r} is not one of revolute, continuous, '
                         'prismatic, fixed')
    parent, child = element.find('parent'), element.find('child')
    if parent is None or child is None or not parent.get('link') or not child.get('link'):
        raise InputError(f'{what}: needs <parent link=...> and <child link=...>')
    origin = element.find('origin')
    xyz = _numbers(origin, 'xyz', '0 0 0', what)
    rpy = _numbers(origin, 'rpy', '0 0 0', what)
    axis = _numbers(element.find('axis'), 'xyz', '1 0 0', what)
    norm = float(np.linalg.norm(axis))
    if kind != FIXED and norm < 1e-12:
        raise InputError(f'{what}: its axis is zero')
    q = quaternion_from_euler_xyz(rpy[None])[0]
    unit = axis / norm if norm >= 1e-12 else axis
    return UrdfJoint(name, kind, str(parent.get('link')), str(child.get('link')),
                     (float(xyz[0]), float(xyz[1]), float(xyz[2])),
                     (float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                     (float(unit[0]), float(unit[1]), float(unit[2])))


def quaternion_product(a: FloatArray, b: FloatArray) -> FloatArray:
    """Hamilton products a ⊗ b (..., 4) of quaternions x, y, z, w (the rotation b, then a)."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def rotate(q: FloatArray, v: FloatArray) -> FloatArray:
    """Vectors v (..., 3) turned by unit quaternions q (..., 4) x, y, z, w."""
    u, w = q[..., :3], q[..., 3:]
    t = 2.0 * np.cross(u, v)
    rotated: FloatArray = v + w * t + np.cross(u, t)
    return rotated


class RobotTree:
    """The kinematic tree of a URDF: its root link, its joints and their transforms."""

    def __init__(self, joints: Sequence[UrdfJoint]) -> None:
        self.joints = tuple(joints)
        children = [j.child for j in self.joints]
        duplicated = sorted({c for c in children if children.count(c) > 1})
        if duplicated:
            raise InputError(f'URDF: links {duplicated} have more than one parent (not a tree)')
        roots = sorted({j.parent for j in self.joints} - set(children))
        if len(roots) != 1:
            raise InputError(f'URDF: the joints have {len(roots)} root links {roots}, not one')
        self.root = roots[0]
        self._by_child = {j.child: j for j in self.joints}
        self.moving = tuple(j for j in self.joints if j.kind != FIXED)
        self.fixed = tuple(j for j in self.joints if j.kind == FIXED)
        for link in children:  # a cycle would never reach the root
            self.chain(link)

    @classmethod
    def parse(cls, urdf: str) -> RobotTree:
        """From URDF text. Raises InputError naming what is wrong (not XML, not a robot, a
        joint of an unsupported type or without its links, not a tree)."""
        try:
            root = ET.fromstring(urdf)
        except ET.ParseError as err:
            raise InputError(f'URDF: not XML ({err})') from err
        if root.tag != 'robot':
            raise InputError(f'URDF: the root element is <{root.tag}>, not <robot>')
        return cls([_parse_joint(e) for e in root.findall('joint')])

    def chain(self, link: str) -> tuple[UrdfJoint, ...]:
        """The joints from the root to ``link``, root first."""
        out: list[UrdfJoint] = []
        while link != self.root:
            joint = self._by_child.get(link)
            if joint is None or len(out) > len(self.joints):
                raise InputError(f'URDF: link {link!r} is not reached from the root {self.root!r}')
            out.append(joint)
            link = joint.parent
        return tuple(reversed(out))

    def moving_transforms(self, joint_names: Sequence[str], positions: ArrayLike) -> Transforms:
        """Parent → child transforms of every moving joint (in :attr:`moving` order) for joint
        states ``positions`` (N, len(joint_names)) or (len(joint_names),), named by
        ``joint_names``. Raises InputError when a moving joint is not named or a value is not
        finite."""
        values = np.atleast_2d(np.asarray(positions, dtype=float))
        index = {name: k for k, name in enumerate(joint_names)}
        missing = [j.name for j in self.moving if j.name not in index]
        if missing or values.shape[1] != len(joint_names):
            raise InputError(f'joint state: {len(joint_names)} names and {values.shape[1]} '
                             f'values; joints without a value: {missing}')
        if not np.isfinite(values).all():
            raise InputError('joint state: a value is not finite (NaN or infinite)')
        q = values[:, [index[j.name] for j in self.moving]]
        return self._transforms(self.moving, q)

    def fixed_transforms(self) -> Transforms:
        """Parent → child transforms of the fixed joints (one state: N = 1)."""
        return self._transforms(self.fixed, np.zeros((1, len(self.fixed))))

    def _transforms(self, joints: Sequence[UrdfJoint], q: FloatArray) -> Transforms:
        xyz = np.array([j.xyz for j in joints]).reshape(-1, 3)
        origin_q = np.array([j.quaternion for j in joints]).reshape(-1, 4)
        axis = np.array([j.axis for j in joints]).reshape(-1, 3)
        turning = np.array([j.kind in REVOLUTE_TYPES for j in joints])
        sliding = np.array([j.kind == PRISMATIC for j in joints])
        half = 0.5 * np.where(turning, q, 0.0)[..., None]
        motion_q = np.concatenate([np.sin(half) * axis, np.cos(half)], axis=-1)
        slide = np.where(sliding, q, 0.0)[..., None] * axis
        translation = xyz + rotate(np.broadcast_to(origin_q, slide.shape[:-1] + (4,)), slide)
        quaternion = quaternion_product(np.broadcast_to(origin_q, motion_q.shape), motion_q)
        return Transforms(tuple(j.parent for j in joints), tuple(j.child for j in joints),
                          translation, quaternion)

    def link_poses(self, joint_names: Sequence[str], positions: ArrayLike,
                   links: Sequence[str]) -> tuple[FloatArray, FloatArray]:
        """Poses of ``links`` in the root for joint states ``positions`` (N, J): positions
        (N, L, 3) m and quaternions (N, L, 4) x, y, z, w, composed along each link's chain."""
        moving = self.moving_transforms(joint_names, positions)
        fixed = self.fixed_transforms()
        step = {c: (moving.translation[:, k], moving.quaternion[:, k])
                for k, c in enumerate(moving.children)}
        step.update({c: (fixed.translation[:, k], fixed.quaternion[:, k])
                     for k, c in enumerate(fixed.children)})
        n = moving.translation.shape[0]
        out_p, out_q = np.zeros((n, len(links), 3)), np.zeros((n, len(links), 4))
        for k, link in enumerate(links):
            p, q = np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
            for joint in self.chain(link):
                t, r = step[joint.child]
                p = p + rotate(q, np.broadcast_to(t, p.shape))
                q = quaternion_product(q, np.broadcast_to(r, q.shape))
            out_p[:, k], out_q[:, k] = p, q
        return out_p, out_q
