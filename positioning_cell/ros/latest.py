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
from rclpy.serialization import deserialize_message

from positioning_cell.ros.qos import LATEST_QOS
from positioning_cell.ros.senders import IdentifiedSubscription
from positioning_cell.ros.unspun import destroy_one, unspun_node


class Reader:
    """Messages of ``topic`` taken on demand (module docstring); ``qos`` depth is how many
    unread messages are kept (1: the newest only)."""

    def __init__(self, node: Node, msg_type: Any, topic: str,
                 qos: QoSProfile = LATEST_QOS) -> None:
        # A node no executor spins: its subscription wakes nobody.
        self._owner, self._node = node, unspun_node(node, 'reader', topic)
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
        destroy_one(self._owner, self._node)


class SourceReader:
    """Messages of ``topic`` taken on demand, as :class:`Reader`, but only those published by
    the node ``source`` (its fully qualified name): a message from any other node is dropped
    and its sender remembered (:meth:`foreign`), so a second publisher on the topic can
    neither feed the consumer nor go unnoticed (:mod:`positioning_cell.ros.senders`).
    ``qos`` depth: unread messages kept, of every sender."""

    def __init__(self, node: Node, msg_type: Any, topic: str, source: str,
                 qos: QoSProfile = LATEST_QOS) -> None:
        self.topic, self.source, self._type = topic, source, msg_type
        self._sub = IdentifiedSubscription(node, msg_type, topic, qos)
        self._lock = threading.Lock()
        self._seen: set[str] = set()
        self._reported: set[str] = set()

    def _accepted(self) -> list[bytes]:
        mine = []
        taken = self._sub.take()
        with self._lock:
            for item in taken:
                if item.sender == self.source:
                    mine.append(item.data)
                elif item.sender:  # '': a publisher the graph does not name yet
                    self._seen.add(item.sender)
        return mine

    def take(self) -> list[Any]:
        """Every message of ``source`` received since the last call, oldest first."""
        return [deserialize_message(data, self._type) for data in self._accepted()]

    def newest(self) -> Any | None:
        """The newest message of ``source`` since the last call, or None."""
        mine = self._accepted()
        return deserialize_message(mine[-1], self._type) if mine else None

    def publisher_count(self) -> int:
        """Publishers of ``source`` on the topic (from the graph)."""
        return self._sub.publishers().count(self.source)

    def foreign(self) -> list[str]:
        """Other nodes that sent on the topic since the last call or publish on it now (the
        graph), sorted."""
        now = {n for n in self._sub.publishers() if n != self.source}
        with self._lock:
            found, self._seen = now | self._seen, set()
            self._reported = found
        return sorted(found)

    def unreported(self) -> bool:
        """A node other than ``source`` sent since the last :meth:`foreign` and was not in
        what it returned (report it now rather than at the next periodic report)."""
        with self._lock:
            return bool(self._seen - self._reported)

    def destroy(self) -> None:
        """Release the subscription and its node."""
        self._sub.destroy()
