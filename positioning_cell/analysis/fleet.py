"""Trends over many recorded runs (a fleet of bags, months of a cell): each run boiled down to
a compact, picklable :class:`RunDigest` (what a worker process sends back: kilobytes, never the
analysis), and over the digests in time order (:func:`trends`):

- for each compensation mode and commanded pose, the ISO 9283 figures run after run
  (:class:`PoseSeries`: AP_p, AP_x/y/z, RP_l, AP_a/b/c, RP_a/b/c);
- the calibration epochs (:class:`Epoch`): a new one starts when the calibration file in force
  changes (the positioner's ``calibration`` diagnostic) or at a calibration run recorded in a
  bag (``/cell/calibration`` markers); within an epoch, each pose's *drift*: the movement of
  its barycentre (m) and of its mean attained angles (rad) since its first observation in
  that epoch;
- the tracker's registrations on the base targets over time (:class:`RegistrationSeries`:
  residual RMS and max, m; variance factor).

A commanded pose is one pose across runs when its commanded position and orientation agree
within tolerances (:data:`POSITION_TOLERANCE`, :data:`ANGLE_TOLERANCE`), whatever the program
named it; it takes the name the earliest run gave it. Times are log times of the bags (s since
the Unix epoch, UTC). SI throughout: m, rad, s. Pure library (no rclpy, no dask).
"""

from __future__ import annotations

import math
import os
import traceback
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell import accuracy
from positioning_cell.accuracy.figure_uncertainty import FigureUncertainty
from positioning_cell.accuracy.iso9283 import wrap_angle
from positioning_cell.accuracy.monitor import MonitorSettings
from positioning_cell.accuracy.verdicts import decision_key
from positioning_cell.analysis.context import CalibrationInForce, CalibrationRun, Registration
from positioning_cell.analysis.program import ProgramStep
from positioning_cell.analysis.summary import RunAnalysis, analyse_bag
from positioning_cell.bag import BagError
from positioning_cell.bag.description import bag_description
from positioning_cell.bag.metadata import METADATA_FILE
from positioning_cell.core.poses import Quad, Triple, pose_error
from positioning_cell.errors import InputError, PositioningError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Two commanded positions within this distance (m) are the same pose (with the angle below).
POSITION_TOLERANCE = 1e-5
#: Two commanded orientations within this rotation angle (rad) are the same pose.
ANGLE_TOLERANCE = 2e-5
#: The suffix of a storage file that is a bag by itself.
MCAP_SUFFIX = '.mcap'
#: A pose digest's uncertainty when its analysis stated none.
NOT_STATED = FigureUncertainty(math.nan, math.nan)
#: The decisions a series counts per run, in its columns' order (decision_counts' keys).
DECISION_KEYS = tuple(decision_key(d) for d in accuracy.Decision)


