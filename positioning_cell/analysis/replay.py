"""A recorded run through the monitor's rules, message by message in recorded order, with
every settled visit labelled by the compensation mode and program pose it belongs to.

Labels come from ``/cell/program`` (std_msgs/String, JSON written by :meth:`ProgramStep.to_json`:
``{"mode": "model", "cycle": 2, "pose": "P3", "stamp": 1700000000.25}``) published by the run
driver before each move: a segment (a new target) takes the last step whose ``stamp`` (s, the
publisher's clock; the log time if absent) is not after the target's header stamp; one before
the first step (the homing move) is labelled :data:`BEFORE_PROGRAM`. Without program steps the
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
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from positioning_cell import accuracy
from positioning_cell.accuracy.monitor import Ignored, Monitor, MonitorSettings
from positioning_cell.analysis.program import ProgramStep
from positioning_cell.bag import BagMessage
from positioning_cell.errors import InputError
from positioning_cell.names import (
    DIAGNOSTICS,
    MEASURED_POSE,
    PROGRAM,
    STATUS_POSITIONER,
    TARGET,
    TRUE_POSE,
)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: Without these there is nothing to analyse.
REQUIRED_TOPICS = (TARGET, MEASURED_POSE)
#: Used when present: the simulation truth, the program labels, the positioner's mode.
OPTIONAL_TOPICS = (TRUE_POSE, PROGRAM, DIAGNOSTICS)
UNKNOWN_MODE = 'unknown'
#: The label of a segment that starts before the first program step of a run that has steps
#: (the homing move of run_cell): in the monitor's figures, not in the per-mode summaries.
BEFORE_PROGRAM = 'before program'


@dataclass(frozen=True)
class Segment:
    """A commanded pose taking effect: ``time`` (s, as the monitor clamped it), pose ``key``,
    commanded position (3,) m / quaternion (4,), and its ``mode`` and ``pose`` labels."""

    time: float
    key: int
    position: tuple[float, ...]
    quaternion: tuple[float, ...]
    mode: str
    pose: str


@dataclass(frozen=True)
class LabelledVisit:
    """A settled visit with its labels, its verdict against the monitor's tolerances, and
    ``start`` (s): when its segment started as far as the bag shows (module docstring)."""

    visit: accuracy.Visit
    mode: str
    pose: str
    verdict: accuracy.Verdict
    start: float

    @property
    def settle_duration(self) -> float:
        """Settle time (s): from ``start`` to the last sample of the settle window; never
        longer than the span of the source's samples in the bag."""
        return self.visit.settle_time - self.start


@dataclass(frozen=True)
class Samples:
    """Accepted pose samples of one source: stamps (N,) s, positions (N, 3) m, quaternions
    (N, 4), the error against the current target (N, 3) m and rotation vectors (N, 3) rad
    (NaN before the first target), and the segment index of each (−1: none)."""

    time: FloatArray
    position: FloatArray
    quaternion: FloatArray
    position_error: FloatArray
    orientation_error: FloatArray
    segment: IntArray

    @property
    def count(self) -> int:
        """Number of samples."""
        return int(self.time.size)


class _SampleLog:
    """Growing columns of one source (appends per message; arrays once at the end)."""

    def __init__(self) -> None:
        self.rows: list[tuple[float, Any, Any, Any, Any, int]] = []

    def add(self, t: float, p: Any, q: Any, update: accuracy.SampleUpdate, seg: int) -> None:
        self.rows.append((t, p, q, update.position_error, update.orientation_error, seg))

    def start(self, target_time: float) -> float:
        """Start of a segment as the bag shows it: the later of ``target_time`` and the first
        sample."""
        return max(target_time, self.rows[0][0]) if self.rows else target_time

    def arrays(self) -> Samples:
        n = len(self.rows)
        nan3 = np.full(3, math.nan)
        if n == 0:
            empty = np.empty((0, 3))
            return Samples(np.empty(0), empty, np.empty((0, 4)), empty, empty,
                           np.empty(0, dtype=np.intp))
        cols = list(zip(*self.rows, strict=True))
        return Samples(np.array(cols[0], dtype=float), np.array(cols[1], dtype=float),
                       np.array(cols[2], dtype=float),
                       np.array([nan3 if v is None else v for v in cols[3]], dtype=float),
                       np.array([nan3 if v is None else v for v in cols[4]], dtype=float),
                       np.array(cols[5], dtype=np.intp))


@dataclass(frozen=True)
class Replay:
    """Everything the replay found: the monitor (its :meth:`Monitor.report` equals the
    live node's), the segments, the labelled measured and true visits, the accepted samples,
    the program steps and the notes they carried."""

    monitor: Monitor
    segments: tuple[Segment, ...]
    visits: tuple[LabelledVisit, ...]
    truth_visits: tuple[LabelledVisit, ...]
    measured: Samples
    truth: Samples
    program: tuple[ProgramStep, ...]
    notes: tuple[str, ...]
    problems: tuple[str, ...]


