"""Messages ↔ numpy at the edge of the nodes: poses, vectors, joint states, diagnostics, and the
message class of a ROS type name. No mathematics here."""

from __future__ import annotations

import importlib
import math
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from builtin_interfaces.msg import Duration, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import (
    Point,
    Pose,
    PoseStamped,
    PoseWithCovarianceStamped,
    Vector3,
    Vector3Stamped,
    WrenchStamped,
)
from nav_msgs.msg import Path
from numpy.typing import ArrayLike
from sensor_msgs.msg import JointState
from std_msgs.msg import Header
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint
from visualization_msgs.msg import Marker, MarkerArray

from positioning_cell.accuracy.monitor import PoseMessages
from positioning_cell.accuracy.settle import stamp_seconds
from positioning_cell.core.kinematics import platform_points
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import Registration
from positioning_cell.moves.fingerprint import wire_nanoseconds
from positioning_cell.moves.machine import Answer, JointReading, Measurement
from positioning_cell.names import BASE_FRAME

if TYPE_CHECKING:  # an annotation only: the planner stays out of the nodes that do not plan
    from positioning_cell.moves.trajectory import Trajectory


def pose_arrays(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Position (3,) m and quaternion (4,) x, y, z, w of a geometry_msgs/Pose (not validated)."""
    p, o = pose.position, pose.orientation
    return np.array([p.x, p.y, p.z]), np.array([o.x, o.y, o.z, o.w])


def pose_msg(position: ArrayLike, quaternion: ArrayLike) -> Pose:
    """geometry_msgs/Pose from a position (m) and a quaternion x, y, z, w."""
    msg = Pose()
    msg.position.x, msg.position.y, msg.position.z = (float(v) for v in np.ravel(position))
    (msg.orientation.x, msg.orientation.y, msg.orientation.z,
     msg.orientation.w) = (float(v) for v in np.ravel(quaternion))
    return msg


def pose_stamped(position: ArrayLike, quaternion: ArrayLike, stamp: Time,
                 frame: str = BASE_FRAME) -> PoseStamped:
    """geometry_msgs/PoseStamped in ``frame``."""
    msg = PoseStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.pose = pose_msg(position, quaternion)
    return msg


def vector3(vector: ArrayLike) -> Vector3:
    """geometry_msgs/Vector3 of a vector (3,)."""
    x, y, z = (float(v) for v in np.ravel(vector))
    return Vector3(x=x, y=y, z=z)


def vector_of(msg: Vector3) -> np.ndarray:
    """The vector (3,) of a geometry_msgs/Vector3."""
    return np.array([msg.x, msg.y, msg.z])


def vector3_stamped(vector: ArrayLike, stamp: Time,
                    frame: str = BASE_FRAME) -> Vector3Stamped:
    """geometry_msgs/Vector3Stamped in ``frame``."""
    msg = Vector3Stamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.vector = vector3(vector)
    return msg


def force_stamped(force: ArrayLike, stamp: Time, frame: str = BASE_FRAME) -> WrenchStamped:
    """geometry_msgs/WrenchStamped of a force (3,) N in ``frame`` (no torque)."""
    return wrench_stamped(np.concatenate([np.ravel(force), np.zeros(3)]), stamp, frame)


def wrench_stamped(wrench: ArrayLike, stamp: Time, frame: str = BASE_FRAME) -> WrenchStamped:
    """geometry_msgs/WrenchStamped of a wrench (6,): force N, torque N·m, in ``frame``."""
    msg = WrenchStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    w = [float(v) for v in np.ravel(wrench)]
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = w[:3]
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = w[3:]
    return msg


def wrench_of(msg: WrenchStamped) -> np.ndarray:
    """The wrench (6,) of a geometry_msgs/WrenchStamped: force N, torque N·m."""
    f, t = msg.wrench.force, msg.wrench.torque
    return np.array([f.x, f.y, f.z, t.x, t.y, t.z])


def force_of(msg: WrenchStamped) -> np.ndarray:
    """The force (3,) N of a geometry_msgs/WrenchStamped in ``base``; InputError naming what
    is wrong for another frame or a torque (the load rig pushes at the platform origin)."""
    if msg.header.frame_id != BASE_FRAME:
        raise InputError(f'a force in frame {msg.header.frame_id!r}: the load rig takes '
                         f'{BASE_FRAME!r} only')
    t = msg.wrench.torque
    if any(v != 0.0 for v in (t.x, t.y, t.z)):
        raise InputError('a torque: the load rig pushes at the platform origin, force only')
    f = msg.wrench.force
    return np.array([f.x, f.y, f.z])


def joint_state(names: Sequence[str], stamp: Time, position: ArrayLike,
                velocity: ArrayLike = (), effort: ArrayLike = ()) -> JointState:
    """sensor_msgs/JointState (SI: m, rad, m/s, rad/s, N, N·m)."""
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    msg.position = [float(v) for v in np.ravel(position)]
    msg.velocity = [float(v) for v in np.ravel(velocity)]
    msg.effort = [float(v) for v in np.ravel(effort)]
    return msg


def joint_values(msg: JointState, names: Sequence[str],
                 field: str = 'position') -> np.ndarray | None:
    """The values of ``names`` (in that order) from a JointState field, or None if any is
    missing; JointState may list joints in any order."""
    values = getattr(msg, field)
    index = {n: i for i, n in enumerate(msg.name)}
    if len(values) != len(msg.name) or any(n not in index for n in names):
        return None
    return np.array([values[index[n]] for n in names], dtype=float)


def duration(seconds: float) -> Duration:
    """builtin_interfaces/Duration of ``seconds`` (>= 0): the integer nanoseconds of
    :func:`positioning_cell.moves.fingerprint.wire_nanoseconds` (a trajectory's key is made of
    the same)."""
    ns = int(wire_nanoseconds(seconds))
    return Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def seconds(value: Duration | Time) -> float:
    """A Duration or Time as float seconds."""
    return value.sec + value.nanosec * 1e-9


def stamp(seconds: float) -> Time:
    """builtin_interfaces/Time of a ROS time ``seconds`` (> 0: since the epoch)."""
    ns = round(seconds * 1e9)
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def start_of(value: Time) -> float | None:
    """A start time as ROS time s; None for the zero Time (on receipt)."""
    return None if stamp_is_zero(value) else seconds(value)


def joint_trajectory(traj: Trajectory, start: float | None = None) -> JointTrajectory:
    """trajectory_msgs/JointTrajectory of a planned move: positions and velocities of the six
    actuated joints (JOINT_NAMES order) at each sample time; the header stamp ``start`` (ROS
    time s: when the drives start it), or zero (None; the ROS convention: start on receipt)."""
    msg = JointTrajectory(joint_names=list(JOINT_NAMES))
    if start is not None:
        msg.header.stamp = stamp(start)
    positions = np.hstack([traj.lengths, traj.thetas])
    velocities = np.hstack([traj.length_rates, traj.theta_rates])
    msg.points = [JointTrajectoryPoint(positions=positions[i].tolist(),
                                       velocities=velocities[i].tolist(),
                                       time_from_start=duration(float(t)))
                  for i, t in enumerate(traj.times)]
    return msg


def planned_path(traj: Trajectory, start: float) -> Path:
    """nav_msgs/Path of a planned move sent to start at ``start`` (ROS time s): its platform
    poses in base, each stamped at its commanded instant (``start`` + its sample time)."""
    msg = Path()
    msg.header.stamp, msg.header.frame_id = stamp(start), BASE_FRAME
    msg.poses = [pose_stamped(p, q, stamp(start + float(t)))
                 for t, p, q in zip(traj.times, traj.position, traj.quaternion, strict=True)]
    return msg


def path_arrays(msg: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A nav_msgs/Path's stamps (K,) s, positions (K, 3) m and quaternions (K, 4) (not
    validated)."""
    stamps = np.array([seconds(p.header.stamp) for p in msg.poses], dtype=float)
    poses = [pose_arrays(p.pose) for p in msg.poses]
    return (stamps, np.array([p for p, _ in poses], dtype=float).reshape(-1, 3),
            np.array([q for _, q in poses], dtype=float).reshape(-1, 4))


def stop_trajectory() -> JointTrajectory:
    """The empty trajectory: stop with controlled deceleration."""
    return JointTrajectory(joint_names=list(JOINT_NAMES))


def _points(rows: ArrayLike) -> list[Point]:
    return [Point(x=float(v[0]), y=float(v[1]), z=float(v[2])) for v in np.reshape(rows, (-1, 3))]


def platform_markers(mech: Mechanism, position: ArrayLike, quaternion: ArrayLike,
                     header: Header) -> MarkerArray:
    """Legs (lines A_i → B_i) and the platform triangle for RViz / Foxglove of the machine
    ``mech`` at the platform pose (3,) m, (4,) in the header's frame."""
    a = np.reshape(mech.base_joints, (3, 3))
    b = platform_points(mech, np.reshape(position, (1, 3)), np.reshape(quaternion, (1, 4)))[0]
    legs = Marker(header=header, ns='legs', id=0, type=Marker.LINE_LIST, action=Marker.ADD)
    legs.scale.x, legs.color.r, legs.color.g, legs.color.a = 0.004, 0.2, 0.6, 1.0
    legs.points = _points(np.stack([a, b], axis=1))
    plate = Marker(header=header, ns='platform', id=1, type=Marker.LINE_STRIP,
                   action=Marker.ADD)
    plate.scale.x, plate.color.b, plate.color.a = 0.003, 1.0, 1.0
    plate.points = _points(np.vstack([b, b[:1]]))
    return MarkerArray(markers=[legs, plate])


def joint_reading(msg: JointState | None) -> JointReading | None:
    """The six positions and velocities of a JointState and its stamp (None: no message, or
    one that lacks a joint)."""
    if msg is None:
        return None
    position = joint_values(msg, JOINT_NAMES)
    velocity = joint_values(msg, JOINT_NAMES, 'velocity')
    if position is None or velocity is None:
        return None
    return JointReading(position, velocity, _stamp_seconds(msg.header.stamp))


def measurement(msg: PoseWithCovarianceStamped) -> Measurement:
    """A tracker reading: pose, its covariance (6, 6) and the time of the pose it measured."""
    return Measurement(*pose_arrays(msg.pose.pose),
                       np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6),
                       _stamp_seconds(msg.header.stamp))


