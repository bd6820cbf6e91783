"""Readers that keep only what is needed of a fast stream, without a callback per message.

A subscription with a callback costs an executor wake-up and a deserialisation per message
(~0.14 core for a 200 Hz JointState here). A reader that needs only the newest joint state, or
the messages since it last looked, instead subscribes on a node of its own that no executor
spins: DDS keeps the history (QoS depth), and :meth:`Reader.take` takes it when the consumer
wants it, as ``rclpy.wait_for_message`` does.
"""

from __future__ import annotations

import threading
from typing import Any

from rclpy.node import Node
from rclpy.qos import QoSProfile

from positioning_cell.nodes.qos import LATEST_QOS


class Reader:
    """Messages of ``topic`` taken on demand (module docstring); ``qos`` depth is how many
    unread messages are kept (1: the newest only)."""

    def __init__(self, node: Node, msg_type: Any, topic: str,
                 qos: QoSProfile = LATEST_QOS) -> None:
        # A node no executor spins: its subscription wakes nobody.
        self._node = Node(f'_{node.get_name()}_reader_{topic.strip("/").replace("/", "_")}',
                          context=node.context, start_parameter_services=False,
                          enable_rosout=False)
        self._sub = self._node.create_subscription(msg_type, topic, lambda _: None, qos)
        self._lock = threading.Lock()

    def take(self) -> list[Any]:
        """Every message received since the last call, oldest first."""
        taken = []
        with self._lock, self._sub.handle:
            while (item := self._sub.handle.take_message(self._sub.msg_type,
                                                         self._sub.raw)) is not None:
                taken.append(item[0])
        return taken

    def newest(self) -> Any | None:
        """The newest message since the last call, or None."""
        taken = self.take()
        return taken[-1] if taken else None

    def publisher_count(self) -> int:
        """Publishers matched on the topic."""
        return self._sub.get_publisher_count()

    def destroy(self) -> None:
        """Release the subscription and its node."""
        self._node.destroy_node()
