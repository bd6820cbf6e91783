"""Per compensation mode and per commanded pose: ISO 9283 figures, error extremes, settle times
and tolerance verdicts of a recorded run; the whole analysis of a bag (:func:`analyse_bag`).

Errors of a visit are those of its attained pose (the settle-window mean, see
positioning_cell.accuracy) against its commanded pose: |Δp| (m) and the rotation angle of
R_cmdᵀ·R (rad). Max and RMS are over the visits (the ISO 9283 cycles); the settle time of a
visit (s) is from the start of its segment as the bag shows it (the later of the target taking
effect and the bag's first sample, :attr:`LabelledVisit.settle_duration`) to the last sample of
its settle window, so it never exceeds what the bag covers.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property, partial
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

# Every analysis rotates (each visit's error), tests and fits: the scipy modules it needs are
# imported with it, not at its first visit (the nodes defer them: core.poses.scipy_rotation),
# so that an analysis's time is its own and the plot workers forked from it inherit them.
import scipy.linalg
import scipy.spatial.transform
import scipy.special  # noqa: F401
from numpy.typing import NDArray

from positioning_cell import accuracy
from positioning_cell.accuracy.drift import LEAST_VISITS as DRIFT_LEAST_VISITS
from positioning_cell.accuracy.drift import DriftFigures, drift_figures
from positioning_cell.accuracy.figure_uncertainty import (
    DistanceUncertainty,
    FigureUncertainty,
    OrientationUncertainty,
    distance_figure_uncertainty,
    multidirectional_angle_uncertainty,
    multidirectional_uncertainty,
    pose_uncertainties,
)
from positioning_cell.accuracy.monitor import Ignored, MonitorSettings
from positioning_cell.accuracy.path import PathFigures, path_figures
from positioning_cell.accuracy.path_velocity import PathVelocityFigures, path_velocity_figures
from positioning_cell.accuracy.positioning_time import PositioningTime, positioning_time_of
from positioning_cell.accuracy.stabilisation import StabilisationFigures, stabilisation_figures_of
from positioning_cell.analysis.axis_test import AxisTestResults, axis_test_figures, parse_markers
from positioning_cell.analysis.axis_test import runs as axis_runs
from positioning_cell.analysis.budget_pass import BUDGET_TOPICS, gather
from positioning_cell.analysis.compliance_test import ComplianceResult, compliance_results
from positioning_cell.analysis.compliance_test import parse_markers as compliance_markers
from positioning_cell.analysis.context import RunContext
from positioning_cell.analysis.error_budget import ErrorBudget
from positioning_cell.analysis.reading import Recording, with_recording
from positioning_cell.analysis.replay import (
    CONTEXT_TOPICS,
    OPTIONAL_TOPICS,
    OUTSIDE_PROGRAM,
    REQUIRED_TOPICS,
    LabelledVisit,
    Replay,
    Replayer,
)
from positioning_cell.bag import BagError
from positioning_cell.bag.description import BagDescription, bag_description
from positioning_cell.config import config_path, load_parameter_file, node_parameters
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import pose_error
from positioning_cell.motion.settings import machine_settings
from positioning_cell.moves.trajectory import MotionLimits, cruise
from positioning_cell.names import NODE_DRIVER, NODE_POSITIONER
from positioning_cell.parameters import parse
from positioning_cell.sim.encoders import EncoderSettings

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Extremes:
    """Over a set of visits: max and RMS of |Δp| (m) and of the rotation angle (rad), mean
    and max settle time (s), and how many were within tolerance."""

    n: int
    position_error_max: float
    position_error_rms: float
    orientation_error_max: float
    orientation_error_rms: float
    settle_time_mean: float
    settle_time_max: float
    within_tolerance: int
    decisions: dict[str, int]

    @classmethod
    def of(cls, visits: Sequence[LabelledVisit]) -> Extremes:
        """Of ``visits`` (at least one)."""
        d = np.array([v.verdict.position_error for v in visits])
        a = np.array([v.verdict.orientation_error for v in visits])
        s = np.array([v.settle_duration for v in visits])
        return cls(len(visits), float(d.max()), float(np.sqrt((d * d).mean())),
                   float(a.max()), float(np.sqrt((a * a).mean())), float(s.mean()),
                   float(s.max()), sum(v.verdict.ok for v in visits),
                   accuracy.decision_counts([v.verdict for v in visits]))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI)."""
        return dict(self.__dict__)


