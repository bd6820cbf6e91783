"""The latest of each input of a watch window, written by ROS callbacks (any thread) and read
as one consistent :class:`Snapshot` by the view that draws it. Plain data, no ROS: the node
and the CLI convert messages (:mod:`positioning_cell.ros.watch_inputs`) and call the
setters. Poses in ``base`` (m, unit quaternions x, y, z, w), times in s."""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from positioning_cell.accuracy.verdicts import Tolerances
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import FloatArray, as_pose_batch
from positioning_cell.errors import InputError
from positioning_cell.frames.systems import USER_FRAME, CoordinateSystems
from positioning_cell.limits.axis_ranges import AxisRanges
from positioning_cell.names import ESTIMATED_POSE, MEASURED_POSE, NODE_POSITIONER, TARGET
from positioning_cell.recording.status import RecorderReport, Recording, recording
from positioning_cell.watch.deviation import Deviation, deviation
from positioning_cell.watch.scene import Scene, scene

Pose = tuple[FloatArray, FloatArray]
#: The monitor's defaults, judged against until its own tolerances are known.
DEFAULT_TOLERANCES = Tolerances()
#: A measurement older than this is shown as stale, s.
STALE_AFTER = 1.0


def is_stale(age: float) -> bool:
    """Whether a measurement ``age`` s old (inf or NaN: never measured) is stale."""
    return not math.isfinite(age) or age > STALE_AFTER


@dataclass(frozen=True)
class Status:
    """A diagnostic status as the watch shows it: ``level`` 0 OK, 1 WARN, 2 ERROR, 3 STALE,
    its ``message``, the time it came (s) and its key-values."""

    level: int
    message: str
    stamp: float
    values: Mapping[str, str] = field(default_factory=dict)


#: The positioner's states in which a trajectory runs: the watch judges against its setpoint.
MOVING_STATES = frozenset({'moving', 'correcting', 'homing'})
#: A goal's feedback older than this (s) no longer gives the progress (the status does).
FEEDBACK_FRESH = 1.0


@dataclass(frozen=True)
class Snapshot:
    """Everything a watch window draws, at one instant. ``tolerances`` None: the accuracy
    monitor's are not known yet (the defaults are judged against meanwhile);
    ``systems_known`` False: the positioner has not published its coordinate systems (the
    identities are used meanwhile); ``targets_platform`` the tracker targets (T, 3) m in the
    platform frame, None while unknown; ``user_in_base`` T_base_user = T_base_machine ·
    T_machine_user and ``object_in_platform`` T_platform_object as (p (3,) m, q (4,)), once
    the coordinate systems and the machine are known; ``mech`` the machine (None while
    unknown: the user frame, which starts at its home pose, and the scene wait for it);
    ``recorder`` the recorder's latest status (:meth:`recording` reads it); stamps in s
    (header stamps of the poses)."""

    mech: Mechanism | None
    commanded: Pose | None = None
    commanded_stamp: float = 0.0
    estimated: Pose | None = None
    measured: Pose | None = None
    measured_covariance: FloatArray | None = None
    measured_stamp: float = 0.0
    systems: CoordinateSystems = field(default_factory=CoordinateSystems)
    systems_known: bool = False
    tolerances: Tolerances | None = None
    targets_platform: FloatArray | None = None
    positioner: Status | None = None
    verdict: Status | None = None
    recorder: RecorderReport | None = None
    user_in_base: Pose | None = None
    object_in_platform: Pose | None = None
    setpoint: Pose | None = None
    setpoint_stamp: float = 0.0
    driver: Status | None = None
    #: The newest goal feedback: phase, progress (0..1) and when it came (s); None: none yet.
    progress: tuple[str, float, float] | None = None
    #: The positioner's newest live axis ranges (/positioner/axis_ranges); None: none yet.
    axis_ranges: AxisRanges | None = None

    def phase(self, now: float) -> str:
        """The positioner's phase for people: its state, with the running goal's progress
        while it moves (from the goal's feedback if one came within :data:`FEEDBACK_FRESH` s,
        else from its status)."""
        v = {} if self.positioner is None else self.positioner.values
        phase = v.get('state', '?')
        if not self.moving:
            return phase
        if self.progress is not None and now - self.progress[2] <= FEEDBACK_FRESH:
            return f'{phase} {self.progress[1] * 100.0:.0f}%'
        try:
            return f'{phase} {float(v.get("progress", "")) * 100.0:.0f}%'
        except ValueError:
            return phase

    @property
    def moving(self) -> bool:
        """The positioner's last status says a trajectory runs."""
        return (self.positioner is not None
                and self.positioner.values.get('state', '') in MOVING_STATES)

    @property
    def reference(self) -> tuple[str, Pose | None]:
        """What the measured pose is judged against: the moving setpoint while a trajectory
        runs (once the positioner has published one since the last target), else the goal
        (the last target)."""
        if (self.moving and self.setpoint is not None
                and self.setpoint_stamp >= self.commanded_stamp):
            return 'setpoint', self.setpoint
        return 'goal', self.commanded

    @property
    def judged_tolerances(self) -> Tolerances:
        """The monitor's tolerances, or the defaults while they are not known."""
        return self.tolerances if self.tolerances is not None else DEFAULT_TOLERANCES

    def waiting_for(self) -> list[str]:
        """What has not come yet: the pose topics, and the machine while it is unknown."""
        missing = [topic for topic, value in ((TARGET, self.commanded),
                                              (MEASURED_POSE, self.measured),
                                              (ESTIMATED_POSE, self.estimated)) if value is None]
        return missing + ([f'/{NODE_POSITIONER} mechanism.*'] if self.mech is None else [])

    def recording(self, now: float) -> Recording | None:
        """The recording's state at wall time ``now`` (s) from the recorder's latest status
        (:func:`positioning_cell.recording.recording`: stopped when it failed, stopped or went
        silent); None while no recorder was heard of."""
        return recording(self.recorder, now)

    def deviation(self, frame: str) -> Deviation | None:
        """The measured pose's :class:`~positioning_cell.watch.deviation.Deviation` from the
        command in ``frame``; None until both have come (and, for ``user``, the machine)."""
        reference = self.reference[1]
        if reference is None or self.measured is None or self.measured_covariance is None:
            return None
        if self.mech is None:
            if frame == USER_FRAME:
                return None
            mech = Mechanism()  # not read in base: the platform pose itself
        else:
            mech = self.mech
        return deviation(reference, self.measured, self.measured_covariance, frame,
                         self.systems, mech, self.judged_tolerances)

    def scene(self, magnification: float) -> Scene | None:
        """The 3-D :class:`~positioning_cell.watch.scene.Scene` of the latest poses (None
        while the machine is unknown)."""
        if self.mech is None:
            return None
        return scene(self.mech, self.estimated, self.commanded, self.measured,
                     self.targets_platform, self.judged_tolerances, magnification)


