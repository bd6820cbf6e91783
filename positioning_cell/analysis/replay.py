"""A recorded run through the monitor's rules, batch by batch, with every settled visit
labelled by the compensation mode and program pose it belongs to.

The recording arrives as :class:`MessageBatch` es (:mod:`.reading`): the pose messages of each
topic as arrays, with their place in the recorded order. They go to the monitor as the live
node gives them: put back in stamp order (:class:`~positioning_cell.accuracy.stamp_order.
MonitorInputs`, so that the order in which the recorder and the monitor happened to receive
messages of different topics does not matter), as arrays (:meth:`Monitor.feed`: the one
implementation the live node runs, giving the same figures for any batching), the targets at
their places among the samples. The positioner's move ends (its
``positioner: state`` statuses on /diagnostics that end a move: :func:`move_ends`) go at their
places too, so that each visit is judged on its final settled window (after a ``measured``
mode's correction, not on the pause before it); a bag without them falls back on the last
stable window before the next target, and the end of the bag closes the last visit
(:mod:`positioning_cell.accuracy.settle`). Memory is one batch plus what the run found
(segments, visits, program steps, a bounded error trace), whatever the bag's length.

Labels come from ``/cell/program`` (std_msgs/String, JSON written by :meth:`ProgramStep.to_json`:
``{"mode": "model", "cycle": 2, "pose": "P3", "stamp": 1700000000.25}``) published by the run
driver before each move: a segment (a new target) takes the last step whose ``stamp`` (s, the
publisher's clock; the log time if absent) is not after the target's header stamp; one before
the first step (the homing move) or after a program's end marker (``"end": true``, sent when a
program ends: the homing and calibration moves before a second program) is labelled
:data:`OUTSIDE_PROGRAM`, outside every program. A bag recorded before the end marker existed
labels the moves between two programs with the first one's last step. Without program steps the
mode is the ``mode`` value of the positioner's ``positioner: state``
diagnostics (the first status stamped at or after the target; the positioner publishes it when
the move starts) and the pose is named ``P<key + 1>``.

The settle time of a visit is counted from the *start of its segment as the bag shows it*: the
later of the time its target took effect (the monitor's ``Visit.target_time``) and the stamp of
the first sample of that source (measured or true pose) the bag holds. The two differ only for
a target stamped before the bag's first sample: typically the latched (transient-local)
/positioner/target of a move commanded before the recorder started, which reaches the recorder
first with its old header stamp. Counted from that stamp, a settle time would include time
the bag does not cover (a 159 s settle in a 20 s bag); counted from the first sample, no settle
time exceeds the span of the samples' stamps. The monitor's visits themselves (and so what the
live node reports) keep the target's own stamp.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell import accuracy
from positioning_cell.accuracy.monitor import (
    Monitor,
    MonitorSettings,
    MoveEnds,
    PoseBatch,
    PoseMessages,
)
from positioning_cell.accuracy.path import PathCrossings
from positioning_cell.accuracy.stabilisation import Stabilisation
from positioning_cell.accuracy.stamp_order import MonitorInputs, Released
from positioning_cell.analysis.context import ContextCollector
from positioning_cell.analysis.program import ProgramStep
from positioning_cell.analysis.trace import Envelope, ErrorTrace
from positioning_cell.errors import InputError
from positioning_cell.names import (
    AXIS_TEST,
    CALIBRATION,
    COMPLIANCE_TEST,
    DIAGNOSTICS,
    MEASURED_POSE,
    PROGRAM,
    STATUS_POSITIONER,
    TARGET,
    TRACKER_REGISTRATION,
    TRUE_POSE,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Without these there is nothing to analyse.
REQUIRED_TOPICS = (TARGET, MEASURED_POSE)
#: Used when present (the report names those missing): the simulation truth, the program
#: labels, the positioner's mode (and calibration, the tracker's registration), the
#: registration's covariance (the part of the readings' that averaging does not reduce).
OPTIONAL_TOPICS = (TRUE_POSE, PROGRAM, DIAGNOSTICS, TRACKER_REGISTRATION)
#: Read when present: the calibration runs recorded in the run, its axis tests and compliance
#: tests.
CONTEXT_TOPICS = (CALIBRATION, AXIS_TEST, COMPLIANCE_TEST)
UNKNOWN_MODE = 'unknown'
#: The label of a segment outside every program of a run that has steps (before its first step:
#: the homing move of run_cell; after a program's end marker: the homing and calibration moves
#: before the next program): in the monitor's figures, not in the per-mode summaries.
OUTSIDE_PROGRAM = 'outside program'


@dataclass(frozen=True)
class JointSamples:
    """Joint messages (/legs/joint_states) as arrays: header stamps (M,) s and positions
    (M, 6) in :data:`positioning_cell.core.mechanism.JOINT_NAMES` order (m and rad; NaN for a
    joint a message lacks)."""

    stamp: FloatArray = field(default_factory=lambda: np.empty(0))
    position: FloatArray = field(default_factory=lambda: np.empty((0, 6)))

    @property
    def count(self) -> int:
        """Number of messages."""
        return int(self.stamp.shape[0])


@dataclass(frozen=True)
class MessageBatch:
    """Consecutive messages of a recording, as the analysis needs them: the pose topics as
    :class:`PoseMessages`, the other topics as (log time ns, message) pairs in recorded order
    (program steps, calibration, axis-test and compliance-test markers as their JSON text,
    diagnostics as decoded DiagnosticArray messages: those with the positioner's or the
    tracker's status suffice)."""

    targets: PoseMessages = field(default_factory=PoseMessages.empty)
    measured: PoseMessages = field(default_factory=PoseMessages.empty)
    truth: PoseMessages = field(default_factory=PoseMessages.empty)
    #: /metrology/registration: the tracker's location and its covariance, which each
    #: measurement after it shares (the monitor's U of a settled pose).
    registrations: PoseMessages = field(default_factory=PoseMessages.empty)
    program: tuple[tuple[int, str], ...] = ()
    diagnostics: tuple[tuple[int, Any], ...] = ()
    calibration: tuple[tuple[int, str], ...] = ()
    axis_test: tuple[tuple[int, str], ...] = ()
    compliance_test: tuple[tuple[int, str], ...] = ()
    #: The place of each of ``diagnostics`` in the recorded order (as the pose messages'
    #: ``rank``): where the positioner's move ends go to the monitor. Empty: not known (the
    #: move ends are not used; the monitor falls back on the last stable window of a visit).
    diagnostic_ranks: tuple[int, ...] = ()
    #: Read only when asked (the error budget's pass): /legs/joint_states as arrays and
    #: /legs/joint_trajectory as (log time ns, joint names, the last point's positions (J,);
    #: None for a trajectory without points).
    joint_states: JointSamples = field(default_factory=JointSamples)
    trajectories: tuple[tuple[int, tuple[str, ...], FloatArray | None], ...] = ()


@dataclass(frozen=True)
class Segment:
    """A commanded pose taking effect: ``time`` (s, as the monitor clamped it), pose ``key``,
    commanded position (3,) m / quaternion (4,), and its ``mode``, ``pose`` and ``cycle``
    labels."""

    time: float
    key: int
    position: tuple[float, ...]
    quaternion: tuple[float, ...]
    mode: str
    pose: str
    #: The program's cycle the segment's move belongs to (1-based; None: no program step
    #: names one).
    cycle: int | None = None


@dataclass(frozen=True)
class LabelledVisit:
    """A settled visit with its labels, its verdict against the monitor's tolerances, and
    ``start`` (s): when its segment started as far as the bag shows (module docstring)."""

    visit: accuracy.Visit
    mode: str
    pose: str
    verdict: accuracy.Verdict
    start: float
    #: The covariance (6, 6) of the attained pose as measured (NaN: not stated; zeros: the
    #: simulation's truth, exact).
    covariance: FloatArray = field(default_factory=lambda: np.full((6, 6), math.nan),
                                   compare=False)
    #: Its stabilisation time and overshoot (ISO 9283 §7.4, §7.5) from its segment's readings
    #: (none: not taken, e.g. of the truth).
    stabilisation: Stabilisation = field(default_factory=Stabilisation.none, compare=False)
    #: The program's cycle it was commanded in (None: not known, e.g. no program markers).
    cycle: int | None = None
    #: Its attained path in the normal planes of its commanded path (ISO 9283 §8.2; None:
    #: not taken, e.g. of the truth, a first visit or a short move).
    path: PathCrossings | None = field(default=None, compare=False)

    @property
    def settle_duration(self) -> float:
        """Settle time (s): from ``start`` to the last sample of the settle window; never
        longer than the span of the source's samples in the bag."""
        return self.visit.settle_time - self.start


@dataclass(frozen=True)
class SampleTrace:
    """The pose samples of one source the monitor took: how many, the stamp (s) of the first
    (NaN: none), and their error against the target over time (:class:`Envelope`)."""

    count: int
    first: float
    errors: Envelope

    def start(self, target_time: float) -> float:
        """Start of a segment as the bag shows it: the later of ``target_time`` and the first
        sample."""
        return target_time if math.isnan(self.first) else max(target_time, self.first)


@dataclass(frozen=True)
class Replay:
    """Everything the replay found: the monitor (its :meth:`Monitor.report` equals the
    live node's), the segments, the labelled measured and true visits, the samples taken per
    source, the program steps and the notes they carried."""

    monitor: Monitor
    segments: tuple[Segment, ...]
    visits: tuple[LabelledVisit, ...]
    truth_visits: tuple[LabelledVisit, ...]
    measured: SampleTrace
    truth: SampleTrace
    program: tuple[ProgramStep, ...]
    notes: tuple[str, ...]
    problems: tuple[str, ...]


class _Source:
    """What the replay keeps of one pose source: its count, first stamp and error trace."""

    def __init__(self) -> None:
        self.count = 0
        self.first = math.nan
        self.trace = ErrorTrace()

    def took(self, rows: PoseMessages, batch: PoseBatch) -> None:
        samples = batch.samples
        ok = np.flatnonzero(samples.accepted)
        if ok.size == 0:
            return
        stamps = rows.stamp[ok]
        if self.count == 0:
            self.first = float(stamps[0])
        self.count += int(ok.size)
        self.trace.add(stamps, samples.position_error[ok], samples.orientation_error[ok])

    def result(self) -> SampleTrace:
        return SampleTrace(self.count, self.first, self.trace.envelope())


def move_ends(diagnostics: Sequence[tuple[int, Any]]) -> MoveEnds:
    """The positioner's move ends among decoded /diagnostics messages (rank, DiagnosticArray)
    in recorded order: the header stamp of each message holding a ``positioner: state``
    status that ends a move (:func:`positioning_cell.accuracy.move_ended`)."""
    found = [(rank, accuracy.stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec))
             for rank, msg in diagnostics
             if any(status.name == STATUS_POSITIONER and accuracy.move_ended(
                 {kv.key: kv.value for kv in status.values}) for status in msg.status)]
    return MoveEnds(np.array([r for r, _ in found], dtype=np.intp),
                    np.array([t for _, t in found], dtype=float))


