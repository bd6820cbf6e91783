"""The cell's QoS profiles, chosen on purpose, and their conversions to and from the rosbags
QoS a bag stores.

Everything the cell records is reliable, with histories deep enough that the recorder loses
nothing at the cell's rates (STREAM_QOS); commands are reliable;
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
#: Streams of poses and joint states. The depth is sized for bursts: a reliable keep-last
#: writer overwrites what a reader has not acknowledged once its history is full, so the
#: history must outlast a stalled reader (the recorder on a loaded machine).
#: benchmarks/recorder.py: depth 100 lost 0.3 % at 10 k msgs/s and 2.2 % at 20 k msgs/s
#: (aggregated over the cell's 7 streams) with a CPU hog beside the recorder; 5000 (1.75 s of
#: a topic at that rate, 50 s of the cell's own 100 Hz) lost none. Memory grows only while a
#: reader lags.
STREAM_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
#: The current goal, the run program: the last value for late joiners.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: The markers of a calibration run: every one for a late joiner (a recorder that discovers the
#: topic after the first poses), up to a program of 1000 poses.
MARKER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: A reader of the newest value only (older ones are overwritten unread).
LATEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
#: The positioner's encoder readings, taken with their sender: a few kept, so that a second
#: publisher cannot push the driver's newest reading out of a one-deep history.
JOINT_READER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
#: The positioner's heartbeat: only the newest matters, and a lost one is replaced by the next
#: (best effort, no history).
HEARTBEAT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                           reliability=ReliabilityPolicy.BEST_EFFORT,
                           durability=DurabilityPolicy.VOLATILE)
#: Services: a burst of concurrent callers is queued, not dropped (rclpy's default keeps 10).
SERVICE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
#: /diagnostics, from every node and to every reader (a burst of refusals under a flood of
#: calls is kept too).
DIAGNOSTICS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)

#: /tf: tf2_ros's dynamic broadcaster profile (reliable, volatile, 100 deep).
TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                    reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
#: /joint_states: robot_state_publisher's subscription depth, reliable. (/tf_static and
#: /robot_description are LATCHED_QOS, as tf2_ros and robot_state_publisher publish them.)
JOINT_STATES_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
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