def _pose(position: FloatArray, quaternion: FloatArray) -> Pose:
    p, q = as_pose_batch(position, quaternion)
    return p[0], q[0]


class WatchState:
    """The latest inputs (thread-safe). Each setter validates what it is given and raises
    InputError, keeping the previous value, for a bad one (NaN, non-unit quaternion, a
    covariance that is not a finite (6, 6))."""

    def __init__(self, mech: Mechanism | None) -> None:
        self._lock = threading.Lock()
        self._snapshot = Snapshot(mech=mech)

    def _update(self, **changes: object) -> None:
        with self._lock:
            self._snapshot = replace(self._snapshot, **changes)  # type: ignore[arg-type]

    def snapshot(self) -> Snapshot:
        """The inputs as they are now (immutable)."""
        with self._lock:
            return self._snapshot

    def command(self, position: FloatArray, quaternion: FloatArray, stamp: float) -> None:
        """The commanded platform pose (/positioner/target)."""
        self._update(commanded=_pose(position, quaternion), commanded_stamp=float(stamp))

    def setpoint(self, position: FloatArray, quaternion: FloatArray, stamp: float) -> None:
        """The running trajectory's setpoint (/positioner/setpoint)."""
        self._update(setpoint=_pose(position, quaternion), setpoint_stamp=float(stamp))

    def estimate(self, position: FloatArray, quaternion: FloatArray) -> None:
        """The positioner's estimate from the encoders (/positioner/pose)."""
        self._update(estimated=_pose(position, quaternion))

    def measurement(self, position: FloatArray, quaternion: FloatArray,
                    covariance: FloatArray, stamp: float) -> None:
        """A tracker measurement (/metrology/pose) and its covariance (6, 6)."""
        cov = np.asarray(covariance, dtype=float)
        if cov.shape != (6, 6) or not np.isfinite(cov).all():
            raise InputError(f'covariance: expected a finite (6, 6), got shape {cov.shape}')
        self._update(measured=_pose(position, quaternion), measured_covariance=cov,
                     measured_stamp=float(stamp))

    def _frames(self, snapshot: Snapshot) -> Snapshot:
        """``snapshot`` with the user and object frames as poses (they change rarely: computed
        here, not per send)."""
        if not snapshot.systems_known or snapshot.mech is None:
            return snapshot
        return replace(snapshot,
                       user_in_base=snapshot.systems.user_in_base(snapshot.mech).to_pq(),
                       object_in_platform=snapshot.systems.object.to_pq())

    def mechanism(self, mech: Mechanism) -> None:
        """The machine (the positioner's ``mechanism.*`` parameters)."""
        with self._lock:
            self._snapshot = self._frames(replace(self._snapshot, mech=mech))

    def coordinate_systems(self, systems: CoordinateSystems) -> None:
        """The positioner's user and object coordinate systems."""
        with self._lock:
            self._snapshot = self._frames(replace(self._snapshot, systems=systems,
                                                  systems_known=True))

    def tolerances(self, tolerances: Tolerances) -> None:
        """The accuracy monitor's tolerances in force."""
        self._update(tolerances=tolerances)

    def targets(self, platform: FloatArray) -> None:
        """The tracker targets (T, 3) m in the platform frame."""
        arr = np.asarray(platform, dtype=float)
        if arr.ndim != 2 or arr.shape[1] != 3 or not np.isfinite(arr).all():
            raise InputError(f'targets: expected finite rows (T, 3), got shape {arr.shape}')
        self._update(targets_platform=arr)

    def positioner(self, status: Status) -> None:
        """The positioner's state (its status on /diagnostics)."""
        self._update(positioner=status)

    def goal_progress(self, phase: str, progress: float, stamp: float) -> None:
        """A running goal's feedback: its phase and progress (0..1)."""
        self._update(progress=(phase, float(progress), float(stamp)))

    def driver(self, status: Status) -> None:
        """The leg driver's state (its status on /diagnostics)."""
        self._update(driver=status)

    def verdict(self, status: Status) -> None:
        """The accuracy monitor's last settled-pose verdict."""
        self._update(verdict=status)

    def axis_ranges(self, ranges: AxisRanges) -> None:
        """The positioner's live axis ranges from the current user position."""
        self._update(axis_ranges=ranges)

    def recorder(self, report: RecorderReport) -> None:
        """The recorder's latest status (its ``received`` time on the wall clock, s)."""
        self._update(recorder=report)
