"""A recorded calibration run read back (``calibrate_cell --from-bag``): the markers of one run on
``/cell/calibration``, the encoder readings (/legs/joint_states), the tracker poses
(/metrology/pose) and, when recorded, the air temperature (/cell/air_temperature) and the
tracker's registrations (/metrology/registration) of the bag,
made into the same calibration data as the live run
(:func:`positioning_cell.calibration.collect.collect`). Messages as the bag reader decodes them
(the ROS field names), no rclpy."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from positioning_cell import names
from positioning_cell.accuracy.settle import stamp_seconds
from positioning_cell.bag.opening import open_bag
from positioning_cell.calibration import collect as col
from positioning_cell.core.mechanism import JOINT_NAMES
from positioning_cell.errors import InputError, PositioningError
from positioning_cell.metrology.instrument import Registration


def _stamp(msg: Any) -> float:
    return stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec)


def _joints(msg: Any) -> np.ndarray | None:
    """The positions in JOINT_NAMES order (None: a joint missing)."""
    index = {n: i for i, n in enumerate(msg.name)}
    if len(msg.position) != len(msg.name) or any(n not in index for n in JOINT_NAMES):
        return None
    return np.array([msg.position[index[n]] for n in JOINT_NAMES], dtype=float)


def read_bag(path: Path, run: str | None = None,
             say: Callable[[str], None] = print) -> col.Collected:
    """The calibration data of run ``run`` (its start, as printed; default: the last one)
    recorded in the bag at ``path`` (PositioningError if it lacks the markers, the encoder
    readings or the tracker poses, or holds no such run)."""
    markers: list[col.Marker] = []
    joints: list[tuple[float, np.ndarray]] = []
    poses: list[tuple[float, Any]] = []
    air: list[tuple[float, float]] = []
    located: list[tuple[float, Registration]] = []
    with open_bag(path) as reader:
        topics = (names.CALIBRATION, names.JOINT_STATES, names.MEASURED_POSE)
        missing = [t for t in topics if t not in reader.topics]
        if missing:
            raise PositioningError(f'{path}: not a calibration run: no {", ".join(missing)}')
        optional = [t for t in (names.AIR_TEMPERATURE, names.TRACKER_REGISTRATION)
                    if t in reader.topics]
        has_air = names.AIR_TEMPERATURE in optional
        for item in reader.messages([*topics, *optional]):
            msg = item.message
            if item.topic == names.TRACKER_REGISTRATION:
                p = msg.pose.pose.position
                try:
                    located.append((_stamp(msg), Registration.checked((p.x, p.y, p.z),
                                                                      msg.pose.covariance)))
                except InputError as err:
                    say(f'{path}: a registration not used: {err}')
            elif item.topic == names.AIR_TEMPERATURE:
                air.append((_stamp(msg), float(msg.temperature)))
            elif item.topic == names.CALIBRATION:
                markers.append(col.Marker.from_json(msg.data))
            elif item.topic == names.JOINT_STATES:
                values = _joints(msg)
                if values is not None:
                    joints.append((_stamp(msg), values))
            else:
                poses.append((_stamp(msg), msg.pose))
    found = col.runs(markers)
    if not found:
        raise PositioningError(f'{path}: no calibration marker on {names.CALIBRATION}')
    if run is None:
        run = found[-1]
    elif run not in found:
        raise PositioningError(f'{path}: no calibration run {run!r}; it holds '
                               f'{", ".join(found)}')
    markers = [m for m in markers if m.run == run]
    say(f'{path}: calibration run {run} ({len(markers)} poses; runs in the bag: '
        f'{", ".join(found)})')
    pose_stream = col.Stream(
        np.array([t for t, _ in poses], dtype=float),
        (np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z]
                   for _, p in poses], dtype=float).reshape(-1, 3),
         np.array([[p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z,
                    p.pose.orientation.w] for _, p in poses], dtype=float).reshape(-1, 4),
         np.array([np.asarray(p.covariance, dtype=float) for _, p in poses],
                  dtype=float).reshape(-1, 6, 6)))
    joint_stream = col.Stream(np.array([t for t, _ in joints], dtype=float),
                              (np.array([v for _, v in joints], dtype=float).reshape(-1, 6),))
    if not has_air:
        say(f'{path}: no {names.AIR_TEMPERATURE} recorded')
    air_stream = col.Stream(np.array([t for t, _ in air], dtype=float),
                            (np.array([v for _, v in air], dtype=float),)) if has_air else None
    if not located:
        say(f'{path}: no {names.TRACKER_REGISTRATION} recorded: each pose\'s tracker readings '
            'are taken as independent (its covariance the mean one over their number)')
    collected = col.collect(markers, joint_stream, pose_stream, col.JOINT_SIGMA_FLOOR,
                            air_stream, located)
    for why in collected.missing:
        say(f'calibration: the poses carry no {why}')
    return collected
