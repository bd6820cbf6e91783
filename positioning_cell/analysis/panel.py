"""The coordinated cell's run analysed (issue 27 item 6, ``run_cell --cell``): the panel's
ISO 9283 pose figures from the cell tracker's readings, judged against the simulation's truth.

What the program recorded (:class:`~positioning_cell.procedures.panel_program.PanelStep` on
``/cell/panel_program``) says, for each move, the commanded panel pose, when it was sent and
settled and how many readings were averaged; the analysis takes the same readings again from
``/panel/metrology/pose`` (the first ``readings`` stamped at or after ``settled``) and checks
that their mean is the one the run computed live. ISO 9283:1998 §7.2.1 AP and §7.2.2 RP
(:func:`positioning_cell.accuracy.iso9283.iso9283`) are figured at the panel's test point, the
centroid of its attachment points (a pose's position is that point's; its orientation the
panel's), per named pose over the cycles.

Simulation truth, for judging only (a real cell has none, and nothing here feeds back into the
cell): the panel's true pose (``/sim/panel/true_pose``) over each step's reading window gives
the truth's AP and the error of every measured pose; the panel simulator's internal forces and
stretches (``/sim/panel/internal_forces``) over each move, from its start to its end, give the
largest force and attachment disagreement while the positioners moved, and over each reading
window those at rest.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell import names
from positioning_cell.accuracy.iso9283 import PoseFigures, iso9283
from positioning_cell.analysis.reading import joint_values
from positioning_cell.bag.reader import BagReader
from positioning_cell.coordinated.cell_file import CellFile
from positioning_cell.coordinated.load_cells import attachment_forces, internal_force_sizes
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.errors import InputError
from positioning_cell.frames.transforms import Transform
from positioning_cell.mechanics.statics import Structure
from positioning_cell.moves.correction import mean_pose
from positioning_cell.procedures.panel_program import PanelStep

FloatArray = NDArray[np.float64]
#: The live mean and the bag's agree within this, m (both are the same readings' mean).
SAME_MEAN_M = 1e-9


def _span(stamps: FloatArray, first: float, last: float) -> tuple[int, int]:
    """The slice of the sorted ``stamps`` in [first, last]."""
    return (int(np.searchsorted(stamps, first, side='left')),
            int(np.searchsorted(stamps, last, side='right')))


class StampedPoses(NamedTuple):
    """Poses in stamp order: stamps (N,) s, positions (N, 3) m, quaternions (N, 4)."""

    stamps: FloatArray
    positions: FloatArray
    quaternions: FloatArray

    def window(self, first: float, last: float) -> StampedPoses:
        """The poses stamped in [first, last]."""
        lo, hi = _span(self.stamps, first, last)
        return StampedPoses(self.stamps[lo:hi], self.positions[lo:hi], self.quaternions[lo:hi])


class PanelForces(NamedTuple):
    """The panel simulator's records in stamp order: stamps (N,) s, the largest force at one
    attachment (N,) N, the largest stretch of a pair (N,) m."""

    stamps: FloatArray
    largest_n: FloatArray
    largest_stretch_m: FloatArray

    def largest(self, first: float, last: float) -> tuple[float, float]:
        """The largest force (N) and stretch (m) stamped in [first, last]; NaN when none."""
        lo, hi = _span(self.stamps, first, last)
        if hi <= lo:
            return float('nan'), float('nan')
        return float(self.largest_n[lo:hi].max()), float(self.largest_stretch_m[lo:hi].max())


class SetJoints(NamedTuple):
    """One positioner's joint states in stamp order: stamps (N,) s, encoder values (N, 6) and
    load-cell efforts (N, 6) (m, rad; N, N·m; JOINT_NAMES order)."""

    stamps: FloatArray
    positions: FloatArray
    efforts: FloatArray

    def mean(self, first: float, last: float) -> tuple[FloatArray, FloatArray] | None:
        """The mean encoder values and efforts stamped in [first, last]; None when none."""
        lo, hi = _span(self.stamps, first, last)
        if hi <= lo:
            return None
        return self.positions[lo:hi].mean(axis=0), self.efforts[lo:hi].mean(axis=0)


class PanelRecording(NamedTuple):
    """What a coordinated run's bag holds for the analysis (module docstring); ``joints``:
    each positioner's joint states, by set name (empty: not read)."""

    steps: list[PanelStep]
    readings: StampedPoses
    truth: StampedPoses
    forces: PanelForces
    joints: Mapping[str, SetJoints] = MappingProxyType({})