def pose_messages(msgs: Sequence[PoseStamped | PoseWithCovarianceStamped],
                  first: int = 0) -> PoseMessages:
    """N messages of one pose topic, in arrival order, as the accuracy monitor takes them
    (:class:`~positioning_cell.accuracy.monitor.PoseMessages`, ranked ``first`` on): header
    stamps s (:func:`~positioning_cell.accuracy.settle.stamp_seconds`), frame ids, positions
    (N, 3) m, quaternions (N, 4) x, y, z, w and, of PoseWithCovarianceStamped, the covariances
    (N, 6, 6) they state (not validated: the monitor checks them)."""
    poses = [getattr(msg.pose, 'pose', msg.pose) for msg in msgs]
    values = np.array([(p.position.x, p.position.y, p.position.z, p.orientation.x,
                        p.orientation.y, p.orientation.z, p.orientation.w) for p in poses],
                      dtype=float).reshape(-1, 7)
    stamps = np.array([stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec)
                       for msg in msgs], dtype=float)
    covariance = (np.array([msg.pose.covariance for msg in msgs], dtype=float).reshape(-1, 6, 6)
                  if msgs and hasattr(msgs[0].pose, 'covariance') else None)
    return PoseMessages(np.arange(first, first + len(msgs), dtype=np.intp),
                        stamps,
                        np.array([msg.header.frame_id for msg in msgs], dtype=object),
                        values[:, :3], values[:, 3:], covariance)