# -- one run ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseDigest:
    """One commanded pose under one mode in one run: the program's pose name, ``time`` (s):
    when its first visit settled (the last sample of its settle window: after whatever the
    positioner reported when the move started), and its ISO 9283 figures (commanded pose, AP,
    RP, barycentre, the visit count ``n``)."""

    mode: str
    pose: str
    time: float
    figures: accuracy.PoseFigures
    #: U (k = 2) of AP_p and RP_l from the measurement (None, or NaN in it: not stated).
    uncertainty: FigureUncertainty | None = None
    #: How many of its visits drew each decision by the monitor's rule
    #: (:func:`positioning_cell.accuracy.verdicts.decision_counts`; empty: not known).
    decisions: Mapping[str, int] = field(default_factory=dict)

    @property
    def visits(self) -> int:
        """How many visits (ISO 9283 cycles) the figures are over."""
        return self.figures.n

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; an uncertainty not stated is null)."""
        return {'mode': self.mode, 'pose': self.pose, 'time': self.time,
                'visits': self.visits, 'iso9283': self.figures.to_dict(),
                'iso9283_u': None if self.uncertainty is None else {
                    k: (v if math.isfinite(v) else None)
                    for k, v in self.uncertainty._asdict().items()},
                'decisions': dict(self.decisions)}


#: A run's kinds (:func:`run_kind`).
PROGRAM_RUN, INTERACTIVE_RUN, ABORTED_RUN = 'program', 'interactive', 'aborted'


def run_kind(description: Mapping[str, str], steps: Sequence[ProgramStep]) -> str:
    """What a run was, from its bag's description (``kind``, ``program_moves``) and its
    ``/cell/program`` steps: :data:`INTERACTIVE_RUN` when it says so, or (a bag without a
    description) when it has no step; :data:`ABORTED_RUN` when it marked fewer moves than its
    program has (stopped, interrupted, a mode refused); :data:`PROGRAM_RUN` otherwise (a bag
    without a description: any run with steps)."""
    moves = sum(not step.end for step in steps)
    said = description.get('kind')
    if said == INTERACTIVE_RUN or (said is None and not moves):
        return INTERACTIVE_RUN
    expected = description.get('program_moves', '')
    if said is not None and (not moves or (expected.isdigit() and moves < int(expected))):
        return ABORTED_RUN
    return PROGRAM_RUN


@dataclass(frozen=True)
class RunDigest:
    """What the trends need of one run: the bag, its first and last log time (s), its message
    count, per mode and pose the figures (:class:`PoseDigest`, in the analysis' order), the
    calibration file in force when its program started (None: the nominal machine, or not
    known: ``calibrations`` is then empty), the calibration timeline, the calibration runs and
    the tracker's registrations recorded in it (:mod:`positioning_cell.analysis.context`), the
    problems the analysis found, its ``kind`` (:func:`run_kind`: only a ``program`` run's
    poses are ISO 9283 trends; an ``interactive`` or ``aborted`` run's are kept here and
    :func:`trends` lists the run apart) and the bag's ``description`` (its flat keys,
    :meth:`positioning_cell.bag.description.BagDescription.keys`)."""

    bag: str
    start: float
    end: float
    messages: int
    poses: tuple[PoseDigest, ...]
    calibration: str | None
    calibrations: tuple[CalibrationInForce, ...] = ()
    calibration_runs: tuple[CalibrationRun, ...] = ()
    registrations: tuple[Registration, ...] = ()
    problems: tuple[str, ...] = ()
    kind: str = PROGRAM_RUN
    description: dict[str, str] = field(default_factory=dict)

    @property
    def program(self) -> bool:
        """Whether its poses are a whole program's (ISO 9283 trends)."""
        return self.kind == PROGRAM_RUN

    @property
    def modes(self) -> tuple[str, ...]:
        """The compensation modes with a settled pose, in the analysis' order."""
        return tuple(dict.fromkeys(p.mode for p in self.poses))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; the registrations are in the trends' :class:`RegistrationSeries`)."""
        return {'bag': self.bag, 'start': self.start, 'end': self.end,
                'messages': self.messages, 'calibration': self.calibration,
                'calibrations': [c.__dict__ for c in self.calibrations],
                'calibration_runs': [r.__dict__ for r in self.calibration_runs],
                'problems': list(self.problems), 'kind': self.kind,
                'description': dict(self.description),
                'poses': [p.to_dict() for p in self.poses]}