@dataclass(frozen=True)
class PoseSummary:
    """One commanded pose under one mode: its ISO 9283 figures, the expanded uncertainty
    (k = 2) of AP_p and RP_l and of the angles' AP and RP from the measurement's stated
    covariances (:mod:`positioning_cell.accuracy.figure_uncertainty`; NaN: not stated), and
    extremes."""

    mode: str
    pose: str
    figures: accuracy.PoseFigures
    extremes: Extremes
    uncertainty: FigureUncertainty
    orientation_uncertainty: OrientationUncertainty
    #: ISO 9283 §7.2.3 over the directions its visits were approached from (None: fewer
    #: than two: :func:`approaches`).
    multidirectional: accuracy.MultiDirectionalFigures | None = None
    #: U (k = 2) of its vAP_p, m (NaN: not stated, or no vAP).
    multidirectional_u: float = math.nan
    #: ISO 9283 §7.4, §7.5 over its visits (None: no visit gave a stabilisation time).
    stabilisation: StabilisationFigures | None = None
    #: U (k = 2) of its vAP_a, vAP_b, vAP_c, rad (NaN: not stated, or no vAP).
    multidirectional_angles_u: tuple[float, float, float] = (math.nan,) * 3
    #: ISO 9283 §7.6 between its first and last visits (None: too few visits,
    #: :data:`positioning_cell.accuracy.drift.LEAST_VISITS`).
    drift: DriftFigures | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; an uncertainty not stated is null)."""
        stated = {**self.uncertainty._asdict(), **self.orientation_uncertainty._asdict(),
                  'vap_p': self.multidirectional_u,
                  **dict(zip(('vap_a', 'vap_b', 'vap_c'), self.multidirectional_angles_u,
                             strict=True))}
        return {'mode': self.mode, 'pose': self.pose, 'iso9283': self.figures.to_dict(),
                'iso9283_u': {name: (u if math.isfinite(u) else None)
                              for name, u in stated.items()},
                'multidirectional': None if self.multidirectional is None
                else self.multidirectional.to_dict(),
                'stabilisation': None if self.stabilisation is None
                else self.stabilisation.to_dict(),
                'drift': None if self.drift is None else self.drift.to_dict(),
                **self.extremes.to_dict()}


#: The program's poses between which ISO 9283 §7.3's distance accuracy and repeatability are
#: taken (the test cube's opposite corners P2 and P4, config/program.yaml).
DISTANCE_POSES = ('P2', 'P4')


@dataclass(frozen=True)
class DistanceSummary:
    """ISO 9283 §7.3 between two of a mode's poses (:data:`DISTANCE_POSES`): AD_p and RD_p
    over the cycles that reached both, and their U (k = 2) from the measurement."""

    poses: tuple[str, str]
    figures: accuracy.DistanceFigures
    uncertainty: DistanceUncertainty

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI; an uncertainty not stated is null)."""
        return {'poses': list(self.poses), 'iso9283': self.figures.to_dict(),
                'iso9283_u': {name: (u if math.isfinite(u) else None)
                              for name, u in self.uncertainty._asdict().items()}}


def distance_summary(visits: Sequence[LabelledVisit],
                     poses: tuple[str, str] = DISTANCE_POSES) -> DistanceSummary | None:
    """AD_p and RD_p of one mode's visits between ``poses``, one pair per cycle of the
    program (:func:`cycle_pairs`); None when no cycle reached both."""
    first, second = cycle_pairs([v for v in visits if v.pose == poses[0]],
                                [v for v in visits if v.pose == poses[1]])
    if not first:
        return None
    p1, p2 = ([v.visit.position for v in group] for group in (first, second))
    cov1, cov2 = (np.array([v.covariance[:3, :3] for v in group]) for group in (first, second))
    return DistanceSummary(
        poses, accuracy.distance_figures(first[0].visit.commanded_position,
                                         second[0].visit.commanded_position, p1, p2),
        distance_figure_uncertainty(p1, p2, cov1, cov2))


