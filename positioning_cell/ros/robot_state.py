"""The positioner's machine as ROS tools see it (docs/conventions/robot-description.md): the
URDF of its model latched on /robot_description, every joint's value at the pose estimate on
/joint_states, and the tree's transforms on /tf and /tf_static — robot_state_publisher's work,
done where the estimate is made (:mod:`positioning_cell.robot`) — with the static frames of
the operator's coordinate systems (base → machine and user, platform → object) and the legs
and platform as markers on /positioner/markers.

QoS as tf2_ros and robot_state_publisher use them: /tf reliable, volatile, 100 deep;
/tf_static and /robot_description reliable, transient-local, the last message (a static
broadcaster sends its whole set each time)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
from numpy.typing import ArrayLike, NDArray
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Header, String
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from positioning_cell import names
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.frames.systems import CoordinateSystems, machine_origin
from positioning_cell.robot.joints import joint_positions
from positioning_cell.robot.tree import RobotTree, Transforms
from positioning_cell.robot.urdf import MOVING_JOINT_NAMES, machine_urdf
from positioning_cell.ros import messages as m
from positioning_cell.ros.qos import JOINT_STATES_QOS, LATCHED_QOS, STREAM_QOS, TF_QOS

FloatArray = NDArray[np.float64]

def transform_messages(transforms: Transforms, stamp: Any, state: int = 0
                       ) -> list[TransformStamped]:
    """TransformStamped messages of joint state ``state`` of ``transforms``, stamped."""
    return [TransformStamped(
        header=Header(stamp=stamp, frame_id=parent), child_frame_id=child,
        transform=Transform(translation=Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                            rotation=Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]),
                                                w=float(q[3]))))
        for parent, child, t, q in zip(transforms.parents, transforms.children,
                                       transforms.translation[state],
                                       transforms.quaternion[state], strict=True)]


def frame_transforms(frames: Sequence[tuple[str, str, ArrayLike, ArrayLike]]) -> Transforms:
    """Transforms of named frames: (parent, child, position (3,) m, quaternion (4,))."""
    return Transforms(tuple(f[0] for f in frames), tuple(f[1] for f in frames),
                      np.array([[f[2] for f in frames]]).reshape(1, -1, 3),
                      np.array([[f[3] for f in frames]]).reshape(1, -1, 4))


def systems_frames(mech: Mechanism, systems: CoordinateSystems
                   ) -> list[tuple[str, str, FloatArray, FloatArray]]:
    """base → machine, base → user (T_base_machine · T_machine_user), platform → object."""
    return [(names.BASE_FRAME, names.MACHINE_FRAME, *machine_origin(mech).to_pq()),
            (names.BASE_FRAME, names.USER_FRAME, *systems.user_in_base(mech).to_pq()),
            (names.PLATFORM_FRAME, names.OBJECT_FRAME, *systems.object.to_pq())]


def frames_message(frames: Sequence[tuple[str, str, ArrayLike, ArrayLike]],
                   stamp: Any) -> TFMessage:
    """The TFMessage of named frames (parent, child, position (3,) m, quaternion (4,))."""
    return TFMessage(transforms=transform_messages(frame_transforms(frames), stamp))


class RobotState:
    """Publishes the machine ``mech`` for ROS tools from ``node``: the description and the
    static frames at once (again when ``systems()`` returns new coordinate systems), the joint
    states, /tf and the markers with every ``every``-th pose estimate given to
    :meth:`publish`."""

    def __init__(self, node: Node, mech: Mechanism, every: int,
                 systems: Callable[[], CoordinateSystems]) -> None:
        self._node, self._mech, self._every, self._systems = node, mech, every, systems
        urdf = machine_urdf(mech)
        self.tree = RobotTree.parse(urdf)
        node.create_publisher(String, names.ROBOT_DESCRIPTION, LATCHED_QOS).publish(
            String(data=urdf))
        self._pub_joints = node.create_publisher(JointState, names.ROBOT_JOINT_STATES,
                                                 JOINT_STATES_QOS)
        self._pub_tf = node.create_publisher(TFMessage, names.TF, TF_QOS)
        self._pub_static = node.create_publisher(TFMessage, names.TF_STATIC, LATCHED_QOS)
        self._pub_markers = node.create_publisher(MarkerArray, names.MARKERS, STREAM_QOS)
        self._published_systems: CoordinateSystems | None = None
        self._estimates = 0
        self._publish_static(node.get_clock().now().to_msg())

    def _publish_static(self, stamp: Any) -> None:
        systems = self._published_systems = self._systems()
        self._pub_static.publish(TFMessage(transforms=[
            *transform_messages(self.tree.fixed_transforms(), stamp),
            *frames_message(systems_frames(self._mech, systems), stamp).transforms]))

    def publish(self, position: FloatArray, quaternion: FloatArray, stamp: Any) -> None:
        """With every ``every``-th estimate (3,) m, (4,) x, y, z, w: every joint's value on
        /joint_states, the tree's moving joints on /tf and the markers, stamped ``stamp``; the
        static frames again if the coordinate systems changed."""
        if self._systems() is not self._published_systems:
            self._publish_static(stamp)
        self._estimates += 1
        if self._estimates % self._every:
            return
        header = Header(stamp=stamp, frame_id=names.BASE_FRAME)
        self._pub_markers.publish(m.platform_markers(self._mech, position, quaternion, header))
        values = joint_positions(self._mech, position, quaternion)
        self._pub_joints.publish(JointState(header=Header(stamp=stamp),
                                            name=list(MOVING_JOINT_NAMES),
                                            position=[float(v) for v in values[0]]))
        self._pub_tf.publish(TFMessage(transforms=transform_messages(
            self.tree.moving_transforms(MOVING_JOINT_NAMES, values), stamp)))
