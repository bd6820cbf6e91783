"""The machine as ROS tools see it (positioning_cell.robot): the URDF is a tree with the
machine's geometry and limits, the joint values put every link where the kinematics puts it
(property tests over the workspace, nominal and offset machines), each joint transform is the
URDF's own semantics (checked against scipy's rotations), and bad descriptions are refused."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from workspace import MECH, poses, random_poses

from positioning_cell import names
from positioning_cell.core.kinematics import inverse, leg_directions, platform_points
from positioning_cell.core.limits import within_limits
from positioning_cell.core.mechanism import PASSIVE_JOINT_NAMES, Mechanism
from positioning_cell.errors import InputError
from positioning_cell.robot.joints import joint_positions
from positioning_cell.robot.tree import RobotTree
from positioning_cell.robot.urdf import (
    MOVING_JOINT_NAMES,
    PLATFORM_LINK,
    ROOT_LINK,
    S_JOINT_NAMES,
    link_names,
    machine_urdf,
)

#: A machine with joint-centre offsets of a few tenths of a millimetre (an identified geometry).
OFFSET_MECH = MECH.with_offsets(
    np.random.default_rng(7).normal(0.0, 3e-4, (3, 3)),
    np.random.default_rng(8).normal(0.0, 3e-4, (3, 3)))
#: Links compared with the kinematics: the platform, each leg's rod (origin at B_i, z along u_i)
#: and each leg's S ball (at B_i, turned as the platform).
RODS = [link_names(leg)[2] for leg in (1, 2, 3)]
BALLS = [link_names(leg)[-1] for leg in (1, 2, 3)]
LINKS = [PLATFORM_LINK, *RODS, *BALLS]


def _rotation_error(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    return (Rotation.from_quat(q1).inv() * Rotation.from_quat(q2)).magnitude()


def _check_links(mech: Mechanism, p: np.ndarray, q: np.ndarray) -> None:
    """The tree at the joint values of poses (p, q) against the kinematics: 1e-12 m and rad."""
    values = joint_positions(mech, p, q)
    tree = RobotTree.parse(machine_urdf(mech))
    lp, lq = tree.link_poses(MOVING_JOINT_NAMES, values, LINKS)
    b = platform_points(mech, p, q)
    joints = inverse(mech, p, q)
    u = leg_directions(mech, joints.phis, joints.thetas)
    assert np.abs(lp[:, 0] - p).max() < 1e-12
    assert _rotation_error(lq[:, 0], q).max() < 1e-12
    for leg in range(3):
        assert np.abs(lp[:, 1 + leg] - b[:, leg]).max() < 1e-12  # rod end at B_i
        rod_z = Rotation.from_quat(lq[:, 1 + leg]).apply([0.0, 0.0, 1.0])
        assert np.abs(rod_z - u[:, leg]).max() < 1e-12  # rod along u_i
        assert np.abs(lp[:, 4 + leg] - b[:, leg]).max() < 1e-12  # ball at B_i
        assert _rotation_error(lq[:, 4 + leg], q).max() < 1e-12  # ball turned as the platform


@settings(max_examples=150, deadline=None)
@given(poses(), st.sampled_from([MECH, OFFSET_MECH]))
def test_every_link_lies_where_the_kinematics_puts_it(
        pose: tuple[np.ndarray, np.ndarray], mech: Mechanism) -> None:
    p, q = pose
    assume(within_limits(mech, p[None], q[None])[0])
    _check_links(mech, p[None], q[None])


def test_a_batch_of_workspace_poses_on_both_machines() -> None:
    for mech in (MECH, OFFSET_MECH):
        _check_links(mech, *random_poses(500, np.random.default_rng(3), mech))


def test_the_joint_values_are_the_kinematics_and_the_s_angles_the_tilt() -> None:
    p, q = random_poses(500, np.random.default_rng(4))
    values = joint_positions(MECH, p, q)
    joints = inverse(MECH, p, q)
    column = {name: k for k, name in enumerate(MOVING_JOINT_NAMES)}
    assert [column[n] for n in names.JOINT_NAMES] == list(range(6))
    np.testing.assert_allclose(values[:, :3], joints.lengths, rtol=0, atol=1e-15)
    np.testing.assert_allclose(values[:, 3:6], joints.thetas, rtol=0, atol=1e-15)
    np.testing.assert_allclose(values[:, [column[n] for n in PASSIVE_JOINT_NAMES]], joints.phis,
                               rtol=0, atol=1e-15)
    # The S joint's tilt (the angle between u_i and the platform normal, core.limits) is
    # cos t = cos s_x cos s_y.
    normal = Rotation.from_quat(q).apply([0.0, 0.0, 1.0])
    u = leg_directions(MECH, joints.phis, joints.thetas)
    tilt = np.arccos(np.einsum('nkj,nj->nk', u, normal))
    s_x = values[:, [column[f'leg{i}_s_x'] for i in (1, 2, 3)]]
    s_y = values[:, [column[f'leg{i}_s_y'] for i in (1, 2, 3)]]
    np.testing.assert_allclose(np.arccos(np.cos(s_x) * np.cos(s_y)), tilt, rtol=0, atol=1e-7)
    assert np.abs(s_x).max() <= MECH.tilt_max and np.abs(s_y).max() <= MECH.tilt_max


def test_the_description_is_one_tree_with_the_machines_geometry_and_limits() -> None:
    text = machine_urdf(OFFSET_MECH)
    tree = RobotTree.parse(text)
    assert tree.root == ROOT_LINK == names.BASE_FRAME
    assert {j.name for j in tree.moving} == set(MOVING_JOINT_NAMES)
    assert len(MOVING_JOINT_NAMES) == 18 and len(S_JOINT_NAMES) == 9
    root = ET.fromstring(text)
    links = {e.get('name') for e in root.findall('link')}
    assert links == {ROOT_LINK, PLATFORM_LINK, *(n for leg in (1, 2, 3) for n in link_names(leg))}
    assert {j.child for j in tree.joints} == links - {ROOT_LINK}
    limits = {e.get('name'): e.find('limit') for e in root.findall('joint')}
    for leg in (1, 2, 3):
        for joint, low, high in ((f'leg{leg}_length', 'length_min', 'length_max'),
                                 (f'leg{leg}_theta', 'theta_min', 'theta_max'),
                                 (f'leg{leg}_phi', 'phi_min', 'phi_max')):
            element = limits[joint]
            assert element is not None
            assert float(element.get('lower', 'nan')) == getattr(OFFSET_MECH, low)
            assert float(element.get('upper', 'nan')) == getattr(OFFSET_MECH, high)
        phi = next(j for j in tree.joints if j.name == f'leg{leg}_phi')
        assert np.array(phi.xyz) == pytest.approx(OFFSET_MECH.base_joints[leg - 1], abs=0)
    platform = next(j for j in tree.joints if j.child == PLATFORM_LINK)
    assert np.array(platform.xyz) == pytest.approx(-OFFSET_MECH.platform_joints[0], abs=0)


@given(st.floats(-3.0, 3.0), st.tuples(*[st.floats(-np.pi, np.pi)] * 3),
       st.tuples(*[st.floats(-1.0, 1.0)] * 3), st.tuples(*[st.floats(-1.0, 1.0)] * 3),
       st.sampled_from(['revolute', 'continuous', 'prismatic', 'fixed']))
def test_a_joints_transform_is_the_urdf_semantics(
        value: float, rpy: tuple[float, float, float], xyz: tuple[float, float, float],
        axis: tuple[float, float, float], kind: str) -> None:
    """origin (xyz, rpy = fixed-axis x, y, z) then the motion about or along the axis, checked
    with scipy's own rotations."""
    a = np.array(axis)
    assume(np.linalg.norm(a) > 1e-3)
    text = (f'<robot name="r"><joint name="j" type="{kind}"><parent link="a"/><child link="b"/>'
            f'<origin xyz="{xyz[0]!r} {xyz[1]!r} {xyz[2]!r}" rpy="{rpy[0]!r} {rpy[1]!r} '
            f'{rpy[2]!r}"/><axis xyz="{axis[0]!r} {axis[1]!r} {axis[2]!r}"/></joint></robot>')
    tree = RobotTree.parse(text)
    out = tree.fixed_transforms() if kind == 'fixed' else tree.moving_transforms(['j'], [value])
    origin = Rotation.from_euler('xyz', rpy)
    unit = a / np.linalg.norm(a)
    turn = Rotation.from_rotvec(unit * value) if kind in ('revolute', 'continuous') else None
    slide = unit * value if kind == 'prismatic' else np.zeros(3)
    expected_r = origin * turn if turn is not None else origin
    assert out.parents == ('a',) and out.children == ('b',)
    np.testing.assert_allclose(out.translation[0, 0], np.array(xyz) + origin.apply(slide),
                               rtol=0, atol=1e-12)
    assert _rotation_error(out.quaternion[0, 0], expected_r.as_quat()) < 1e-12


