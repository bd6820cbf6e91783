"""The leg_driver node's work without ROS: six servo axes with their encoders, injected faults,
and the efforts (leg forces, θ torques) that hold the payload at the current pose.

One physics step per timer tick (:meth:`LegDriver.step`): the servos are integrated to the
tick's time, the following error checked, and every ``publish_every``-th step a joint-state
publication is due. Time is the driver's own clock in s (any origin shared by all calls).
"""

from __future__ import annotations

import contextlib
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.kinematics import forward, inverse
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.errors import InputError
from positioning_cell.mechanics.statics import (
    Payload,
    Structure,
    actuator_efforts,
    efforts_from_wrench,
)
from positioning_cell.moves.fingerprint import fingerprint
from positioning_cell.names import JOINT_TRAJECTORY, NODE_POSITIONER
from positioning_cell.parameters import ParameterError, check_fields, group, setting
from positioning_cell.sim.encoders import EncoderReading, Encoders, EncoderSettings
from positioning_cell.sim.faults import DriveFaults
from positioning_cell.sim.guard import AxisGuard, Refusal, TrajectoryRefusedError, check_path
from positioning_cell.sim.paths import (
    JointNamesError,
    JointPath,
    Points,
    Times,
    path_from_points,
)
from positioning_cell.sim.servo import AxisState, Fault, LegServos, ServoSettings

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class HomingSettings:
    """How the drives are referenced (``/leg_driver/reference``, the positioner's home)."""

    virtual: bool = setting(True, 'virtual homing: the axes are referenced where they stand '
                            '(simulation); else a referencing run to the home position')
    speed_fraction: float = setting(0.1, 'speed of the referencing run, fraction of each '
                                    "axis's max_velocity", low=0.0, low_open=True, high=1.0)

    def __post_init__(self) -> None:
        check_fields(self)


@dataclass(frozen=True)
class CommandSettings:
    """Whom the drives obey and what a command may be (the ``command:`` block)."""

    commander: str = setting('/' + NODE_POSITIONER, 'fully qualified name of the only node '
                             'whose trajectories and heartbeats are taken; any other '
                             'publisher on the command topic is refused and reported')
    heartbeat_timeout: float = setting(
        0.5, 'a move in progress stops under control when the commander has sent neither a '
        "heartbeat nor a trajectory for this long (the positioner's "
        'liveness.heartbeat_period is 0.05 s)', 's', low=0.02, high=10.0, dynamic=True)
    max_points: int = setting(60_000, 'trajectories with more points are refused before '
                              'their points are read (10 min at the 0.01 s period)', low=2,
                              high=1_000_000)
    stamp_tolerance: float = setting(
        0.05, 'a trajectory whose header stamp lies further in the past is refused as too old '
        '(a zero stamp starts on receipt)', 's', low=0.0, high=10.0, dynamic=True)
    max_start_delay: float = setting(
        1.0, 'a trajectory whose header stamp lies further in the future is refused', 's',
        low=0.0, high=60.0, dynamic=True)

    def __post_init__(self) -> None:
        check_fields(self)
        if not self.commander.startswith('/'):
            raise ParameterError('commander', self.commander,
                                 "a fully qualified node name ('/positioner', '/ns/node')")