def _diagnostic_modes(msg: Any) -> list[tuple[float, str]]:
    stamp = accuracy.stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec)
    return [(stamp, kv.value) for status in msg.status if status.name == STATUS_POSITIONER
            for kv in status.values if kv.key == 'mode']


class Replayer:
    """The replay, batch by batch: :meth:`feed` each :class:`MessageBatch` in recorded order,
    then :meth:`finish`."""

    def __init__(self, settings: MonitorSettings | None = None) -> None:
        self.monitor = Monitor(settings, per_segment=True)
        #: The monitor's inputs, put in stamp order as the live node puts them.
        self.inputs = MonitorInputs(self.monitor)
        self._steps: list[ProgramStep] = []
        self._modes: list[tuple[float, str]] = []
        self._problems: list[str] = []
        # Per segment: measured target time, truth target time, key, p, q, target stamp.
        self._segments: list[tuple[float, float, int, Any, Any, float]] = []
        self._measured, self._truth = _Source(), _Source()
        self.context = ContextCollector()
        #: The /cell/axis_test markers (JSON), one per measured stop of an axis test.
        self.axis_test: list[str] = []
        #: The /cell/compliance_test markers (JSON), one per load step of a compliance test.
        self.compliance_test: list[str] = []

    def feed(self, batch: MessageBatch) -> None:
        """The batch's messages, in their recorded order: the monitor's inputs through
        :class:`~positioning_cell.accuracy.stamp_order.MonitorInputs` (in stamp order, as the
        live node takes them)."""
        for log_ns, text in batch.program:
            try:
                self._steps.append(ProgramStep.from_json(text, log_ns * 1e-9))
            except InputError as err:
                self._problems.append(str(err))
        for _, msg in batch.diagnostics:
            self._modes.extend(_diagnostic_modes(msg))
            self.context.diagnostics(
                accuracy.stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec),
                msg.status)
        for log_ns, text in batch.calibration:
            self.context.calibration_marker(log_ns * 1e-9, text)
        self.axis_test.extend(text for _, text in batch.axis_test)
        self.compliance_test.extend(text for _, text in batch.compliance_test)
        ranked = (tuple(zip(batch.diagnostic_ranks, (m for _, m in batch.diagnostics),
                            strict=True))
                  if len(batch.diagnostic_ranks) == len(batch.diagnostics) else ())
        self.inputs.arrive(batch.targets, batch.measured, batch.truth, move_ends(ranked),
                           batch.registrations)
        self._took(self.inputs.release())

    def _took(self, released: Released | None) -> None:
        """Keep what the monitor took of the messages it was fed."""
        if released is None:
            return
        fed = released.fed
        for seg in fed.segments:
            self._segments.append((seg.time, seg.truth_time, seg.key, seg.position,
                                   seg.quaternion, float(released.targets.stamp[seg.target])))
        self._measured.took(released.measured, fed.measured)
        self._truth.took(released.truth, fed.truth)

    def finish(self) -> Replay:
        """The replay of everything fed; the end of the recording releases the messages still
        held for their stamp order and closes the visit still open (:meth:`Monitor.finish`)."""
        monitor = self.monitor
        self._took(self.inputs.release(flush=True))
        monitor.finish()
        segments = _label(self._segments, self._steps, self._modes)
        by_time = {s[0]: i for i, s in enumerate(self._segments)}
        by_truth_time = {s[1]: i for i, s in enumerate(self._segments)}
        measured, truth = self._measured.result(), self._truth.result()
        visits = tuple(LabelledVisit(v, segments[by_time[v.target_time]].mode,
                                     segments[by_time[v.target_time]].pose, verdict,
                                     measured.start(v.target_time), covariance, stabilised,
                                     segments[by_time[v.target_time]].cycle, path)
                       for v, verdict, covariance, stabilised, path in zip(
                           monitor.measured.visits, monitor.verdicts, monitor.covariances,
                           monitor.stabilisations, monitor.paths, strict=True))
        true = monitor.truth_accumulator.visits
        exact = np.zeros((len(true), 6, 6))  # the simulation's truth: U = 0
        truth_visits = tuple(
            LabelledVisit(v, segments[by_truth_time[v.target_time]].mode,
                          segments[by_truth_time[v.target_time]].pose, verdict,
                          truth.start(v.target_time), covariance,
                          cycle=segments[by_truth_time[v.target_time]].cycle)
            for v, verdict, covariance in zip(
                true, accuracy.judge_visits(true, monitor.tolerances, exact), exact,
                strict=True))
        notes = tuple(dict.fromkeys(s.note for s in self._steps if s.note))
        return Replay(monitor, segments, visits, truth_visits, measured, truth,
                      tuple(self._steps), notes, (*self._problems, *self.context.problems))


