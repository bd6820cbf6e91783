"""The accuracy monitor's rules, the one implementation the live node (what came in the last
0.1 s at a time) and the offline replay of a bag (thousands at a time, as arrays) both run.

Messages go in in the order they are given (stamp s, frame id, position (3,) m, quaternion
(4,) x, y, z, w; the live node and the offline replay give them in stamp order:
:mod:`positioning_cell.accuracy.stamp_order`), with the positioner's move ends (the stamp of a
``positioner: state`` status on /diagnostics that ends a move: :func:`move_ended`), which go to
both accumulators at their place
(a visit is judged on its final settled window: :mod:`positioning_cell.accuracy.settle`): a
pose message not in the ``base`` frame, not finite, with a quaternion off unit
length or older than the latest taken from its topic is ignored with its reason; a target is
clamped to just after the last sample (``add_target(..., clamp=True)``) and goes to both the
measured and the truth accumulators at its place among the samples; measurements go to the
measured accumulator and to the tracker pairing; true poses to the truth accumulator and to the
tracker pairing. Each settled measured visit gets a verdict against the tolerances in force
when it settled, its stabilisation time and overshoot from the readings of its segment
(:mod:`positioning_cell.accuracy.stabilisation`), and its attained path in the normal planes
of its commanded path from the pose visited before it (:mod:`positioning_cell.accuracy.path`;
the path figures are those of a path's cycles together, offline). The tracker's registration
(/metrology/registration: where the tracker located itself, with its covariance) is the part
of every reading's stated covariance that averaging a settle window does not reduce; each
reading keeps the registration in force when it arrived (:class:`Readings`). However the
messages are grouped into
feeds, the figures are the same (the accumulators' batch form:
:meth:`positioning_cell.accuracy.settle.AccuracyAccumulator.add`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.accuracy.decisions import covariance_checks
from positioning_cell.accuracy.path import PathCrossings, path_crossings
from positioning_cell.accuracy.settle import (
    AccuracyAccumulator,
    CheckedSamples,
    Ends,
    SampleBatch,
    SampleUpdate,
    SettleSettings,
    Targets,
    Visit,
    as_time,
    check_samples,
)
from positioning_cell.accuracy.stabilisation import (
    Stabilisation,
    StabilisationSettings,
    stabilisation,
    stabilisation_values,
)
from positioning_cell.accuracy.tracker_errors import TrackerErrorAccumulator
from positioning_cell.accuracy.verdicts import (
    Tolerances,
    Verdict,
    decision_counts,
    judge_visits,
)
from positioning_cell.config import load_parameter_file, node_parameters
from positioning_cell.core.poses import Triple, as_pose_batch
from positioning_cell.errors import InputError
from positioning_cell.metrology.instrument import Registration, averaged_covariance
from positioning_cell.moves.correction import mean_reading
from positioning_cell.moves.outcomes import ResultCode, State
from positioning_cell.names import (
    BASE_FRAME,
    DIAGNOSTICS,
    MEASURED_POSE,
    NODE_MONITOR,
    TARGET,
    TRACKER_REGISTRATION,
    TRUE_POSE,
)
from positioning_cell.parameters import check_fields, group, parse, setting

FloatArray = NDArray[np.float64]


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
    stabilisation: StabilisationSettings = group(
        StabilisationSettings, 'pose stabilisation time and overshoot (ISO 9283 7.4, 7.5)')

    def __post_init__(self) -> None:
        check_fields(self)

    @classmethod
    def from_file(cls, path: str | Path) -> MonitorSettings:
        """From the ``accuracy_monitor`` section (and ``/**``) of a ROS 2 parameter file; keys
        the monitor does not declare (the shared mechanism block) are left out."""
        params = node_parameters(load_parameter_file(path), NODE_MONITOR)
        return parse(cls, {k: v for k, v in params.items()
                           if k in ('tolerance', 'settle', 'tracker_error',
                                    'stabilisation')})

#: The monitor's tolerances as parameters (``tolerance.position``, ...): the prefix the watch
#: windows read and follow them by (:mod:`positioning_cell.ros.watch_inputs`).
TOLERANCES_PREFIX = 'tolerance.'



#: The positioner's states that end a move (with the result code of the move they end).
MOVE_END_STATES = frozenset({State.SETTLED.value, State.ABORTED.value, State.FAULT.value})


def move_ended(values: Mapping[str, str]) -> bool:
    """Whether the values of a ``positioner: state`` status (``state``, ``code``) report the
    end of a move: a state that ends one (settled, aborted, fault) with the result code of the
    move it ends; not a refusal (the state stays, nothing moved) nor a periodic status (no
    code)."""
    code = values.get('code', '')
    return (values.get('state') in MOVE_END_STATES and code != ''
            and not code.startswith('refused') and code in _RESULT_CODES)


_RESULT_CODES = frozenset(c.value for c in ResultCode)


@dataclass(frozen=True)
class MoveEnds:
    """K move ends reported by the positioner, in arrival order: ``rank`` (K,) their places in
    the arrival order of everything fed together (as :attr:`PoseMessages.rank`) and the stamps
    (K,) s of the statuses that reported them."""

    rank: NDArray[np.intp]
    stamp: FloatArray

    @classmethod
    def empty(cls) -> MoveEnds:
        """No move end."""
        return cls(np.empty(0, dtype=np.intp), np.empty(0))

    @classmethod
    def one(cls, stamp: float) -> MoveEnds:
        """A single move end."""
        return cls(np.zeros(1, dtype=np.intp), np.array([stamp], dtype=float))

    @property
    def count(self) -> int:
        """K."""
        return int(self.rank.size)


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


@dataclass(frozen=True)
class PoseMessages:
    """N pose messages of one topic, in arrival order: ``rank`` (N,) their places in the
    arrival order of everything fed together (increasing; comparable across topics), header
    stamps (N,) s, frame ids (N,), positions (N, 3) m, quaternions (N, 4) x, y, z, w (as
    received: the monitor checks them), and the covariances (N, 6, 6) they state
    (PoseWithCovarianceStamped's, row-major: x, y, z, rot-x, rot-y, rot-z in their frame;
    None: the topic states none)."""

    rank: NDArray[np.intp]
    stamp: FloatArray
    frame: NDArray[np.object_]
    position: FloatArray
    quaternion: FloatArray
    covariance: FloatArray | None = None

    @classmethod
    def empty(cls) -> PoseMessages:
        """No message."""
        return cls(np.empty(0, dtype=np.intp), np.empty(0), np.empty(0, dtype=object),
                   np.empty((0, 3)), np.empty((0, 4)))

    @classmethod
    def one(cls, stamp: float, frame: str, position: ArrayLike, quaternion: ArrayLike,
            covariance: ArrayLike | None = None) -> PoseMessages:
        """A single message (its values checked by the monitor, not here; ``covariance``:
        the 36 or 6 x 6 values it states, or None)."""
        try:
            p = np.asarray(position, dtype=float).reshape(1, 3)
            q = np.asarray(quaternion, dtype=float).reshape(1, 4)
            c = (None if covariance is None
                 else np.asarray(covariance, dtype=float).reshape(1, 6, 6))
        except (TypeError, ValueError) as err:
            raise InputError(f'expected a position (3,), a quaternion (4,) and a covariance '
                             f'(36,), got {position!r}, {quaternion!r}, {covariance!r}'
                             ) from err
        return cls(np.zeros(1, dtype=np.intp), np.array([stamp], dtype=float),
                   np.array([frame], dtype=object), p, q, c)

    @property
    def count(self) -> int:
        """N."""
        return int(self.rank.size)


@dataclass(frozen=True)
class PoseBatch:
    """What the pose messages of one source gave: ``samples`` the accumulator's answer per
    message (an ignored message is not accepted there), ``segment`` (N,) the segment each fell
    in (numbered since the monitor started, −1: before any target), the ``ignored`` rows in
    row order with their reasons, and the (row, verdict) of each visit they settled
    (measurements only)."""

    samples: SampleBatch
    segment: NDArray[np.intp]
    ignored: tuple[tuple[int, Ignored], ...] = ()
    verdicts: tuple[tuple[int, Verdict], ...] = ()


@dataclass(frozen=True)
class NewSegment:
    """A target that started a segment: its index among the targets fed, the time it took
    effect for the measured and for the true poses (s; each clamped after its own samples),
    its pose key, position (3,) m and unit quaternion (4,)."""

    target: int
    time: float
    truth_time: float
    key: int
    position: FloatArray
    quaternion: FloatArray


@dataclass(frozen=True)
class Fed:
    """What :meth:`Monitor.feed` did: the targets ignored (index, reason), the segments
    started, the measured and true poses' batches, and the measured visits a target closed on
    their last stable window (no move end settled them): (index of that target, visit,
    verdict)."""

    targets_ignored: tuple[tuple[int, Ignored], ...]
    segments: tuple[NewSegment, ...]
    measured: PoseBatch
    truth: PoseBatch
    closed: tuple[tuple[int, Visit, Verdict], ...] = ()


_EMPTY = np.empty((0, 3))
#: What a source without messages or targets gives.
_NOTHING = PoseBatch(SampleBatch(np.zeros(0, dtype=bool), {}, np.empty(0, dtype=np.intp), _EMPTY,
                                 _EMPTY), np.empty(0, dtype=np.intp))
_NOTHING_CHECKED = CheckedSamples(np.empty(0), _EMPTY, np.empty((0, 4)), np.zeros(0, dtype=bool),
                                  {})


#: Most readings the monitor holds (a segment that does not settle: a pose held oscillating
#: past the settle threshold, with no next target): 2 min at the tracker's 20 Hz, 0.8 MB,
#: which the live node copies once per reading while it lasts (a move and its settling take
#: seconds). What is dropped beyond it leaves a visit of that segment without a stabilisation
#: figure.
READINGS_KEPT = 2_400


class Readings:
    """The measurements the monitor took that a visit still to come may need: times (n,) s,
    positions (n, 3) m, quaternions (n, 4), stated covariances (n, 6, 6) (NaN: not
    stated) and the registration in force when each arrived (n,) (an index into the
    monitor's :attr:`Monitor.registrations`, −1: none yet), so that a settled visit's
    attained pose gets the covariance of the mean of its window's readings and its
    stabilisation is taken over its segment's readings. Bounded:
    what precedes the accumulator's
    :meth:`~positioning_cell.accuracy.settle.AccuracyAccumulator.open_since` is dropped, and
    at most :data:`READINGS_KEPT` are held."""

    def __init__(self) -> None:
        self.time = np.empty(0)
        self.position = np.empty((0, 3))
        self.quaternion = np.empty((0, 4))
        self.covariance = np.empty((0, 6, 6))
        self.registration = np.empty(0, dtype=np.intp)
        #: The latest time (s) of a reading dropped while it could still be needed (−inf:
        #: none): a visit whose segment began before it lacks readings.
        self.dropped_until = -math.inf

    def add(self, time: FloatArray, position: FloatArray, quaternion: FloatArray,
            covariance: FloatArray | None, registration: NDArray[np.intp] | None = None
            ) -> None:
        """Readings taken (time-ordered, after those held); ``covariance`` None: not
        stated; ``registration`` (n,): the registration in force at each (None: none). A
        covariance that is not one (a NaN or infinite entry, not symmetric, not positive
        semi-definite) is held as not stated: the visit it falls in gets no U (its verdict
        says ``± ?``), and nothing raises on what a tracker or a bag sent."""
        cov = (np.full((time.size, 6, 6), math.nan) if covariance is None
               else np.array(covariance, dtype=float))
        cov[~covariance_checks(cov).usable] = math.nan
        self.time = np.concatenate([self.time, time])
        self.position = np.concatenate([self.position, position])
        self.quaternion = np.concatenate([self.quaternion, quaternion])
        self.covariance = np.concatenate([self.covariance, cov])
        self.registration = np.concatenate([
            self.registration, np.full(time.size, -1, dtype=np.intp) if registration is None
            else np.asarray(registration, dtype=np.intp)])

    def drop_before(self, time: float) -> None:
        """Forget the readings older than ``time`` s (all of them for inf), and the oldest
        beyond :data:`READINGS_KEPT` (remembered in :attr:`dropped_until`)."""
        keep = int(np.searchsorted(self.time, time, side='left'))
        if self.time.size - keep > READINGS_KEPT:
            keep = self.time.size - READINGS_KEPT
            self.dropped_until = float(self.time[keep - 1])
        if keep:
            self.time, self.position = self.time[keep:], self.position[keep:]
            self.quaternion, self.covariance = self.quaternion[keep:], self.covariance[keep:]
            self.registration = self.registration[keep:]

    def stabilisation_of(self, visits: Sequence[Visit], covariances: FloatArray,
                         settings: StabilisationSettings) -> list[Stabilisation]:
        """Each visit's :class:`~positioning_cell.accuracy.stabilisation.Stabilisation` over
        the readings of its segment (target_time..settle_time) against its attained position
        of covariance ``covariances`` (N, 6, 6); none when readings of the segment were
        dropped (:attr:`dropped_until`)."""
        out = []
        for visit, cov in zip(visits, covariances, strict=True):  # over visits
            if self.dropped_until >= visit.target_time:
                out.append(Stabilisation.none())
                continue
            rows = slice(int(np.searchsorted(self.time, visit.target_time, side='left')),
                         int(np.searchsorted(self.time, visit.settle_time, side='right')))
            out.append(stabilisation(self.time[rows], self.position[rows],
                                     self.covariance[rows, :3, :3], visit.position,
                                     cov[:3, :3], settings.band, visit.target_time))
        return out

    def paths_of(self, visits: Sequence[Visit], starts: Sequence[Triple | None]
                 ) -> list[PathCrossings | None]:
        """Each visit's attained path in the normal planes of its commanded path from
        ``starts`` (the commanded position it was moved from; None: not known) over the
        readings of its segment (:func:`~positioning_cell.accuracy.path.path_crossings`);
        none without a start, for a short path, or when readings of the segment were
        dropped."""
        out: list[PathCrossings | None] = []
        for visit, start in zip(visits, starts, strict=True):  # over visits
            if start is None or self.dropped_until >= visit.target_time:
                out.append(None)
                continue
            rows = slice(int(np.searchsorted(self.time, visit.target_time, side='left')),
                         int(np.searchsorted(self.time, visit.settle_time, side='right')))
            out.append(path_crossings(start, visit.commanded_position, self.time[rows],
                                      self.position[rows], self.covariance[rows, :3, :3]))
        return out

    def covariance_of(self, visits: Sequence[Visit],
                      registrations: Sequence[Registration] = ()) -> FloatArray:
        """The covariance (N, 6, 6) of each visit's attained pose, the mean of the readings
        of its settle window (window_start..settle_time), by
        :func:`positioning_cell.moves.correction.mean_reading` (the closed loop's mean of a
        pose's readings): the readings' own noise averaged down, the part every reading
        shares (the tracker's registration) not. That part is the registration's covariance
        at the readings' mean position when one registration was in force for all of them
        (``registrations``: the monitor's, indexed by :attr:`registration`), as the closed
        loop takes it; else (none received, or the tracker re-located within the window) the
        readings' scatter tells the two apart. NaN rows: no reading of the window held, or
        one stated no covariance. With the registration known, the covariance is that of
        mean_reading without the mean pose and checks it does not need (the same numbers:
        0.02 ms a visit against mean_reading's 0.34 ms, ad hoc; issue 24)."""
        out = np.full((len(visits), 6, 6), math.nan)
        for i, visit in enumerate(visits):  # over visits, not samples
            rows = slice(int(np.searchsorted(self.time, visit.window_start, side='left')),
                         int(np.searchsorted(self.time, visit.settle_time, side='right')))
            cov = self.covariance[rows]
            if not (cov.shape[0] and np.all(np.isfinite(cov))):
                continue
            position, index = self.position[rows], self.registration[rows]
            if index[0] >= 0 and np.all(index == index[0]):
                common = registrations[int(index[0])].covariance_at(position.mean(axis=0))[0]
                out[i] = averaged_covariance(cov.mean(axis=0), common, cov.shape[0])
            else:
                out[i] = mean_reading(position, self.quaternion[rows], cov)[2]
        return out


class Monitor:
    """Messages in, the monitor's state out. :meth:`feed` takes the targets, measured and true
    poses that arrived together (any number, interleaved by their ranks: one implementation,
    vectorised over the samples and across segments, the same figures however the messages are
    split into feeds); :meth:`target`, :meth:`measurement` and :meth:`truth` feed one message;
    :meth:`report` is /accuracy_monitor/report. With ``per_segment`` the tracker's pairs are
    also summed per pair of segments the measurement and the truth came in (the offline
    analysis' per-mode figures)."""

    def __init__(self, settings: MonitorSettings | None = None, *,
                 per_segment: bool = False) -> None:
        self.settings = settings or MonitorSettings()
        self.tolerances = self.settings.tolerance
        self.measured = AccuracyAccumulator(self.settings.settle)
        self.truth_accumulator = AccuracyAccumulator(self.settings.settle)
        self.tracker = TrackerErrorAccumulator(self.settings.tracker_error.max_stamp_difference)
        self.per_segment = per_segment
        #: Targets taken that started a segment since the start (reset keeps counting).
        self.segments = 0
        self.truth_seen = False
        self.verdicts: list[Verdict] = []
        #: The covariance (6, 6) of each verdict's attained pose as measured (NaN: not stated;
        #: :meth:`Readings.covariance_of`), in step with :attr:`verdicts`.
        self.covariances: list[FloatArray] = []
        #: Each verdict's visit's stabilisation time and overshoot, in step with
        #: :attr:`verdicts`.
        self.stabilisations: list[Stabilisation] = []
        self._stabilised: dict[Visit, Stabilisation] = {}
        #: Each verdict's visit's attained path in its commanded path's normal planes (None:
        #: not taken, :meth:`Readings.paths_of`), in step with :attr:`verdicts`.
        self.paths: list[PathCrossings | None] = []
        self._paths: dict[Visit, PathCrossings | None] = {}
        #: The commanded position of the latest visit settled (the next one's path starts
        #: there; kept over reset: it is where the machine was sent).
        self._moved_from: Triple | None = None
        self.ignored: list[Ignored] = []
        self.readings = Readings()
        #: The tracker's registrations taken, in arrival order (the last is in force; kept
        #: over reset: it is the instrument's state, not a figure).
        self.registrations: list[Registration] = []
        # The latest stamp taken per source: an older sample is ignored (kept over reset).
        self._latest = {MEASURED_POSE: -math.inf, TRUE_POSE: -math.inf}

    def _targets(self, targets: PoseMessages) -> tuple[NDArray[np.intp], Targets,
                                                       list[tuple[int, Ignored]]]:
        """The valid targets (their indices and values) and the ignored ones."""
        ignored: list[tuple[int, Ignored]] = []
        keep: list[int] = []
        for k in range(targets.count):  # over targets, not samples
            stamp, frame = float(targets.stamp[k]), str(targets.frame[k])
            if frame != BASE_FRAME:
                ignored.append((k, Ignored(TARGET, stamp,
                                           f'frame_id {frame!r}: expected {BASE_FRAME!r}')))
                continue
            try:
                as_time(stamp, 'target time')
                as_pose_batch(targets.position[k], targets.quaternion[k])
            except InputError as err:
                ignored.append((k, Ignored(TARGET, stamp, str(err))))
                continue
            keep.append(k)
        rows = np.array(keep, dtype=np.intp)
        _, q = as_pose_batch(targets.position[rows], targets.quaternion[rows]) if keep else (
            None, np.empty((0, 4)))
        return rows, Targets(np.zeros(rows.size, dtype=np.intp), targets.stamp[rows],
                             targets.position[rows], q), ignored

    def _source(self, topic: str, accumulator: AccuracyAccumulator, poses: PoseMessages,
                target_rank: NDArray[np.intp], targets: Targets, ends: MoveEnds,
                ends_after: NDArray[np.intp]
                ) -> tuple[PoseBatch, NDArray[np.intp], CheckedSamples]:
        """The messages of one source the monitor takes (frame ``base``, the sample checks,
        not older than the latest taken) through ``accumulator`` with the targets; the rows
        taken and the checked values."""
        n = poses.count
        if n == 0 and targets.count == 0 and ends.count == 0:  # a message of another source
            return _NOTHING, np.empty(0, dtype=np.intp), _NOTHING_CHECKED
        in_base = poses.frame == BASE_FRAME if n else np.zeros(0, dtype=bool)
        base_rows = np.flatnonzero(in_base)
        checked = check_samples(poses.stamp[base_rows], poses.position[base_rows],
                                poses.quaternion[base_rows], self._latest[topic])
        rows = base_rows[checked.accepted]
        at = np.searchsorted(poses.rank[rows], target_rank)
        ok = checked.accepted
        batch = accumulator.add_checked(
            CheckedSamples(checked.time[ok], checked.position[ok], checked.quaternion[ok],
                           np.ones(rows.size, dtype=bool), {}),
            Targets(at, targets.time, targets.position, targets.quaternion),
            Ends(np.searchsorted(poses.rank[rows], ends.rank), ends.stamp, ends_after))
        if rows.size:
            self._latest[topic] = float(checked.time[checked.accepted][-1])
        reasons = {int(i): f'frame_id {poses.frame[i]!r}: expected {BASE_FRAME!r}'
                   for i in np.flatnonzero(~in_base)}
        reasons.update({int(base_rows[i]): r for i, r in checked.reasons.items()})
        accepted = np.zeros(n, dtype=bool)
        accepted[rows] = batch.accepted
        local = np.full(n, -1, dtype=np.intp)
        local[rows] = batch.segment
        segment = np.where(local >= 0, self.segments - 1 + local, -1)
        dp, rv = np.full((n, 3), math.nan), np.full((n, 3), math.nan)
        dp[rows], rv[rows] = batch.position_error, batch.orientation_error
        samples = SampleBatch(accepted, reasons, local, dp, rv, batch.started,
                              tuple((int(rows[r]), v) for r, v in batch.visits), batch.closed)
        ignored = tuple((i, Ignored(topic, float(poses.stamp[i]), reasons[i]))
                        for i in sorted(reasons))
        return PoseBatch(samples, segment, ignored), rows, checked

    def _registrations(self, messages: PoseMessages
                       ) -> tuple[NDArray[np.intp], list[tuple[int, Ignored]]]:
        """Take the valid registrations (frame ``base``, finite, covariance symmetric
        positive semi-definite: :meth:`Registration.checked`) that differ from the one in
        force; the ranks of those taken and the others (rank, ignored with the reason)."""
        taken: list[int] = []
        ignored: list[tuple[int, Ignored]] = []
        for k in range(messages.count):  # registrations: one per tracker location
            stamp, frame = float(messages.stamp[k]), str(messages.frame[k])
            try:
                if frame != BASE_FRAME:
                    raise InputError(f'frame_id {frame!r}: expected {BASE_FRAME!r}')
                if messages.covariance is None:
                    raise InputError('a registration states its covariance')
                registration = Registration.checked(messages.position[k],
                                                    messages.covariance[k])
                if not covariance_checks(registration.covariance[None]).usable[0]:
                    raise InputError('the registration\'s covariance is not positive '
                                     'semi-definite')
                # the same one again (latched: delivered anew to a late or reconnected
                # subscriber) changes nothing
                last = self.registrations[-1] if self.registrations else None
                if last is None or not (np.array_equal(last.position, registration.position)
                                        and np.array_equal(last.covariance,
                                                           registration.covariance)):
                    self.registrations.append(registration)
                    taken.append(int(messages.rank[k]))
            except InputError as err:
                ignored.append((int(messages.rank[k]),
                                Ignored(TRACKER_REGISTRATION, stamp, str(err))))
        return np.array(taken, dtype=np.intp), ignored

    def _ends(self, ends: MoveEnds) -> tuple[MoveEnds, list[tuple[int, Ignored]]]:
        """The move ends with a finite stamp, and the others (rank, ignored with the reason)."""
        finite = np.isfinite(ends.stamp)
        ignored = []
        for k in np.flatnonzero(~finite):  # rare
            try:
                as_time(float(ends.stamp[k]), 'move end stamp')
            except InputError as err:
                ignored.append((int(ends.rank[k]),
                                Ignored(DIAGNOSTICS, float(ends.stamp[k]), str(err))))
        return MoveEnds(ends.rank[finite], ends.stamp[finite]), ignored

    def feed(self, targets: PoseMessages | None = None, measured: PoseMessages | None = None,
             truth: PoseMessages | None = None, ends: MoveEnds | None = None,
             registrations: PoseMessages | None = None) -> Fed:
        """Targets (/positioner/target), measurements (/metrology/pose), true poses
        (/sim/platform/true_pose), the positioner's move ends (/diagnostics) and the
        tracker's registrations (/metrology/registration) that arrived together, each in
        arrival order and all interleaved by their ``rank``. A message is ignored with its
        reason when not in ``base``, not finite, with a quaternion off unit length, or (a
        pose) older than the latest taken from its topic, a registration whose covariance is
        not one; every target and move end goes to both accumulators at its place, and each
        measurement keeps the registration in force at its place. Each measured visit settled
        (by a measurement after a move end, or closed by the next target) gets a verdict
        against the tolerances in force."""
        targets = targets or PoseMessages.empty()
        measured = measured or PoseMessages.empty()
        truth = truth or PoseMessages.empty()
        in_force = len(self.registrations) - 1
        registered, registrations_ignored = self._registrations(
            registrations or PoseMessages.empty())
        ends, ends_ignored = self._ends(ends or MoveEnds.empty())
        valid, values, targets_ignored = self._targets(targets)
        rank = targets.rank[valid]
        ends_after = np.searchsorted(rank, ends.rank)
        before = self.measured.visit_count
        m_batch, m_rows, m_checked = self._source(MEASURED_POSE, self.measured, measured,
                                                  rank, values, ends, ends_after)
        t_batch, t_rows, t_checked = self._source(TRUE_POSE, self.truth_accumulator, truth,
                                                  rank, values, ends, ends_after)
        truth_started = {s.target: s.time for s in t_batch.samples.started}
        segments = tuple(NewSegment(int(valid[s.target]), s.time,
                                    truth_started.get(s.target, s.time), s.key,
                                    values.position[s.target], values.quaternion[s.target])
                         for s in m_batch.samples.started)
        self.segments += len(segments)
        label_m = m_batch.segment[m_rows] if self.per_segment else 0
        label_t = t_batch.segment[t_rows] if self.per_segment else 0
        ok_m, ok_t = m_checked.accepted, t_checked.accepted
        self.tracker.add_measured(m_checked.time[ok_m], m_checked.position[ok_m],
                                  m_checked.quaternion[ok_m], label_m)
        self.tracker.add_truth(t_checked.time[ok_t], t_checked.position[ok_t],
                               t_checked.quaternion[ok_t], label_t)
        self.truth_seen = self.truth_seen or bool(t_rows.size)
        self.readings.add(m_checked.time[ok_m], m_checked.position[ok_m],
                          m_checked.quaternion[ok_m],
                          None if measured.covariance is None else measured.covariance[m_rows],
                          in_force + np.searchsorted(registered, measured.rank[m_rows]))
        new = self.measured.visits[before:]
        covariances = self.readings.covariance_of(new, self.registrations)
        judged = judge_visits(new, self.tolerances, covariances)
        self._stabilise(new, covariances)
        self.readings.drop_before(self.measured.open_since())
        self.verdicts.extend(judged)
        self.covariances.extend(covariances)
        verdict_of = {id(v): j for v, j in zip(new, judged, strict=True)}
        verdicts = tuple((r, verdict_of[id(v)]) for r, v in m_batch.samples.visits)
        closed = tuple((int(valid[k]), v, verdict_of[id(v)]) for k, v in m_batch.samples.closed)
        m_batch = PoseBatch(m_batch.samples, m_batch.segment, m_batch.ignored, verdicts)
        ranked = sorted([(int(targets.rank[i]), x) for i, x in targets_ignored]
                        + [(int(measured.rank[i]), x) for i, x in m_batch.ignored]
                        + [(int(truth.rank[i]), x) for i, x in t_batch.ignored]
                        + ends_ignored + registrations_ignored,
                        key=lambda item: item[0])
        self.ignored.extend(x for _, x in ranked)
        return Fed(tuple(targets_ignored), segments, m_batch, t_batch, closed)

    def target(self, stamp: float, frame: str, position: ArrayLike,
               quaternion: ArrayLike) -> Ignored | None:
        """One /positioner/target message; None when it was taken (even if it repeats the
        current target)."""
        fed = self.feed(targets=PoseMessages.one(stamp, frame, position, quaternion))
        return fed.targets_ignored[0][1] if fed.targets_ignored else None

    def measurement(self, stamp: float, frame: str, position: ArrayLike,
                    quaternion: ArrayLike, covariance: ArrayLike | None = None
                    ) -> Measured | Ignored:
        """One /metrology/pose message (``covariance``: the 36 values it states, or None):
        the update and the verdict of a visit it settled."""
        batch = self.feed(measured=PoseMessages.one(stamp, frame, position, quaternion,
                                                    covariance)).measured
        if batch.ignored:
            return batch.ignored[0][1]
        return Measured(batch.samples.update(0), batch.verdicts[0][1] if batch.verdicts
                        else None)

    def truth(self, stamp: float, frame: str, position: ArrayLike,
              quaternion: ArrayLike) -> SampleUpdate | Ignored:
        """One /sim/platform/true_pose message: the truth accumulator's update."""
        batch = self.feed(truth=PoseMessages.one(stamp, frame, position, quaternion)).truth
        if batch.ignored:
            return batch.ignored[0][1]
        return batch.samples.update(0)

    def registration(self, stamp: float, frame: str, position: ArrayLike,
                     quaternion: ArrayLike, covariance: ArrayLike) -> Ignored | None:
        """One /metrology/registration message (the tracker's origin in ``base``, its
        orientation, the 36 values of its covariance); None when it was taken."""
        count = len(self.ignored)
        self.feed(registrations=PoseMessages.one(stamp, frame, position, quaternion,
                                                 covariance))
        return self.ignored[-1] if len(self.ignored) > count else None

    def move_end(self, stamp: float) -> Ignored | None:
        """One move end (the stamp of a ``positioner: state`` status :func:`move_ended`
        accepts); None when it was taken."""
        count = len(self.ignored)
        self.feed(ends=MoveEnds.one(stamp))
        return self.ignored[-1] if len(self.ignored) > count else None

    def finish(self) -> tuple[tuple[Visit, Verdict], ...]:
        """The end of the stream (a bag's end): each accumulator's open segment closed on its
        last stable window as a next target would; the measured visit closed, with its
        verdict."""
        self.truth_accumulator.finish()
        visit = self.measured.finish()
        if visit is None:
            return ()
        covariance = self.readings.covariance_of([visit], self.registrations)
        verdict = judge_visits([visit], self.tolerances, covariance)[0]
        self._stabilise([visit], covariance)
        self.readings.drop_before(math.inf)
        self.verdicts.append(verdict)
        self.covariances.append(covariance[0])
        return ((visit, verdict),)

    def _stabilise(self, visits: Sequence[Visit], covariances: FloatArray) -> None:
        """The stabilisation and path of newly settled ``visits`` (:attr:`stabilisations`,
        :attr:`paths`)."""
        found = self.readings.stabilisation_of(visits, covariances,
                                                self.settings.stabilisation)
        self.stabilisations.extend(found)
        self._stabilised.update(zip(visits, found, strict=True))
        if not visits:
            return
        starts = [self._moved_from, *(v.commanded_position for v in visits[:-1])]
        paths = self.readings.paths_of(visits, starts)
        self.paths.extend(paths)
        self._paths.update(zip(visits, paths, strict=True))
        self._moved_from = visits[-1].commanded_position

    def visit_values(self, visit: Visit) -> dict[str, str]:
        """What a verdict's status says of ``visit`` beside the verdict (for people): the ISO
        9283 figures of its pose (:meth:`figures_of`), its own stabilisation time and
        overshoot (:func:`~positioning_cell.accuracy.stabilisation.stabilisation_values`) and
        its path's largest deviation from the commanded line, m (``path_deviation``:
        :meth:`~positioning_cell.accuracy.path.PathCrossings.deviation`; nan: no path)."""
        figure = self._stabilised.get(visit, Stabilisation.none())
        path = self._paths.get(visit)
        deviation = math.nan if path is None else path.deviation()
        return {**self.figures_of(visit), **stabilisation_values(figure),
                'path_deviation': f'{deviation:.7f}'}

    def figures_of(self, visit: Visit) -> dict[str, str]:
        """The ISO 9283 figures (for people) of the pose that ``visit`` is a visit of."""
        return next(f for f in self.measured.result().poses if f.key == visit.key).for_people()

    def reset(self) -> None:
        """Forget every sample, visit, pairing and verdict; the current target stays."""
        self.measured.reset(keep_target=True)
        self.truth_accumulator.reset(keep_target=True)
        self.tracker.reset()
        self.truth_seen = False
        self.verdicts, self.covariances, self.stabilisations = [], [], []
        self._stabilised, self.paths, self._paths = {}, [], {}
        self.readings = Readings()

    def report(self) -> dict[str, Any]:
        """The JSON document of /accuracy_monitor/report (SI: m, rad, s): ``tolerances``,
        ``settle`` (settings), ``target`` (current one or null, with the ``move_end`` time
        reported for it or null), ``verdicts`` (counts ok / error, the errors as measured
        against the tolerances), ``decisions`` (counts of each decision by the rule in force
        when each was drawn: ``conforms``, ``indeterminate``, ``does_not_conform``),
        ``measured`` and ``truth`` (settled ``visits`` and ISO 9283 ``poses``; truth
        null until a true pose arrives), ``tracker`` (measured − true statistics, or null)."""
        target = self.measured.target
        stats = self.tracker.statistics()
        ok = sum(v.ok for v in self.verdicts)
        return {
            'tolerances': {'position': self.tolerances.position,
                           'orientation': self.tolerances.orientation,
                           'decision_rule': self.tolerances.decision_rule},
            'settle': self.measured.settings.to_params(),
            'target': None if target is None else {
                'time': target[0], 'position': target[1].tolist(),
                'quaternion': target[2].tolist(), 'key': target[3],
                'move_end': self.measured.move_end},
            'verdicts': {'ok': ok, 'error': len(self.verdicts) - ok},
            'decisions': decision_counts(self.verdicts),
            'measured': self.measured.result().to_dict(),
            'truth': self.truth_accumulator.result().to_dict() if self.truth_seen else None,
            'tracker': None if stats is None else stats.to_dict(),
        }
