"""The live view of a coordinated cell (``live_view`` with ``view: panel``; issue 27 item 6):
its Foxglove messages (foxglove-sdk, no rclpy) from a
:class:`~positioning_cell.watch.panel.PanelSnapshot`, in the ``cell`` frame: each positioner's
base where the cell file puts it, its legs (coloured by stroke, as in the positioner's own
view) and platform where its encoders put them, the panel where its tracker measures it (the
triangle of its attachment points and a ball at each), and the internal force at each
attachment from the legs' load cells as an arrow ``force_scale`` m per N long, green below
half the cell file's limit, yellow below it, red beyond, labelled with its size; the frame
transforms (cell → panel as measured, cell → ``<name>/base``); the status as JSON. Foxglove's
schemas are SI; the JSON's names say their units."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from foxglove import Channel, Schema
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from foxglove.messages import (
    ArrowPrimitive,
    FrameTransform,
    FrameTransforms,
    LinePrimitive,
    LinePrimitiveLineType,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    TextPrimitive,
    Vector3,
)

from positioning_cell import names
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.panel_motion import bases
from positioning_cell.core.kinematics import platform_points
from positioning_cell.errors import PositioningError
from positioning_cell.frames.transforms import Transform
from positioning_cell.nodes.live_view_messages import (
    BASE_COLOUR,
    LEG_THICKNESS,
    PLATFORM_COLOUR,
    colour,
    point3s,
    pose,
    quaternion,
    status_value,
    timestamp,
    triangle,
    vector3,
)
from positioning_cell.watch.panel import PanelForces, PanelSnapshot
from positioning_cell.watch.scene import arrow_quaternion, leg_colours
from positioning_cell.watch.state import is_stale

BALL_DIAMETER = 0.03  # m
#: The force arrows' colours: below half the limit, below it, beyond it.
FORCE_COLOURS = ((0.1, 0.75, 0.25, 1.0), (0.95, 0.75, 0.1, 1.0), (0.9, 0.1, 0.1, 1.0))
#: The schema name of the panel view's status channel.
PANEL_STATUS_SCHEMA = 'positioning_cell.LivePanelStatus'


def base_frame(name: str) -> str:
    """The frame of positioner ``name``'s base in the panel view's transforms."""
    return f'{name}/{names.BASE_FRAME}'


def force_colour(size: float, limit: float) -> tuple[float, float, float, float]:
    """The arrow's colour of an internal force ``size`` N against the cell's ``limit`` N."""
    return FORCE_COLOURS[0 if size < 0.5 * limit else 1 if size < limit else 2]


def _cell(snapshot: PanelSnapshot) -> CellFile | None:
    if snapshot.settings is None:
        return None
    try:
        return snapshot.settings.cell()
    except PositioningError:
        return None


def panel_scene(snapshot: PanelSnapshot, stamp: float, force_scale: float) -> SceneUpdate:
    """The scene (module docstring): entities ``bases`` once the cell file is known,
    ``positioners`` (legs and platforms) once encoders are heard, ``panel`` once the panel is
    measured, ``forces`` once the load cells give them too."""
    ts = timestamp(stamp)
    cell = _cell(snapshot)
    if cell is None or snapshot.settings is None:
        return SceneUpdate(entities=[])
    mech = snapshot.settings.mechanism
    base_joints = np.asarray(mech.base_joints, dtype=float)
    placed = bases(cell)
    entities = [SceneEntity(timestamp=ts, frame_id=names.CELL_FRAME, id='bases', lines=[
        triangle(base_joints @ b.R.T + b.p, BASE_COLOUR, 0.004) for b in placed])]
    platforms = snapshot.platforms()
    if platforms:
        legs, colours, tops = [], [], []
        for entry, b in zip(cell.positioners, placed, strict=True):
            if entry.name not in platforms:
                continue
            p, q = platforms[entry.name]
            top = platform_points(mech, p[None], q[None])[0]
            _, stroke_colours = leg_colours(mech, top)
            bottom_cell, top_cell = base_joints @ b.R.T + b.p, top @ b.R.T + b.p
            legs.append(np.stack([bottom_cell, top_cell], axis=1).reshape(-1, 3))
            colours += [colour(c) for c in np.repeat(stroke_colours, 2, axis=0)]
            tops.append(triangle(top_cell, PLATFORM_COLOUR, 0.004))
        entities.append(SceneEntity(
            timestamp=ts, frame_id=names.CELL_FRAME, id='positioners',
            lines=[LinePrimitive(type=LinePrimitiveLineType.LineList, pose=pose(),
                                 thickness=LEG_THICKNESS, points=point3s(np.vstack(legs)),
                                 colors=colours), *tops]))
    if snapshot.panel is None:
        return SceneUpdate(entities=entities)
    panel = Transform.from_pq(*snapshot.panel)
    balls = panel.apply(cell.panel_points(mech))
    size = Vector3(x=BALL_DIAMETER, y=BALL_DIAMETER, z=BALL_DIAMETER)
    entities.append(SceneEntity(
        timestamp=ts, frame_id=names.CELL_FRAME, id='panel',
        lines=[triangle(balls, PLATFORM_COLOUR, 0.006)],
        spheres=[SpherePrimitive(pose=pose(b), size=size, color=colour(PLATFORM_COLOUR))
                 for b in balls]))
    forces = snapshot.forces()
    if isinstance(forces, PanelForces):
        arrows, texts = [], []
        for name, ball, force, load in zip(forces.names, balls, forces.internal, forces.sizes,
                                           strict=True):
            length = max(float(load) * force_scale, 1e-6)
            arrows.append(ArrowPrimitive(
                pose=pose(ball, arrow_quaternion(force)), shaft_length=0.8 * length,
                shaft_diameter=0.004, head_length=0.2 * length, head_diameter=0.012,
                color=colour(force_colour(float(load), forces.limit))))
            texts.append(TextPrimitive(pose=pose(ball + np.array([0.0, 0.0, 0.04])),
                                       billboard=True, font_size=14.0, scale_invariant=True,
                                       color=colour((1.0, 1.0, 1.0, 1.0)),
                                       text=f'{name} {float(load):.0f} N'))
        entities.append(SceneEntity(timestamp=ts, frame_id=names.CELL_FRAME, id='forces',
                                    arrows=arrows, texts=texts))
    return SceneUpdate(entities=entities)


def panel_transforms(snapshot: PanelSnapshot, stamp: float) -> FrameTransforms:
    """cell → each ``<name>/base`` (the cell file) once known, cell → panel once measured."""
    ts = timestamp(stamp)
    cell = _cell(snapshot)
    pairs = [(base_frame(e.name), (b.p, b.q)) for e, b in
             zip(cell.positioners, bases(cell), strict=True)] if cell is not None else []
    if snapshot.panel is not None:
        pairs.append((names.PANEL_FRAME, snapshot.panel))
    return FrameTransforms(transforms=[
        FrameTransform(timestamp=ts, parent_frame_id=names.CELL_FRAME, child_frame_id=child,
                       translation=vector3(p), rotation=quaternion(q))
        for child, (p, q) in pairs])


def panel_status_document(snapshot: PanelSnapshot, now: float) -> dict[str, Any]:
    """The status channel's message at wall time ``now`` s: the coordinator's status, the
    panel's measurement age (``panel_age_s``, ``panel_stale``), the largest internal force
    (``internal_force_n``, null with ``forces_waiting`` saying why) against the cell file's
    ``internal_force_limit_n``, each attachment's (``attachments``: ``name``, ``force_n``
    (x, y, z in the cell frame), ``size_n``), each positioner's and its drives' status, and
    what has not come yet."""
    age = now - snapshot.panel_stamp if snapshot.panel is not None else None
    forces = snapshot.forces()
    found = forces if isinstance(forces, PanelForces) else None
    return {
        'coordinator': status_value(snapshot.coordinator),
        'panel_age_s': age, 'panel_stale': age is None or is_stale(age),
        'internal_force_n': float(found.sizes.max()) if found is not None else None,
        'internal_force_limit_n': found.limit if found is not None else None,
        'forces_waiting': forces if isinstance(forces, str) else None,
        'attachments': [] if found is None else [
            {'name': n, 'force_n': [float(v) for v in f], 'size_n': float(s)}
            for n, f, s in zip(found.names, found.internal, found.sizes, strict=True)],
        'positioners': [{'name': n, 'positioner': status_value(snapshot.positioners.get(n)),
                         'drives': status_value(snapshot.drives.get(n))}
                        for n in snapshot.names],
        'waiting_for': snapshot.waiting_for()}


def panel_status_schema() -> dict[str, Any]:
    """JSON Schema of :func:`panel_status_document`."""
    status = {'type': ['object', 'null'], 'properties': {
        'level': {'type': 'integer'}, 'message': {'type': 'string'}}}
    number, maybe = {'type': 'number'}, {'type': ['number', 'null']}
    return {'type': 'object', 'properties': {
        'coordinator': status, 'panel_age_s': maybe, 'panel_stale': {'type': 'boolean'},
        'internal_force_n': maybe, 'internal_force_limit_n': maybe,
        'forces_waiting': {'type': ['string', 'null']},
        'attachments': {'type': 'array', 'items': {'type': 'object', 'properties': {
            'name': {'type': 'string'}, 'size_n': number,
            'force_n': {'type': 'array', 'items': number, 'minItems': 3, 'maxItems': 3}}}},
        'positioners': {'type': 'array', 'items': {'type': 'object', 'properties': {
            'name': {'type': 'string'}, 'positioner': status, 'drives': status}}},
        'waiting_for': {'type': 'array', 'items': {'type': 'string'}}}}


class PanelChannels:
    """The panel view's three channels on a foxglove ``context`` (the live view's
    LIVE_SCENE, LIVE_TRANSFORMS and LIVE_STATUS) and one send of a snapshot."""

    def __init__(self, context: Any, force_scale: float) -> None:
        self.force_scale = force_scale
        self.scene = SceneUpdateChannel(names.LIVE_SCENE, context=context)
        self.transforms = FrameTransformsChannel(names.LIVE_TRANSFORMS, context=context)
        self.status = Channel(names.LIVE_STATUS, message_encoding='json', context=context,
                              schema=Schema(name=PANEL_STATUS_SCHEMA, encoding='jsonschema',
                                            data=json.dumps(panel_status_schema()).encode()))

    def send(self, snapshot: PanelSnapshot, stamp: float) -> None:
        """Log the scene, the transforms and the status at ``stamp`` (s, wall time)."""
        self.scene.log(panel_scene(snapshot, stamp, self.force_scale))
        self.transforms.log(panel_transforms(snapshot, stamp))
        self.status.log(panel_status_document(snapshot, stamp))