@dataclass(frozen=True)
class DriverSettings:
    """Every parameter of the ``leg_driver`` node (config/cell.yaml)."""

    mechanism: Mechanism = group(Mechanism, 'the machine (home pose)')
    payload: Payload = group(Payload, 'what the platform carries (efforts)')
    structure: Structure = group(Structure, 'stiffness and masses of the machine (efforts)')
    servo: ServoSettings = group(ServoSettings, 'the six position servos')
    encoder: EncoderSettings = group(EncoderSettings, 'the six encoders')
    fault: DriveFaults = group(DriveFaults, 'injected faults (dynamic)')
    command: CommandSettings = group(CommandSettings, 'whom the drives obey, and the bounds of '
                                     'a command')
    physics_rate: float = setting(100.0, 'servo integration timer', 'Hz', low=10.0,
                                  high=2000.0)
    publish_every: int = setting(1, 'joint states are published every this many physics '
                                 'steps', low=1, high=1000)
    effort_rate: float = setting(20.0, 'largest rate of the payload-effort update (only '
                                 'while the axes move)', 'Hz', low=1.0, high=200.0)
    diagnostics_period: float = setting(1.0, 'periodic /diagnostics', 's', low=0.1, high=60.0)
    panel_pushes: bool = setting(False, 'a panel simulator pushes on the platform (a set of a '
                                 'coordinated cell): the load cells read nothing until its '
                                 'first push has come')
    enabled_at_start: bool = setting(True, 'drives enabled at start')
    referenced_at_start: bool = setting(False, 'drives referenced at start (else every motion '
                                        'is refused until they are referenced)')
    homing: HomingSettings = group(HomingSettings, 'referencing')
    initial_at_home: bool = setting(True, 'start at the home pose (else initial_positions)')
    initial_positions: tuple[float, ...] = setting(
        (0.2, 0.2, 0.2, 0.0, 0.0, 0.0), 'start positions in JOINT_NAMES order', 'm, rad',
        length=6)

    def __post_init__(self) -> None:
        check_fields(self)
        scale, duration = self.fault.noise_burst
        if duration > 0.0 and scale > 1.0 and not self.encoder.noise.any():
            raise ParameterError('fault.noise_burst', list(self.fault.noise_burst),
                                 'the encoders have no noise to scale (encoder.linear_noise = '
                                 'encoder.rotary_noise = 0)')

    @property
    def publish_rate(self) -> float:
        """Nominal joint-state publication rate, Hz."""
        return self.physics_rate / self.publish_every

    def start_positions(self) -> FloatArray:
        """Axis positions (6,) at start: home, or ``initial_positions``."""
        return self.home_positions() if self.initial_at_home else np.asarray(
            self.initial_positions, dtype=float)

    def home_positions(self) -> FloatArray:
        """Axis positions (6,) of the mechanism's home pose (the reference positions)."""
        mech = self.mechanism
        home = inverse(mech, mech.home_position, mech.home_quaternion)
        return np.concatenate([home.lengths[0], home.thetas[0]])

    def guard(self) -> AxisGuard:
        """The limits every trajectory is held to."""
        s = self.servo
        return AxisGuard.of(self.mechanism, s.velocity_limits, s.acceleration_limits,
                            s.jump_limits)


class Step(NamedTuple):
    """What one physics step gave: a fault that tripped in it (the axes then stop and hold),
    whether a joint-state publication is due, and the reason of a stop the drives made by
    themselves in it (the commander fell silent)."""

    fault: Fault | None
    publish: bool
    stopped: str | None = None


class Outcome(NamedTuple):
    """Whether a command was accepted, and the words for it; for a trajectory also its
    :func:`~positioning_cell.moves.fingerprint.fingerprint`, the refusal's code and the count of
    trajectories received so far."""

    accepted: bool
    message: str
    key: str = ''
    code: Refusal | None = None
    sequence: int = 0


class Prepared(NamedTuple):
    """A trajectory that passed every check of :meth:`LegDriver.prepare`: its key, its path,
    its start (s on the drives' clock; None: on receipt) and the setpoint it was checked
    joined to."""

    key: str
    path: JointPath
    start: float | None
    setpoint: tuple[FloatArray, FloatArray]


