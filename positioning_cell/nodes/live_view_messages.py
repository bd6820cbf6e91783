"""The live view's Foxglove messages (foxglove-sdk, no rclpy): the 3-D scene, the frame
transforms, and the JSON documents of the deviation and status channels, built from a watch
:class:`~positioning_cell.watch.state.Snapshot`. Foxglove's schemas are SI (m, quaternions);
the JSON channels carry SI values and display values whose names say their units."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
from foxglove import Channel, Schema
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    FrameTransform,
    FrameTransforms,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)
from numpy.typing import ArrayLike

from positioning_cell import names
from positioning_cell.accuracy.decisions import Decision, DecisionRule
from positioning_cell.frames.systems import OBJECT_FRAME, USER_FRAME
from positioning_cell.watch.deviation import AXES, Deviation
from positioning_cell.watch.scene import Scene, arrow_quaternion
from positioning_cell.watch.state import Snapshot, Status

LEG_THICKNESS = 0.006  # m
PLATFORM_COLOUR = (0.2, 0.45, 0.9, 1.0)
GHOST_COLOUR = (0.7, 0.7, 0.7, 0.35)
BASE_COLOUR = (0.4, 0.4, 0.4, 1.0)
TARGET_COLOUR = (1.0, 0.55, 0.0, 1.0)
ARROW_COLOUR = (0.9, 0.1, 0.6, 1.0)
TOLERANCE_COLOUR = (0.1, 0.8, 0.3, 0.25)
TARGET_DIAMETER = 0.0381  # m, a 1.5" SMR


def timestamp(seconds: float) -> Timestamp:
    """A Foxglove timestamp of ``seconds`` since the epoch."""
    ns = round(seconds * 1e9)
    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _floats(values: ArrayLike, n: int) -> list[float]:
    return [float(x) for x in np.asarray(values, dtype=float).reshape(n)]


def colour(rgba: ArrayLike) -> Color:
    r, g, b, a = _floats(rgba, 4)
    return Color(r=r, g=g, b=b, a=a)


def vector3(v: ArrayLike) -> Vector3:
    x, y, z = _floats(v, 3)
    return Vector3(x=x, y=y, z=z)


def quaternion(q: ArrayLike) -> Quaternion:
    x, y, z, w = _floats(q, 4)
    return Quaternion(x=x, y=y, z=z, w=w)


def pose(position: ArrayLike = (0.0, 0.0, 0.0),
         orientation: ArrayLike = (0.0, 0.0, 0.0, 1.0)) -> Pose:
    return Pose(position=vector3(position), orientation=quaternion(orientation))


def point3s(rows: Any) -> list[Point3]:
    return [Point3(x=float(r[0]), y=float(r[1]), z=float(r[2]))
            for r in np.reshape(rows, (-1, 3))]


def triangle(points: Any, rgba: ArrayLike, thickness: float) -> LinePrimitive:
    closed = np.vstack([points, points[:1]])
    return LinePrimitive(type=LinePrimitiveLineType.LineStrip, pose=pose(),
                         thickness=thickness, points=point3s(closed), color=colour(rgba))


def scene_update(scene: Scene, stamp: float, static: bool = True) -> SceneUpdate:
    """The positioner in ``base`` (entities ``base``, ``legs``, ``platform``, ``commanded``,
    ``targets``, ``error``); an entity whose inputs are missing is left out, and so are the
    two that change only with the command (``base``, ``commanded``) unless ``static``: an
    entity stays drawn until it is replaced."""
    ts = timestamp(stamp)
    entities = []
    if static:
        entities.append(SceneEntity(timestamp=ts, frame_id=names.BASE_FRAME, id='base',
                                    lines=[triangle(scene.base_joints, BASE_COLOUR, 0.004)]))
    if scene.platform_joints is not None and scene.leg_colours is not None:
        legs = np.stack([scene.base_joints, scene.platform_joints], axis=1).reshape(-1, 3)
        colours = [colour(c) for c in np.repeat(scene.leg_colours, 2, axis=0)]
        entities += [
            SceneEntity(timestamp=ts, frame_id=names.BASE_FRAME, id='legs',
                        lines=[LinePrimitive(
                            type=LinePrimitiveLineType.LineList, pose=pose(),
                            thickness=LEG_THICKNESS, points=point3s(legs), colors=colours)]),
            SceneEntity(timestamp=ts, frame_id=names.BASE_FRAME, id='platform',
                        lines=[triangle(scene.platform_joints, PLATFORM_COLOUR, 0.004)])]
    if static and scene.ghost_joints is not None:
        entities.append(SceneEntity(timestamp=ts, frame_id=names.BASE_FRAME, id='commanded',
                                    lines=[triangle(scene.ghost_joints, GHOST_COLOUR, 0.004)]))
    if scene.targets is not None:
        size = Vector3(x=TARGET_DIAMETER, y=TARGET_DIAMETER, z=TARGET_DIAMETER)
        entities.append(SceneEntity(timestamp=ts, frame_id=names.BASE_FRAME, id='targets',
                                    spheres=[SpherePrimitive(pose=pose(t), size=size,
                                                             color=colour(TARGET_COLOUR))
                                             for t in scene.targets]))
    if scene.tolerance_centre is not None:
        d = 2.0 * scene.tolerance_radius
        arrows = []
        if scene.arrow is not None:
            start, vector = scene.arrow
            length = float(np.linalg.norm(vector))
            arrows.append(ArrowPrimitive(
                pose=pose(start, arrow_quaternion(vector)), shaft_length=0.8 * length,
                shaft_diameter=0.002, head_length=0.2 * length, head_diameter=0.006,
                color=colour(ARROW_COLOUR)))
        entities.append(SceneEntity(
            timestamp=ts, frame_id=names.BASE_FRAME, id='error', arrows=arrows,
            spheres=[SpherePrimitive(pose=pose(scene.tolerance_centre),
                                     size=Vector3(x=d, y=d, z=d),
                                     color=colour(TOLERANCE_COLOUR))]))
    return SceneUpdate(entities=entities)


def frame_transforms(snapshot: Snapshot, stamp: float) -> FrameTransforms:
    """base → platform (the encoders' estimate), platform_commanded, platform_measured and
    user (T_base_user = T_base_machine · T_machine_user), platform → object; each once its
    input has come (user and object once the positioner has published them)."""
    ts = timestamp(stamp)
    out = [FrameTransform(timestamp=ts, parent_frame_id=parent, child_frame_id=child,
                          translation=vector3(pose[0]), rotation=quaternion(pose[1]))
           for parent, child, pose in (
               (names.BASE_FRAME, names.PLATFORM_FRAME, snapshot.estimated),
               (names.BASE_FRAME, names.PLATFORM_COMMANDED_FRAME, snapshot.commanded),
               (names.BASE_FRAME, names.PLATFORM_MEASURED_FRAME, snapshot.measured),
               (names.BASE_FRAME, USER_FRAME, snapshot.user_in_base),
               (names.PLATFORM_FRAME, OBJECT_FRAME, snapshot.object_in_platform))
           if pose is not None]
    return FrameTransforms(transforms=out)


def deviation_document(dev: Deviation, stamp: float) -> dict[str, Any]:
    """The /live/deviation message: SI arrays (``commanded``, ``measured``, ``deviation``,
    ``uncertainty``: x, y, z m, rx, ry, rz rad), per-axis display values (``x_um`` …
    ``rz_deg``), |Δp| µm, |Δθ| deg with their U (k = 2), the tolerances, the in/out verdict
    as measured, the decision by the monitor's rule (``decision``: conforms, indeterminate,
    does not conform; ``decision_rule``), and ``stamp`` (s) of the measurement."""
    doc: dict[str, Any] = {
        'stamp': stamp, 'frame': dev.frame,
        'commanded': dev.commanded.tolist(), 'measured': dev.measured.tolist(),
        'deviation': dev.deviation.tolist(), 'uncertainty': dev.uncertainty.tolist(),
        'position_error_um': dev.position_error * 1e6,
        'orientation_error_deg': math.degrees(dev.orientation_error),
        'position_tolerance_um': dev.tolerances.position * 1e6,
        'orientation_tolerance_deg': math.degrees(dev.tolerances.orientation),
        'position_uncertainty_um': dev.verdict.position_uncertainty * 1e6,
        'orientation_uncertainty_deg': math.degrees(dev.verdict.orientation_uncertainty),
        'in_tolerance': dev.ok, 'axis_in_tolerance': [bool(b) for b in dev.axis_ok],
        'decision': dev.verdict.decision.value,
        'decision_rule': dev.tolerances.decision_rule}
    for i, axis in enumerate(AXES):
        if i < 3:
            doc[f'{axis}_um'] = float(dev.deviation[i]) * 1e6
        else:
            doc[f'{axis}_deg'] = math.degrees(float(dev.deviation[i]))
    return doc


def status_value(status: Status | None) -> dict[str, Any] | None:
    return None if status is None else {'level': status.level, 'message': status.message}


def status_document(snapshot: Snapshot, now: float) -> dict[str, Any]:
    """The /live/status message at wall time ``now`` (s): the positioner's state, the last
    verdict, the recording (``stopped`` true when the recorder failed, stopped or went silent;
    null while no recorder was heard of), what has not come yet, and whether the monitor's
    tolerances and the coordinate systems are known."""
    record = snapshot.recording(now)
    return {'positioner': status_value(snapshot.positioner),
            'verdict': status_value(snapshot.verdict),
            'recording': None if record is None else record.to_dict(),
            'waiting_for': snapshot.waiting_for(),
            'tolerances_known': snapshot.tolerances is not None,
            'coordinate_systems_known': snapshot.systems_known}


def deviation_schema() -> dict[str, Any]:
    """JSON Schema of :func:`deviation_document` (Foxglove's plot and table panels)."""
    number = {'type': 'number'}
    six = {'type': 'array', 'items': number, 'minItems': 6, 'maxItems': 6}
    props: dict[str, Any] = {
        'stamp': number, 'frame': {'type': 'string'}, 'commanded': six, 'measured': six,
        'deviation': six, 'uncertainty': six, 'position_error_um': number,
        'orientation_error_deg': number, 'position_tolerance_um': number,
        'orientation_tolerance_deg': number, 'position_uncertainty_um': number,
        'orientation_uncertainty_deg': number, 'in_tolerance': {'type': 'boolean'},
        'axis_in_tolerance': {'type': 'array', 'items': {'type': 'boolean'}},
        'decision': {'type': 'string', 'enum': [d.value for d in Decision]},
        'decision_rule': {'type': 'string', 'enum': [r.value for r in DecisionRule]}}
    props.update({f'{a}_um': number for a in AXES[:3]})
    props.update({f'{a}_deg': number for a in AXES[3:]})
    return {'type': 'object', 'properties': props}


def status_schema() -> dict[str, Any]:
    """JSON Schema of :func:`status_document`."""
    status = {'type': ['object', 'null'], 'properties': {
        'level': {'type': 'integer'}, 'message': {'type': 'string'}}}
    return {'type': 'object', 'properties': {
        'positioner': status, 'verdict': status,
        'recording': {'type': ['object', 'null'], 'properties': {
            'level': {'type': 'integer'}, 'message': {'type': 'string'},
            'stopped': {'type': 'boolean'}}},
        'waiting_for': {'type': 'array', 'items': {'type': 'string'}},
        'tolerances_known': {'type': 'boolean'},
        'coordinate_systems_known': {'type': 'boolean'}}}


#: Schema names of the JSON channels.
DEVIATION_SCHEMA = 'positioning_cell.LiveDeviation'
STATUS_SCHEMA = 'positioning_cell.LiveStatus'


def _json_schema(name: str, schema: dict[str, Any]) -> Schema:
    return Schema(name=name, encoding='jsonschema', data=json.dumps(schema).encode())


class LiveChannels:
    """The live view's four channels on a foxglove ``context`` (:mod:`positioning_cell.names`:
    LIVE_SCENE, LIVE_TRANSFORMS, LIVE_DEVIATION, LIVE_STATUS) and one send of a snapshot."""

    def __init__(self, context: Any) -> None:
        self.scene = SceneUpdateChannel(names.LIVE_SCENE, context=context)
        self.transforms = FrameTransformsChannel(names.LIVE_TRANSFORMS, context=context)
        self.deviation = Channel(names.LIVE_DEVIATION, message_encoding='json', context=context,
                                 schema=_json_schema(DEVIATION_SCHEMA, deviation_schema()))
        self.status = Channel(names.LIVE_STATUS, message_encoding='json', context=context,
                              schema=_json_schema(STATUS_SCHEMA, status_schema()))
        self._commanded: object = None

    def send(self, snapshot: Snapshot, frame: str, magnification: float, stamp: float,
             full: bool = True) -> bool:
        """Log the scene, the transforms, the status and (once there is a command and a
        measurement) the deviation in ``frame`` at ``stamp`` (s); the scene's static entities
        only when ``full`` or the command changed. Whether the deviation was sent."""
        scene = snapshot.scene(magnification)
        if scene is not None:
            changed = snapshot.commanded is not self._commanded
            self._commanded = snapshot.commanded
            self.scene.log(scene_update(scene, stamp, static=full or changed))
        self.transforms.log(frame_transforms(snapshot, stamp))
        self.status.log(status_document(snapshot, stamp))
        dev = snapshot.deviation(frame)
        if dev is not None:
            self.deviation.log(deviation_document(dev, snapshot.measured_stamp))
        return dev is not None