def pose_batches(taken: Mapping[str, Sequence[PoseStamped | PoseWithCovarianceStamped]]
                 ) -> tuple[dict[str, PoseMessages], list[Time]]:
    """Messages of several pose topics taken together (each a list in arrival order, keyed by
    what it is to the monitor): each as :func:`pose_messages`, ranked after the one before
    (their order across topics is their stamps', which the monitor sorts by), and their header
    stamps in rank order."""
    batches, first = {}, 0
    for key, msgs in taken.items():
        batches[key], first = pose_messages(msgs, first), first + len(msgs)
    return batches, [msg.header.stamp for msgs in taken.values() for msg in msgs]


def _stamp_seconds(stamp: Time) -> float:
    """A header stamp as s (NaN for a zero stamp: no time given)."""
    return math.nan if stamp_is_zero(stamp) else seconds(stamp)


def registration(msg: PoseWithCovarianceStamped) -> Registration:
    """The tracker's registration (/metrology/registration): its origin (3,) m in ``base`` and
    the covariance (6, 6) of its pose."""
    position, _ = pose_arrays(msg.pose.pose)
    return Registration.checked(position, msg.pose.covariance)


def pose_with_covariance(position: ArrayLike, quaternion: ArrayLike, covariance: ArrayLike,
                         stamp: Time, frame: str = BASE_FRAME) -> PoseWithCovarianceStamped:
    """A measured pose in ``frame`` (m, x, y, z, w) with its covariance (6, 6)."""
    msg = PoseWithCovarianceStamped()
    msg.header.stamp, msg.header.frame_id = stamp, frame
    msg.pose.pose = pose_msg(position, quaternion)
    msg.pose.covariance = np.asarray(covariance, dtype=float).reshape(36).tolist()
    return msg


