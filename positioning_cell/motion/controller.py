"""The operator's surface of the positioner, without ROS: a move request in the base, machine or
user CS (absolute, or relative to the user or the object), resolved through the coordinate
systems (:mod:`positioning_cell.frames`) and run by the mover (:mod:`.mover`) within three
limit layers (factory, machine box, user box: :mod:`positioning_cell.limits`) at the speeds
the operator set; a check of a request returning the validity bits; the coordinate systems
persisted; a jog of one axis.

Every pose in and out is SI: positions (3,) m, unit quaternions (4,) x, y, z, w.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from positioning_cell.errors import InputError
from positioning_cell.frames import file as frames_file
from positioning_cell.frames.named import NamedSystems
from positioning_cell.frames.systems import (
    ABSOLUTE,
    MOVE_KINDS,
    CoordinateSystems,
)
from positioning_cell.frames.transforms import (
    Transform,
    compose_poses,
    format_human,
    pose6_from_pq,
    pq_from_pose6,
)
from positioning_cell.limits.axis_ranges import AxisRanges, RangeModel
from positioning_cell.limits.boxes import BoxLimits, LimitLayers
from positioning_cell.limits.jog import axis_index, jog_target, jog_trajectory
from positioning_cell.limits.speed import Speeds, motion_limits, scaled, set_speeds
from positioning_cell.limits.validity import (
    VALID,
    CheckResult,
    Validity,
    factory_check,
    invalid_goal,
    state_check,
)
from positioning_cell.motion.mover import JointReading, MoveAbortedError, Mover, MoveResult
from positioning_cell.motion.settings import OperatorSettings
from positioning_cell.moves.outcomes import ResultCode, State
from positioning_cell.moves.timing import Timing
from positioning_cell.moves.trajectory import MotionLimits, checked_pivot

FloatArray = NDArray[np.float64]

#: Where the coordinate systems persist when ``operator.coordinate_systems_file`` is empty,
#: under ROS_HOME (default ~/.ros).
DEFAULT_SYSTEMS_FILE = Path('positioning_cell') / 'coordinate_systems.yaml'


def systems_path(configured: str) -> Path:
    """The coordinate-systems file: ``configured``, or ROS_HOME (~/.ros) /
    :data:`DEFAULT_SYSTEMS_FILE`."""
    if configured:
        return Path(configured).expanduser()
    home = os.environ.get('ROS_HOME') or str(Path.home() / '.ros')
    return Path(home) / DEFAULT_SYSTEMS_FILE


@dataclass(frozen=True)
class MoveCommand:
    """A move request (the ROS MoveCommand): ``kind`` absolute / relative_user /
    relative_object, ``frame_id`` of ``position`` (3,) m and ``quaternion`` (4,), the settle
    ``tolerance`` m (0: the configured one), ``speed_scale`` in (0, 1] (0: 1), the motion's
    least ``duration`` s (0: as fast as the speeds allow) and its ``start`` (ROS time s; None:
    on receipt): :class:`~positioning_cell.moves.timing.Timing`; the ``pivot`` (3,) m, the
    point of the platform (platform frame) the motion carries on a straight line (None or
    zeros: its origin; :func:`~positioning_cell.moves.trajectory.plan_move`)."""

    kind: str
    frame_id: str
    position: ArrayLike
    quaternion: ArrayLike
    tolerance: float = 0.0
    speed_scale: float = 0.0
    duration: float = 0.0
    start: float | None = None
    pivot: ArrayLike | None = None

    def timing(self) -> Timing:
        """The request's time base (InputError naming a bad duration or start)."""
        return Timing(float(self.duration), self.start)


@dataclass(frozen=True)
class Check:
    """A checked request: the validity found, the goal in base (None when it could not be
    resolved), the planned duration s (0 when nothing was planned) and the axis ranges from
    the goal (:meth:`Controller.axis_ranges_at`: how far each user axis of the goal may go,
    the others held; none when the goal itself is outside a limit or not resolved)."""

    result: CheckResult
    goal: tuple[FloatArray, FloatArray] | None
    duration: float
    ranges: AxisRanges


