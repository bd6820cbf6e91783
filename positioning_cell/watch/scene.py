"""The positioner drawn in 3-D for the live view: base and platform joint centres, the legs
coloured by how close each is to an end of its stroke, the commanded platform as a ghost, the
tracker targets where the tracker measures them, the position error as an arrow magnified by a
stated factor and the position tolerance as a sphere of the same magnification. All points in
``base``, m; the geometry is the nominal mechanism's (seed 000 Table 1), the poses are what the
cell publishes (encoder estimate, command, measurement), never the simulator's truth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from positioning_cell.accuracy.verdicts import Tolerances
from positioning_cell.core.kinematics import platform_points
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import FloatArray, as_pose_batch, matrix_from_quaternion
from positioning_cell.errors import InputError

#: Colours (RGBA, 0–1) of a leg at mid-stroke, halfway to an end, and at an end.
MID_STROKE_COLOUR = (0.1, 0.75, 0.2, 1.0)
HALF_COLOUR = (0.95, 0.8, 0.1, 1.0)
END_COLOUR = (0.9, 0.1, 0.1, 1.0)

Pose = tuple[FloatArray, FloatArray]


@dataclass(frozen=True)
class Scene:
    """What the 3-D view draws, ``base`` frame, m. ``platform_joints`` at the displayed pose
    (the encoders' estimate, else the measurement), ``stroke`` (3,) the fraction of each leg's
    stroke (0 at ``length_min``, 1 at ``length_max``), ``leg_colours`` (3, 4) RGBA;
    ``ghost_joints`` at the commanded pose, ``targets`` (T, 3) at the measured pose, ``arrow``
    (start, vector): from the commanded platform origin, ``magnification`` × (p_meas − p_cmd),
    and the tolerance sphere about the commanded origin, radius ``magnification`` ×
    position tolerance; each None while its inputs are missing."""

    base_joints: FloatArray
    platform_joints: FloatArray | None
    stroke: FloatArray | None
    leg_colours: FloatArray | None
    ghost_joints: FloatArray | None
    targets: FloatArray | None
    arrow: tuple[FloatArray, FloatArray] | None
    tolerance_centre: FloatArray | None
    tolerance_radius: float
    magnification: float


def stroke_colour(stroke: FloatArray) -> FloatArray:
    """RGBA (N, 4) of stroke fractions (N,): by the distance to the nearer end, |2f − 1|,
    green at mid-stroke through yellow to red at an end (beyond an end: red)."""
    f = np.asarray(stroke, dtype=float)
    near = np.clip(np.abs(2.0 * f - 1.0), 0.0, 1.0)[:, None]
    mid, half, end = (np.array(c) for c in (MID_STROKE_COLOUR, HALF_COLOUR, END_COLOUR))
    low = mid + (half - mid) * np.clip(2.0 * near, 0.0, 1.0)
    colours: FloatArray = np.where(near <= 0.5, low, half + (end - half) * (2.0 * near - 1.0))
    return colours


def leg_colours(mech: Mechanism, platform_joints: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each leg's stroke fraction (3,) (0 at ``length_min``, 1 at ``length_max``) and its
    colour (3, 4) RGBA (:func:`stroke_colour`) with the platform's joint centres at
    ``platform_joints`` (3, 3) m, base frame."""
    lengths = np.linalg.norm(platform_joints - mech.base_joints, axis=1)
    stroke: FloatArray = (lengths - mech.length_min) / (mech.length_max - mech.length_min)
    return stroke, stroke_colour(stroke)


def scene(mech: Mechanism, estimated: Pose | None, commanded: Pose | None,
          measured: Pose | None, targets_platform: FloatArray | None,
          tolerances: Tolerances, magnification: float) -> Scene:
    """The :class:`Scene` of the cell's latest poses (each (position (3,) m, unit quaternion
    (4,) x, y, z, w) in ``base``, or None), the tracker targets in the platform frame
    ``targets_platform`` (T, 3) m (None: unknown) and the arrow's ``magnification`` (> 0).
    The poses given go through the kinematics as one batch."""
    if not (np.isfinite(magnification) and magnification > 0.0):
        raise InputError(f'magnification = {magnification!r}: must be a finite number > 0')
    shown = estimated if estimated is not None else measured
    given = {k: v for k, v in (('shown', shown), ('commanded', commanded),
                               ('measured', measured)) if v is not None}
    joints: dict[str, FloatArray] = {}
    validated: dict[str, Pose] = {}
    if given:
        p, q = as_pose_batch(np.array([v[0] for v in given.values()]),
                             np.array([v[1] for v in given.values()]))
        joints = dict(zip(given, platform_points(mech, p, q), strict=True))
        validated = {k: (p[i], q[i]) for i, k in enumerate(given)}
    platform = joints.get('shown')
    stroke = colours = None
    if platform is not None:
        stroke, colours = leg_colours(mech, platform)
    targets = None
    if measured is not None and targets_platform is not None:
        p_meas, q_meas = validated['measured']
        targets = p_meas + (np.asarray(targets_platform, dtype=float)
                            @ matrix_from_quaternion(q_meas[np.newaxis])[0].T)
    arrow = centre = None
    if commanded is not None:
        centre = np.asarray(commanded[0], dtype=float).copy()
        if measured is not None:
            arrow = (centre, magnification * (np.asarray(measured[0], dtype=float) - centre))
    return Scene(base_joints=np.asarray(mech.base_joints, dtype=float), platform_joints=platform,
                 stroke=stroke, leg_colours=colours, ghost_joints=joints.get('commanded'),
                 targets=targets, arrow=arrow, tolerance_centre=centre,
                 tolerance_radius=magnification * tolerances.position,
                 magnification=float(magnification))


def arrow_quaternion(vector: FloatArray) -> FloatArray:
    """The unit quaternion (4,) x, y, z, w turning +x onto ``vector`` (3,) (an arrow's pose;
    the identity for a zero vector, a half turn about z for −x)."""
    v = np.asarray(vector, dtype=float)
    n = float(np.linalg.norm(v))
    if n == 0.0:
        return np.array([0.0, 0.0, 0.0, 1.0])
    u = v / n
    w = 1.0 + u[0]  # q = (x × u, 1 + x·u), normalised: the shortest arc
    if w < 1e-12:
        return np.array([0.0, 0.0, 1.0, 0.0])
    q = np.array([0.0, -u[2], u[1], w])
    return np.asarray(q / np.linalg.norm(q))