@pytest.mark.parametrize(('text', 'words'), [
    ('<robot', 'not XML'),
    ('<model/>', 'root element is <model>'),
    ('<robot><joint name="j" type="floating"><parent link="a"/><child link="b"/></joint></robot>',
     "type 'floating'"),
    ('<robot><joint name="j" type="fixed"><parent link="a"/></joint></robot>', 'needs <parent'),
    ('<robot><joint name="j" type="fixed"><parent link="a"/><child link="b"/>'
     '<origin xyz="0 nan 0"/></joint></robot>', 'three finite numbers'),
    ('<robot><joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
     '<axis xyz="0 0 0"/></joint></robot>', 'axis is zero'),
    ('<robot><joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint>'
     '<joint name="k" type="fixed"><parent link="c"/><child link="b"/></joint></robot>',
     'more than one parent'),
    ('<robot><joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint>'
     '<joint name="k" type="fixed"><parent link="b"/><child link="a"/></joint></robot>',
     '0 root links'),
])
def test_a_bad_description_is_refused_with_what_is_wrong(text: str, words: str) -> None:
    with pytest.raises(InputError, match=words):
        RobotTree.parse(text)


def test_a_joint_state_without_a_joint_or_with_nan_is_refused() -> None:
    tree = RobotTree.parse(machine_urdf(MECH))
    values = joint_positions(MECH, MECH.home_position, MECH.home_quaternion)
    with pytest.raises(InputError, match='leg3_s_z'):
        tree.moving_transforms(MOVING_JOINT_NAMES[:-1], values[:, :-1])
    values[0, 4] = np.nan
    with pytest.raises(InputError, match='not finite'):
        tree.moving_transforms(MOVING_JOINT_NAMES, values)
    with pytest.raises(InputError, match='not finite'):
        joint_positions(MECH, [0.0, np.nan, 0.2], MECH.home_quaternion)