def digest(analysis: RunAnalysis) -> RunDigest:
    """The digest of one run's analysis (:func:`positioning_cell.analysis.analyse_bag`). A
    pose's ``time`` is the earliest settle time of its visits; the calibration in force
    during the program is the one at the earliest of them (at the bag's start without any)."""
    context = analysis.context
    first: dict[tuple[str, str], float] = {}
    verdicts: dict[tuple[str, str], list[accuracy.Verdict]] = {}
    for v in analysis.replay.visits:  # over visits, not samples
        settled = v.visit.settle_time
        first[v.mode, v.pose] = min(first.get((v.mode, v.pose), math.inf), settled)
        verdicts.setdefault((v.mode, v.pose), []).append(v.verdict)
    poses = tuple(PoseDigest(p.mode, p.pose, first.get((p.mode, p.pose), context.start),
                             p.figures, p.uncertainty,
                             accuracy.decision_counts(verdicts.get((p.mode, p.pose), [])))
                  for m in analysis.modes for p in m.poses)
    program = min((p.time for p in poses), default=context.start)
    description = analysis.description.keys()
    return RunDigest(str(analysis.bag), context.start, context.end, analysis.message_count,
                     poses, context.calibration_at(program), context.calibrations,
                     context.calibration_runs, context.registrations, analysis.problems,
                     kind=run_kind(description, analysis.replay.program),
                     description=description)


@dataclass(frozen=True)
class BagFailure:
    """A bag that could not be analysed and why (the reason does not repeat the bag)."""

    bag: str
    reason: str


def digest_bag(path: str | Path, settings: MonitorSettings | None = None
               ) -> RunDigest | BagFailure:
    """Analyse the bag at ``path`` and digest it: the task a worker runs. Never raises for a
    bag that fails: a :class:`BagFailure` with the reason comes back instead (the library's
    error text; for anything else its type, text and where it was raised), so that what
    crosses the wire is always a small picklable value."""
    try:
        return digest(analyse_bag(path, settings))
    except BagError as err:
        return BagFailure(str(path), err.reason if err.path == Path(path) else str(err))
    except PositioningError as err:
        return BagFailure(str(path), str(err))
    except Exception as err:
        where = traceback.extract_tb(err.__traceback__)[-1]
        return BagFailure(str(path), f'{type(err).__name__}: {err} (in {where.filename}, '
                                     f'line {where.lineno})')


# -- finding the bags ------------------------------------------------------------------------
def _bag_of_file(path: Path) -> Path:
    """The bag an explicitly named file belongs to: its folder if that is a rosbag2 folder,
    else the file itself if it is an MCAP file."""
    if (path.parent / METADATA_FILE).is_file():
        return path.parent
    if path.suffix != MCAP_SUFFIX:
        raise InputError(f'{path}: not a bag (a bag is a folder with {METADATA_FILE}, or an '
                         f'{MCAP_SUFFIX} file)')
    return path


def _bags_under(folder: Path) -> list[Path]:
    """The bags in ``folder`` and below: rosbag2 folders (not searched further) and
    ``.mcap`` files outside them."""
    found: list[Path] = []
    for root, dirs, files in os.walk(folder):
        if METADATA_FILE in files:
            found.append(Path(root))
            dirs[:] = []
        else:
            found += [Path(root) / f for f in files if f.endswith(MCAP_SUFFIX)]
    return found


def find_bags(paths: Iterable[str | Path]) -> list[Path]:
    """The bags named by ``paths`` (absolute, sorted, each once): a folder with
    ``metadata.yaml`` is a bag; another folder is searched recursively for such folders and
    for ``.mcap`` files not inside one; a file is a bag if it is an ``.mcap`` file (one inside
    a rosbag2 folder stands for that folder). InputError naming the path when one does not
    exist, or is neither a bag nor holds one."""
    found: set[Path] = set()
    for p in paths:
        path = Path(os.path.abspath(p))
        if not path.exists():
            raise InputError(f'{p}: no such file or folder')
        if path.is_dir():
            bags = _bags_under(path)
            if not bags:
                raise InputError(f'{p}: no bag in this folder or below (a bag is a folder '
                                 f'with {METADATA_FILE}, or an {MCAP_SUFFIX} file)')
            found.update(bags)
        else:
            found.add(_bag_of_file(path))
    return sorted(found)