class Controller:
    """The operator's surface over one :class:`Mover` (module docstring). Thread-safe."""

    def __init__(self, mover: Mover, settings: OperatorSettings) -> None:
        self.mover = mover
        self.mech = mover.mech
        self._lock = threading.Lock()
        self.settings = settings
        self.systems_file = systems_path(settings.coordinate_systems_file)
        #: The stored systems by name; ``systems``, the active pair every request uses.
        self.named = frames_file.load_named(self.systems_file)  # ConfigError: no start
        self.systems = self.named.active
        self.maxima = Speeds(settings.max_linear_speed, settings.max_angular_speed,
                             settings.max_linear_acceleration,
                             settings.max_angular_acceleration)
        self.speeds = set_speeds(self.maxima, self.maxima, Speeds.of(mover.settings.motion))
        factory = LimitLayers.for_mechanism(self.mech, settings.factory_box)
        machine = (BoxLimits(settings.machine_lower, settings.machine_upper)
                   if settings.machine_lower is not None and settings.machine_upper is not None
                   else factory.factory_box)
        user = (BoxLimits(settings.user_lower, settings.user_upper)
                if settings.user_lower is not None and settings.user_upper is not None
                else BoxLimits.unlimited())
        self.layers = factory.validated(machine, user, self._user_to_machine)
        #: What searches the axis ranges: in this process by default (the compiled kernel); a
        #: node gives the search of its range worker (:mod:`positioning_cell.limits.range_worker`)
        #: so as never to load numba itself.
        self.range_search: Callable[[RangeModel, FloatArray], AxisRanges] = RangeModel.ranges

    # -- coordinate systems -------------------------------------------------------------------
    def set_systems(self, user: Transform, obj: Transform) -> Path:
        """New values of the active user and object coordinate systems, persisted (the file
        written); never moves the machine. The user box must still map into the machine box
        (InputError, nothing changed, otherwise)."""
        return self._apply(lambda named: named.with_active(CoordinateSystems(user, obj)))

    def define_system(self, kind: str, name: str, value: Transform, activate: bool) -> Path:
        """Store system ``name`` of ``kind`` (``user``: in the machine CS; ``object``: in the
        platform frame), made active if ``activate``; as :meth:`set_systems` otherwise."""
        return self._apply(lambda named: named.defined(kind, name, value, activate=activate))

    def select_systems(self, user: str, obj: str) -> Path:
        """Make the named systems active ('' keeps a kind); as :meth:`set_systems`."""
        return self._apply(lambda named: named.selected(user, obj))

    def _apply(self, change: Callable[[NamedSystems], NamedSystems]) -> Path:
        """The named systems changed by ``change``, the active pair checked against the limit
        layers, then persisted; on any error (InputError, a file that cannot be written)
        nothing changed."""
        with self._lock:
            previous = self.named, self.systems
            named = change(self.named)
            self.named, self.systems = named, named.active
            try:
                self.layers = self.layers.validated(self.layers.machine_box,
                                                    self.layers.user_box,
                                                    self._user_to_machine)
                path = frames_file.write(self.systems_file, named)
            except Exception:
                self.named, self.systems = previous
                raise
        return path

    def _user_to_machine(self, user_pose6: FloatArray) -> FloatArray:
        """Poses (N, 6) of the object frame in the user CS → the platform in the machine CS."""
        p, q = compose_poses(self.systems.user, *pq_from_pose6(user_pose6),
                             self.systems.object.inverse())
        return pose6_from_pq(p, q)

    def user_position(self, position: ArrayLike, quaternion: ArrayLike) -> Transform:
        """The user position (object frame in the user CS) of a platform pose in base."""
        return self.systems.user_position(position, quaternion, self.mech)

    def current_user_position(self) -> Transform | None:
        """What relative moves start from: the user position of the last goal once that move
        settled (its target position), else of where the encoders are (None before the first
        reading)."""
        goal = self._current_pose()
        return None if goal is None else self.user_position(*goal)

    def _current_pose(self) -> tuple[FloatArray, FloatArray] | None:
        """The platform pose in base relative moves start from (:meth:`current_user_position`),
        None before the first reading."""
        mover = self.mover
        goal = mover.goal if mover.state is State.SETTLED else None
        if goal is None:
            estimate = mover.estimate_pose()
            if estimate is None:
                return None
            goal = (estimate.position, estimate.quaternion)
        return goal

    def status_values(self) -> dict[str, str | float]:
        """The operator's settings in force, for /diagnostics: the active coordinate systems
        (their names; six numbers, mm and deg), their file, the speeds (m/s, rad/s, m/s²,
        rad/s²)."""
        speeds = self.speeds
        return {'user_cs_name': self.named.active_user,
                'object_cs_name': self.named.active_object,
                'user_cs': format_human(self.systems.user.to_human()),
                'object_cs': format_human(self.systems.object.to_human()),
                'coordinate_systems_file': str(self.systems_file),
                'linear_speed': speeds.linear_speed, 'angular_speed': speeds.angular_speed,
                'linear_acceleration': speeds.linear_acceleration,
                'angular_acceleration': speeds.angular_acceleration}

    # -- axis ranges ----------------------------------------------------------------------------
    def axis_ranges_at(self, position: ArrayLike, quaternion: ArrayLike) -> AxisRanges:
        """The live axis ranges (:mod:`positioning_cell.limits.axis_ranges`) of the user
        position of a platform pose in base (``position`` (3,) m, ``quaternion`` (4,) x, y, z,
        w), in the active user CS, within the limit layers in force; none, with the reason,
        for a pose outside a limit. Searched by :attr:`range_search`. Never raises."""
        layers, systems = self.layers, self.systems
        try:
            pose6 = systems.user_position(position, quaternion, self.mech).to_pose6()
            model = RangeModel.cached(self.mech, layers, systems,
                                      self.settings.axis_ranges.spans)
            return self.range_search(model, pose6)
        except InputError as err:
            return AxisRanges.unknown(f'no axis ranges: {err}')

    def current_axis_ranges(self) -> AxisRanges:
        """The axis ranges from the pose relative moves start from
        (:meth:`current_user_position`: the settled goal, else the encoders' estimate); none
        before the first reading."""
        goal = self._current_pose()
        if goal is None:
            return AxisRanges.unknown('no pose estimate yet')
        return self.axis_ranges_at(*goal)

    # -- limits and speeds ----------------------------------------------------------------------
    def set_limits(self, machine: BoxLimits, user: BoxLimits) -> LimitLayers:
        """New machine and user boxes (InputError listing what lies outside, nothing changed)."""
        with self._lock:
            self.layers = self.layers.validated(machine, user, self._user_to_machine)
            return self.layers

    def set_speeds(self, request: Speeds) -> Speeds:
        """New speeds within the factory maxima (a field of 0 keeps its value; InputError
        naming a field above its maximum, negative or not finite: nothing changed)."""
        with self._lock:
            self.speeds = set_speeds(self.speeds, self.maxima, request)
            return self.speeds

    def limits_for(self, speed_scale: float) -> MotionLimits:
        """The motion limits of a move at ``speed_scale`` (0: 1) of the current speeds."""
        scale = 1.0 if speed_scale == 0.0 else speed_scale
        return motion_limits(self.mover.settings.motion, scaled(self.speeds, scale))

    def box_check(self, position: FloatArray, quaternion: FloatArray) -> CheckResult:
        """The machine and user layers over platform poses (N, 3) m / (N, 4) in base."""
        machine = pose6_from_pq(position - self.mech.home_position, quaternion)
        user = None
        if not self.layers.user_box.is_unlimited:
            user = pose6_from_pq(*self.systems.user_positions(position, quaternion, self.mech))
        return self.layers.check(machine, user)

    def _path_check(self, position: FloatArray, quaternion: FloatArray) -> list[str]:
        return list(self.box_check(position, quaternion).violations)

    # -- requests -------------------------------------------------------------------------------
    def resolve(self, command: MoveCommand) -> tuple[FloatArray, FloatArray]:
        """The platform goal in base of a request (InputError naming what is wrong: kind,
        frame, numbers, speed scale, duration, start, pivot)."""
        if command.kind not in MOVE_KINDS:
            raise InputError(f'move mode {command.kind!r} is not one of {", ".join(MOVE_KINDS)}')
        scale = float(command.speed_scale)
        if not (math.isfinite(scale) and 0.0 <= scale <= 1.0):
            raise InputError(f'speed_scale = {scale!r}: must be in (0, 1] (0: 1)')
        command.timing()
        checked_pivot(command.pivot)
        current = None if command.kind == ABSOLUTE else self.current_user_position()
        if command.kind != ABSOLUTE and current is None:
            raise InputError('a relative move needs a pose to start from: no pose estimate yet')
        pose = (command.position, command.quaternion)
        return self.systems.resolve_goal(command.kind, command.frame_id, pose, current,
                                         self.mech)

    def move(self, command: MoveCommand,
             resolved: tuple[FloatArray, FloatArray] | None = None) -> MoveResult:
        """Run a request: resolved (``resolved``: the goal :meth:`resolve` already gave for
        it, not resolved again, so that a relative move and the feedback of its caller use
        one goal), planned within every layer at the requested speed, moved and settled
        within its tolerance (MoveAbortedError names the outcome otherwise)."""
        try:
            p, q = resolved if resolved is not None else self.resolve(command)
            timing = command.timing()
        except InputError as err:
            raise self.mover.refusal(ResultCode.REFUSED_INVALID_GOAL, str(err)) from err
        return self.mover.move('base', p, q, command.tolerance,
                               limits=self.limits_for(float(command.speed_scale)),
                               path_check=self._path_check, timing=timing,
                               pivot=checked_pivot(command.pivot))

    def check(self, command: MoveCommand) -> Check:
        """Every check of a request without moving: the state of the cell, then the path from
        the current command to the goal against the factory, machine and user layers (the
        goal alone when no path can be planned yet). Never raises for a bad request: its
        bits say what is wrong."""
        state = self._state_check()
        try:
            p, q = self.resolve(command)
        except InputError as err:
            return Check(state.merged(invalid_goal(str(err))), None, 0.0,
                         AxisRanges.unknown(f'no goal: {err}'))
        tolerance = float(command.tolerance)
        try:
            self.mover.settings.goal_tolerance.for_request(tolerance)
        except InputError as err:
            state = state.merged(invalid_goal(str(err)))
        duration = 0.0
        try:
            traj = self.mover.plan_path(p, q, self.limits_for(float(command.speed_scale)),
                                        float(command.duration), checked_pivot(command.pivot))
            path_p, path_q, duration = traj.position, traj.quaternion, traj.duration
        except MoveAbortedError:  # no pose estimate yet: the goal alone
            path_p, path_q = p[None], q[None]
        result = state.merged(factory_check(self.mech, path_p, path_q),
                              self.box_check(path_p, path_q))
        return Check(result, (p, q), duration if result.valid else 0.0,
                     self.axis_ranges_at(p, q))

    def _state_check(self) -> CheckResult:
        mover = self.mover
        driver = dict(mover.driver)
        fault = driver.get('message', 'in fault') if driver.get('state') == 'fault' else None
        busy = mover.busy
        result = state_check(referenced=mover.referenced,
                             drives_enabled=driver.get('enabled', 'true').lower() != 'false',
                             drive_fault=fault, busy=busy)
        try:  # the world's liveness, as a move would find it (silent driver or tracker)
            mover.ready(homing=True)
        except MoveAbortedError as err:
            bit = _LIVENESS_BITS.get(err.code)
            if bit is not None:
                result = result.merged(CheckResult(bit, (f'state: {err}',)))
        return result if result.bits != VALID else CheckResult()

    # -- jog ------------------------------------------------------------------------------------
    def jog(self, axis: str, delta: float) -> JointReading:
        """Move one axis by ``delta`` (m or rad) outside the kinematics, within its range and the
        largest jog step, at the jog speed (MoveAbortedError: refused or aborted)."""
        mover, s = self.mover, self.settings
        reading = mover.joints
        if reading is None:
            raise mover.refusal(ResultCode.REFUSED_DRIVER_SILENT, 'no encoder readings yet')
        try:
            k = axis_index(axis)
            if not math.isfinite(float(delta)):
                raise InputError(f'jog {axis}: step {delta!r} is not finite')
        except (InputError, TypeError, ValueError) as err:
            raise mover.refusal(ResultCode.REFUSED_INVALID_GOAL, str(err)) from err
        try:  # the axis range and the largest step
            target = jog_target(self.mech, reading.position, k, delta, s.jog_largest_length_step,
                                s.jog_largest_theta_step)
        except InputError as err:
            raise mover.refusal(ResultCode.REFUSED_LIMITS, str(err)) from err
        linear = k < 3
        times, joints = jog_trajectory(
            reading.position, target, s.jog_length_speed if linear else s.jog_theta_speed,
            s.jog_length_acceleration if linear else s.jog_theta_acceleration,
            mover.settings.trajectory.period)
        return mover.jog(times, joints)


#: The bit of each liveness refusal of the mover (the others are :func:`state_check`'s).
_LIVENESS_BITS = {ResultCode.REFUSED_DRIVER_SILENT: Validity.DRIVER_SILENT,
                  ResultCode.REFUSED_NO_ESTIMATE: Validity.DRIVER_SILENT,
                  ResultCode.REFUSED_NOT_COMMANDER: Validity.DRIVER_SILENT,
                  ResultCode.REFUSED_TRACKER_SILENT: Validity.TRACKER_SILENT}