def _pose(msg: Any) -> tuple[float, str, tuple[float, float, float],
                             tuple[float, float, float, float]]:
    """(stamp s, frame id, position, quaternion) of a PoseStamped or a
    PoseWithCovarianceStamped."""
    h, pose = msg.header, msg.pose
    pose = getattr(pose, 'pose', pose)
    p, o = pose.position, pose.orientation
    return (accuracy.stamp_seconds(h.stamp.sec, h.stamp.nanosec), h.frame_id,
            (p.x, p.y, p.z), (o.x, o.y, o.z, o.w))


def _diagnostic_modes(msg: Any) -> list[tuple[float, str]]:
    stamp = accuracy.stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec)
    return [(stamp, kv.value) for status in msg.status if status.name == STATUS_POSITIONER
            for kv in status.values if kv.key == 'mode']


def replay(messages: Sequence[BagMessage], settings: MonitorSettings | None = None) -> Replay:
    """Feed the recorded messages (in recorded order) through the monitor's rules
    (:class:`Monitor`) as the live monitor took them, and label what settled."""
    monitor = Monitor(settings)
    steps: list[ProgramStep] = []
    modes: list[tuple[float, str]] = []
    problems: list[str] = []
    raw_segments: list[tuple[float, float, int, Any, Any, float]] = []  # meas t, truth t, ...
    measured, truth = _SampleLog(), _SampleLog()
    for item in messages:
        topic, msg = item.topic, item.message
        if topic == PROGRAM:
            try:
                steps.append(ProgramStep.from_json(msg.data, item.log_time_ns * 1e-9))
            except InputError as err:
                problems.append(str(err))
        elif topic == DIAGNOSTICS:
            modes.extend(_diagnostic_modes(msg))
        elif topic == TARGET:
            before = monitor.measured.target
            stamp, frame, p, q = _pose(msg)
            taken = monitor.target(stamp, frame, p, q) is None
            after = monitor.measured.target if taken else before
            if after is not None and after is not before:
                truth_target = monitor.truth_accumulator.target
                raw_segments.append((after[0], truth_target[0] if truth_target else after[0],
                                     after[3], after[1], after[2], stamp))
        elif topic == MEASURED_POSE:
            stamp, frame, p, q = _pose(msg)
            result = monitor.measurement(stamp, frame, p, q)
            if not isinstance(result, Ignored):
                measured.add(stamp, p, q, result.update, len(raw_segments) - 1)
        elif topic == TRUE_POSE:
            stamp, frame, p, q = _pose(msg)
            update = monitor.truth(stamp, frame, p, q)
            if not isinstance(update, Ignored):
                truth.add(stamp, p, q, update, len(raw_segments) - 1)
    segments = _label(raw_segments, steps, modes)
    by_time = {s[0]: i for i, s in enumerate(raw_segments)}
    by_truth_time = {s[1]: i for i, s in enumerate(raw_segments)}
    tolerances = monitor.tolerances
    visits = tuple(LabelledVisit(v, segments[by_time[v.target_time]].mode,
                                 segments[by_time[v.target_time]].pose, verdict,
                                 measured.start(v.target_time))
                   for v, verdict in zip(monitor.measured.visits, monitor.verdicts, strict=True))
    truth_visits = tuple(
        LabelledVisit(v, segments[by_truth_time[v.target_time]].mode,
                      segments[by_truth_time[v.target_time]].pose,
                      accuracy.judge_visit(v, tolerances), truth.start(v.target_time))
        for v in monitor.truth_accumulator.visits)
    notes = tuple(dict.fromkeys(s.note for s in steps if s.note))
    return Replay(monitor, segments, visits, truth_visits, measured.arrays(), truth.arrays(),
                  tuple(steps), notes, tuple(problems))


def _label(raw: Sequence[tuple[float, float, int, Any, Any, float]],
           steps: Sequence[ProgramStep], modes: Sequence[tuple[float, str]]
           ) -> tuple[Segment, ...]:
    """Mode and pose labels of each segment (module docstring)."""
    step_times = np.array([s.stamp for s in steps])
    order = np.argsort(step_times, kind='stable')
    mode_times = np.array([m[0] for m in modes])
    mode_order = np.argsort(mode_times, kind='stable')
    out = []
    for time, _, key, p, q, stamp in raw:
        mode, pose = UNKNOWN_MODE, f'P{key + 1}'
        i = int(np.searchsorted(step_times[order], stamp, side='right')) - 1
        if steps:
            step = steps[int(order[i])] if i >= 0 else None
            mode, pose = (step.mode, step.pose or pose) if step else (BEFORE_PROGRAM, pose)
        elif modes:
            j = min(int(np.searchsorted(mode_times[mode_order], stamp, side='left')),
                    len(modes) - 1)
            mode = modes[int(mode_order[j])][1]
        out.append(Segment(time, key, tuple(float(v) for v in p),
                           tuple(float(v) for v in q), mode, pose))
    return tuple(out)