@dataclass(frozen=True)
class PanelFigures:
    """The analysis of a coordinated run (module docstring). ``measured`` and ``truth``: the
    ISO 9283 figures per pose (``poses``, in the program's order) of the tracker's and of the
    true poses at the panel's test point; ``errors_m`` each settled step's distance (m) of the
    measured test point from the true one; ``command_errors_m`` of the true one from its
    goal; ``moving`` and ``at_rest`` the largest internal force (N) and stretch (m) over the
    moves and over the reading windows; ``same_as_live``: every mean taken again from the bag
    equals the run's own; ``load_cells_n``: each settled step's largest internal force at one
    attachment as the legs' load cells say it over its reading window (N; empty: not
    figured, :mod:`positioning_cell.coordinated.load_cells`)."""

    test_point: tuple[float, float, float]
    steps: int
    failed: tuple[str, ...]
    poses: tuple[str, ...]
    measured: tuple[PoseFigures, ...]
    truth: tuple[PoseFigures, ...]
    errors_m: tuple[float, ...]
    command_errors_m: tuple[float, ...]
    moving: tuple[float, float]
    at_rest: tuple[float, float]
    same_as_live: bool
    load_cells_n: tuple[float, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (NaN as None)."""
        def clean(v: float) -> float | None:
            return None if np.isnan(v) else float(v)

        return {'test_point': list(self.test_point), 'steps': self.steps,
                'failed': list(self.failed), 'poses': list(self.poses),
                'measured': [f.to_dict() for f in self.measured],
                'truth': [f.to_dict() for f in self.truth],
                'tracker_error_um': [round(e * 1e6, 3) for e in self.errors_m],
                'true_error_um': [round(e * 1e6, 3) for e in self.command_errors_m],
                'moving': {'largest_force_n': clean(self.moving[0]),
                           'largest_stretch_um': clean(self.moving[1] * 1e6)},
                'at_rest': {'largest_force_n': clean(self.at_rest[0]),
                            'largest_stretch_um': clean(self.at_rest[1] * 1e6)},
                'same_as_live': self.same_as_live,
                'load_cells_internal_n': [round(f, 1) for f in self.load_cells_n]}


def _at_point(point: FloatArray, positions: FloatArray, quaternions: FloatArray) -> FloatArray:
    """The positions (N, 3) m of ``point`` (panel frame) carried by the poses."""
    from scipy.spatial.transform import Rotation

    if len(positions) == 0:
        return np.empty((0, 3))
    return np.asarray(positions + Rotation.from_quat(quaternions).apply(point))


def _taken(readings: StampedPoses, step: PanelStep) -> StampedPoses:
    """The readings the run averaged for ``step``: the first ``readings`` at or after
    ``settled``; InputError when the bag holds fewer."""
    lo = int(np.searchsorted(readings.stamps, step.settled, side='left'))
    hi = lo + step.readings
    if hi > len(readings.stamps):
        raise InputError(f'cycle {step.cycle} {step.pose}: the bag holds '
                         f'{len(readings.stamps) - lo} readings after the move, the run '
                         f'averaged {step.readings}')
    return StampedPoses(readings.stamps[lo:hi], readings.positions[lo:hi],
                        readings.quaternions[lo:hi])


def panel_figures(recording: PanelRecording, cell: CellFile | None = None,
                  mech: Mechanism | None = None, structure: Structure | None = None
                  ) -> PanelFigures:
    """The figures (module docstring) of ``recording``, at its steps' test point (m, the panel
    frame's: the cell's with the panel at home); with the ``cell`` (its nominal machine
    ``mech``, the positioners' own ``structure``) and the sets' joint states, also the
    internal force the load cells say at each settled step. InputError when no step settled
    or the readings a step averaged are not in the bag."""
    done = [s for s in recording.steps if s.succeeded]
    if not done:
        raise InputError('no panel move of the program settled: nothing to figure')
    point = np.asarray(done[0].test_point, dtype=float)
    order = list(dict.fromkeys(s.pose for s in done))
    measured: list[PoseFigures] = []
    truth: list[PoseFigures] = []
    errors: list[float] = []
    command_errors: list[float] = []
    load_cells: list[float] = []
    same = True
    at_rest = (float('nan'), float('nan'))
    by_pose: dict[str, list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]]] = {
        name: [] for name in order}
    for step in done:
        taken = _taken(recording.readings, step)
        p, q = mean_pose(taken.positions, taken.quaternions)
        same &= bool(np.linalg.norm(p - np.array(step.measured_position)) <= SAME_MEAN_M)
        true = recording.truth.window(taken.stamps[0], taken.stamps[-1])
        if len(true.stamps) == 0:
            raise InputError(f'cycle {step.cycle} {step.pose}: no true panel pose in the bag '
                             'over its readings')
        tp, tq = mean_pose(true.positions, true.quaternions)
        by_pose[step.pose].append((p, q, tp, tq))
        measured_point, true_point, goal_point = (
            Transform.from_pq(*pose).apply(point) for pose in
            ((p, q), (tp, tq), (step.commanded_position, step.commanded_quaternion)))
        errors.append(float(np.linalg.norm(measured_point - true_point)))
        command_errors.append(float(np.linalg.norm(true_point - goal_point)))
        at_rest = _larger(at_rest, recording.forces.largest(taken.stamps[0], taken.stamps[-1]))
        if cell is not None and mech is not None:
            load_cells.append(_load_cells(recording, cell, mech, structure,
                                          taken.stamps[0], taken.stamps[-1]))
    moving = (float('nan'), float('nan'))
    for step in recording.steps:
        moving = _larger(moving, recording.forces.largest(step.started, step.settled))
    for k, name in enumerate(order):
        first = next(s for s in done if s.pose == name)
        cp = _at_point(point, np.array([first.commanded_position]),
                       np.array([first.commanded_quaternion]))[0]
        rows = by_pose[name]
        for out, (i, j) in ((measured, (0, 1)), (truth, (2, 3))):
            ps, qs = np.array([r[i] for r in rows]), np.array([r[j] for r in rows])
            out.append(iso9283(cp, first.commanded_quaternion, _at_point(point, ps, qs), qs,
                               key=k + 1))
    return PanelFigures(
        test_point=(float(point[0]), float(point[1]), float(point[2])),
        steps=len(recording.steps),
        failed=tuple(f'cycle {s.cycle} {s.pose}: {s.code}' for s in recording.steps
                     if not s.succeeded), poses=tuple(order),
        measured=tuple(measured), truth=tuple(truth), errors_m=tuple(errors),
        command_errors_m=tuple(command_errors), moving=moving, at_rest=at_rest,
        same_as_live=same, load_cells_n=tuple(load_cells))


def _load_cells(recording: PanelRecording, cell: CellFile, mech: Mechanism,
                structure: Structure | None, first: float, last: float) -> float:
    """The largest internal force (N) the sets' load cells say over [first, last]; NaN when
    a set's joint states are not in the bag for it or do not give it (no efforts, no pose):
    the rest of the analysis stands without it."""
    means = [recording.joints[e.name].mean(first, last) if e.name in recording.joints
             else None for e in cell.positioners]
    if any(m is None for m in means):
        return float('nan')
    joints = np.array([m[0] for m in means if m is not None])
    efforts = np.array([m[1] for m in means if m is not None])
    try:
        forces = attachment_forces(cell, mech, joints, efforts, structure)
    except InputError:
        return float('nan')
    return float(internal_force_sizes(cell, mech, forces).max())


def _larger(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    """Each of two (force, stretch) pairs' larger, NaN (none) giving way."""
    return (float(np.fmax(a[0], b[0])), float(np.fmax(a[1], b[1])))


#: The topics :func:`read_panel_bag` reads.
PANEL_TOPICS = (names.PANEL_PROGRAM, names.PANEL_MEASURED_POSE, names.PANEL_TRUE_POSE,
                names.PANEL_FORCES)


def _stamp(header: Any) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _pose_row(pose: Any) -> list[float]:
    p, o = pose.position, pose.orientation
    return [p.x, p.y, p.z, o.x, o.y, o.z, o.w]


def _stamped(rows: list[list[float]]) -> StampedPoses:
    a = np.array(rows, dtype=float).reshape(-1, 8)
    a = a[np.argsort(a[:, 0], kind='stable')]
    return StampedPoses(a[:, 0], a[:, 1:4], a[:, 4:8])


def read_panel_bag(path: str | Path, sets: Sequence[str] = ()) -> PanelRecording:
    """A coordinated run's bag at ``path`` as the analysis uses it, with the joint states of
    the positioners ``sets`` (their names) (BagError for a bag that cannot be read;
    InputError for a step record that is not one). Only the cell frame's panel readings are
    taken."""
    steps: list[PanelStep] = []
    readings: list[list[float]] = []
    truth: list[list[float]] = []
    forces: list[tuple[float, float, float]] = []
    by_topic = {names.in_set(names.JOINT_STATES, name): name for name in sets}
    joints: dict[str, list[list[float]]] = {name: [] for name in sets}
    with BagReader(path) as bag:
        wanted = [t for t in (*PANEL_TOPICS, *by_topic) if t in bag.topics]
        for item in bag.messages(wanted):
            msg = item.message
            if item.topic in by_topic:
                joints[by_topic[item.topic]].append(
                    [_stamp(msg.header), *joint_values(msg.name, msg.position),
                     *joint_values(msg.name, msg.effort)])
            elif item.topic == names.PANEL_PROGRAM:
                steps.append(PanelStep.from_json(msg.data))
            elif item.topic == names.PANEL_MEASURED_POSE:
                if msg.header.frame_id == names.CELL_FRAME:
                    readings.append([_stamp(msg.header), *_pose_row(msg.pose.pose)])
            elif item.topic == names.PANEL_TRUE_POSE:
                truth.append([_stamp(msg.header), *_pose_row(msg.pose)])
            else:
                record = json.loads(msg.data)
                forces.append((float(record['stamp']), float(record['largest_n']),
                               float(record['largest_stretch_um']) * 1e-6))
    f = np.array(forces, dtype=float).reshape(-1, 3)
    f = f[np.argsort(f[:, 0], kind='stable')]
    return PanelRecording(steps, _stamped(readings), _stamped(truth),
                          PanelForces(f[:, 0], f[:, 1], f[:, 2]),
                          {name: _set_joints(rows) for name, rows in joints.items()})


def _set_joints(rows: list[list[float]]) -> SetJoints:
    a = np.array(rows, dtype=float).reshape(-1, 13)
    a = a[np.argsort(a[:, 0], kind='stable')]
    return SetJoints(a[:, 0], a[:, 1:7], a[:, 7:13])


def report_lines(figures: PanelFigures) -> list[str]:
    """The figures for people (Markdown): a table per pose, then the truth's judgement."""
    def um(v: float | None) -> str:
        return 'n/a' if v is None or np.isnan(v) else f'{v * 1e6:.1f}'

    lines = [f'Panel test point (cell frame, panel at home): '
             f'{np.round(np.array(figures.test_point) * 1e3, 1).tolist()} mm; '
             f'{figures.steps} moves, {len(figures.failed)} failed.', '',
             '| pose | n | AP_p um | RP_l um | AP_a mdeg | AP_b mdeg | AP_c mdeg '
             '| truth AP_p um |', '|---|---:|---:|---:|---:|---:|---:|---:|']
    for name, m, t in zip(figures.poses, figures.measured, figures.truth, strict=True):
        lines.append(f'| {name} | {m.n} | {um(m.ap_p)} | {um(m.rp_l)} | '
                     f'{np.degrees(m.ap_a) * 1e3:.2f} | {np.degrees(m.ap_b) * 1e3:.2f} | '
                     f'{np.degrees(m.ap_c) * 1e3:.2f} | {um(t.ap_p)} |')
    errors, true = np.array(figures.errors_m), np.array(figures.command_errors_m)
    lines += ['', f'Simulation truth (judging only): the panel test point {um(_rms(true))} um '
              f'RMS from its goal (largest {um(float(true.max()))} um); the tracker '
              f'{um(_rms(errors))} um RMS from the truth. Largest attachment disagreement '
              f'{um(figures.moving[1])} um and internal force {figures.moving[0]:.0f} N '
              f'while moving; {um(figures.at_rest[1])} um, {figures.at_rest[0]:.0f} N at rest.']
    said = np.array(figures.load_cells_n)
    if said.size and np.isnan(said).all():
        lines.append("The legs' load cells gave no figure (the sets' joint states lack "
                     'efforts or poses).')
    elif said.size:
        lines.append(f"The legs' load cells say at most {np.nanmax(said):.0f} N of internal force "
                     f'at rest (median {np.nanmedian(said):.0f} N over the settled moves; the '
                     f'truth at most {figures.at_rest[0]:.0f} N).')
    lines += [f'failed: {f}' for f in figures.failed]
    if not figures.same_as_live:
        lines.append('WARNING: a mean taken again from the bag differs from the run\'s own')
    return lines


def _rms(values: FloatArray) -> float:
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else float('nan')
