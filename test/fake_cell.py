"""The test (or benchmark) playing the cell for a watch window: the command (latched), the
encoder estimate, the tracker's measurements with a stated covariance, the coordinate systems
(latched), and a stand-in positioner node that serves only its ``mechanism.*`` parameters.
Used by test_live_view_node, test_cell_watch and benchmarks/live_view.py."""

from __future__ import annotations

from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from numpy.typing import ArrayLike
from positioning_cell_interfaces.msg import CoordinateSystems as CoordinateSystemsMsg
from rclpy.node import Node

from positioning_cell import names
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.parameters import declarations
from positioning_cell.ros.messages import pose_msg, pose_stamped
from positioning_cell.ros.qos import LATCHED_QOS, STREAM_QOS

IDENTITY = (0.0, 0.0, 0.0, 1.0)


class FakeCell:
    """Publishers on ``node`` of what a watch window reads."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.target = node.create_publisher(PoseStamped, names.TARGET, LATCHED_QOS)
        self.estimate = node.create_publisher(PoseStamped, names.ESTIMATED_POSE, STREAM_QOS)
        self.measured = node.create_publisher(PoseWithCovarianceStamped, names.MEASURED_POSE,
                                              STREAM_QOS)
        self.systems = node.create_publisher(CoordinateSystemsMsg, names.COORDINATE_SYSTEMS,
                                             LATCHED_QOS)

    def now(self) -> Any:
        return self.node.get_clock().now().to_msg()

    def command(self, position: ArrayLike, quaternion: ArrayLike = IDENTITY) -> None:
        """The commanded platform pose in base (m, x, y, z, w)."""
        self.target.publish(pose_stamped(position, quaternion, self.now()))

    def coordinate_systems(self, user: tuple[ArrayLike, ArrayLike],
                           obj: tuple[ArrayLike, ArrayLike] = ((0, 0, 0), IDENTITY)) -> None:
        """The user CS (in the machine CS) and the object CS (in the platform frame)."""
        self.systems.publish(CoordinateSystemsMsg(user=pose_msg(*user), object=pose_msg(*obj)))

    def estimated(self, position: ArrayLike, quaternion: ArrayLike = IDENTITY) -> None:
        """An encoder estimate."""
        self.estimate.publish(pose_stamped(position, quaternion, self.now()))

    def measure(self, position: ArrayLike, quaternion: ArrayLike = IDENTITY,
                sigma_position: float = 5e-6, sigma_rotation: float = 1e-5) -> Any:
        """A tracker measurement with a diagonal covariance (σ m per axis, σ rad per axis);
        its header stamp."""
        msg = PoseWithCovarianceStamped()
        msg.header.stamp, msg.header.frame_id = self.now(), names.BASE_FRAME
        msg.pose.pose = pose_msg(position, quaternion)
        msg.pose.covariance = np.diag([sigma_position**2] * 3
                                      + [sigma_rotation**2] * 3).ravel().tolist()
        self.measured.publish(msg)
        return msg.header.stamp


def stand_in_positioner(node_context: Any) -> Node:
    """A node named like the positioner, in ``node_context``, with the default mechanism's
    ``mechanism.*`` parameters declared (the offsets, unset meaning zero, left out); the
    caller spins and destroys it."""
    node = Node(names.NODE_POSITIONER, context=node_context)
    for d in declarations(Mechanism, 'mechanism.'):
        if d.default not in (None, []):
            node.declare_parameter(d.name, d.default)
    return node