def replay(batches: Iterable[MessageBatch], settings: MonitorSettings | None = None) -> Replay:
    """Feed the recorded batches (in recorded order) through the monitor's rules
    (:class:`Monitor`) as the live monitor took them, and label what settled."""
    replayer = Replayer(settings)
    for batch in batches:
        replayer.feed(batch)
    return replayer.finish()


def _label(raw: Sequence[tuple[float, float, int, Any, Any, float]],
           steps: Sequence[ProgramStep], modes: Sequence[tuple[float, str]]
           ) -> tuple[Segment, ...]:
    """Mode, pose and program-cycle labels of each segment (module docstring)."""
    step_times = np.array([s.stamp for s in steps])
    order = np.argsort(step_times, kind='stable')
    mode_times = np.array([m[0] for m in modes])
    mode_order = np.argsort(mode_times, kind='stable')
    out = []
    shared: dict[tuple[float, ...], tuple[float, ...]] = {}  # each commanded pose once
    for time, _, key, p, q, stamp in raw:
        mode, pose, cycle = UNKNOWN_MODE, f'P{key + 1}', None
        i = int(np.searchsorted(step_times[order], stamp, side='right')) - 1
        if steps:
            step = steps[int(order[i])] if i >= 0 else None
            mode, pose, cycle = ((step.mode, step.pose or pose, step.cycle)
                                 if step and not step.end else (OUTSIDE_PROGRAM, pose, None))
        elif modes:
            j = min(int(np.searchsorted(mode_times[mode_order], stamp, side='left')),
                    len(modes) - 1)
            mode = modes[int(mode_order[j])][1]
        position, quaternion = tuple(float(v) for v in p), tuple(float(v) for v in q)
        out.append(Segment(time, key, shared.setdefault(position, position),
                           shared.setdefault(quaternion, quaternion), mode, pose, cycle))
    return tuple(out)
