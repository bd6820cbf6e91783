"""The leg_driver node's work without ROS: six servo axes with their encoders, injected faults,
and the efforts (leg forces, θ torques) that hold the payload at the current pose.

One physics step per timer tick (:meth:`LegDriver.step`): the servos are integrated to the
tick's time, the following error checked, and every ``publish_every``-th step a joint-state
publication is due. Time is the driver's own clock in s (any origin shared by all calls).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from positioning_cell.core.kinematics import forward, inverse
from positioning_cell.core.mechanism import JOINT_NAMES, Mechanism
from positioning_cell.errors import InputError
from positioning_cell.mechanics.statics import Payload, Structure, actuator_efforts
from positioning_cell.motion.trajectory import fingerprint
from positioning_cell.parameters import ParameterError, check_fields, group, setting
from positioning_cell.sim.encoders import EncoderReading, Encoders, EncoderSettings
from positioning_cell.sim.faults import DriveFaults
from positioning_cell.sim.guard import AxisGuard, Refusal, TrajectoryRefusedError, check_path
from positioning_cell.sim.paths import JointNamesError, JointPath, path_from_points
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
class DriverSettings:
    """Every parameter of the ``leg_driver`` node (config/cell.yaml)."""

    mechanism: Mechanism = group(Mechanism, 'the machine (home pose)')
    payload: Payload = group(Payload, 'what the platform carries (efforts)')
    structure: Structure = group(Structure, 'stiffness and masses of the machine (efforts)')
    servo: ServoSettings = group(ServoSettings, 'the six position servos')
    encoder: EncoderSettings = group(EncoderSettings, 'the six encoders')
    fault: DriveFaults = group(DriveFaults, 'injected faults (dynamic)')
    physics_rate: float = setting(200.0, 'servo integration timer', 'Hz', low=10.0,
                                  high=2000.0)
    publish_every: int = setting(2, 'joint states are published every this many physics '
                                 'steps', low=1, high=1000)
    effort_rate: float = setting(20.0, 'largest rate of the payload-effort update (only '
                                 'while the axes move)', 'Hz', low=1.0, high=200.0)
    diagnostics_period: float = setting(1.0, 'periodic /diagnostics', 's', low=0.1, high=60.0)
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
    and whether a joint-state publication is due."""

    fault: Fault | None
    publish: bool


class Outcome(NamedTuple):
    """Whether a command was accepted, and the words for it; for a trajectory also its
    :func:`~positioning_cell.motion.trajectory.fingerprint`, the refusal's code and the count of
    trajectories received so far."""

    accepted: bool
    message: str
    key: str = ''
    code: Refusal | None = None
    sequence: int = 0


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
        self._phis: FloatArray | None = None

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
        self._steps += 1
        s = self.settings
        if self._steps % max(1, round(s.physics_rate / s.effort_rate)) == 0:
            self.update_effort()
        return Step(fault, self._steps % s.publish_every == 0)

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

    def update_effort(self) -> FloatArray | None:
        """The efforts (6,) (N, N·m) holding the payload at the axes' true position; computed
        again only when the axes have moved since."""
        q = self.servos.state.position
        if self._effort_position is not None and np.array_equal(q, self._effort_position):
            return self.effort
        s = self.settings
        fk = forward(s.mechanism, q[:3], q[3:], self._phis)
        if fk.converged[0]:
            self._phis = fk.phis
            self.effort = actuator_efforts(s.mechanism, fk.position, fk.quaternion, s.payload,
                                           s.structure)[0]
            self._effort_position = q.copy()
        return self.effort

    def follow(self, names: Sequence[str], times: Sequence[float],
               positions: Sequence[Sequence[float]], velocities: Sequence[Sequence[float]],
               start: float | None, now: float) -> Outcome:
        """Follow trajectory points (trajectory_msgs/JointTrajectory fields) from ``start``
        (s on this clock; None: on receipt), after every check of :mod:`.guard`. A refused
        trajectory changes nothing; the outcome says why, with the trajectory's key."""
        self.servos.advance(now)
        self.received += 1
        key = _key(times, positions)
        try:
            path = self._path(names, times, positions, velocities)
            if not self.referenced:
                raise TrajectoryRefusedError(
                    Refusal.NOT_REFERENCED, 'axes not referenced: home them first '
                    '(/positioner/home or /leg_driver/reference)')
            self._command(path, now if start is None else start)
        except TrajectoryRefusedError as err:
            self.event = f'trajectory refused: {err}'
            return Outcome(False, self.event, key, err.code, self.received)
        self.event = f'trajectory accepted: {len(times)} points, {path.duration:.3f} s'
        return Outcome(True, self.event, key, None, self.received)

    def _path(self, names: Sequence[str], times: Sequence[float],
              positions: Sequence[Sequence[float]],
              velocities: Sequence[Sequence[float]]) -> JointPath:
        try:
            return path_from_points(names, times, positions, velocities)
        except JointNamesError as err:
            raise TrajectoryRefusedError(Refusal.INVALID_JOINTS, str(err)) from err
        except InputError as err:
            raise TrajectoryRefusedError(Refusal.INVALID_GOAL, str(err)) from err

    def _command(self, path: JointPath, start: float) -> None:
        """Check ``path`` joined to the setpoint at ``start``, then follow it."""
        position, velocity = self.servos.setpoint(max(start, self.servos.time))
        check_path(path.starting_from(position, velocity), self.guard, position)
        self.servos.command(path, start)

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
        goal = self.settings.home_positions()
        v = self.settings.servo.velocity_limits * self.settings.homing.speed_fraction
        a = self.settings.servo.acceleration_limits * self.settings.homing.speed_fraction
        duration = float(np.max(np.abs(goal - start) / v + v / a, initial=0.0)) + 1e-3
        times = np.linspace(0.0, duration, 51)
        tau = times / duration
        shape = tau * tau * (3.0 - 2.0 * tau)  # smoothstep: rest to rest
        rate = 6.0 * tau * (1.0 - tau) / duration
        path = JointPath(times, start + shape[:, None] * (goal - start),
                         rate[:, None] * (goal - start))
        self.referenced, self.referencing = False, True
        s.command(path, now)
        self.event = f'referencing run to the home position, {duration:.1f} s'
        return self.event

    def stop(self, now: float) -> str:
        """Controlled stop from the current setpoint, then hold."""
        self.servos.advance(now)
        self.servos.stop()
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
        values = {'state': mode, 'enabled': s.enabled, 'moving': s.moving,
                  'referenced': self.referenced, 'referencing': self.referencing,
                  'fault_axis': s.fault.name if s.fault else '', 'last_event': self.event,
                  **{f'following_error.{n}': f'{e:.3e}'
                     for n, e in zip(JOINT_NAMES, s.following_error, strict=True)}}
        return level, message, values


def _key(times: Sequence[float], positions: Sequence[Sequence[float]]) -> str:
    """The fingerprint of a trajectory as received, also of one the drives refuse as
    malformed (its sender must learn of the refusal); '' when it has no points or ragged
    ones."""
    try:
        return fingerprint(times, positions)
    except (ValueError, IndexError, TypeError):
        return ''