def select_bags(bags: Sequence[Path], where: Mapping[str, str]) -> list[Path]:
    """The ``bags`` whose description (:func:`positioning_cell.bag.description.bag_description`,
    read from each file's summary) has every ``key: value`` of ``where``; all of them for an
    empty ``where``. A bag whose description cannot be read is not selected."""
    if not where:
        return list(bags)
    selected = []
    for bag in bags:
        try:
            if bag_description(bag).matches(where):
                selected.append(bag)
        except BagError:
            continue
    return selected


# -- trends ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class CommandedPose:
    """A commanded pose as identified across runs: its name (the earliest run's), commanded
    position (m, base frame) and quaternion (x, y, z, w) as first seen."""

    name: str
    position: Triple
    quaternion: Quad


@dataclass(frozen=True)
class Epoch:
    """A calibration epoch: from ``start`` (s; None for the one before the first calibration
    event seen) to the next epoch's start; ``cause``: what began it; ``calibration``: the file
    in force at its start (None: none loaded, or not known); ``bags``: the runs with a pose
    observed in it."""

    index: int
    start: float | None
    cause: str
    calibration: str | None
    bags: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class PoseSeries:
    """One commanded pose under one mode over the runs: R observations in time order, each
    with its run's ``bags`` entry, ``time`` (s), visit count ``n`` and ISO 9283 figures:
    ``ap_p`` (R,) m, ``ap`` (R, 3) AP_x/y/z m, ``rp_l`` (R,) m, ``ap_angles`` (R, 3)
    AP_a/b/c rad, ``rp_angles`` (R, 3) RP_a/b/c half-widths rad (NaN below two visits),
    ``barycentre`` (R, 3) m; its calibration ``epoch`` (R,) (:attr:`Epoch.index`) and the
    drift since its first observation in that epoch: ``drift`` (R, 3) m (barycentre minus
    that one's), ``drift_distance`` (R,) m, ``drift_angles`` (R, 3) rad (mean attained
    angles a, b, c minus that one's, wrapped into [−π, π)); ``ap_p_u``, ``rp_l_u`` (R,) m
    the U (k = 2) of AP_p and RP_l (NaN: not stated) and ``decisions`` (R, 3) how many of
    each run's visits conformed, were indeterminate, did not conform."""

    mode: str
    pose: CommandedPose
    bags: tuple[str, ...]
    time: FloatArray
    n: IntArray
    ap_p: FloatArray
    ap: FloatArray
    rp_l: FloatArray
    ap_angles: FloatArray
    rp_angles: FloatArray
    barycentre: FloatArray
    epoch: IntArray
    drift: FloatArray
    drift_distance: FloatArray
    drift_angles: FloatArray
    ap_p_u: FloatArray
    rp_l_u: FloatArray
    decisions: IntArray

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; NaN as null)."""
        arrays = {k: _listed(v) for k, v in self.__dict__.items()
                  if isinstance(v, np.ndarray)}
        return {'mode': self.mode, 'pose': self.pose.name,
                'commanded_position': list(self.pose.position),
                'commanded_quaternion': list(self.pose.quaternion), 'bags': list(self.bags),
                **arrays}


@dataclass(frozen=True, eq=False)
class RegistrationSeries:
    """The tracker's registrations over the runs, in time order (one entry per registration:
    a registration seen again in a later bag of the same tracker session is not repeated):
    ``time`` (K,) s, ``bags``, the tracker's location count ``locations`` (K,), residual
    RMS and max over the base targets ``residual_rms``, ``residual_max`` (K,) m, and the
    ``variance_factor`` (K,)."""

    bags: tuple[str, ...]
    time: FloatArray
    locations: IntArray
    residual_rms: FloatArray
    residual_max: FloatArray
    variance_factor: FloatArray

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; NaN as null)."""
        return {'bags': list(self.bags), **{k: _listed(v) for k, v in self.__dict__.items()
                                            if isinstance(v, np.ndarray)}}


