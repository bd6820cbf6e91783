"""The positioner's move state machine, without ROS: goals validated, paths planned and checked,
trajectories sent to the drives and their answers awaited, arrival watched, the closed loop on
the tracker run, the pose estimated from the encoders, the drives referenced.

The mover reaches the outside world only through :class:`Machine`, a set of callables (send a
trajectory, stop the drives, read the newest joint state, take the tracker readings and the
drives' answers that came in, ask for referencing, report, the clock), so its whole state
machine runs in a unit test without DDS. Poses are in the ``base`` frame: positions (3,) m,
unit quaternions (4,) x, y, z, w; joints in JOINT_NAMES order.

A move (:meth:`Mover.move`) goes IDLE → MOVING → SETTLING (→ CORRECTING → MOVING … in
``measured`` mode) → SETTLED, and succeeds only within its tolerance. Before anything moves it
may be refused (a bad goal, a limit, drives off, in fault, not referenced, silent, busy: the
state does not change, the refusal is reported); once the drives were commanded, every abort
stops them (stop, drive fault, drives disabled, no joint states, an encoder frozen or not a
number, the drives refusing the trajectory or not answering it, a silent or inconsistent
tracker, a timeout). Compensation modes: ``none`` commands nominal inverse kinematics; ``model``
the configured clearance model; ``measured`` the model, then corrections from averaged tracker
readings until within the goal tolerance or out of iterations (a goal near recently settled
ones starts with their corrections, :meth:`Mover._carried`).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.calibration.calibrated import Calibrated, calibrated_machine
from positioning_cell.clearance import ClearanceModel, attained_pose
from positioning_cell.core.limits import LimitReport
from positioning_cell.core.poses import as_pose_batch, as_vectors
from positioning_cell.errors import InputError, PositioningError
from positioning_cell.metrology.instrument import Registration
from positioning_cell.motion.compensation import Compensation
from positioning_cell.motion.hearing import Hearing
from positioning_cell.motion.rest import RestWatch
from positioning_cell.motion.settings import CompensationMode, GoalTolerance, PositionerSettings
from positioning_cell.motion.standstill import Motion, StandstillWatch
from positioning_cell.motion.watch import FreezeWatch, unreadable_axes
from positioning_cell.moves.correction import (
    Verdict,
    corrected_command,
    correction_offset,
    deviation,
    mean_reading,
    offset_command,
    predicted_offset,
    unread_sigma,
    verdict,
)
from positioning_cell.moves.drive_stops import SILENCE_STOPS, drives_stopped
from positioning_cell.moves.fingerprint import fingerprint
from positioning_cell.moves.machine import Answer, JointReading, Machine, Measurement
from positioning_cell.moves.outcomes import (
    ESTIMATED,
    MEASURED,
    Attained,
    MoveAbortedError,
    MoveResult,
    ResultCode,
    State,
)
from positioning_cell.moves.stopping import (
    JOIN_LEAD,
    joined_late,
    stop_along_path,
    until_stopped,
)
from positioning_cell.moves.timing import AT_ONCE, Timing
from positioning_cell.moves.trajectory import MotionLimits, Trajectory, plan_move, pose_at
from positioning_cell.names import (
    BASE_FRAME,
    DRIVER_ENABLE,
    DRIVER_REFERENCE,
    HOME,
    JOINT_TRAJECTORY,
    MEASURED_POSE,
    NO_CALIBRATION,
    STOP,
    STOP_ALONG_PATH,
    TRAJECTORY_STATUS,
)

FloatArray = NDArray[np.float64]
#: Further limits on a planned path: positions (M, 3) m and quaternions (M, 4) in base → one
#: line per violation (empty: within them).
PathCheck = Callable[[FloatArray, FloatArray], list[str]]
#: A remaining error within this many standard uncertainties of its measurement, in every
#: component, is not corrected (measured mode).
SIGNIFICANCE = 2.0

__all__ = ['Answer', 'Estimate', 'JointReading', 'Machine', 'Measurement', 'MoveAbortedError',
           'MoveResult', 'Mover', 'PathCheck', 'PositionerSettings', 'ResultCode', 'State',
           'joints_arrived', 'validate_goal']


# -- goals and arrival ---------------------------------------------------------------------------
def validate_goal(frame_id: str, position: ArrayLike,
                  quaternion: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """A goal pose as (3,) m and a unit quaternion (4,); InputError names what is wrong (a frame
    other than ``base``, NaN or infinite numbers, a zero or non-unit quaternion)."""
    if frame_id != BASE_FRAME:
        raise InputError(f"goal frame '{frame_id}' is not '{BASE_FRAME}': poses are commanded "
                         f"in the base frame")
    p, q = as_pose_batch(position, quaternion)
    return p[0], q[0]


def joints_arrived(position: ArrayLike, velocity: ArrayLike, target: ArrayLike,
                   position_tolerance: ArrayLike, velocity_tolerance: ArrayLike) -> bool:
    """True when every axis is within its position tolerance of the target and slower than its
    velocity tolerance; all (6,) in joint order (m, rad; m/s, rad/s)."""
    pos = as_vectors(position, 6, 'position')[0]
    vel = as_vectors(velocity, 6, 'velocity')[0]
    tgt = as_vectors(target, 6, 'target')[0]
    return bool(np.all(np.abs(pos - tgt) <= np.asarray(position_tolerance))
                and np.all(np.abs(vel) <= np.asarray(velocity_tolerance)))


# -- the pose estimate ---------------------------------------------------------------------------
class Estimate(NamedTuple):
    """The pose estimate from the encoders: position (3,) m, quaternion (4,), passive angles
    φ (3,) rad of the solution."""

    position: FloatArray
    quaternion: FloatArray
    phis: FloatArray


#: How often a wait re-reads the world and re-checks stop, faults and liveness, s.
POLL_PERIOD = 0.02
#: Tracker readings kept for averaging.
MEASUREMENTS_KEPT = 200
#: Pose estimates kept by encoder reading: at rest the servos hunt a count about their
#: targets, so a few dozen readings recur (65 distinct in 500, changing in 471, ad hoc on the
#: simulated cell); each is solved once while it recurs.
SOLVED_KEPT = 256
#: The model of no estimate solved yet (None is a model: nominal kinematics).
_NOT_SOLVED = object()
#: Settled moves whose corrections a nearby goal starts with (``measured`` mode).
CARRIED_MOVES = 6


def _joints(traj: Trajectory, t: float) -> FloatArray:
    """The commanded joints (6,) of ``traj`` at ``t`` s from its start (held at the ends)."""
    joints = np.hstack([traj.lengths, traj.thetas])
    return np.array([np.interp(t, traj.times, joints[:, i]) for i in range(6)])


class Mover:
    """The positioner's state machine (module docstring). Thread-safe: a move runs in the
    caller's thread (a service callback) while others estimate the pose, stop, or feed the
    driver's status."""

    def __init__(self, settings: PositionerSettings, machine: Machine) -> None:
        self.settings = settings
        self.mech = settings.mechanism
        self.model = settings.clearance_model()
        self.calibration: Calibrated | None = calibrated_machine(settings)  # ConfigError
        self._pending: tuple[str, Calibrated | None] | None = None
        #: The conditions the calibrated machine is compensated under (temperature, approach).
        self.compensation = Compensation(settings.compensation.temperature)
        self.machine = machine
        self.cond = threading.Condition()
        self._tickets = 0  # refreshes begun (_refresh)
        self._joints_ticket = 0  # the ticket of the refresh that stored self.joints
        self._busy = threading.Lock()
        self.joints: JointReading | None = None
        #: What the looks at the joint states and at the tracker's readings found: their
        #: silence is judged from it (motion.hearing), not from the clock alone.
        self.joints_heard, self.tracker_heard = Hearing(), Hearing()
        self.joints_time = -math.inf  # when the stored joint state was taken (clock, s)
        #: State changes reported so far: a command whose count has not moved since it began
        #: has not started (a refusal changes no state), and shows no progress.
        self.state_changes = 0
        #: The code and words of the last command's end or refusal (None: none yet): kept, as
        #: ``cell status`` shows them after the event has passed.
        self.last_code: ResultCode | None = None
        self.last_reason = ''
        self.measurements: list[Measurement] = []
        self.measurement_count = 0
        #: The tracker's newest registration (the readings' common covariance); None: none yet.
        self.registration: Registration | None = None
        self.answers: list[Answer] = []
        self.driver: dict[str, str] = {}
        self.command: tuple[FloatArray, FloatArray] | None = None
        #: The goal of the last move (what it was asked to reach; its command may differ).
        self.goal: tuple[FloatArray, FloatArray] | None = None
        self.estimate: Estimate | None = None
        #: Estimates solved through the model :attr:`_solved_model`, by the encoder reading's
        #: bytes, newest last (at most :data:`SOLVED_KEPT`; emptied when the model changes).
        self._solved: OrderedDict[bytes, Estimate] = OrderedDict()
        self._solved_model: ClearanceModel | object = _NOT_SOLVED
        self._path: list[tuple[FloatArray, FloatArray]] | None = None
        self._motion: tuple[float, Trajectory, FreezeWatch] | None = None
        self._silence_stops = '0'
        self.stop_requested = False
        #: A stop along the path under way (:meth:`stop_along`): the stop trajectory's key, its
        #: last joints and when it must be over (clock s).
        self._stopping: tuple[str, FloatArray, float] | None = None
        self._sent: tuple[float, float] | None = None
        #: The stamp from which tracker readings measure the pose the last motion ended at (the
        #: settle dwell's :attr:`RestWatch.still_from`, or the newest encoder reading's stamp
        #: when the dwell ran its whole time), for the next reading only; NaN: not known.
        self._still_from = math.nan
        self._move_limits: tuple[MotionLimits | None, PathCheck | None] = (None, None)
        self.state, self.reason = State.IDLE, 'waiting for encoder readings'
        #: Standstill monitoring (fed while no command runs; armed again after every motion).
        self.standstill = StandstillWatch(settings.standstill)
        self.standstill.arm(machine.clock())
        self._commanding = False
        self._moved = False
        #: False once the machine moved while nothing was commanded, until a move settles.
        self.position_confirmed = True
        #: ``measured``: the averaged reading (position, quaternion, covariance) that ended the
        #: last move, while the machine has not moved since (None otherwise).
        self._verified: tuple[FloatArray, FloatArray, FloatArray] | None = None
        #: ``measured``: the last :data:`CARRIED_MOVES` moves that settled on the tracker, as
        #: (goal position, goal quaternion, correction offset, standard uncertainty (6,) of the
        #: reading it rests on): nearby goals start with them.
        self._carry: list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = []

    # -- inputs ---------------------------------------------------------------------------------
    def reconfigure(self, settings: PositionerSettings) -> None:
        """New dynamic settings (mode, tolerances, limits, the calibration file, ...); the
        a-priori clearance model is read-only. After a change of mode or of calibration the
        next move starts from where the encoders are (the last command's joints under the old
        model are not those of the new one)."""
        with self.cond:
            if settings.mode is not self.settings.mode:
                self.command, self._carry = None, []
            path = settings.compensation.calibration_file
            if path != self.settings.compensation.calibration_file:
                pending = self._pending
                self.calibration = (pending[1] if pending is not None and pending[0] == path
                                    else calibrated_machine(settings))
                self._pending, self.command, self._carry = None, None, []
            self.settings = settings
            self.standstill.settings = settings.standstill
            self.compensation.temperature.settings = settings.compensation.temperature

    def prepare(self, settings: PositionerSettings) -> None:
        """Check new settings before they are accepted: a new calibration file is loaded now
        (CalibrationFileError, a ConfigError, says why it cannot be used; nothing changes)."""
        path = settings.compensation.calibration_file
        if path != self.settings.compensation.calibration_file:
            self._pending = (path, calibrated_machine(settings))

    def air_temperature(self, value: float, variance: float) -> str:
        """A reading of the cell's air temperature (°C, K²) now: '' when taken, else why it
        was refused (the previous reading kept; :mod:`positioning_cell.motion.temperature`)."""
        return self.compensation.temperature.update(value, variance, self.machine.clock())

    def driver_status(self, values: Mapping[str, str]) -> None:
        """The leg driver's latest diagnostic values (state, enabled, referenced, message)."""
        with self.cond:
            self.driver = dict(values)
            self.cond.notify_all()

    def _refresh(self) -> None:
        """Take what came in: the newest joint state, tracker readings and registration, the
        drives' answers. Threads refresh at once (the pose timer and a move's wait), each
        taking part of the inputs outside the lock; a joint state is stored only if no
        refresh that began later has stored one already (a ticket drawn before taking), so
        that the thread that took the older reading cannot store it after the newer one. (It
        did: homing settled 'outside tolerance, estimated error 2000 um' when the axes had
        arrived, test_operator_node in CI.) Taking and storing under one lock instead held
        every refresh up behind the slowest: the in-process fault matrix's uncommanded motion
        was stopped after 1.0-1.3 mm in 3 of 6 trials beside three busy loops (1.8 mm in CI),
        against none of 6 over its bound without that lock. Each take is timed as it begins,
        and whether it found anything is recorded (:class:`Hearing`)."""
        with self.cond:
            self._tickets += 1
            ticket = self._tickets
        joints_looked = self.machine.clock()
        joints = self.machine.latest_joints()
        tracker_looked = self.machine.clock()
        taken = self.machine.new_measurements()
        registration = self.machine.registration()
        answers = self.machine.trajectory_answers()
        now = self.machine.clock()
        with self.cond:
            if registration is not None:
                self.registration = registration
            self.joints_heard.look(joints_looked, joints is not None)
            self.tracker_heard.look(tracker_looked, bool(taken))
            if joints is not None and ticket < self._joints_ticket:
                joints = None  # older than the joint state a later refresh stored
            if joints is not None:
                self._joints_ticket = ticket
                self.joints, self.joints_time = joints, joints_looked
                if self._motion is not None:
                    self._motion[2].reading(joints.position, now)
            if taken:
                self.measurements.extend(taken)
                self.measurement_count += len(taken)
                del self.measurements[:-MEASUREMENTS_KEPT]
            self.answers.extend(answers)
            if not self._commanding:
                self._watch_standstill(joints, taken, now)

    def _watch_standstill(self, joints: JointReading | None, taken: list[Measurement],
                          now: float) -> None:
        """Standstill monitoring of what just came in (called under the lock while no command
        runs): motion found stops the drives at once (:meth:`_uncommanded`)."""
        found: Motion | None = None
        if joints is not None and np.all(np.isfinite(joints.position)):
            found = self.standstill.joints(joints.position, joints.velocity,
                                           self.settings.arrival.speed_tolerance, now)
        for reading in taken:
            found = found or self.standstill.tracker(reading.position, reading.quaternion,
                                                     reading.stamp)
        if found is not None:
            self._uncommanded(found, now)

    def _uncommanded(self, motion: Motion, now: float) -> None:
        """The machine moved while nothing was commanded (under the lock): stop the drives,
        mark the position unconfirmed, plan the next move from the encoders, watch again."""
        self.machine.stop_drives()
        self.command = None
        self._verified = None
        self.position_confirmed = False
        self.standstill.arm(now, self._joints_stamp())
        self._set_state(State.FAULT, f'{motion.reason}; drives stopped, the position is '
                        'unconfirmed: the next move plans from the encoders',
                        ResultCode.UNCOMMANDED_MOTION)

    def _joints_stamp(self) -> float:
        """The stamp of the newest encoder reading (under the lock; NaN: none, or unstamped)."""
        return math.nan if self.joints is None else self.joints.stamp

    @property
    def mode(self) -> CompensationMode:
        """The compensation mode in force."""
        return self.settings.mode

    @property
    def referenced(self) -> bool:
        """The drives report themselves referenced."""
        return self.driver.get('referenced', 'false').lower() == 'true'

    def _model(self, approach: FloatArray | None = None) -> ClearanceModel:
        """The compensation model of the mode: none, the a-priori clearance model, or the
        calibrated machine under the conditions now (``approach``: of the move being
        planned; None: the axes' last)."""
        if self.mode is CompensationMode.NONE:
            return None
        if self.calibration is None:
            return self.model
        return self.compensation.model(self.calibration, self.machine.clock(), approach)

    def _approach_to(self, p: FloatArray, q: FloatArray) -> FloatArray | None:
        """The direction each axis moves in to reach (p, q) from the encoders (None: no
        calibrated machine in use or no reading yet: the axes' last directions stand)."""
        with self.cond:
            joints = self.joints
        if self.mode is CompensationMode.NONE or self.calibration is None or joints is None:
            return None
        return self.compensation.approach_to(self.calibration, p, q, joints.position,
                                             self.machine.clock())

    # -- the pose estimate --------------------------------------------------------------------
    def estimate_pose(self) -> Estimate | None:
        """The platform pose from the newest encoder reading through the compensation model
        (None before the first reading, or FAULT when it has no solution); while a move runs
        it is added to the move's executed path."""
        self._refresh()
        with self.cond:
            joints, previous = self.joints, self.estimate
        if joints is None:
            return None
        bad = unreadable_axes(joints.position)
        if bad:
            self._set_state(State.FAULT, f'encoder reading of {", ".join(bad)} is not a '
                                         'number: no pose estimate', ResultCode.ABORTED_ENCODER)
            return None
        model, reading = self._model(), joints.position.tobytes()
        with self.cond:
            solved = self._solved.get(reading) if self._solved_model is model else None
        if solved is not None:
            estimate = solved  # a reading seen before through the same model: solved already
        else:
            try:
                fk = attained_pose(self.mech, model, joints.position[:3], joints.position[3:],
                                   previous.phis if previous is not None else None)
            except PositioningError as err:
                self._set_state(State.FAULT, f'pose estimate failed: {err}',
                                ResultCode.ABORTED_FAULT)
                return None
            if not fk.converged[0]:
                self._set_state(State.FAULT, 'forward kinematics did not converge for the '
                                             f'encoder readings {joints.position.tolist()}',
                                ResultCode.ABORTED_FAULT)
                return None
            estimate = Estimate(fk.position[0], fk.quaternion[0], fk.phis[0])
        with self.cond:
            self.estimate = estimate
            if self._solved_model is not model:
                self._solved.clear()
                self._solved_model = model
            self._solved[reading] = estimate
            self._solved.move_to_end(reading)
            if len(self._solved) > SOLVED_KEPT:
                self._solved.popitem(last=False)
            if self._path is not None:
                self._path.append((estimate.position, estimate.quaternion))
        if self.state is State.FAULT and self.reason.startswith(('encoder reading',
                                                                 'pose estimate',
                                                                 'forward kinematics')):
            self._set_state(State.IDLE, 'ready: the pose estimate is back')
        if self.state is State.IDLE and self.reason == 'waiting for encoder readings':
            self._set_state(State.IDLE, 'ready')
        return estimate

    # -- commands -------------------------------------------------------------------------------
    def check(self, frame_id: str, position: ArrayLike, quaternion: ArrayLike, *,
              limits: MotionLimits | None = None,
              path_check: PathCheck | None = None) -> Trajectory:
        """The move to a goal, planned and checked without moving (a "virtual move");
        MoveAbortedError says why it would be refused. ``limits``: the speeds to plan with
        (None: the configured ``motion``); ``path_check``: further limits on the planned path
        (:data:`PathCheck`)."""
        goal = self._goal(frame_id, position, quaternion)
        self.ready()
        try:
            return self._checked(self.plan_path(*goal, limits), path_check)
        except MoveAbortedError as err:
            raise self.refusal(err.code, str(err)) from err

    def move(self, frame_id: str, position: ArrayLike, quaternion: ArrayLike,
             tolerance: float = 0.0, *, limits: MotionLimits | None = None,
             path_check: PathCheck | None = None, timing: Timing = AT_ONCE,
             pivot: FloatArray | None = None) -> MoveResult:
        """Move to a goal and return when settled within the tolerance (``tolerance``: the
        settle tolerance in m, 0 for the configured one); MoveAbortedError names the outcome
        otherwise (refused: nothing moved; aborted: the drives were stopped; out of
        tolerance: settled elsewhere). A goal the machine is already settled at within the
        tolerance succeeds without moving. ``limits`` and ``path_check``: as :meth:`check`;
        ``timing``: the motion's least duration and its start (the first trajectory's; a
        start already past when it is sent is refused, nothing moved); ``pivot`` (3,) m: the
        point of the platform (platform frame) the motion carries on a straight line
        (:func:`~positioning_cell.moves.trajectory.plan_move`; None: its origin; the first
        trajectory's, the corrections after it are short)."""
        with self._exclusive():
            goal = self._goal(frame_id, position, quaternion)
            try:
                tol = self.settings.goal_tolerance.for_request(float(tolerance))
            except InputError as err:
                raise self.refusal(ResultCode.REFUSED_INVALID_GOAL, str(err)) from err
            self.ready()
            return self._execute(*goal, tol, limits, path_check, timing, pivot)

    def home(self) -> MoveResult:
        """Reference the drives if they are not, then move to the home pose."""
        with self._exclusive():
            self.ready(homing=True)
            if not self.referenced:
                with self.cond:
                    self._moved = True  # a referencing run moves the axes
                if not self.machine.reference_drives():
                    raise self.refusal(ResultCode.REFUSED_DRIVER_SILENT,
                                        f'the drives cannot be referenced: {DRIVER_REFERENCE} '
                                        'is not available')
                self._set_state(State.HOMING, 'referencing the drives')
                try:
                    self._wait(lambda: self.referenced, self.settings.liveness.homing_timeout,
                               'the drives to be referenced')
                except MoveAbortedError as err:
                    self.machine.stop_drives()
                    self._set_state(State.ABORTED, str(err), err.code)
                    raise
            return self._execute(self.mech.home_position, self.mech.home_quaternion,
                                 self.settings.goal_tolerance, None, None)

    def stop(self) -> str:
        """Stop now: the drives decelerate under control; a running move ends aborted (also
        one stopping along its path: it no longer waits for that stop's end)."""
        with self.cond:
            self.stop_requested, self._stopping = True, None
            self.machine.stop_drives()
            self.cond.notify_all()
        return 'stopping with controlled deceleration'

    def stop_along(self, start: float, duration: float) -> str:
        """Stop the running move along its path (:mod:`positioning_cell.moves.stopping`): from
        ``start`` (ROS time s, the drives' clock) its time law slows to rest over ``duration``
        s, sent to the drives as a trajectory starting then; the move ends aborted (stopped)
        once the axes rest at the stop's end (or at once, the drives stopped as by
        :meth:`stop`, when they refuse it or it is not over in time). Heard too late to start
        then, to the same point of the path, sooner
        (:func:`~positioning_cell.moves.stopping.joined_late`). Without a running trajectory,
        or too late for that: :meth:`stop`.
        InputError for a duration that is not a positive number of seconds (nothing
        changes)."""
        if not (math.isfinite(duration) and duration > 0.0):
            raise InputError(f'duration = {duration!r}: a stop needs a positive number of '
                             'seconds')
        with self.cond:
            joined = joined_late(start, duration, self.machine.wall_clock() + JOIN_LEAD)
            if self._motion is None or joined is None or self._stopping is not None:
                return self.stop()
            start, duration = joined
            delay = start - self.machine.wall_clock()
            sent, traj, _ = self._motion
            start_at = self.machine.clock() + delay
            stop = stop_along_path(traj, start_at - sent, duration)
            joints = np.hstack([stop.lengths, stop.thetas])
            live = self.settings.liveness
            counts = np.array([live.linear_count] * 3 + [live.rotary_count] * 3)
            self._motion = (sent, until_stopped(traj, start_at - sent, stop),
                            FreezeWatch(live.freeze_window, live.freeze_motion, counts, sent))
            self._stopping = (fingerprint(stop.times, joints), joints[-1],
                              start_at + duration + self.settings.arrival.timeout)
            self.stop_requested = True
            self.machine.send_trajectory(stop, start)
            self.cond.notify_all()
        return f'stopping along the path in {delay + duration:.2f} s'

    @property
    def busy(self) -> bool:
        """A command (move, homing, jog) is running."""
        return self._busy.locked()

    def setpoint(self) -> tuple[FloatArray, FloatArray] | None:
        """Where the running trajectory commands the platform now (position (3,) m,
        quaternion (4,) in base; :func:`~positioning_cell.moves.trajectory.pose_at`); None
        when none runs (the watch then judges against the goal)."""
        with self.cond:
            motion = self._motion
        if motion is None:
            return None
        sent, traj, _ = motion
        return pose_at(traj, self.machine.clock() - sent)

    def progress(self) -> float:
        """0..1: the share of the running trajectory's duration elapsed (0 while a move is
        about to send one, 1 when none runs)."""
        with self.cond:
            sent = self._sent
        if sent is None or sent[1] <= 0.0:
            return 0.0 if sent is None and self.state is State.MOVING else 1.0
        return float(min(max((self.machine.clock() - sent[0]) / sent[1], 0.0), 1.0))

    def jog(self, times: FloatArray, joints: FloatArray) -> JointReading:
        """Run a joint-space trajectory outside the kinematics (times (K,) s, joints (K, 6) m /
        rad from where the encoders are; :mod:`positioning_cell.limits.jog` makes it within
        the axis ranges): refused like a move when the world is not ready, except that the
        drives need not be referenced; aborted (drives stopped) like a move. The next move
        plans from where the encoders are. Returns the encoder reading at the end."""
        with self._exclusive():
            self.ready(homing=True)
            rates = np.gradient(joints, times, axis=0) if len(times) > 1 else np.zeros_like(joints)
            estimate = self.estimate
            p = np.broadcast_to(estimate.position if estimate else self.mech.home_position,
                                (len(times), 3))
            q = np.broadcast_to(estimate.quaternion if estimate else self.mech.home_quaternion,
                                (len(times), 4))
            traj = Trajectory(np.asarray(times, float), p, q, joints[:, :3], joints[:, 3:],
                              rates[:, :3], rates[:, 3:], LimitReport(len(times), (), 0))
            try:
                self._drive(traj, None)
            except MoveAbortedError as err:
                with self.cond:
                    self._motion, self._sent, self.command = None, None, None
                self.machine.stop_drives()
                self._set_state(State.FAULT if err.code is ResultCode.ABORTED_FAULT
                                else State.ABORTED, f'jog: {err}', err.code)
                raise
            self._set_state(State.IDLE, 'jogged: the next move plans from the encoders',
                            ResultCode.SUCCESS)
            assert self.joints is not None
            return self.joints

    # -- refusals -------------------------------------------------------------------------------
    def attained_now(self) -> Attained | None:
        """Where the platform is, as well as the positioner knows it now: the tracker's newest
        reading if it was heard within ``liveness.tracker_silence`` (:data:`MEASURED`, its
        standard uncertainty), else the encoders' pose estimate through the model
        (:data:`ESTIMATED`, uncertainty not known), else None (no estimate yet). For the
        outcome of a move that did not settle (refused, stopped, aborted)."""
        estimate = self.estimate_pose()  # also takes the newest readings
        with self.cond:
            live = self.settings.liveness
            heard = self.machine.clock() - self.tracker_heard.heard_at <= live.tracker_silence
            newest = self.measurements[-1] if self.measurements and heard else None
        if newest is not None:
            return Attained(np.asarray(newest.position, dtype=float),
                            np.asarray(newest.quaternion, dtype=float), MEASURED,
                            np.sqrt(np.diag(newest.covariance)))
        if estimate is None:
            return None
        return Attained(estimate.position, estimate.quaternion, ESTIMATED)

    def refusal(self, code: ResultCode, reason: str) -> MoveAbortedError:
        """Report a refusal (every time; the state does not change) and make its error."""
        self.last_code, self.last_reason = code, reason
        self.machine.refused(code, reason)
        return MoveAbortedError(code, reason)

    def _exclusive(self) -> _Exclusive:
        return _Exclusive(self)

    def _goal(self, frame_id: str, position: ArrayLike,
              quaternion: ArrayLike) -> tuple[FloatArray, FloatArray]:
        try:
            return validate_goal(frame_id, position, quaternion)
        except InputError as err:
            raise self.refusal(ResultCode.REFUSED_INVALID_GOAL, str(err)) from err

    def ready(self, *, homing: bool = False) -> None:
        """Refuse when the world is not ready for motion: no or silent joint states, drives
        not connected or bound to another commander, drives off or in fault, not referenced
        (homing references), no pose estimate, a silent tracker in ``measured`` mode. Inputs
        never seen yet (a positioner just started beside a running driver) are waited for up
        to ``liveness.discovery_timeout`` first; inputs that went silent are refused at
        once."""
        self._await_inputs()
        live = self.settings.liveness
        self._await_fresh_inputs()
        with self.cond:
            silence = self.joints_heard.silence()
            driver, estimate = dict(self.driver), self.estimate
        if self.joints is None or silence > live.joint_silence:
            raise self.refusal(ResultCode.REFUSED_DRIVER_SILENT,
                                'leg driver not responding: no /legs/joint_states for '
                                + ('ever' if self.joints is None else f'{silence:.2f} s'))
        if not self.machine.drives_connected():
            raise self.refusal(ResultCode.REFUSED_DRIVER_SILENT,
                                f'leg driver not connected: no subscriber on {JOINT_TRAJECTORY} '
                                f'or no publisher on {TRAJECTORY_STATUS} yet')
        bound, me = driver.get('commander', ''), self.machine.identity
        if me and bound and bound != me:
            raise self.refusal(ResultCode.REFUSED_NOT_COMMANDER,
                                f'the leg driver takes commands only from {bound}, not from '
                                f'this positioner ({me}): its command.commander names another '
                                'node')
        if not self._driver_hears_me(driver):
            raise self.refusal(ResultCode.REFUSED_DRIVER_SILENT,
                                "leg driver not connected: it has not discovered this "
                                f"positioner's publisher on {JOINT_TRAJECTORY} yet")
        if driver.get('enabled', 'true').lower() == 'false':
            raise self.refusal(ResultCode.REFUSED_DRIVES_OFF,
                                f'drives disabled: enable them with {DRIVER_ENABLE}')
        if driver.get('state') == 'fault':
            raise self.refusal(ResultCode.REFUSED_DRIVE_FAULT,
                                f'drive fault: {driver.get("message", "")}; clear it with '
                                f'{DRIVER_ENABLE}')
        if not homing and not self.referenced:
            raise self.refusal(ResultCode.REFUSED_NOT_REFERENCED,
                                f'axes not referenced: home them first ({HOME})')
        if estimate is None and self.command is None:
            raise self.refusal(ResultCode.REFUSED_NO_ESTIMATE,
                                'no pose estimate from the encoders yet')
        tracker_silence = self.tracker_heard.silence()
        if self.mode is CompensationMode.MEASURED and tracker_silence > live.tracker_silence:
            raise self.refusal(ResultCode.REFUSED_TRACKER_SILENT,
                                f'laser tracker not responding: no {MEASURED_POSE} for '
                                + ('ever' if math.isinf(tracker_silence)
                                   else f'{tracker_silence:.2f} s')
                                + ' (the measured mode needs it)')

    def _driver_hears_me(self, driver: dict[str, str]) -> bool:
        """The driver's status says it has discovered this positioner's trajectory publisher:
        by its GIDs where both sides give them (value ``commander_publishers``), else by name
        (``commander_seen``). By name alone, a positioner restarted within the middleware's
        lease of its killed predecessor is "seen" before the driver can hear it, and its first
        trajectory is lost (fault matrix: "positioner killed"). Values arrive as words
        (``str(True)``)."""
        if driver.get('commander_seen', '').lower() == 'false':
            return False
        mine, listed = self.machine.publisher_ids(), driver.get('commander_publishers')
        return not mine or listed is None or mine <= set(listed.split())

    def _unseen(self) -> bool:
        """Some input of :meth:`ready` has never been seen yet (called under the lock)."""
        driver = self.driver
        return (self.joints is None or not driver or not self._driver_hears_me(driver)
                or (self.estimate is None and self.command is None)
                or (self.mode is CompensationMode.MEASURED
                    and math.isinf(self.tracker_heard.heard_at))
                or not self.machine.drives_connected())

    def _await_fresh_inputs(self) -> None:
        """Before motion, when the newest joint state is older than ``liveness.joint_silence``
        or, in ``measured`` mode, the newest tracker reading older than
        ``liveness.tracker_silence``: give that input as long again to show it is alive. A
        driver or a tracker (or this process) held up for a moment by a loaded machine is not
        a silent one, and nothing moves meanwhile; one still silent after it is refused
        (:meth:`ready`). (A measured move of ``make run`` was refused once for a tracker silent
        1.47 s that the recorder heard every 50 ms throughout.)"""
        live = self.settings.liveness
        measuring = self.mode is CompensationMode.MEASURED
        window = max(live.joint_silence, live.tracker_silence if measuring else 0.0)
        deadline = self.machine.clock() + window
        while True:
            self._refresh()
            with self.cond:
                now = self.machine.clock()
                fresh = (self.joints_heard.silence() <= live.joint_silence
                         and (not measuring
                              or self.tracker_heard.silence() <= live.tracker_silence))
                if fresh or now >= deadline:
                    return
                self.cond.wait(min(deadline - now, POLL_PERIOD))

    def _await_inputs(self) -> None:
        """Wait (bounded by ``liveness.discovery_timeout``) until every input has been seen
        once: the first joint state, the driver's status naming this positioner seen, the
        driver matched both ways, a pose estimate, in ``measured`` mode a tracker reading."""
        deadline = self.machine.clock() + self.settings.liveness.discovery_timeout
        while True:
            self._refresh()
            with self.cond:
                remaining = deadline - self.machine.clock()
                if remaining <= 0.0 or not self._unseen():
                    return
                self.cond.wait(min(remaining, POLL_PERIOD))

    def plan_path(self, p: FloatArray, q: FloatArray, limits: MotionLimits | None = None,
                  duration: float = 0.0, pivot: FloatArray | None = None) -> Trajectory:
        """The move from the last command (or, after an abort, from where the encoders are)
        to (p, q) (3,) m, (4,) in base, planned with ``limits`` (None: the configured
        ``motion``), lasting at least ``duration`` s, its ``pivot`` (3,) m (platform frame;
        None: the origin) on a straight line, but not judged: its ``limits`` report says what
        it violates.
        MoveAbortedError REFUSED_NO_ESTIMATE before the first encoder reading."""
        with self.cond:
            command = self.command
        if command is None:
            estimate = self.estimate_pose()  # where the encoders are now
            if estimate is None:
                raise MoveAbortedError(ResultCode.REFUSED_NO_ESTIMATE,
                                       'no pose estimate from the encoders yet')
            command = (estimate.position, estimate.quaternion)
        return plan_move(self.mech, *command, p, q, period=self.settings.trajectory.period,
                         limits=limits or self.settings.motion,
                         clearance=self._model(self._approach_to(p, q)), duration=duration,
                         pivot=pivot)

    def _checked(self, traj: Trajectory, path_check: PathCheck | None) -> Trajectory:
        """``traj`` if it violates no limit (the mechanism's, then ``path_check``'s, then the
        most points the drives take, as their status says); MoveAbortedError REFUSED_LIMITS
        naming what it violates."""
        if not traj.limits.ok:
            raise MoveAbortedError(ResultCode.REFUSED_LIMITS, _refused_path(traj.limits))
        most = int(self.driver.get('max_points', '0') or 0)
        if most and traj.times.size > most:
            raise MoveAbortedError(
                ResultCode.REFUSED_LIMITS, f'path refused, {traj.times.size} trajectory points '
                f'({traj.duration:.1f} s): the leg driver takes at most {most} '
                '(its command.max_points): move in shorter steps')
        violations = path_check(traj.position, traj.quaternion) if path_check else []
        if violations:
            raise MoveAbortedError(ResultCode.REFUSED_LIMITS,
                                   'path refused, ' + '; '.join(violations[:3])
                                   + (f' (+{len(violations) - 3} more)'
                                      if len(violations) > 3 else ''))
        return traj

    def _plan(self, p: FloatArray, q: FloatArray, duration: float = 0.0,
              pivot: FloatArray | None = None) -> Trajectory:
        """The checked move to (p, q) with the running move's speeds and path check, lasting
        at least ``duration`` s, about ``pivot`` (:meth:`plan_path`)."""
        limits, path_check = self._move_limits
        return self._checked(self.plan_path(p, q, limits, duration, pivot), path_check)

    # -- the move -------------------------------------------------------------------------------
    def _execute(self, p: FloatArray, q: FloatArray, tol: GoalTolerance,
                 limits: MotionLimits | None, path_check: PathCheck | None,
                 timing: Timing = AT_ONCE, pivot: FloatArray | None = None) -> MoveResult:
        self._move_limits = (limits, path_check)
        command = self._carried(p, q)
        try:  # refused before anything is announced or moved
            try:
                first = self._plan(*command, timing.duration, pivot)
            except MoveAbortedError:
                if command[0] is p:
                    raise
                command = (p, q)  # the goal itself, without the carried correction
                first = self._plan(p, q, timing.duration, pivot)
            late = timing.late(self.machine.wall_clock())
            if late is not None:
                raise MoveAbortedError(ResultCode.REFUSED_INVALID_GOAL, late)
        except MoveAbortedError as err:
            raise self.refusal(err.code, str(err)) from err
        with self.cond:
            self._path = []
        moved = False
        try:
            self.machine.publish_target(p, q)
            self.goal = (p, q)
            there = self._already_there(p, q, tol)
            if there is not None:
                self._set_state(State.SETTLED, there[0], ResultCode.SUCCESS)
                return MoveResult(np.empty((0, 3)), np.empty((0, 4)), *there)
            moved = True
            self._go(*command, first, timing.start)
            sigma: FloatArray | None = None
            source = MEASURED if self.mode is CompensationMode.MEASURED else ESTIMATED
            if source == MEASURED:
                e_p, e_r, reason, sigma = self._correct(command, p, q, tol)
            else:
                e_p, e_r, reason, sigma = self._check_estimate(p, q, tol)
        except MoveAbortedError as err:
            with self.cond:
                self.command = None  # the axes stopped somewhere else: re-plan from them
                self._motion, self._sent = None, None
            if moved and err.code is not ResultCode.OUT_OF_TOLERANCE:
                self.machine.stop_drives()
            self._set_state(State.FAULT if err.code is ResultCode.ABORTED_FAULT
                            else State.ABORTED, str(err), err.code)
            raise
        finally:
            with self.cond:
                path, self._path = self._path or [], None
            self._move_limits = (None, None)
        self.position_confirmed = True
        reason += self._warnings(p, q)
        self._set_state(State.SETTLED, reason, ResultCode.SUCCESS)
        return MoveResult(np.array([x[0] for x in path]).reshape(-1, 3),
                          np.array([x[1] for x in path]).reshape(-1, 4), reason, e_p, e_r, sigma,
                          source)

    def status_values(self, code: ResultCode | None) -> dict[str, object]:
        """The positioner's state for its diagnostics (``code``: of the move that just ended,
        if any), the last command's code and words however long ago it ended, referenced,
        position confirmed, calibration, and whether the tracker's registration (the readings'
        common covariance) was received."""
        return {'state': self.state.value, 'reason': self.reason, 'mode': self.mode.value,
                'code': code.value if code else '',
                'last_code': self.last_code.value if self.last_code else '',
                'last_reason': self.last_reason, 'progress': round(self.progress(), 3),
                'referenced': self.referenced,
                'position_confirmed': self.position_confirmed,
                'calibration': self.settings.compensation.calibration_file or NO_CALIBRATION,
                'tracker_registration': 'received' if self.registration is not None
                else 'none (the readings\' common part told by their scatter)'}

    def compensation_report(self) -> tuple[str, str, dict[str, str]]:
        """(level, message, values) of the conditions the compensation works under
        (:meth:`Compensation.report`)."""
        calibrated = self.calibration if self.mode is not CompensationMode.NONE else None
        return self.compensation.report(calibrated, self.machine.clock())

    def _warnings(self, p: FloatArray, q: FloatArray) -> str:
        """What the move's outcome adds about its compensation: '' or '; warning: ...'
        (outside the calibration's envelope, a stale or nominal temperature)."""
        calibrated = self.calibration if self.mode is not CompensationMode.NONE else None
        found = self.compensation.judge(calibrated, self.mech, self.settings.payload.mass, p,
                                        q, self.machine.clock())
        return ''.join(f'; warning: {w}' for w in found)

    def _already_there(self, p: FloatArray, q: FloatArray, tol: GoalTolerance
                       ) -> tuple[str, FloatArray, FloatArray, FloatArray | None, str] | None:
        """When the machine is settled at its last command and the goal is within ``tol`` of
        where it is (the encoders' estimate; the tracker's in ``measured`` mode): (words,
        Δp, rotation error, uncertainty, source) of a move that need not move; else None."""
        with self.cond:
            at_rest = self.state is State.SETTLED and self.command is not None
        if not at_rest:
            return None
        sigma: FloatArray | None = None
        if self.mode is CompensationMode.MEASURED:
            with self.cond:
                verified = self._verified
            if verified is not None and self._verdict(*verified, p, q, tol) is Verdict.OUTSIDE:
                return None  # the reading that ended the last move puts the goal out of reach
            m_p, m_q, cov = self._measure(lambda mp, mq, c, _: self._verdict(mp, mq, c, p, q,
                                                                            tol)
                                          is not Verdict.UNDECIDED)
            e_p, e_r = deviation(m_p, m_q, p, q)
            sigma = np.sqrt(np.diag(cov))
            what = 'measured error'
        else:
            estimate = self.estimate_pose()
            if estimate is None:
                return None
            e_p, e_r = deviation(estimate.position, estimate.quaternion, p, q)
            what = 'estimated error'
        if not tol.holds(e_p, e_r):
            return None
        if sigma is not None:
            with self.cond:
                self._verified = (m_p, m_q, cov)
        # self.command stays the command that got the machine here (in measured mode the
        # corrected one, not the goal): the next move starts where the axes are
        return (f'already within tolerance, not moved: {_error_text(e_p, e_r, what)}', e_p, e_r,
                sigma, MEASURED if what.startswith(MEASURED) else ESTIMATED)

    def _check_estimate(self, p: FloatArray, q: FloatArray, tol: GoalTolerance
                        ) -> tuple[FloatArray, FloatArray, str, FloatArray | None]:
        """``none`` / ``model``: the pose the encoders show (through the model) must be within
        the tolerance of the goal. In ``model`` mode with a calibration file, the result
        states the calibration's uncertainty at the goal under the conditions in use
        (:meth:`Compensation.uncertainty`); else none."""
        estimate = self.estimate_pose()
        if estimate is None:
            raise MoveAbortedError(ResultCode.ABORTED_FAULT, f'no pose estimate: {self.reason}')
        e_p, e_r = deviation(estimate.position, estimate.quaternion, p, q)
        text = _error_text(e_p, e_r, 'estimated error')
        sigma = None
        if self.mode is CompensationMode.MODEL and self.calibration is not None:
            sigma = self.compensation.uncertainty(self.calibration, p, q, self.machine.clock())
        if sigma is not None:
            text += f' ± {_sigma_text(sigma)} (1 sigma, the calibration\'s)'
        if not tol.holds(e_p, e_r):
            raise MoveAbortedError(ResultCode.OUT_OF_TOLERANCE,
                                   f'settled outside tolerance: {text}',
                                   Attained(estimate.position, estimate.quaternion, ESTIMATED,
                                            sigma))
        return e_p, e_r, f'settled within tolerance: {text}', sigma

    def _correct(self, command: tuple[FloatArray, FloatArray], p: FloatArray, q: FloatArray,
                 tol: GoalTolerance) -> tuple[FloatArray, FloatArray, str, FloatArray]:
        """``measured``: the closed loop on the tracker until within ``tol``. A remaining error
        that no component of exceeds :data:`SIGNIFICANCE` standard uncertainties of the
        averaged measurement is not corrected (that would chase noise): within tolerance it is
        a success, else out of tolerance, as is running out of iterations. A start with carried
        corrections (:meth:`_carried`) that lands within tolerance but with a significant error
        is corrected once (a correction from the model would land closer). A reading may end
        early (``min_samples``) once no reading still to come could make the average leave
        the tolerance (:meth:`_holds_whatever_follows`); not the first reading of a carried
        start, whose significance decides whether to correct. The result states the measured
        error with its uncertainty."""
        iterations = self.settings.compensation.max_iterations
        carried = (' (started with the last move\'s correction)'
                   if command[0] is not p else '')
        for done in range(iterations + 1):
            self._set_state(self.state, f'measuring: up to {self.settings.compensation.samples}'
                            f' readings on {MEASURED_POSE}')
            m_p, m_q, cov = self._measure(None if carried and done == 0 else partial(
                self._holds_whatever_follows, p=p, q=q, tol=tol))
            e_p, e_r = deviation(m_p, m_q, p, q)
            sigma = np.sqrt(np.diag(cov))
            text = (_error_text(e_p, e_r, 'measured error') + f' ± {_sigma_text(sigma)} (1 '
                    f'sigma) after {done} corrections{carried}')
            significant = bool(np.any(np.abs(np.concatenate([e_p, e_r])) > SIGNIFICANCE * sigma))
            # a carried start is kept only where a correction could not improve it
            if tol.holds(e_p, e_r) and not (carried and done == 0 and significant):
                with self.cond:
                    self._verified = (m_p, m_q, cov)
                    self._carry = [*self._carry[1 - CARRIED_MOVES:],
                                   (p, q, correction_offset(*command, m_p, m_q), sigma)]
                return e_p, e_r, f'settled within tolerance: {text}', sigma
            judged = Attained(m_p, m_q, MEASURED, sigma)
            if not significant:
                raise MoveAbortedError(
                    ResultCode.OUT_OF_TOLERANCE, f'settled outside tolerance: {text}; the '
                    f'error is within {SIGNIFICANCE:g} sigma of the measurement, a correction '
                    'would be noise', judged)
            if done == iterations:
                raise MoveAbortedError(ResultCode.OUT_OF_TOLERANCE,
                                       f'settled outside tolerance: {text}', judged)
            self._set_state(State.CORRECTING, f'{text}: correcting')
            command = corrected_command(*command, p, q, m_p, m_q)
            self._go(*command)
        raise AssertionError('unreachable')

    def _carried(self, p: FloatArray, q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The first command of a move to (p, q): in ``measured`` mode, the goal moved by the
        correction expected there from the last moves that settled on the tracker with goals
        within ``compensation.carry_distance`` and ``carry_angle`` of it (the machine's error
        changes little and smoothly over such steps: :func:`predicted_offset`, an affine fit
        over their goals); without such moves, or when no component of that correction
        exceeds :data:`SIGNIFICANCE` times the mean standard uncertainty of their readings (a
        machine the model already fits: carrying would only add the readings' noise), the
        goal."""
        comp = self.settings.compensation
        with self.cond:
            carry = list(self._carry)
        if self.mode is not CompensationMode.MEASURED or comp.carry_distance <= 0.0:
            return p, q
        near = [(g_p, off, sigma) for g_p, g_q, off, sigma in carry
                if np.linalg.norm(g_p - p) <= comp.carry_distance
                and np.linalg.norm(deviation(p, q, g_p, g_q)[1]) <= comp.carry_angle]
        if not near:
            return p, q
        offset = predicted_offset([g for g, _, _ in near], [o for _, o, _ in near], p,
                                  comp.carry_distance)
        noise = np.mean([sigma for _, _, sigma in near], axis=0)
        if not np.any(np.abs(offset) > SIGNIFICANCE * noise):
            return p, q
        return offset_command(p, q, offset)

    def _go(self, p: FloatArray, q: FloatArray, planned: Trajectory | None = None,
            start: float | None = None) -> None:
        """Send the move to (p, q) (to start at ``start``, ROS time s; None: on receipt),
        wait for the drives to accept it, to arrive, to settle."""
        traj = planned if planned is not None else self._plan(p, q)
        with self.cond:
            joints = self.joints
        if joints is not None:  # the direction each axis takes (what the plan was made with)
            self.compensation.moved(np.r_[traj.lengths[-1], traj.thetas[-1]], joints.position)
        self._drive(traj, (p, q), start)

    def _drive(self, traj: Trajectory, command: tuple[FloatArray, FloatArray] | None,
               start: float | None = None) -> None:
        """Send ``traj`` (``command``: the pose it ends at, None for a move outside the
        kinematics; ``start``: when the drives start it, ROS time s, None: on receipt), wait
        for the drives to accept it, to arrive, to settle."""
        joints = np.hstack([traj.lengths, traj.thetas])
        key = fingerprint(traj.times, joints)
        live, arrival = self.settings.liveness, self.settings.arrival
        self._set_state(State.MOVING, f'moving for {traj.duration:.2f} s')
        with self.cond:  # a stop cannot slip in between the check and the send
            if self.stop_requested:
                raise MoveAbortedError(ResultCode.ABORTED_STOP, f'stopped by {STOP}')
            self.command = command
            self._verified = None
            self._still_from = math.nan
            self._moved = True
            self.answers.clear()
            counts = np.array([live.linear_count] * 3 + [live.rotary_count] * 3)
            delay = 0.0 if start is None else max(start - self.machine.wall_clock(), 0.0)
            start_at = self.machine.clock() + delay
            self._motion = (start_at, traj, FreezeWatch(live.freeze_window, live.freeze_motion,
                                                        counts, start_at))
            self._silence_stops = self.driver.get(SILENCE_STOPS, '0')
            self._sent = (self._motion[0], traj.duration)
            self.machine.send_trajectory(traj, start)
        measuring = self.mode is CompensationMode.MEASURED  # the tracker must stay live
        self._wait(lambda: any(a.key == key for a in self.answers), live.answer_timeout,
                   'the leg driver to answer the trajectory', ResultCode.ABORTED_DRIVER_LOST,
                   measuring=measuring)
        answer = next(a for a in self.answers if a.key == key)
        if not answer.accepted:
            raise MoveAbortedError(ResultCode.ABORTED_DRIVER_REFUSED,
                                   f'the drives refused the trajectory: {answer.reason}')
        final = joints[-1]
        # A move with a start ahead has not arrived before its trajectory's end: the axes
        # stand still until the start, and a step within the arrival tolerance would count as
        # arrived at once (a relaxing step of 5 um, its common start 1.5 s ahead, was judged
        # on axes that had not moved yet: 10 um out of tolerance). A move started on receipt
        # runs at once; the settle dwell then waits for the axes within a count of its end.
        judged_from = start_at + traj.duration if start is not None else -math.inf

        def arrived() -> bool:
            reading = self.joints
            return self.machine.clock() >= judged_from and reading is not None and \
                joints_arrived(reading.position, reading.velocity, final,
                               arrival.position_tolerance, arrival.speed_tolerance)

        self._wait(arrived, delay + traj.duration + arrival.timeout, 'the drives to arrive',
                   measuring=measuring)
        with self.cond:
            self._motion = None
            self._sent = None
        self._set_state(State.SETTLING, 'settling')
        deadline = self.machine.clock() + self.settings.settle_time
        rest = RestWatch(final, arrival.settle_tolerance, arrival.settle_window)

        def settled() -> bool:  # under the lock (_wait): at rest, or the longest dwell over
            reading = self.joints
            if reading is not None and rest.reading(reading.position, self.joints_time,
                                                    reading.stamp):
                self._still_from = rest.still_from
                return True
            if self.machine.clock() < deadline:
                return False
            self._still_from = self._joints_stamp()
            return True

        self._wait(settled, self.settings.settle_time + 1.0, 'settling', measuring=measuring)

    def _measure(self, decided: Callable[[FloatArray, FloatArray, FloatArray, FloatArray], bool]
                 | None = None) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The next ``samples`` tracker readings averaged (:func:`mean_reading`; right after
        a motion, by :func:`readings_since` the settle dwell's end: those already in that were
        stamped since it found the axes standing still count too, :class:`RestWatch`, and
        those that come in stamped before it do not): the mean position and rotation, and
        the covariance (6, 6) of that mean, each axis' stated variance split into a part that
        averages down and one common to all (the tracker's registration, when published; else
        told apart by the readings' own scatter) that does not. From ``min_samples`` readings
        on, the average so far ends the wait early when ``decided(mean, quaternion,
        covariance, unread)`` says it settles the question asked (``unread`` (6,): how far the
        full average could still move from it, :func:`unread_sigma`). A tracker that falls
        silent or readings that scatter beyond their stated uncertainty abort."""
        comp = self.settings.compensation
        n, least = comp.samples, min(comp.min_samples, comp.samples)
        with self.cond:  # readings stamped since the axes stood still count already
            since, start = self._still_from, self.measurement_count
            self._still_from = math.nan
        seen, early = [0], [(np.empty(0), np.empty(0), np.empty(0))]

        def fresh() -> list[Measurement]:  # under the lock
            new = min(self.measurement_count - start, len(self.measurements))
            return readings_since(self.measurements, new, since)

        def enough() -> bool:  # under the lock (_wait)
            samples = fresh()
            got = len(samples)
            if got >= n:
                return True
            if decided is None or got < least or got == seen[0]:
                return False
            seen[0] = got
            early[0] = self._averaged(samples)
            unread = unread_sigma([s.covariance for s in samples],
                                  self._common(np.array([s.position for s in samples])), n)
            return decided(*early[0], unread)

        self._wait(enough, self.settings.measurement_timeout,
                   f'{n} new samples on {MEASURED_POSE}', measuring=True)
        with self.cond:
            samples = fresh()
        if len(samples) < n:
            return early[0]
        return self._averaged(samples[-n:])

    def _common(self, positions: FloatArray) -> FloatArray | None:
        """The covariance (6, 6) every reading at ``positions`` (k, 3) m shares: the
        published registration's at their mean (None while none is published)."""
        if self.registration is None:
            return None
        common: FloatArray = self.registration.covariance_at(positions.mean(axis=0))[0]
        return common

    def _averaged(self, samples: list[Measurement]) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:func:`mean_reading` of ``samples``, after checking that they scatter within
        ``liveness.scatter_limit`` times their stated σ (more than two of them; else
        ABORTED_TRACKER_INCONSISTENT)."""
        positions = np.array([s.position for s in samples])
        sigma = np.sqrt(np.mean([np.diag(s.covariance)[:3] for s in samples], axis=0))
        if len(samples) > 2:
            scatter = positions.std(axis=0, ddof=1)
            ratio = float(np.max(scatter / np.maximum(sigma, 1e-12)))
            if ratio > self.settings.liveness.scatter_limit:
                raise MoveAbortedError(
                    ResultCode.ABORTED_TRACKER_INCONSISTENT,
                    f'tracker readings scatter {np.max(scatter) * 1e6:.1f} um, {ratio:.0f}x '
                    'their stated sigma: outliers or a disturbed line of sight')
        return mean_reading(positions, [s.quaternion for s in samples],
                            [s.covariance for s in samples], self._common(positions))

    @classmethod
    def _holds_whatever_follows(cls, m_p: FloatArray, m_q: FloatArray, _cov: FloatArray,
                                unread: FloatArray, *, p: FloatArray, q: FloatArray,
                                tol: GoalTolerance) -> bool:
        """The early end of a reading that decides success: the average so far (m_p, m_q)
        is within ``tol`` of (p, q) even with every component enlarged by
        :data:`SIGNIFICANCE` times ``unread`` (6,), how far the full average could still move
        from it. The full average would then hold too (what success asks of it), though its
        stated uncertainty, the registration's included, may be larger than the tolerance
        allows beyond doubt; the outcome states that uncertainty, of the readings used."""
        return cls._verdict(m_p, m_q, np.diag(unread**2), p, q, tol) is Verdict.WITHIN

    @staticmethod
    def _verdict(m_p: FloatArray, m_q: FloatArray, cov: FloatArray, p: FloatArray,
                 q: FloatArray, tol: GoalTolerance) -> Verdict:
        """What an averaged reading (position, quaternion, covariance) says of the goal (p, q)
        and its tolerance, beyond :data:`SIGNIFICANCE` standard uncertainties (:func:`verdict`)."""
        e_p, e_r = deviation(m_p, m_q, p, q)
        return verdict(e_p, e_r, np.sqrt(np.clip(np.diag(cov), 0.0, None)), tol.position,
                       tol.orientation, SIGNIFICANCE)

    def _wait(self, condition: Callable[[], bool], timeout: float, what: str,
              timeout_code: ResultCode = ResultCode.ABORTED_TIMEOUT, *,
              measuring: bool = False) -> None:
        """Until ``condition()`` holds (checked under the lock after re-reading the world and
        checking it); MoveAbortedError on stop, drive fault or drives off, silent or unreadable
        encoders, an encoder frozen while its axis moves, a silent tracker (``measuring``: the
        whole of a ``measured``-mode move), timeout."""
        deadline = self.machine.clock() + timeout
        while True:
            self._refresh()
            with self.cond:
                self._check_world(measuring)
                if condition():
                    return
                remaining = deadline - self.machine.clock()
                if remaining <= 0:
                    raise MoveAbortedError(timeout_code,
                                           f'timed out after {timeout:.1f} s waiting for {what}')
                self.cond.wait(min(remaining, POLL_PERIOD))

    def _check_world(self, measuring: bool) -> None:
        """The checks of :meth:`_wait` (called under the lock)."""
        now, live, driver = self.machine.clock(), self.settings.liveness, self.driver
        if self.stop_requested and self._stopping is None:
            raise MoveAbortedError(ResultCode.ABORTED_STOP, f'stopped by {STOP}')
        stopped = drives_stopped(driver, None if self._motion is None else self._silence_stops)
        if stopped is not None:
            raise MoveAbortedError(*stopped)
        silence = self.joints_heard.silence()
        if silence > live.joint_silence:
            raise MoveAbortedError(ResultCode.ABORTED_DRIVER_LOST,
                                   f'leg driver not responding: no /legs/joint_states for '
                                   f'{silence:.2f} s')
        bad = unreadable_axes(self.joints.position) if self.joints is not None else []
        if bad:
            raise MoveAbortedError(ResultCode.ABORTED_ENCODER,
                                   f'encoder reading of {", ".join(bad)} is not a number')
        if self._motion is not None:
            sent, traj, watch = self._motion
            motion = _joints(traj, now - sent) - _joints(traj, now - sent - watch.window)
            frozen = watch.frozen(motion, now)
            if frozen:
                name, amount = frozen[0]
                unit, scale = ('mm', 1e3) if name.endswith('length') else ('mrad', 1e3)
                raise MoveAbortedError(
                    ResultCode.ABORTED_ENCODER,
                    f'encoder of {name} frozen: no change for {watch.window:.2f} s while the '
                    f'axis was commanded to move {abs(amount) * scale:.3f} {unit}')
        tracker_silence = self.tracker_heard.silence()
        if measuring and tracker_silence > live.tracker_silence:
            raise MoveAbortedError(ResultCode.ABORTED_TRACKER_LOST,
                                   f'laser tracker not responding: no {MEASURED_POSE} for '
                                   f'{tracker_silence:.2f} s')
        if self._stopping is not None:
            self._check_stop_along(now)

    def _check_stop_along(self, now: float) -> None:
        """The end of a stop along the path (under the lock): MoveAbortedError ABORTED_STOP
        once the axes rest where it ends, or when the drives refused it or it is late (the
        move's abort then stops the drives at once)."""
        assert self._stopping is not None
        key, final, deadline = self._stopping
        answer = next((a for a in self.answers if a.key == key), None)
        why = None
        if answer is not None and not answer.accepted:
            why = f'the drives refused the stop along the path ({answer.reason}): stopped at once'
        elif now > deadline:
            why = 'the stop along the path not over in time: stopped at once'
        elif self.joints is not None and joints_arrived(
                self.joints.position, self.joints.velocity, final,
                self.settings.arrival.position_tolerance, self.settings.arrival.speed_tolerance):
            why = 'stopped along the path'
        if why is not None:
            raise MoveAbortedError(ResultCode.ABORTED_STOP, f'{why} by {STOP_ALONG_PATH}')

    # -- state ----------------------------------------------------------------------------------
    def _set_state(self, state: State, reason: str, code: ResultCode | None = None) -> None:
        changed = (state, reason) != (self.state, self.reason)
        self.state, self.reason = state, reason
        if code is not None:
            self.last_code, self.last_reason = code, reason
        if changed or code is not None:
            self.state_changes += 1
            self.machine.state_changed(state, reason, code)


class _Exclusive:
    """One command at a time: a second one while busy is refused and changes nothing. While
    it runs the standstill watch is not fed; a command that moved the axes arms it again at
    its end. A stop heard before it began is forgotten; one heard from then on, while it
    checks and plans too, ends it (cleared only once the plan was made, a stop during the
    planning was lost and the move ran on)."""

    def __init__(self, mover: Mover) -> None:
        self.mover = mover

    def __enter__(self) -> None:
        m = self.mover
        if not m._busy.acquire(blocking=False):
            raise m.refusal(ResultCode.REFUSED_BUSY, 'busy: a move is in progress')
        with m.cond:
            m._commanding, m._moved = True, False
            m.stop_requested, m._stopping = False, None

    def __exit__(self, *exc: object) -> None:
        m = self.mover
        with m.cond:
            if m._moved:
                m.standstill.arm(m.machine.clock(), m._joints_stamp())
            m._commanding = m._moved = False
        m._busy.release()


def readings_since(readings: Sequence[Measurement], new: int,
                   stamp: float) -> list[Measurement]:
    """The tracker ``readings`` (kept, in the order received; the last ``new`` of them came
    in since a reading began) that measure the platform from ``stamp`` s on: those stamped
    at or after it, whenever they came in, and the unstamped ones among the new (NaN
    ``stamp``: every new one not stamped). A tracker that lags sends readings of where the
    platform was before the last motion after it has ended: by their stamps they are not
    taken. (Taken by arrival they were averaged with those of the pose reached: readings
    "scattering 190 um" aborted homings in CI, as they do in test_mover with a lag.)"""
    old = len(readings) - new
    return [r for k, r in enumerate(readings)
            if r.stamp >= stamp or (k >= old and not r.stamp < stamp)]


def _refused_path(report: LimitReport) -> str:
    return f'path refused, {report.message()}'


def _sigma_text(sigma: FloatArray) -> str:
    """|σ_p| µm, |σ_r| deg of a standard-uncertainty vector (6,)."""
    return (f'{np.linalg.norm(sigma[:3]) * 1e6:.1f} um, '
            f'{math.degrees(float(np.linalg.norm(sigma[3:]))):.5f} deg')


def _error_text(e_p: FloatArray, e_r: FloatArray, what: str) -> str:
    return (f'{what} {np.linalg.norm(e_p) * 1e6:.1f} um, '
            f'{math.degrees(float(np.linalg.norm(e_r))):.5f} deg')
