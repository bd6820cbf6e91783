"""The accuracy monitor's rules without ROS: the same accumulators, fed the same way as
``accuracy_monitor_node`` feeds them, so a recorded run replayed here gives the figures the
live monitor reported.

The node's rules (positioning_cell/nodes/accuracy_monitor_node.py): a pose message not in the
``base`` frame, or one the accumulators refuse (InputError: a quaternion off unit length, a
sample older than the previous one), is ignored; a target is clamped to just after the last
sample (``add_target(..., clamp=True)``) and goes to both the measured and the truth
accumulators; a measurement goes to the measured accumulator, then to the tracker pairing; a
true pose to the truth accumulator, then to the tracker pairing. Each settled measured visit
gets a verdict against the tolerances.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike

from positioning_cell import accuracy
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.errors import ConfigError, InputError

#: Node name whose section of config/cell.yaml holds the monitor's settings.
MONITOR_NODE = 'accuracy_monitor'
#: The node's default for ``truth.max_stamp_difference``, s.
MAX_STAMP_DIFFERENCE = 1e-3
BASE_FRAME = 'base'


@dataclass(frozen=True)
class MonitorSettings:
    """The monitor's settings: settle detection, tolerances, the truth pairing window (s)."""

    settle: accuracy.SettleSettings = field(default_factory=accuracy.SettleSettings)
    tolerances: accuracy.Tolerances = field(default_factory=accuracy.Tolerances)
    max_stamp_difference: float = MAX_STAMP_DIFFERENCE

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> MonitorSettings:
        """From the nested ``accuracy_monitor`` parameters (``settle``, ``tolerance``,
        ``truth`` blocks; missing keys keep the node's defaults)."""
        def block(name: str) -> dict[str, Any]:
            value = params.get(name, {}) or {}
            if not isinstance(value, Mapping):
                raise ConfigError(f'{MONITOR_NODE}.{name}: expected a mapping, got {value!r}')
            return dict(value)

        tol = block('tolerance')
        defaults = accuracy.Tolerances()
        tolerances = accuracy.Tolerances(float(tol.get('position', defaults.position)),
                                         float(tol.get('orientation', defaults.orientation)))
        difference = float(block('truth').get('max_stamp_difference', MAX_STAMP_DIFFERENCE))
        return cls(accuracy.SettleSettings.from_params(block('settle')), tolerances,
                   difference)

    @classmethod
    def from_file(cls, path: str | Path) -> MonitorSettings:
        """From the ``accuracy_monitor`` section (and ``/**``) of a ROS 2 parameter file."""
        return cls.from_params(node_parameters(load_parameter_file(path), MONITOR_NODE))


@dataclass(frozen=True)
class Ignored:
    """A message the monitor would have ignored: topic, log time (s) and the reason."""

    topic: str
    time: float
    reason: str


class MonitorReplay:
    """Messages in, the monitor's state out: :meth:`target`, :meth:`measurement` and
    :meth:`truth` take one message each (stamp s, frame id, position (3,) m, quaternion (4,)
    x, y, z, w) in recorded order; :meth:`report` is the node's /accuracy_monitor/report."""

    def __init__(self, settings: MonitorSettings | None = None) -> None:
        self.settings = settings or MonitorSettings()
        self.measured = accuracy.AccuracyAccumulator(self.settings.settle)
        self.truth_accumulator = accuracy.AccuracyAccumulator(self.settings.settle)
        self.tracker = accuracy.TrackerErrorAccumulator(self.settings.max_stamp_difference)
        self.truth_seen = False
        self.verdicts: list[accuracy.Verdict] = []
        self.ignored: list[Ignored] = []

    def _check(self, topic: str, stamp: float, frame: str) -> bool:
        if frame != BASE_FRAME:
            self.ignored.append(Ignored(topic, stamp,
                                        f'frame_id {frame!r}: expected {BASE_FRAME!r}'))
            return False
        return True

    def target(self, stamp: float, frame: str, position: ArrayLike,
               quaternion: ArrayLike) -> bool:
        """A /positioner/target message; True when it was taken (even if it repeats the
        current target)."""
        if not self._check('/positioner/target', stamp, frame):
            return False
        try:
            self.measured.add_target(stamp, position, quaternion, clamp=True)
            self.truth_accumulator.add_target(stamp, position, quaternion, clamp=True)
        except InputError as err:
            self.ignored.append(Ignored('/positioner/target', stamp, str(err)))
            return False
        return True

    def measurement(self, stamp: float, frame: str, position: ArrayLike,
                    quaternion: ArrayLike) -> accuracy.SampleUpdate | None:
        """A /metrology/pose message: the monitor's update (None when ignored)."""
        if not self._check('/metrology/pose', stamp, frame):
            return None
        try:
            update = self.measured.add_sample(stamp, position, quaternion)
            self.tracker.add_measured(stamp, position, quaternion)
        except InputError as err:
            self.ignored.append(Ignored('/metrology/pose', stamp, str(err)))
            return None
        if update.visit is not None:
            self.verdicts.append(accuracy.judge_visit(update.visit, self.settings.tolerances))
        return update

    def truth(self, stamp: float, frame: str, position: ArrayLike,
              quaternion: ArrayLike) -> accuracy.SampleUpdate | None:
        """A /sim/platform/true_pose message: the truth accumulator's update (None when
        ignored)."""
        if not self._check('/sim/platform/true_pose', stamp, frame):
            return None
        try:
            update = self.truth_accumulator.add_sample(stamp, position, quaternion)
            self.tracker.add_truth(stamp, position, quaternion)
        except InputError as err:
            self.ignored.append(Ignored('/sim/platform/true_pose', stamp, str(err)))
            return None
        self.truth_seen = True
        return update

    def report(self) -> dict[str, Any]:
        """The JSON document of /accuracy_monitor/report (see accuracy_monitor_node)."""
        target = self.measured.target
        stats = self.tracker.statistics()
        ok = sum(v.ok for v in self.verdicts)
        return {
            'tolerances': {'position': self.settings.tolerances.position,
                           'orientation': self.settings.tolerances.orientation},
            'settle': self.measured.settings.to_params(),
            'target': None if target is None else {
                'time': target[0], 'position': target[1].tolist(),
                'quaternion': target[2].tolist(), 'key': target[3]},
            'verdicts': {'ok': ok, 'error': len(self.verdicts) - ok},
            'measured': self.measured.result().to_dict(),
            'truth': self.truth_accumulator.result().to_dict() if self.truth_seen else None,
            'tracker': None if stats is None else stats.to_dict(),
        }

