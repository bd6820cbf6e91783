"""The positioner's move state machine, without ROS: goals validated, paths planned and checked,
trajectories sent to the drives, arrival awaited, the closed loop on the tracker run, and the
pose estimated from the encoders.

The mover reaches the outside world only through :class:`Machine`, a set of callables (publish
a trajectory, stop the drives, read the latest joint state, take the tracker samples that came
in, the clock), so its whole state machine runs in a unit test without DDS. Poses are in the
``base`` frame: positions (3,) m, unit quaternions (4,) x, y, z, w; joints in JOINT_NAMES order.

A move (:meth:`Mover.move`) goes IDLE → MOVING → SETTLING (→ CORRECTING → MOVING … in
``measured`` mode) → SETTLED, or ends ABORTED (stop, timeout, drive fault) or FAULT (no pose
estimate). Compensation modes: ``none`` commands nominal inverse kinematics; ``model`` the
configured clearance model; ``measured`` the model, then corrections from averaged tracker
readings until within the goal tolerance or out of iterations.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.clearance import ClearanceModel, ClearanceParameters, attained_pose, build
from positioning_cell.core.mechanism import Mechanism
from positioning_cell.core.poses import as_pose_batch, as_vectors
from positioning_cell.errors import InputError, PositioningError
from positioning_cell.mechanics.statics import Payload, Structure
from positioning_cell.motion.correction import corrected_command, deviation, mean_pose
from positioning_cell.motion.trajectory import MotionLimits, Trajectory, plan_move
from positioning_cell.names import BASE_FRAME, DRIVER_ENABLE, STOP
from positioning_cell.parameters import check_fields, group, setting

FloatArray = NDArray[np.float64]


class State(Enum):
    """States of the positioner, as reported on /diagnostics."""

    IDLE = 'idle'
    MOVING = 'moving'
    SETTLING = 'settling'
    CORRECTING = 'correcting'
    SETTLED = 'settled'
    ABORTED = 'aborted'
    FAULT = 'fault'


class CompensationMode(Enum):
    """none: nominal IK; model: the configured clearance model; measured: the model, then
    closed-loop correction from the measured pose."""

    NONE = 'none'
    MODEL = 'model'
    MEASURED = 'measured'


# -- settings ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CompensationSettings:
    """The ``compensation:`` block."""

    mode: str = setting('measured', 'none: nominal inverse kinematics; model: the clearance '
                        'model; measured: the model, then closed loop on the tracker',
                        choices=tuple(m.value for m in CompensationMode), dynamic=True)
    clearance: ClearanceParameters = group(ClearanceParameters,
                                           'the clearance model used by model and measured')
    max_iterations: int = setting(5, 'closed-loop corrections per move', low=0, high=50,
                                  dynamic=True)
    samples: int = setting(10, 'tracker samples averaged per correction', low=1, high=200,
                           dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class GoalTolerance:
    """The settle tolerance of a move (a request's tolerance overrides the position)."""

    position: float = setting(10e-6, 'settle tolerance of a move, position', 'm', low=0.0,
                              low_open=True, high=0.01, dynamic=True)
    orientation: float = setting(1e-4, 'settle tolerance of a move, orientation', 'rad',
                                 low=0.0, low_open=True, high=0.1, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)

    def holds(self, position_error: ArrayLike, rotation_error: ArrayLike) -> bool:
        """True when |Δp| ≤ position and |rotation vector| ≤ orientation."""
        return bool(np.linalg.norm(position_error) <= self.position
                    and np.linalg.norm(rotation_error) <= self.orientation)


@dataclass(frozen=True)
class ArrivalSettings:
    """When the drives count as arrived: every encoder within its tolerance of the target and
    slower than its speed; ``timeout`` beyond the trajectory's duration."""

    length_tolerance: float = setting(5e-6, 'encoder arrival tolerance, legs', 'm', low=0.0,
                                      high=0.01, dynamic=True)
    theta_tolerance: float = setting(5e-5, 'encoder arrival tolerance, theta', 'rad',
                                     low=0.0, high=0.1, dynamic=True)
    length_speed: float = setting(2e-4, 'at rest below this speed, legs', 'm/s', low=0.0,
                                  high=1.0, dynamic=True)
    theta_speed: float = setting(2e-3, 'at rest below this speed, theta', 'rad/s', low=0.0,
                                 high=1.0, dynamic=True)
    timeout: float = setting(5.0, 'extra time to arrive after the trajectory ends', 's',
                             low=0.1, high=120.0, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def position_tolerance(self) -> FloatArray:
        """Arrival tolerance (6,) m, rad."""
        return np.array([self.length_tolerance] * 3 + [self.theta_tolerance] * 3)

    @property
    def speed_tolerance(self) -> FloatArray:
        """At-rest speed (6,) m/s, rad/s."""
        return np.array([self.length_speed] * 3 + [self.theta_speed] * 3)


@dataclass(frozen=True)
class TrajectorySettings:
    """The ``trajectory:`` block."""

    period: float = setting(0.01, 'spacing of the trajectory points', 's', low=0.001,
                            high=0.5, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class PositionerSettings:
    """Every parameter of the ``positioner`` node (config/cell.yaml)."""

    mechanism: Mechanism = group(Mechanism, 'the machine')
    payload: Payload = group(Payload, 'what the platform carries (load-driven clearance)')
    structure: Structure = group(Structure, 'stiffness and masses of the machine')
    compensation: CompensationSettings = group(CompensationSettings, 'compensation')
    goal_tolerance: GoalTolerance = group(GoalTolerance, 'settle tolerance of a move')
    motion: MotionLimits = group(MotionLimits, 'Cartesian limits of a move')
    trajectory: TrajectorySettings = group(TrajectorySettings, 'the joint trajectories')
    arrival: ArrivalSettings = group(ArrivalSettings, 'arrival of the drives')
    settle_time: float = setting(0.2, 'dwell after arrival before the pose counts as settled',
                                 's', low=0.0, high=10.0, dynamic=True)
    measurement_timeout: float = setting(5.0, 'wait for tracker samples', 's', low=0.1,
                                         high=60.0, dynamic=True)
    pose_rate_hz: float = setting(50.0, 'rate of the pose estimate on /positioner/pose', 'Hz',
                                  low=1.0, high=200.0)
    markers_every: int = setting(5, 'markers are published with every this many pose '
                                 'estimates', low=1, high=1000)

    def __post_init__(self) -> None:
        check_fields(self)

    @property
    def mode(self) -> CompensationMode:
        """The compensation mode."""
        return CompensationMode(self.compensation.mode)

    def clearance_model(self) -> ClearanceModel:
        """The compensation's clearance model (ConfigError naming a bad key)."""
        return build(self.compensation.clearance, self.mechanism, self.payload, self.structure)


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


# -- the outside world ---------------------------------------------------------------------------
class JointReading(NamedTuple):
    """Encoder readings: position (6,) m / rad, velocity (6,) m/s / rad/s."""

    position: FloatArray
    velocity: FloatArray


class Estimate(NamedTuple):
    """The pose estimate from the encoders: position (3,) m, quaternion (4,), passive angles
    φ (3,) rad of the solution."""

    position: FloatArray
    quaternion: FloatArray
    phis: FloatArray


@dataclass(frozen=True)
class Machine:
    """What the mover does to and reads from the world.

    ``send_trajectory(traj)`` commands the drives (a planned :class:`Trajectory`);
    ``stop_drives()`` sends the controlled stop; ``publish_target(p, q)`` announces the
    commanded goal; ``latest_joints()`` gives the newest encoder reading (None: none yet);
    ``new_measurements()`` the tracker poses (p, q) that came in since the last call, oldest
    first; ``state_changed(state, reason)`` reports a new state; ``clock()`` is a monotonic
    clock in s.
    """

    send_trajectory: Callable[[Trajectory], None]
    stop_drives: Callable[[], None]
    publish_target: Callable[[FloatArray, FloatArray], None]
    latest_joints: Callable[[], JointReading | None]
    new_measurements: Callable[[], list[tuple[FloatArray, FloatArray]]]
    state_changed: Callable[[State, str], None] = field(default=lambda state, reason: None)
    clock: Callable[[], float] = time.monotonic


class MoveAbortedError(PositioningError):
    """A move was refused or ended before it settled; the message says why."""


class MoveResult(NamedTuple):
    """A settled move: the estimated poses while it ran, positions (M, 3) m and quaternions
    (M, 4), and the words for how it ended."""

    positions: FloatArray
    quaternions: FloatArray
    reason: str


#: How often a wait re-reads the world and re-checks stop and faults, s.
POLL_PERIOD = 0.02
#: Tracker poses kept for averaging.
MEASUREMENTS_KEPT = 200


class Mover:
    """The positioner's state machine (module docstring). Thread-safe: a move runs in the
    caller's thread (a service callback) while others estimate the pose, stop, or feed the
    driver's status."""

    def __init__(self, settings: PositionerSettings, machine: Machine) -> None:
        self.settings = settings
        self.mech = settings.mechanism
        self.model = settings.clearance_model()
        self.machine = machine
        self.cond = threading.Condition()
        self._busy = threading.Lock()
        self.joints: JointReading | None = None
        self.measurements: list[tuple[FloatArray, FloatArray]] = []
        self.measurement_count = 0
        self.driver: dict[str, str] = {}
        self.command: tuple[FloatArray, FloatArray] | None = None
        self.estimate: Estimate | None = None
        self._path: list[tuple[FloatArray, FloatArray]] | None = None
        self.stop_requested = False
        self.state, self.reason = State.IDLE, 'waiting for encoder readings'

    # -- inputs ---------------------------------------------------------------------------------
    def reconfigure(self, settings: PositionerSettings) -> None:
        """New dynamic settings (mode, tolerances, limits, ...); the model is read-only."""
        self.settings = settings

    def driver_status(self, values: Mapping[str, str]) -> None:
        """The leg driver's latest diagnostic values (state, enabled, level, message)."""
        with self.cond:
            self.driver = dict(values)
            self.cond.notify_all()

    def _refresh(self) -> None:
        """Read the newest joint state and the tracker poses that came in."""
        joints = self.machine.latest_joints()
        taken = self.machine.new_measurements()
        with self.cond:
            if joints is not None:
                self.joints = joints
            if taken:
                self.measurements.extend(taken)
                self.measurement_count += len(taken)
                del self.measurements[:-MEASUREMENTS_KEPT]

    @property
    def mode(self) -> CompensationMode:
        """The compensation mode in force."""
        return self.settings.mode

    def _model(self) -> ClearanceModel:
        return None if self.mode is CompensationMode.NONE else self.model

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
        phi0 = previous.phis if previous is not None else None
        try:
            fk = attained_pose(self.mech, self._model(), joints.position[:3],
                               joints.position[3:], phi0)
        except PositioningError as err:
            self._set_state(State.FAULT, f'pose estimate failed: {err}')
            return None
        if not fk.converged[0]:
            self._set_state(State.FAULT, 'forward kinematics did not converge for the encoder '
                                         f'readings {joints.position.tolist()}')
            return None
        estimate = Estimate(fk.position[0], fk.quaternion[0], fk.phis[0])
        with self.cond:
            self.estimate = estimate
            if self._path is not None:
                self._path.append((estimate.position, estimate.quaternion))
        if self.state is State.IDLE and self.reason == 'waiting for encoder readings':
            self._set_state(State.IDLE, 'ready')
        return estimate

    # -- commands -------------------------------------------------------------------------------
    def check(self, frame_id: str, position: ArrayLike, quaternion: ArrayLike) -> Trajectory:
        """The move to a goal, planned and checked without moving (a "virtual move");
        MoveAbortedError (or InputError) says why it would be refused."""
        try:
            goal = validate_goal(frame_id, position, quaternion)
            return self._plan(*goal)
        except PositioningError as err:
            self._refused(str(err))
            raise MoveAbortedError(str(err)) from err

    def move(self, frame_id: str, position: ArrayLike, quaternion: ArrayLike,
             tolerance: float = 0.0) -> MoveResult:
        """Move to a goal and return when settled (``tolerance``: the settle tolerance in m,
        0 for the configured one); MoveAbortedError says why it was refused or aborted."""
        if not self._busy.acquire(blocking=False):
            self._refused('busy: a move is in progress')
            raise MoveAbortedError('busy: a move is in progress')
        try:
            p, q = validate_goal(frame_id, position, quaternion)
            goal_tol = self.settings.goal_tolerance
            tol = GoalTolerance(tolerance or goal_tol.position, goal_tol.orientation)
            return self._execute(p, q, tol)
        except PositioningError as err:
            self._refused(str(err))
            raise MoveAbortedError(str(err)) from err
        finally:
            self._busy.release()

    def home(self) -> MoveResult:
        """Move to the home pose."""
        return self.move(BASE_FRAME, self.mech.home_position, self.mech.home_quaternion)

    def stop(self) -> str:
        """Stop now: the drives decelerate under control; a running move ends aborted."""
        self.stop_requested = True
        self.machine.stop_drives()
        with self.cond:
            self.cond.notify_all()
        return 'stopping with controlled deceleration'

    # -- the move -------------------------------------------------------------------------------
    def _refused(self, reason: str) -> None:
        """Report a refusal, every time (a caller who asks twice hears it twice)."""
        self._set_state(State.ABORTED if self.state is not State.FAULT else State.FAULT, reason,
                        always=True)

    def _plan(self, p: FloatArray, q: FloatArray) -> Trajectory:
        self._refresh()
        with self.cond:
            driver, command, estimate = dict(self.driver), self.command, self.estimate
        if command is None:  # at start and after an aborted move: where the encoders are
            if estimate is None:
                raise MoveAbortedError('no encoder readings yet from /legs/joint_states')
            command = (estimate.position, estimate.quaternion)
        if driver.get('enabled', 'true').lower() == 'false':
            raise MoveAbortedError(f'drives disabled: enable them with {DRIVER_ENABLE}')
        if driver.get('state') == 'fault':
            raise MoveAbortedError(f'drive fault: {driver.get("message", "")}; clear it '
                                   f'with {DRIVER_ENABLE}')
        traj = plan_move(self.mech, *command, p, q, period=self.settings.trajectory.period,
                         limits=self.settings.motion, clearance=self._model())
        if not traj.limits.ok:
            raise MoveAbortedError(f'path refused, {traj.limits.message()}')
        return traj

    def _execute(self, p: FloatArray, q: FloatArray, tol: GoalTolerance) -> MoveResult:
        self.stop_requested = False
        with self.cond:
            self._path = []
        try:
            first = self._plan(p, q)  # refused before anything is announced or moved
            self.machine.publish_target(p, q)
            command = (p, q)
            self._go(*command, first)
            reason = 'settled'
            if self.mode is CompensationMode.MEASURED:
                reason = self._correct(command, p, q, tol)
            self.estimate_pose()  # the executed path ends at the settled pose
            self._set_state(State.SETTLED, reason)
        except MoveAbortedError:
            with self.cond:
                self.command = None  # the axes stopped somewhere else: re-plan from them
            raise
        finally:
            with self.cond:
                path, self._path = self._path or [], None
        positions = np.array([x[0] for x in path]).reshape(-1, 3)
        quaternions = np.array([x[1] for x in path]).reshape(-1, 4)
        return MoveResult(positions, quaternions, reason)

    def _correct(self, command: tuple[FloatArray, FloatArray], p: FloatArray, q: FloatArray,
                 tol: GoalTolerance) -> str:
        """Closed loop on the tracker until within ``tol`` or out of iterations."""
        iterations = self.settings.compensation.max_iterations
        for done in range(iterations + 1):
            measured = self._measure()
            e_p, e_r = deviation(*measured, p, q)
            text = (f'measured error {np.linalg.norm(e_p) * 1e6:.1f} um, '
                    f'{math.degrees(float(np.linalg.norm(e_r))):.5f} deg after {done} '
                    'corrections')
            if tol.holds(e_p, e_r):
                return f'settled within tolerance: {text}'
            if done == iterations:
                return f'settled outside tolerance: {text}'
            self._set_state(State.CORRECTING, f'{text}: correcting')
            command = corrected_command(*command, p, q, *measured)
            self._go(*command)
        raise AssertionError('unreachable')

    def _go(self, p: FloatArray, q: FloatArray, planned: Trajectory | None = None) -> None:
        traj = planned if planned is not None else self._plan(p, q)
        final = np.concatenate([traj.lengths[-1], traj.thetas[-1]])
        self._set_state(State.MOVING, f'moving for {traj.duration:.2f} s')
        with self.cond:
            self.command = (p, q)
        self.machine.send_trajectory(traj)
        arrival = self.settings.arrival

        def arrived() -> bool:
            joints = self.joints
            return joints is not None and joints_arrived(
                joints.position, joints.velocity, final, arrival.position_tolerance,
                arrival.speed_tolerance)

        self._wait(arrived, traj.duration + arrival.timeout, 'the drives to arrive')
        self._set_state(State.SETTLING, 'settling')
        deadline = self.machine.clock() + self.settings.settle_time
        self._wait(lambda: self.machine.clock() >= deadline, self.settings.settle_time + 1.0,
                   'settling')

    def _measure(self) -> tuple[FloatArray, FloatArray]:
        n = self.settings.compensation.samples
        with self.cond:
            start = self.measurement_count
        self._wait(lambda: self.measurement_count - start >= n,
                   self.settings.measurement_timeout, f'{n} new samples on /metrology/pose')
        with self.cond:
            samples = self.measurements[-n:]
        return mean_pose([s[0] for s in samples], [s[1] for s in samples])

    def _wait(self, condition: Callable[[], bool], timeout: float, what: str) -> None:
        """Until ``condition()`` holds (checked under the lock after re-reading the world),
        MoveAbortedError on stop, drive fault or timeout."""
        deadline = self.machine.clock() + timeout
        while True:
            self._refresh()
            with self.cond:
                if condition():
                    return
                if self.stop_requested:
                    raise MoveAbortedError(f'stopped by {STOP}')
                if self.driver.get('state') == 'fault':
                    raise MoveAbortedError(f'drive fault: {self.driver.get("message", "")}')
                remaining = deadline - self.machine.clock()
                if remaining <= 0:
                    raise MoveAbortedError(f'timed out after {timeout:.1f} s waiting for {what}')
                self.cond.wait(min(remaining, POLL_PERIOD))

    # -- state ----------------------------------------------------------------------------------
    def _set_state(self, state: State, reason: str, *, always: bool = False) -> None:
        changed = (state, reason) != (self.state, self.reason)
        self.state, self.reason = state, reason
        if changed or always:
            self.machine.state_changed(state, reason)