def cycle_pairs(first: Sequence[LabelledVisit], second: Sequence[LabelledVisit]
                ) -> tuple[list[LabelledVisit], list[LabelledVisit]]:
    """The visits of two poses paired by the program's cycle they were commanded in (the
    last visit of a pose in a cycle: a retried move's), the cycles that reached both in
    order; when a visit has no cycle (a bag without program markers), the k-th of one with
    the k-th of the other, as many as both have. ISO 9283 §7.3 takes the distance between
    the two poses of one cycle: a cycle that missed a pose must not shift the pairs after
    it."""
    if any(v.cycle is None for v in (*first, *second)):
        n = min(len(first), len(second))
        return list(first[:n]), list(second[:n])
    one = {v.cycle: v for v in first if v.cycle is not None}
    other = {v.cycle: v for v in second if v.cycle is not None}
    both = sorted(set(one) & set(other))
    return [one[c] for c in both], [other[c] for c in both]


@dataclass(frozen=True)
class PathSummary:
    """ISO 9283 §8.2 of one commanded path of a mode: from the pose ``start`` to the pose
    ``end`` (their names), over the visits that moved along it."""

    start: str
    end: str
    figures: PathFigures
    #: ISO 9283 §8.6 along it (None: no motion limits given, or no plane interval within
    #: the plan's cruise that every cycle crossed).
    velocity: PathVelocityFigures | None = None
    #: ISO 9283 §9 along it (None: no visit's readings stabilised).
    positioning: PositioningTime | None = None

    @property
    def name(self) -> str:
        """'P2 → P3'."""
        return f'{self.start} → {self.end}'

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI)."""
        return {'start': self.start, 'end': self.end, 'iso9283': self.figures.to_dict(),
                'velocity': None if self.velocity is None else self.velocity.to_dict(),
                'positioning_time': None if self.positioning is None
                else self.positioning.to_dict()}


#: Commanded positions closer than this (m) are the same point of a path.
SAME_POINT = 1e-7


def path_summaries(visits: Sequence[LabelledVisit], before: Mapping[int, LabelledVisit],
                   motion: MotionLimits | None = None) -> tuple[PathSummary, ...]:
    """The path figures (:func:`~positioning_cell.accuracy.path.path_figures`) of one mode's
    visits, grouped by commanded path (start and end), in the order of each path's first
    visit. A visit's path counts when the visit before it (``before``, by ``id``: the run's
    visits in time order, :func:`visits_before`) was of the same mode and commanded at the
    path's start: the first move after a mode switch, or after a visit outside the program,
    was planned from where the other mode left the platform, not along the commanded path.
    A path none of whose planes every visit crossed is left out. With the positioner's
    ``motion`` limits, each path's velocity figures too (the commanded speed and cruise of
    its plan: :func:`~positioning_cell.moves.trajectory.cruise`). Each path's positioning
    time from its visits' stabilisation records
    (:func:`~positioning_cell.accuracy.positioning_time.positioning_time_of`)."""
    groups: dict[tuple[str, tuple[float, ...]], list[LabelledVisit]] = {}
    for v in visits:  # over visits, not samples
        previous = before.get(id(v))
        if (v.path is None or previous is None or previous.mode != v.mode
                or not np.allclose(previous.visit.commanded_position, v.path.start, rtol=0.0,
                                   atol=SAME_POINT)):
            continue
        point = tuple(round(x / SAME_POINT) * SAME_POINT for x in v.path.start)
        groups.setdefault((v.pose, point), []).append(v)
    out = []
    for (pose, _), group in groups.items():
        crossings = [v.path for v in group if v.path is not None]
        figures = path_figures(crossings)
        if figures is None:
            continue
        start = before[id(group[0])]
        velocity = None
        if motion is not None:
            _, turn = pose_error(np.zeros(3), np.asarray(group[0].visit.commanded_quaternion),
                                 np.zeros(3), np.asarray(start.visit.commanded_quaternion))
            speed, begins, ends = cruise(figures.length, float(np.linalg.norm(turn)), motion)
            if speed > 0.0:
                velocity = path_velocity_figures(crossings, speed, (begins, ends))
        out.append(PathSummary(start.pose, pose, figures, velocity, positioning_time_of(
            figures.length, [v.stabilisation for v in group])))
    return tuple(out)


def visits_before(visits: Sequence[LabelledVisit]) -> dict[int, LabelledVisit]:
    """The visit before each of ``visits`` (time order), keyed by ``id`` of the visit."""
    return {id(v): previous for previous, v in pairwise(visits)}  # over visits


@dataclass(frozen=True)
class ModeSummary:
    """One compensation mode: every visit's extremes, the worst pose accuracy AP_p (m) and
    repeatability RP_l (m; None below two cycles), the worst orientation AP (largest |AP_a|,
    |AP_b|, |AP_c|, rad) and RP half-width (rad), and the per-pose summaries."""

    mode: str
    extremes: Extremes
    ap_p_max: float
    rp_l_max: float | None
    ap_angle_max: float
    rp_angle_max: float | None
    poses: tuple[PoseSummary, ...]
    tracker: accuracy.ErrorStatistics | None = None
    distance: DistanceSummary | None = None
    #: ISO 9283 §8.2 of each commanded path its visits moved along (:func:`path_summaries`).
    paths: tuple[PathSummary, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (SI)."""
        return {'mode': self.mode, **self.extremes.to_dict(), 'ap_p_max': self.ap_p_max,
                'rp_l_max': self.rp_l_max, 'ap_angle_max': self.ap_angle_max,
                'rp_angle_max': self.rp_angle_max,
                'tracker': None if self.tracker is None else self.tracker.to_dict(),
                'poses': [p.to_dict() for p in self.poses],
                'distance': None if self.distance is None else self.distance.to_dict(),
                'paths': [p.to_dict() for p in self.paths]}


