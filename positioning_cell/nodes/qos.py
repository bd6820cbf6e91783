"""The cell's QoS profiles, chosen on purpose, and their conversions to and from the rosbags
QoS a bag stores.

Everything the cell records is reliable (a recorder must lose nothing); commands are reliable;
the current goal and the run program are latched for late joiners; readers that only want the
newest value (joint states for the pose estimate and the truth) keep one.
"""

from __future__ import annotations

from typing import Any

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

#: Trajectories and other commands.
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
#: Streams of poses and joint states.
STREAM_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
#: The current goal, the run program: the last value for late joiners.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: A reader of the newest value only (older ones are overwritten unread).
LATEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
#: /diagnostics, from every node and to every reader.
DIAGNOSTICS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)

_INFINITE_NS = 2**63 - 1


def _time_of(duration: Duration) -> QosTime:
    ns = min(max(int(duration.nanoseconds), 0), _INFINITE_NS)
    return QosTime(ns // 1_000_000_000, ns % 1_000_000_000)


def qos_from_profile(profile: QoSProfile) -> Qos:
    """The rosbags Qos of an rclpy QoSProfile (rclpy's policy enums carry the rmw integer
    values, which are rosbags' enum values too)."""
    return Qos(QosHistory(int(profile.history)), int(profile.depth),
               QosReliability(int(profile.reliability)), QosDurability(int(profile.durability)),
               _time_of(profile.deadline), _time_of(profile.lifespan),
               QosLiveliness(int(profile.liveliness)),
               _time_of(profile.liveliness_lease_duration),
               bool(profile.avoid_ros_namespace_conventions))


def profile_from_qos(qos: Qos) -> QoSProfile:
    """The rclpy QoSProfile of a rosbags Qos: history, depth, reliability and durability
    (timing and liveliness stay rclpy's defaults)."""
    kwargs: dict[str, Any] = {
        'history': HistoryPolicy(qos.history.value), 'depth': max(int(qos.depth), 1),
        'reliability': ReliabilityPolicy(qos.reliability.value),
        'durability': DurabilityPolicy(qos.durability.value)}
    return QoSProfile(**kwargs)
