"""Subscriptions a node's publishers cannot serve (incompatible QoS or type), watched from the
ROS graph instead of by two event handlers per publisher.

By default rclpy gives every publisher two QoS event handlers, which log when a subscription
is discovered that asks for a QoS the publisher cannot offer, or for another type on its topic.
On a multi-threaded executor each handler is a Python waitable of a wait set that is rebuilt at
every wake, twice per callback: the positioner's 15 publishers had 30 of them, beside its 20
services, 4 timers, 2 subscriptions (their 4 handlers), a client and 2 action servers. Without
them the positioner used 0.17-0.20 core at rest instead of 0.20-0.23, and 0.22-0.27 instead of
0.25-0.28 while moving (issue 24; benchmarks/idle_cpu.py, four runs of each, alternated, 15
and 30 s windows, ad hoc). A :class:`QosWatchedNode` creates its publishers without those
handlers and reads the graph every :data:`WATCH_PERIOD_S` instead (~1 ms of CPU for the
positioner's topics, ad hoc). Each subscription on one of its topics that asks for another
type or a QoS the publisher cannot serve (``rclpy.qos.qos_check_compatible``) is logged once,
in the words of rclpy's own handlers, at most a period after it appears. Its subscriptions
keep their handlers: they give the same warnings from the subscriber's side.
"""

from __future__ import annotations

from typing import Any

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSCompatibility, qos_check_compatible

#: How often (s) the graph is read for subscriptions the node's publishers cannot serve: the
#: longest a warning comes after the subscription appears.
WATCH_PERIOD_S = 1.0


class QosWatchedNode(Node):
    """A node whose publishers have no QoS event handlers and whose graph is read every
    :data:`WATCH_PERIOD_S` for the subscriptions they cannot serve (module docstring); for the
    nodes on a multi-threaded executor."""

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        self._unserved: set[tuple[str, bytes]] = set()  # (topic, subscription gid) logged
        super().__init__(node_name, **kwargs)
        self.create_timer(WATCH_PERIOD_S, self._log_unserved,
                          callback_group=MutuallyExclusiveCallbackGroup())

    def create_publisher(self, *args: Any, **kwargs: Any) -> Publisher:
        """:meth:`rclpy.node.Node.create_publisher`, without the default event handlers
        unless ``event_callbacks`` are given."""
        if kwargs.get('event_callbacks') is None:
            kwargs['event_callbacks'] = PublisherEventCallbacks(use_default_callbacks=False)
        return super().create_publisher(*args, **kwargs)

    def unserved_subscriptions(self) -> list[str]:
        """A warning for each subscription on one of this node's publishers' topics that asks
        for another type or a QoS the publisher cannot serve, not reported before. Both sides
        as the graph has them (a profile as created says "infinite" otherwise than one
        discovered, which qos_check_compatible would take for a mismatch)."""
        found = []
        me = self.get_name(), self.get_namespace()
        for topic in sorted({publisher.topic_name for publisher in self.publishers}):
            ours = [info for info in self.get_publishers_info_by_topic(topic)
                    if (info.node_name, info.node_namespace) == me]
            for info in self.get_subscriptions_info_by_topic(topic) if ours else ():
                key = (topic, bytes(info.endpoint_gid))
                if key in self._unserved:
                    continue
                types = sorted({own.topic_type for own in ours} - {info.topic_type})
                reasons = [reason for own in ours
                           for compatibility, reason in [qos_check_compatible(
                               own.qos_profile, info.qos_profile)]
                           if compatibility == QoSCompatibility.ERROR]
                if types:
                    found.append(f"Incompatible type on topic '{topic}', no messages will be "
                                 f'sent to it (it asks for {info.topic_type}, this node '
                                 f'publishes {", ".join(types)}).')
                elif reasons:
                    found.append(f"New subscription discovered on topic '{topic}', requesting "
                                 f'incompatible QoS. No messages will be sent to it. '
                                 f'{reasons[0]}')
                else:
                    continue
                self._unserved.add(key)
        return found

    def _log_unserved(self) -> None:
        for warning in self.unserved_subscriptions():
            self.get_logger().warning(warning)
