"""The accuracy monitor's rules, the one implementation the live node and the offline replay of
a bag both run.

Messages go in one at a time, in the order they arrive (stamp s, frame id, position (3,) m,
quaternion (4,) x, y, z, w): a pose message not in the ``base`` frame, or one the accumulators
refuse (InputError: a quaternion off unit length, a sample older than the previous one), is
ignored with its reason; a target is clamped to just after the last sample
(``add_target(..., clamp=True)``) and goes to both the measured and the truth accumulators; a
measurement goes to the measured accumulator, then to the tracker pairing; a true pose to the
truth accumulator, then to the tracker pairing. Each settled measured visit gets a verdict
against the tolerances in force when it settled.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike

from positioning_cell.accuracy.settle import (
    AccuracyAccumulator,
    SampleUpdate,
    SettleSettings,
    Visit,
)
from positioning_cell.accuracy.tracker_errors import TrackerErrorAccumulator
from positioning_cell.accuracy.verdicts import Tolerances, Verdict, judge_visit
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.errors import InputError
from positioning_cell.names import BASE_FRAME, MEASURED_POSE, NODE_MONITOR, TARGET, TRUE_POSE
from positioning_cell.parameters import check_fields, group, parse, setting


@dataclass(frozen=True)
class TrackerErrorSettings:
    """How the tracker is judged against the simulation truth."""

    max_stamp_difference: float = setting(
        1e-3, 'largest stamp difference of a measurement and a true pose that pair', 's',
        low=0.0, low_open=True, high=1.0)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class MonitorSettings:
    """The accuracy monitor's parameters: tolerances (dynamic), settle detection, and the
    tracker-error pairing (the ``accuracy_monitor`` section of config/cell.yaml)."""

    tolerance: Tolerances = group(Tolerances, 'verdict of each settled pose')
    settle: SettleSettings = group(SettleSettings, 'settle detection and pose grouping')
    tracker_error: TrackerErrorSettings = group(TrackerErrorSettings,
                                                'the tracker against the simulation truth')

    def __post_init__(self) -> None:
        check_fields(self)

    @classmethod
    def from_file(cls, path: str | Path) -> MonitorSettings:
        """From the ``accuracy_monitor`` section (and ``/**``) of a ROS 2 parameter file; keys
        the monitor does not declare (the shared mechanism block) are left out."""
        params = node_parameters(load_parameter_file(path), NODE_MONITOR)
        return parse(cls, {k: v for k, v in params.items()
                           if k in ('tolerance', 'settle', 'tracker_error')})


@dataclass(frozen=True)
class Ignored:
    """A message the monitor ignored: topic, stamp (s) and the reason."""

    topic: str
    time: float
    reason: str


@dataclass(frozen=True)
class Measured:
    """What a taken measurement gave: the accumulator's update and, if it settled a visit, the
    verdict of that visit."""

    update: SampleUpdate
    verdict: Verdict | None = None


class Monitor:
    """Messages in, the monitor's state out: :meth:`target`, :meth:`measurement` and
    :meth:`truth` take one message each; :meth:`report` is /accuracy_monitor/report."""

    def __init__(self, settings: MonitorSettings | None = None) -> None:
        self.settings = settings or MonitorSettings()
        self.tolerances = self.settings.tolerance
        self.measured = AccuracyAccumulator(self.settings.settle)
        self.truth_accumulator = AccuracyAccumulator(self.settings.settle)
        self.tracker = TrackerErrorAccumulator(self.settings.tracker_error.max_stamp_difference)
        self.truth_seen = False
        self.verdicts: list[Verdict] = []
        self.ignored: list[Ignored] = []

    def _ignore(self, topic: str, stamp: float, reason: str) -> Ignored:
        item = Ignored(topic, stamp, reason)
        self.ignored.append(item)
        return item

    def target(self, stamp: float, frame: str, position: ArrayLike,
               quaternion: ArrayLike) -> Ignored | None:
        """A /positioner/target message; None when it was taken (even if it repeats the
        current target)."""
        if frame != BASE_FRAME:
            return self._ignore(TARGET, stamp, f'frame_id {frame!r}: expected {BASE_FRAME!r}')
        try:
            self.measured.add_target(stamp, position, quaternion, clamp=True)
            self.truth_accumulator.add_target(stamp, position, quaternion, clamp=True)
        except InputError as err:
            return self._ignore(TARGET, stamp, str(err))
        return None

    def measurement(self, stamp: float, frame: str, position: ArrayLike,
                    quaternion: ArrayLike) -> Measured | Ignored:
        """A /metrology/pose message: the update and the verdict of a visit it settled."""
        if frame != BASE_FRAME:
            return self._ignore(MEASURED_POSE, stamp,
                                f'frame_id {frame!r}: expected {BASE_FRAME!r}')
        try:
            update = self.measured.add_sample(stamp, position, quaternion)
            self.tracker.add_measured(stamp, position, quaternion)
        except InputError as err:
            return self._ignore(MEASURED_POSE, stamp, str(err))
        verdict = None
        if update.visit is not None:
            verdict = judge_visit(update.visit, self.tolerances)
            self.verdicts.append(verdict)
        return Measured(update, verdict)

    def truth(self, stamp: float, frame: str, position: ArrayLike,
              quaternion: ArrayLike) -> SampleUpdate | Ignored:
        """A /sim/platform/true_pose message: the truth accumulator's update."""
        if frame != BASE_FRAME:
            return self._ignore(TRUE_POSE, stamp, f'frame_id {frame!r}: expected {BASE_FRAME!r}')
        try:
            update = self.truth_accumulator.add_sample(stamp, position, quaternion)
            self.tracker.add_truth(stamp, position, quaternion)
        except InputError as err:
            return self._ignore(TRUE_POSE, stamp, str(err))
        self.truth_seen = True
        return update

    def figures_of(self, visit: Visit) -> dict[str, str]:
        """The ISO 9283 figures (for people) of the pose that ``visit`` is a visit of."""
        return next(f for f in self.measured.result().poses if f.key == visit.key).for_people()

    def reset(self) -> None:
        """Forget every sample, visit, pairing and verdict; the current target stays."""
        self.measured.reset(keep_target=True)
        self.truth_accumulator.reset(keep_target=True)
        self.tracker.reset()
        self.truth_seen = False
        self.verdicts = []

    def report(self) -> dict[str, Any]:
        """The JSON document of /accuracy_monitor/report (SI: m, rad, s): ``tolerances``,
        ``settle`` (settings), ``target`` (current one or null), ``verdicts`` (counts ok /
        error), ``measured`` and ``truth`` (settled ``visits`` and ISO 9283 ``poses``; truth
        null until a true pose arrives), ``tracker`` (measured − true statistics, or null)."""
        target = self.measured.target
        stats = self.tracker.statistics()
        ok = sum(v.ok for v in self.verdicts)
        return {
            'tolerances': {'position': self.tolerances.position,
                           'orientation': self.tolerances.orientation},
            'settle': self.measured.settings.to_params(),
            'target': None if target is None else {
                'time': target[0], 'position': target[1].tolist(),
                'quaternion': target[2].tolist(), 'key': target[3]},
            'verdicts': {'ok': ok, 'error': len(self.verdicts) - ok},
            'measured': self.measured.result().to_dict(),
            'truth': self.truth_accumulator.result().to_dict() if self.truth_seen else None,
            'tracker': None if stats is None else stats.to_dict(),
        }