@dataclass(frozen=True, eq=False)
class Trends:
    """The trends of a fleet of runs (module docstring): the runs in time order, the
    commanded poses identified across them, the modes (order of first appearance), the
    calibration epochs that hold an observation, a :class:`PoseSeries` per mode and pose
    (modes, then poses, in order of first appearance) and the registrations."""

    runs: tuple[RunDigest, ...]
    poses: tuple[CommandedPose, ...]
    modes: tuple[str, ...]
    epochs: tuple[Epoch, ...]
    series: tuple[PoseSeries, ...]
    registrations: RegistrationSeries

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI: m, rad, s)."""
        return {'runs': [r.to_dict() for r in self.runs],
                'poses': [p.__dict__ for p in self.poses], 'modes': list(self.modes),
                'epochs': [e.__dict__ for e in self.epochs],
                'series': [s.to_dict() for s in self.series],
                'registrations': self.registrations.to_dict()}


def _listed(values: NDArray[Any]) -> list[Any]:
    """An array as nested lists, NaN as None (JSON null)."""
    if values.dtype.kind != 'f':
        return list(values.tolist())
    out = values.astype(object)
    out[np.isnan(values)] = None
    return list(out.tolist())


def _number(value: float | None) -> float:
    return math.nan if value is None else value


def identify_poses(position: FloatArray, quaternion: FloatArray, names: Sequence[str],
                   position_tolerance: float = POSITION_TOLERANCE,
                   angle_tolerance: float = ANGLE_TOLERANCE
                   ) -> tuple[tuple[CommandedPose, ...], IntArray]:
    """The commanded poses (N, 3) m / (N, 4), named ``names``, grouped into poses across runs:
    the identified poses and the index (N,) of each row's. A row joins the nearest pose
    identified before it (in row order) whose first-seen position is within
    ``position_tolerance`` m and orientation within ``angle_tolerance`` rad, else starts a
    new one named after it (``name#2``, ``#3``, … when an earlier pose has that name). Equal
    rows are matched once."""
    rows = np.hstack([position, quaternion * np.where(quaternion[:, 3:] < 0.0, -1.0, 1.0)])
    unique, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind='stable')
    of_unique = np.empty(unique.shape[0], dtype=np.intp)
    ref_p = np.empty((0, 3))
    ref_q = np.empty((0, 4))
    poses: list[CommandedPose] = []
    for u in order:
        p, q = unique[u, :3], unique[u, 3:]
        match = -1
        if poses:
            dp, dr = pose_error(ref_p, ref_q, p[None], q[None])
            distance = np.sqrt((dp * dp).sum(axis=1))
            angle = np.sqrt((dr * dr).sum(axis=1))
            near = np.flatnonzero((distance <= position_tolerance) & (angle <= angle_tolerance))
            if near.size:
                match = int(near[np.argmin(distance[near])])
        if match < 0:
            name = names[int(first[u])]
            taken = sum(c.name == name or c.name.startswith(f'{name}#') for c in poses)
            poses.append(CommandedPose(name if not taken else f'{name}#{taken + 1}',
                                       (float(p[0]), float(p[1]), float(p[2])),
                                       (float(q[0]), float(q[1]), float(q[2]), float(q[3]))))
            ref_p, ref_q = np.vstack([ref_p, p]), np.vstack([ref_q, q])
            match = len(poses) - 1
        of_unique[u] = match
    return tuple(poses), of_unique[inverse.ravel()]


@dataclass(frozen=True)
class _Event:
    """A calibration event: at ``time`` s, a ``cause``; ``file``: the calibration file in force
    from then on (None: none loaded or not known)."""

    time: float
    cause: str
    file: str | None


def _calibration_events(runs: Sequence[RunDigest]) -> tuple[list[_Event], str | None]:
    """The events that start an epoch, in time order, and the calibration file in force
    before the first of them (the earliest known one; None: none known). A file change is a
    change against the file in force before it, whichever bag said so; a calibration run
    seen in several bags counts once, at its earliest time."""
    changes = sorted(((c.time, c.file) for r in runs for c in r.calibrations),
                     key=lambda c: c[0])
    initial = changes[0][1] if changes else None
    events: list[_Event] = []
    current = initial
    for time, file in changes:
        if file != current:
            what = f'calibration file {file} in force' if file else 'no calibration file'
            events.append(_Event(time, what, file))
            current = file
    earliest: dict[str, float] = {}
    for r in runs:
        for c in r.calibration_runs:
            earliest[c.run] = min(earliest.get(c.run, math.inf), c.time)
    in_force = [(e.time, e.file) for e in events]
    for name, time in earliest.items():
        before = [f for t, f in in_force if t <= time]
        events.append(_Event(time, f'calibration run {name}', before[-1] if before
                             else initial))
    events.sort(key=lambda e: e.time)
    return events, initial


class _Observations:
    """Every pose digest of the program runs as flat arrays (O rows): run index, time, mode
    index, pose index and the figures; rows in time order (ties: run order). An interactive
    session's poses are left out (:attr:`RunDigest.program`)."""

    def __init__(self, runs: Sequence[RunDigest], position_tolerance: float,
                 angle_tolerance: float) -> None:
        flat = [(i, p) for i, r in enumerate(runs) if r.program for p in r.poses]
        flat.sort(key=lambda item: (item[1].time, item[0]))
        self.run = np.array([i for i, _ in flat], dtype=np.intp)
        digests = [p for _, p in flat]
        self.time = np.array([p.time for p in digests], dtype=float)
        self.modes = tuple(dict.fromkeys(p.mode for p in digests))
        code = {m: k for k, m in enumerate(self.modes)}
        self.mode = np.array([code[p.mode] for p in digests], dtype=np.intp)
        f = [p.figures for p in digests]
        self.poses, self.pose = identify_poses(
            np.array([x.commanded_position for x in f], dtype=float).reshape(-1, 3),
            np.array([x.commanded_quaternion for x in f], dtype=float).reshape(-1, 4),
            [p.pose for p in digests], position_tolerance, angle_tolerance)
        self.n = np.array([x.n for x in f], dtype=np.intp)
        self.ap_p = np.array([x.ap_p for x in f], dtype=float)
        self.ap = np.array([(x.ap_x, x.ap_y, x.ap_z) for x in f], dtype=float).reshape(-1, 3)
        self.rp_l = np.array([_number(x.rp_l) for x in f], dtype=float)
        self.ap_angles = np.array([(x.ap_a, x.ap_b, x.ap_c) for x in f],
                                  dtype=float).reshape(-1, 3)
        self.rp_angles = np.array([tuple(map(_number, (x.rp_a, x.rp_b, x.rp_c))) for x in f],
                                  dtype=float).reshape(-1, 3)
        self.barycentre = np.array([x.barycentre for x in f], dtype=float).reshape(-1, 3)
        stated = [p.uncertainty or NOT_STATED for p in digests]
        self.ap_p_u = np.array([u.ap_p for u in stated], dtype=float)
        self.rp_l_u = np.array([u.rp_l for u in stated], dtype=float)
        self.decisions = np.array([[p.decisions.get(name, 0) for name in DECISION_KEYS]
                                   for p in digests], dtype=np.intp).reshape(-1, 3)
        commanded = np.array([x.commanded_angles for x in f], dtype=float).reshape(-1, 3)
        self.angles = commanded + self.ap_angles  # mean attained a, b, c (ISO 9283's ā)


def _drift(key: IntArray, barycentre: FloatArray, angles: FloatArray
           ) -> tuple[FloatArray, FloatArray]:
    """Rows grouped by ``key`` (equal keys contiguous, each group in time order): each row's
    barycentre (m) and mean angles (rad) minus those of its group's first row."""
    start = np.r_[True, key[1:] != key[:-1]] if key.size else np.zeros(0, dtype=bool)
    first = np.flatnonzero(start)[np.cumsum(start) - 1]
    return barycentre - barycentre[first], wrap_angle(angles - angles[first])


def _registrations(runs: Sequence[RunDigest]) -> RegistrationSeries:
    """Every registration of the runs in time order, one seen again (same location count,
    residuals and variance factor as the one before it) left out."""
    seen = sorted(((reg.time, r.bag, reg) for r in runs for reg in r.registrations),
                  key=lambda item: item[0])
    kept: list[tuple[float, str, Registration]] = []
    for item in seen:
        reg = item[2]
        last = kept[-1][2] if kept else None
        if last is None or (last.locations, last.residuals_um, last.variance_factor) != (
                reg.locations, reg.residuals_um, reg.variance_factor):
            kept.append(item)
    regs = [k[2] for k in kept]
    return RegistrationSeries(
        tuple(k[1] for k in kept), np.array([k[0] for k in kept], dtype=float),
        np.array([g.locations for g in regs], dtype=np.intp),
        np.array([g.residual_rms_um for g in regs], dtype=float) * 1e-6,
        np.array([g.residual_max_um for g in regs], dtype=float) * 1e-6,
        np.array([g.variance_factor for g in regs], dtype=float))


def trends(digests: Iterable[RunDigest], position_tolerance: float = POSITION_TOLERANCE,
           angle_tolerance: float = ANGLE_TOLERANCE) -> Trends:
    """The trends of the runs (module docstring), in any order: sorted by start time (ties:
    bag path). An observation belongs to the epoch in force at its time (an event at the
    same time as it included); its drift is against the first observation of the same mode
    and pose in that epoch (the first run of the epoch that has it)."""
    runs = tuple(sorted(digests, key=lambda r: (r.start, r.bag)))
    if len({r.bag for r in runs}) != len(runs):
        raise InputError('trends: a bag is given more than once')
    obs = _Observations(runs, position_tolerance, angle_tolerance)
    events, initial = _calibration_events(runs)
    epoch = np.searchsorted(np.array([e.time for e in events], dtype=float), obs.time,
                            side='right').astype(np.intp)
    # Grouped by mode, pose and epoch; within a group in time order (epochs follow time).
    order = np.lexsort((obs.time, epoch, obs.pose, obs.mode))
    series_key = obs.mode[order] * len(obs.poses) + obs.pose[order]
    drift, drift_angles = _drift(series_key * (len(events) + 1) + epoch[order],
                                 obs.barycentre[order], obs.angles[order])
    bounds = np.r_[np.flatnonzero(np.r_[order.size > 0, series_key[1:] != series_key[:-1]]),
                   order.size]
    series = []
    for a, b in pairwise(bounds):
        rows = order[a:b]
        series.append(PoseSeries(
            obs.modes[int(obs.mode[rows[0]])], obs.poses[int(obs.pose[rows[0]])],
            tuple(runs[int(i)].bag for i in obs.run[rows]), obs.time[rows], obs.n[rows],
            obs.ap_p[rows], obs.ap[rows], obs.rp_l[rows], obs.ap_angles[rows],
            obs.rp_angles[rows], obs.barycentre[rows], epoch[rows], drift[a:b],
            np.sqrt((drift[a:b] ** 2).sum(axis=1)), drift_angles[a:b], obs.ap_p_u[rows],
            obs.rp_l_u[rows], obs.decisions[rows]))
    epochs = []
    for k in np.unique(epoch):
        bags = tuple(dict.fromkeys(runs[int(i)].bag for i in obs.run[epoch == k]))
        if k == 0:
            epochs.append(Epoch(0, None, 'before the first calibration event seen', initial,
                                bags))
        else:
            e = events[int(k) - 1]
            epochs.append(Epoch(int(k), e.time, e.cause, e.file, bags))
    return Trends(runs, obs.poses, obs.modes, tuple(epochs), tuple(series),
                  _registrations(runs))