def _worst(values: Sequence[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return max(known) if known else None


#: A commanded position closer than this (m) to the one before it was not approached from a
#: direction (a pose commanded again, or only turned).
APPROACH_LEAST = 1e-4


def approaches(visits: Sequence[LabelledVisit]) -> dict[int, FloatArray]:
    """The direction (3,) (not normalised, base frame) each visit's commanded position was
    approached from: from the commanded position of the visit before it (visits in time
    order, any mode), keyed by ``id`` of the visit; the first visit, and one commanded within
    :data:`APPROACH_LEAST` of the one before, have none."""
    out: dict[int, FloatArray] = {}
    for before, visit in pairwise(visits):  # over visits, not samples
        step = (np.asarray(visit.visit.commanded_position)
                - np.asarray(before.visit.commanded_position))
        if float(np.linalg.norm(step)) >= APPROACH_LEAST:
            out[id(visit)] = step
    return out


def summarise(visits: Sequence[LabelledVisit], *, over_run: bool = True
              ) -> tuple[ModeSummary, ...]:
    """Group labelled visits by mode (order of first appearance) and pose (order of the pose
    key), with the ISO 9283 figures of each group (:func:`accuracy.iso9283`; the commanded
    pose of a group is that of its first visit); with ``over_run``, also each pose's drift
    and each mode's paths (:func:`with_drift_and_paths`, which the analysis of a bag runs
    while the plots, which need neither, are drawn)."""
    approach = approaches(visits)
    out = []
    for mode in dict.fromkeys(v.mode for v in visits):
        mine = [v for v in visits if v.mode == mode]
        poses = []
        groups = [[v for v in mine if v.pose == pose] for pose in sorted(
            dict.fromkeys(v.pose for v in mine),
            key=lambda name: min(v.visit.key for v in mine if v.pose == name))]
        stated = _pose_uncertainties(groups)
        for group in groups:
            pose, first = group[0].pose, group[0].visit
            figures = accuracy.iso9283(first.commanded_position, first.commanded_quaternion,
                                       [v.visit.position for v in group],
                                       [v.visit.quaternion for v in group], first.key)
            uncertainty, orientation = stated[id(group[0])]
            known = [v for v in group if id(v) in approach]
            multidirectional = accuracy.multidirectional_figures(
                first.commanded_quaternion, [v.visit.position for v in known],
                [v.visit.quaternion for v in known],
                [approach[id(v)] for v in known]) if known else None
            multidirectional_u, multidirectional_angles_u = math.nan, (math.nan,) * 3
            if multidirectional is not None:
                directions = accuracy.approach_groups([approach[id(v)] for v in known])
                known_cov = np.array([v.covariance for v in known])
                multidirectional_u = multidirectional_uncertainty(
                    [v.visit.position for v in known], known_cov[:, :3, :3], directions)
                multidirectional_angles_u = multidirectional_angle_uncertainty(
                    [v.visit.quaternion for v in known], known_cov[:, 3:, 3:], directions)
            poses.append(PoseSummary(
                mode, pose, figures, Extremes.of(group), uncertainty, orientation,
                multidirectional, multidirectional_u,
                stabilisation_figures_of([v.stabilisation for v in group]),
                multidirectional_angles_u))
        out.append(ModeSummary(
            mode, Extremes.of(mine), max(p.figures.ap_p for p in poses),
            _worst([p.figures.rp_l for p in poses]),
            max(max(abs(p.figures.ap_a), abs(p.figures.ap_b), abs(p.figures.ap_c))
                for p in poses),
            _worst([_worst([p.figures.rp_a, p.figures.rp_b, p.figures.rp_c])
                    for p in poses]),
            tuple(poses), distance=distance_summary(mine)))
    return with_drift_and_paths(tuple(out), visits) if over_run else tuple(out)


def _pose_uncertainties(groups: Sequence[Sequence[LabelledVisit]]
                        ) -> dict[int, tuple[FigureUncertainty, OrientationUncertainty]]:
    """The U of each pose's figures (:func:`pose_uncertainties`, its position and angles
    from one Monte Carlo), keyed by ``id`` of the pose's first visit. One pose at a time:
    a Monte Carlo of several poses together must draw until the slowest to converge has,
    and took twice as long on a tiled `make run` bag."""
    return {id(g[0]): pose_uncertainties(
        [g[0].visit.commanded_position], [[v.visit.position for v in g]],
        [[v.visit.quaternion for v in g]], [[v.covariance for v in g]])[0] for g in groups}


def with_drift_and_paths(modes: tuple[ModeSummary, ...], visits: Sequence[LabelledVisit],
                         motion: MotionLimits | None = None) -> tuple[ModeSummary, ...]:
    """``modes`` (:func:`summarise` of ``visits``) with each pose's drift
    (:func:`~positioning_cell.accuracy.drift.drift_figures`, of a pose visited often enough)
    and each mode's paths (:func:`path_summaries`; their velocity with ``motion``)."""
    before = visits_before(visits)
    out = []
    for m in modes:
        mine = [v for v in visits if v.mode == m.mode]
        poses = []
        for p in m.poses:
            group = [v for v in mine if v.pose == p.pose]
            poses.append(replace(p, drift=drift_figures(
                p.figures.commanded_position, p.figures.commanded_quaternion,
                [v.visit.position for v in group], [v.visit.quaternion for v in group],
                [v.visit.settle_time for v in group], np.array([v.covariance for v in group])
            ) if len(group) >= DRIFT_LEAST_VISITS else None))
        out.append(replace(m, poses=tuple(poses), paths=path_summaries(mine, before, motion)))
    return tuple(out)


def _with_tracker(modes: tuple[ModeSummary, ...], result: Replay) -> tuple[ModeSummary, ...]:
    """Each mode with the tracker's error against the truth over the pairs whose measurement
    and true pose were both taken in that mode's segments (the monitor's pairs,
    :class:`accuracy.TrackerErrorAccumulator`, summed per pair of segments)."""
    per_segment = result.monitor.tracker.sums()
    mode_of = [s.mode for s in result.segments]
    return tuple(replace(mode, tracker=accuracy.ErrorSums.total(
        sums for (seg_m, seg_t), sums in per_segment.items()
        if min(seg_m, seg_t) >= 0 and mode_of[seg_m] == mode_of[seg_t] == mode.mode
    ).statistics()) for mode in modes)


@dataclass(frozen=True)
class RunAnalysis:
    """The analysis of one recorded run (see the module docstring and :func:`analyse_bag`)."""

    bag: Path
    message_count: int
    topics: dict[str, tuple[str, int]]
    settings: MonitorSettings
    replay: Replay
    modes: tuple[ModeSummary, ...]
    truth_modes: tuple[ModeSummary, ...]
    context: RunContext
    axis_tests: tuple[AxisTestResults, ...] = ()
    #: The static compliance of each direction of the run's compliance tests (ISO 9283 §10).
    compliance: tuple[ComplianceResult, ...] = ()
    problems: tuple[str, ...] = ()
    missing_optional: tuple[str, ...] = ()
    ignored: tuple[Ignored, ...] = field(default_factory=tuple)
    #: The error budget of each mode (:mod:`.error_budget`).
    budgets: tuple[ErrorBudget, ...] = ()
    #: What the bag says of itself: the run, its configuration, program and calibrations.
    description: BagDescription = field(default_factory=BagDescription)

    @cached_property
    def monitor(self) -> dict[str, Any]:
        """What the live monitor's /accuracy_monitor/report gave at the end of the run."""
        return self.replay.monitor.report()

    @property
    def tracker(self) -> accuracy.ErrorStatistics | None:
        """The tracker against the simulation truth over the whole run (the monitor's)."""
        return self.replay.monitor.tracker.statistics()

    def to_dict(self) -> dict[str, Any]:
        """The JSON summary (SI: m, rad, s)."""
        s = self.settings
        tracker = self.tracker
        return {
            'bag': str(self.bag), 'messages': self.message_count,
            'topics': {k: {'type': v[0], 'count': v[1]} for k, v in self.topics.items()},
            'problems': list(self.problems), 'missing_optional_topics':
                list(self.missing_optional),
            'notes': list(self.replay.notes),
            'samples': {'measured': self.replay.measured.count,
                        'truth': self.replay.truth.count},
            'settings': {'settle': s.settle.to_params(),
                         'tolerances': {'position': s.tolerance.position,
                                        'orientation': s.tolerance.orientation,
                                        'decision_rule': s.tolerance.decision_rule},
                         'max_stamp_difference': s.tracker_error.max_stamp_difference,
                         'stabilisation_band': s.stabilisation.band},
            'modes': [m.to_dict() for m in self.modes],
            'truth_modes': [m.to_dict() for m in self.truth_modes],
            'tracker': None if tracker is None else tracker.to_dict(),
            'visits': [{'mode': v.mode, 'pose': v.pose, 'program_cycle': v.cycle,
                        'ok': v.verdict.ok,
                        'position_error': v.verdict.position_error,
                        'orientation_error': v.verdict.orientation_error,
                        'position_uncertainty': _stated(v.verdict.position_uncertainty),
                        'orientation_uncertainty': _stated(v.verdict.orientation_uncertainty),
                        'decision': v.verdict.decision.value,
                        'segment_start': v.start, 'settle_duration': v.settle_duration,
                        'stabilisation': v.stabilisation.to_dict(),
                        **v.visit.to_dict()} for v in self.replay.visits],
            'ignored': [i.__dict__ for i in self.ignored],
            'context': self.context.to_dict(),
            'description': self.description.to_dict(),
            'axis_tests': [a.to_dict() for a in self.axis_tests],
            'compliance': [c.to_dict() for c in self.compliance],
            'error_budget': [b.to_dict() for b in self.budgets],
            'monitor': self.monitor,
        }


def _stated(uncertainty: float) -> float | None:
    """An expanded uncertainty for JSON: None when the measurement stated none (NaN)."""
    return uncertainty if math.isfinite(uncertainty) else None


#: The topics the replay reads (the first pass over the bag).
ANALYSED_TOPICS = (*REQUIRED_TOPICS, *OPTIONAL_TOPICS, *CONTEXT_TOPICS)
#: Every topic the analysis reads: the replay's and the error budget's second pass.
READ_TOPICS = tuple(dict.fromkeys((*ANALYSED_TOPICS, *BUDGET_TOPICS)))


def in_program(visits: Sequence[LabelledVisit]) -> list[LabelledVisit]:
    """The visits commanded by the run's program (not those outside it)."""
    return [v for v in visits if v.mode != OUTSIDE_PROGRAM]


def _analyse(recording: Recording, settings: MonitorSettings) -> RunAnalysis:
    """The analysis of an open recording (:func:`analyse_bag`)."""
    missing = [t for t in REQUIRED_TOPICS if t not in recording.topics]
    if missing:
        have = ', '.join(sorted(recording.topics)) or 'none'
        raise BagError(recording.path, f'lacks {", ".join(missing)}, which the analysis '
                                       f'needs (the bag has: {have})')
    replayer = Replayer(settings)
    for batch in recording.batches():
        replayer.feed(batch)
    result = replayer.finish()
    truth = bool(result.truth.count)

    markers, bad_markers = parse_markers(replayer.axis_test)
    loads, bad_loads = compliance_markers(replayer.compliance_test)
    compliance, no_compliance = compliance_results(loads)

    return RunAnalysis(
        bag=recording.path, message_count=recording.message_count, topics=recording.topics,
        settings=settings, replay=result,
        modes=_with_tracker(summarise(in_program(result.visits), over_run=False), result),
        truth_modes=summarise(in_program(result.truth_visits), over_run=False)
        if truth else (),
        context=replayer.context.result(recording.start_ns * 1e-9, recording.end_ns * 1e-9),
        axis_tests=tuple(axis_test_figures(markers, run) for run in axis_runs(markers)),
        compliance=compliance,
        problems=(*recording.problems, *result.problems, *bad_markers, *bad_loads,
                  *no_compliance),
        missing_optional=tuple(t for t in OPTIONAL_TOPICS if t not in recording.topics),
        ignored=tuple(result.monitor.ignored))


def budget_settings(config: str | Path) -> tuple[Mechanism, FloatArray]:
    """What the error budget takes from a cell parameter file: the nominal mechanism (the
    positioner's ``mechanism:`` block) and the encoder resolution (6,) m and rad (the drives'
    ``encoder:`` block)."""
    params = load_parameter_file(config)
    mech = Mechanism.from_params(node_parameters(params, NODE_POSITIONER).get('mechanism', {}))
    encoder = parse(EncoderSettings, node_parameters(params, NODE_DRIVER).get('encoder', {}))
    return mech, encoder.resolution


def analyse_bag(path: str | Path, settings: MonitorSettings | None = None,
                config: str | Path | None = None, *,
                replayed: Callable[[RunAnalysis], object] | None = None) -> RunAnalysis:
    """Read the bag at ``path`` in recorded order, batch by batch, replay it through the
    monitor's rules and summarise it per mode and pose, then read it again for the error
    budget of each mode (:mod:`.budget_pass`; mechanism and encoders from the cell parameter
    file ``config``, default config/cell.yaml). BagError when it is not a readable bag
    (nothing in it is an MCAP file: an empty or too short file, wrong magic) or lacks a topic
    of :data:`REQUIRED_TOPICS`; a truncated or damaged bag is analysed as far as it is
    readable: its sound chunks (``problems`` names each corrupt chunk and the time range and
    messages lost; :mod:`positioning_cell.analysis.reading`). ``replayed`` is called with
    the analysis before the error budget's pass and the figures over the run (its
    ``budgets`` still empty, no pose's drift, no mode's paths: :func:`with_drift_and_paths`),
    e.g. to start drawing the plots, which need neither."""
    settings = settings or MonitorSettings()
    analysis = with_recording(path, ANALYSED_TOPICS, partial(_analyse, settings=settings))
    if replayed is not None:
        replayed(analysis)
    config = config or config_path('cell.yaml')
    analysis = replace(
        analysis, modes=with_drift_and_paths(analysis.modes, in_program(analysis.replay.visits),
                                             machine_settings(config).motion),
        truth_modes=with_drift_and_paths(analysis.truth_modes,
                                         in_program(analysis.replay.truth_visits)))
    mech, resolution = budget_settings(config)
    budgets = with_recording(path, BUDGET_TOPICS, partial(
        gather, visits=analysis.replay.visits, mech=mech, resolution=resolution))
    try:
        description = bag_description(Path(path))
    except BagError as err:  # the messages were readable: the analysis stands without it
        return replace(analysis, budgets=budgets, problems=(
            *analysis.problems, f'the bag\'s description is unreadable: {err.reason}'))
    return replace(analysis, budgets=budgets, description=description)