def registration_msg(position: ArrayLike, quaternion: ArrayLike, covariance: ArrayLike,
                     stamp: Time) -> PoseWithCovarianceStamped:
    """/metrology/registration: the located tracker's pose in ``base`` (m, x, y, z, w) and its
    covariance (6, 6: δp m, δθ rad about the base axes at the tracker origin)."""
    return pose_with_covariance(position, quaternion, covariance, stamp)


def answer(status: DiagnosticStatus) -> Answer | None:
    """The drives' answer to a trajectory (/legs/trajectory_status), None without a key."""
    values = status_values(status)
    if not values.get('key'):
        return None
    return Answer(values['key'], values.get('accepted') == 'true', status.message)


def published_monotonic(info: Mapping[str, int]) -> float:
    """When a message received now was published, on this process's ``time.monotonic()`` clock
    (s): its age from the middleware's source timestamp (system clock, ns) taken off now.
    Without a source timestamp (0), or one from the future, the time of receipt."""
    now = time.monotonic()
    source_ns = int(info.get('source_timestamp', 0))
    if source_ns <= 0:
        return now
    return now - max(0.0, (time.time_ns() - source_ns) * 1e-9)


def stamp_is_zero(stamp: Time) -> bool:
    """A zero header stamp (ROS convention: "now" / "on receipt")."""
    return stamp.sec == 0 and stamp.nanosec == 0


LEVELS = {'ok': DiagnosticStatus.OK, 'warn': DiagnosticStatus.WARN,
          'error': DiagnosticStatus.ERROR, 'stale': DiagnosticStatus.STALE}


def status_level(status: DiagnosticStatus) -> int:
    """The level of a DiagnosticStatus as an int (rclpy gives a byte)."""
    level = status.level
    return int.from_bytes(level, 'little') if isinstance(level, bytes) else int(level)


def status(name: str, level: str, message: str, values: Mapping[str, Any],
           hardware_id: str = 'positioning_cell') -> DiagnosticStatus:
    """A DiagnosticStatus; ``level`` is ok, warn, error or stale."""
    return DiagnosticStatus(level=LEVELS[level], name=name, message=message,
                            hardware_id=hardware_id,
                            values=[KeyValue(key=str(k), value=str(v))
                                    for k, v in values.items()])


def status_values(status: DiagnosticStatus) -> dict[str, str]:
    """The key-value pairs of a status."""
    return {kv.key: kv.value for kv in status.values}


def diagnostic(name: str, level: str, message: str, values: Mapping[str, Any],
               stamp: Time, hardware_id: str = 'positioning_cell') -> DiagnosticArray:
    """A DiagnosticArray with one status (:func:`status`)."""
    array = DiagnosticArray()
    array.header.stamp = stamp
    array.status = [status(name, level, message, values, hardware_id)]
    return array


def message_class(msgtype: str) -> Any:
    """The Python class of ROS message type ``pkg/msg/Type`` from its generated package (what
    a raw publisher or subscription of a recorded type needs); InputError if not installed."""
    parts = msgtype.split('/')
    if len(parts) != 3 or parts[1] != 'msg' or not all(parts):
        raise InputError(f'{msgtype!r} is not a ROS message type name (pkg/msg/Type)')
    try:
        return getattr(importlib.import_module(f'{parts[0]}.msg'), parts[2])
    except (ImportError, AttributeError) as err:
        raise InputError(f'message type {msgtype} is not installed: {err}') from err