class LegDriver:
    """The drives (module docstring). :attr:`event` is the latest thing that happened, for
    the diagnostics."""

    def __init__(self, settings: DriverSettings, now: float = 0.0) -> None:
        self.settings = settings
        self.guard = settings.guard()
        self.servos = LegServos(settings.servo, settings.start_positions(), now,
                                enabled=settings.enabled_at_start, low=self.guard.low,
                                high=self.guard.high)
        self.referenced = settings.referenced_at_start
        self.referencing = False
        self.received = 0
        self.encoders = Encoders(settings.encoder, np.random.default_rng(settings.encoder.seed))
        self.faults = settings.fault
        self.servos.stuck = self.faults.stuck
        self.event = 'started'
        self._burst_start = now
        self._steps = 0
        self.effort: FloatArray | None = None
        self._effort_position: FloatArray | None = None
        #: What else pushes on the platform (force N, moment N·m about its origin, base): the
        #: coordinated cell's panel (simulation truth, :meth:`push`); None until it first
        #: pushes.
        self.pushed: FloatArray | None = None
        self._effort_pose: tuple[FloatArray, FloatArray] = (np.zeros((1, 3)), np.zeros((1, 4)))
        self._payload_effort: FloatArray = np.zeros(6)
        self._phis: FloatArray | None = None
        #: Last word from the commander (a heartbeat or a trajectory), s; a commanded motion
        #: is in progress while ``_following`` (cleared once it ended or was stopped).
        self._heard = now
        self._following = False
        #: Moves stopped because the commander fell silent (on /diagnostics: the commander,
        #: when it was only slow, learns its move was stopped).
        self.silence_stops = 0
        #: Other nodes publishing on the command topic (the graph), whether the commander is
        #: among its publishers, and the GIDs (hex) of the commander's publishers there.
        self.foreign: tuple[str, ...] = ()
        self.commander_seen = False
        self.commander_ids: tuple[str, ...] = ()

    def reconfigure(self, settings: DriverSettings, changed: Collection[str],
                    now: float) -> None:
        """New dynamic settings: the injected faults; ``changed`` the dotted names that were
        set (setting ``fault.noise_burst`` starts a burst now)."""
        if 'fault.noise_burst' in changed:
            self._burst_start = now
        self.settings, self.faults = settings, settings.fault
        self.servos.stuck = self.faults.stuck
        if changed:
            self.event = f'fault injection set: {", ".join(sorted(changed))}'
        axis, distance = settings.fault.uncommanded_motion
        if 'fault.uncommanded_motion' in changed and distance and self.servos.mode != 'fault':
            self.servos.advance(now)
            start, _ = self.servos.setpoint()
            goal = start.copy()
            goal[int(axis)] += distance
            with contextlib.suppress(TrajectoryRefusedError):  # drives off: nothing moves
                self.servos.command(self._smooth_path(start, goal, 0.2), now)

    def step(self, now: float) -> Step:
        """Integrate to ``now`` (s); a referencing run that has arrived references the axes;
        the efforts are updated every so many steps (at most ``effort_rate``)."""
        fault = self.servos.advance(now)
        if fault is not None:
            self.event = f'fault: {fault.message()}'
        if self.referencing and not self.servos.moving:
            self.referencing = False
            if self.servos.fault is None and self.servos.enabled:
                self.referenced = True
                self.event = 'referenced: referencing run complete'
        stopped = self._watch_commander(now)
        self._steps += 1
        s = self.settings
        if self._steps % max(1, round(s.physics_rate / s.effort_rate)) == 0:
            self.update_effort()
        return Step(fault, self._steps % s.publish_every == 0, stopped)

    def heartbeat(self, now: float) -> None:
        """The commander is alive at ``now`` (a heartbeat of the commander's came)."""
        self._heard = max(self._heard, now)

    def _watch_commander(self, now: float) -> str | None:
        """A commanded motion in progress whose commander fell silent for longer than
        ``command.heartbeat_timeout`` stops under control; the reason, or None."""
        if not self._following:
            return None
        if not self.servos.moving and self.servos.pending is None:
            self._following = False
            return None
        silence = now - self._heard
        timeout = self.settings.command.heartbeat_timeout
        if silence <= timeout:
            return None
        self.servos.stop()
        self._following = False
        self.silence_stops += 1
        self.event = (f'commander {self.settings.command.commander} silent for {silence:.2f} s '
                      f'during a move (heartbeat_timeout {timeout:g} s): controlled stop')
        return self.event

    def note_foreign(self, sender: str) -> bool:
        """A command came from ``sender``, not the commander: reported as foreign from now
        (until the graph no longer lists it). True when it was not reported yet."""
        if not sender or sender in self.foreign:
            return False
        self.foreign = tuple(sorted({*self.foreign, sender}))
        return True

    def publishers(self, endpoints: Sequence[tuple[str, str]]) -> bool:
        """The publishers now on the command topic (from the graph), as (node, GID hex): the
        commander seen or not, with the GIDs of its publishers (a commander restarted within
        the middleware's lease of its predecessor is named twice, and only its own GID tells it
        that this driver has discovered it), the others foreign. True when that changed."""
        commander = self.settings.command.commander
        foreign = tuple(sorted({n for n, _ in endpoints if n != commander}))
        ids = tuple(sorted({gid for n, gid in endpoints if n == commander}))
        changed = (foreign, ids) != (self.foreign, self.commander_ids)
        self.foreign, self.commander_ids, self.commander_seen = foreign, ids, bool(ids)
        return changed

    def readings(self) -> tuple[EncoderReading, AxisState]:
        """The encoder reading of the current state, and the true state. An encoder that gives
        no signal (NaN) faults its drive: the axes stop and hold."""
        s, f = self.servos, self.faults
        reading = self.encoders.read(s.state, dropout=f.dropout, missing=f.missing,
                                     noise_scale=f.noise_scale(s.time - self._burst_start))
        lost = ~np.isfinite(reading.position)
        if lost.any() and s.fault is None:
            s.fail(Fault(int(np.flatnonzero(lost)[0]), encoder_lost=True))
            self.event = f'fault: {s.fault.message() if s.fault else ""}'
        return reading, s.state

    def push(self, wrench: FloatArray) -> None:
        """What else now pushes on the platform (:attr:`pushed`); the load cells read it from
        the next effort update on."""
        self.pushed = np.asarray(wrench, dtype=float)

    def update_effort(self) -> FloatArray | None:
        """The efforts (6,) (N, N·m) at the axes' true position holding the payload, and what
        else pushes on the platform (:meth:`push`): what the load cells read. The pose (forward
        kinematics, uncompiled in a node) and the payload's share are computed again only when
        the axes have moved; the push's share, τ = Jᵀ·(−push) (seed 002 §2,
        :func:`~positioning_cell.mechanics.statics.efforts_from_wrench`), at every update
        while there is one. None while ``panel_pushes`` and no push has come: the load is not
        known, and load cells that read the platform alone would say the panel is not
        strained (a relax from them would take away nothing)."""
        q = self.servos.state.position
        s = self.settings
        if s.panel_pushes and self.pushed is None:
            return None
        if self._effort_position is None or not np.array_equal(q, self._effort_position):
            fk = forward(s.mechanism, q[:3], q[3:], self._phis)
            if not fk.converged[0]:
                return self.effort
            self._phis = fk.phis
            self._effort_pose = (fk.position, fk.quaternion)
            self._payload_effort = actuator_efforts(s.mechanism, fk.position, fk.quaternion,
                                                    s.payload, s.structure)[0]
            self._effort_position = q.copy()
            self.effort = self._payload_effort
        if self.pushed is not None and self.pushed.any():
            self.effort = self._payload_effort + efforts_from_wrench(
                s.mechanism, *self._effort_pose, -self.pushed[None])[0]
        return self.effort

    def follow(self, names: Sequence[str], times: Times, positions: Points, velocities: Points,
               start: float | None, now: float, sender: str | None = None) -> Outcome:
        """Follow trajectory points (trajectory_msgs/JointTrajectory fields) from ``start``
        (s on this clock; None: on receipt), sent by node ``sender`` (its fully qualified
        name; None: not known, as in a test of the rules alone): :meth:`prepare` then
        :meth:`apply`. A refused trajectory changes nothing; the outcome says why, with the
        trajectory's key."""
        self.servos.advance(now)
        prepared = self.prepare(names, times, positions, velocities, start, now, sender,
                                self.setpoint_at(start, now))
        return self.apply(prepared, now)

    def setpoint_at(self, start: float | None, now: float) -> tuple[FloatArray, FloatArray]:
        """The setpoint (position, velocity (6,)) a trajectory starting at ``start`` (None: on
        receipt, ``now``) joins, as the drives stand now."""
        return self.servos.setpoint(max(now if start is None else start, self.servos.time))

    def prepare(self, names: Sequence[str], times: Times, positions: Points,
                velocities: Points, start: float | None, now: float, sender: str | None,
                setpoint: tuple[FloatArray, FloatArray]) -> Prepared | Outcome:
        """Every check of a trajectory received at ``now``, without touching the drives (it
        may run on another thread while they move): the sender is the commander, at most
        ``command.max_points`` points, a start stamp neither older than
        ``command.stamp_tolerance`` nor later than ``command.max_start_delay``, then every
        check of :mod:`.guard` on the path joined to ``setpoint`` (:meth:`setpoint_at`). The
        prepared trajectory for :meth:`apply`, or the refusal (sequence 0: not counted
        yet)."""
        key = _key(times, positions)
        try:
            self._check_command(sender, len(times), start, now)
            path = self._path(names, times, positions, velocities)
            position, velocity = setpoint
            check_path(path.starting_from(position, velocity), self.guard, position)
        except TrajectoryRefusedError as err:
            return Outcome(False, f'trajectory refused: {err}', key, err.code)
        return Prepared(key, path, start, setpoint)

    def apply(self, prepared: Prepared | Outcome, now: float) -> Outcome:
        """Follow a prepared trajectory (or count and report its refusal): refused when the
        drives are not referenced, disabled or in fault; checked again when the setpoint it
        joins is no longer the one it was prepared against (a command that replaces a running
        motion)."""
        self.servos.advance(now)
        self.received += 1
        if isinstance(prepared, Outcome):
            self.event = prepared.message
            return prepared._replace(sequence=self.received)
        key, path, start = prepared.key, prepared.path, prepared.start
        try:
            if not self.referenced:
                raise TrajectoryRefusedError(
                    Refusal.NOT_REFERENCED, 'axes not referenced: home them first '
                    '(/positioner/home or /leg_driver/reference)')
            position, velocity = self.setpoint_at(start, now)
            if not (np.array_equal(position, prepared.setpoint[0])
                    and np.array_equal(velocity, prepared.setpoint[1])):
                check_path(path.starting_from(position, velocity), self.guard, position)
            self.servos.command(path, now if start is None else start)
        except TrajectoryRefusedError as err:
            self.event = f'trajectory refused: {err}'
            return Outcome(False, self.event, key, err.code, self.received)
        self._following, self._heard = True, max(self._heard, now)
        self.event = f'trajectory accepted: {path.times.size} points, {path.duration:.3f} s'
        return Outcome(True, self.event, key, None, self.received)

    def refuse(self, code: Refusal, reason: str, key: str = '') -> Outcome:
        """A command refused before it could be read as points (``reason``), e.g. bytes that
        are not a trajectory or one from a foreign sender: nothing changes."""
        self.received += 1
        self.event = f'trajectory refused: {reason}'
        return Outcome(False, self.event, key, code, self.received)

    def _check_command(self, sender: str | None, points: int, start: float | None,
                       now: float) -> None:
        """The command rules that do not look at the points (TrajectoryRefusedError)."""
        c = self.settings.command
        if sender is not None and sender != c.commander:
            raise TrajectoryRefusedError(Refusal.FOREIGN_SENDER, foreign_sender(sender, c))
        if points > c.max_points:
            raise TrajectoryRefusedError(Refusal.TOO_MANY_POINTS,
                                         f'{points} points: more than command.max_points = '
                                         f'{c.max_points}')
        if start is None:
            return
        if now - start > c.stamp_tolerance:
            raise TrajectoryRefusedError(
                Refusal.OLD_HEADER_TIMESTAMP, f'header stamp {now - start:.3f} s in the past '
                f'(command.stamp_tolerance {c.stamp_tolerance:g} s): too old to start')
        if start - now > c.max_start_delay:
            raise TrajectoryRefusedError(
                Refusal.FUTURE_HEADER_TIMESTAMP, f'header stamp {start - now:.3f} s ahead '
                f'(command.max_start_delay {c.max_start_delay:g} s): too far in the future')

    def _path(self, names: Sequence[str], times: Times, positions: Points,
              velocities: Points) -> JointPath:
        try:
            return path_from_points(names, times, positions, velocities)
        except JointNamesError as err:
            raise TrajectoryRefusedError(Refusal.INVALID_JOINTS, str(err)) from err
        except InputError as err:
            raise TrajectoryRefusedError(Refusal.INVALID_GOAL, str(err)) from err

    def reference(self, now: float) -> str:
        """Reference the axes: at once (virtual homing), or by a referencing run to the home
        position at reduced speed, referenced when it arrives. TrajectoryRefusedError when
        the drives are disabled or in fault."""
        self.servos.advance(now)
        s = self.servos
        if not s.enabled or s.fault is not None:
            code = Refusal.DISABLED if not s.enabled else Refusal.FAULT
            raise TrajectoryRefusedError(code, 'cannot reference: drives '
                                         + ('disabled' if not s.enabled else 'in fault'))
        if self.settings.homing.virtual:
            self.referenced = True
            self.event = 'referenced (virtual homing: where the axes stand)'
            return self.event
        start, _ = s.setpoint()
        path = self._smooth_path(start, self.settings.home_positions(),
                                 self.settings.homing.speed_fraction)
        duration = path.duration
        self.referenced, self.referencing = False, True
        s.command(path, now)
        self._following, self._heard = True, max(self._heard, now)
        self.event = f'referencing run to the home position, {duration:.1f} s'
        return self.event

    def _smooth_path(self, start: FloatArray, goal: FloatArray, fraction: float) -> JointPath:
        """Rest to rest from ``start`` to ``goal`` (6,) (smoothstep), at about ``fraction`` of
        each axis's speed and acceleration limits."""
        v = self.settings.servo.velocity_limits * fraction
        a = self.settings.servo.acceleration_limits * fraction
        duration = float(np.max(np.abs(goal - start) / v + v / a, initial=0.0)) + 1e-3
        times = np.linspace(0.0, duration, 51)
        tau = times / duration
        shape = tau * tau * (3.0 - 2.0 * tau)
        rate = 6.0 * tau * (1.0 - tau) / duration
        return JointPath(times, start + shape[:, None] * (goal - start),
                         rate[:, None] * (goal - start))

    def stop(self, now: float) -> str:
        """Controlled stop from the current setpoint, then hold."""
        self.servos.advance(now)
        self.servos.stop()
        self._following = False
        self.event = 'stop: empty trajectory, controlled deceleration'
        return self.event

    def enable(self, on: bool, now: float) -> str:
        """Drives on (clears a fault; the axes hold where they are) or off (controlled stop,
        motion refused)."""
        self.servos.advance(now)
        cleared = self.servos.fault
        self.servos.enable(on)
        self.event = ('drives enabled' if on else 'drives disabled, axes hold') + (
            f' (fault cleared: {cleared.message()})' if cleared and on else '')
        return self.event

    def status(self, event: str | None = None,
               level: str | None = None) -> tuple[str, str, dict[str, Any]]:
        """(level, message, values) of the /diagnostics status: the drives' mode, fault axis,
        following errors and the latest event; ``event`` (the message) and ``level`` override
        what the mode gives."""
        s = self.servos
        mode = s.mode
        level = level or {'fault': 'error', 'disabled': 'warn'}.get(mode, 'ok')
        message = s.fault.message() if s.fault else (event or mode)
        if self.foreign and not s.fault:
            level = 'error'
            message = (f'foreign publisher on {JOINT_TRAJECTORY}: {", ".join(self.foreign)} '
                       f'(only {self.settings.command.commander} is obeyed; its trajectories '
                       'are refused)' + (f'; {event}' if event else ''))
        values = {'state': mode, 'enabled': s.enabled, 'moving': s.moving,
                  'referenced': self.referenced, 'referencing': self.referencing,
                  'commander': self.settings.command.commander,
                  'commander_seen': self.commander_seen,
                  'commander_publishers': ' '.join(self.commander_ids),
                  'foreign_publishers': ' '.join(self.foreign),
                  'max_points': self.settings.command.max_points,
                  'silence_stops': self.silence_stops,
                  'fault_axis': s.fault.name if s.fault else '', 'last_event': self.event,
                  **{f'following_error.{n}': f'{e:.3e}'
                     for n, e in zip(JOINT_NAMES, s.following_error, strict=True)}}
        return level, message, values


def foreign_sender(sender: str, command: CommandSettings) -> str:
    """The refusal of a command from ``sender``, not the commander."""
    who = sender or 'a publisher the graph does not name yet'
    return (f'sent by {who}: this driver takes commands only from {command.commander} '
            '(command.commander)')


def _key(times: Times, positions: Points) -> str:
    """The fingerprint of a trajectory as received, also of one the drives refuse as
    malformed (its sender must learn of the refusal); '' when it has no points or ragged
    ones."""
    try:
        return fingerprint(times, positions)
    except (ValueError, IndexError, TypeError):
        return ''
