"""leg_driver: simulated drives and encoders of the three legs (six axes).

Follows /legs/joint_trajectory (an empty one stops with controlled deceleration), publishes
the encoder readings on /legs/joint_states and the truth on /sim/legs/true_joint_states, is
switched by /leg_driver/enable, reports on /diagnostics. The model is positioning_cell.servo.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool
from trajectory_msgs.msg import JointTrajectory

from positioning_cell import kinematics
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.mechanism import JOINT_NAMES
from positioning_cell.nodes.common import (
    COMMAND_QOS,
    STREAM_QOS,
    Parameters,
    ParamSpec,
    block_specs,
    diagnostic,
    flat_block,
    joint_state,
    mechanism_from,
    mechanism_specs,
    run,
)
from positioning_cell.servo import (
    AxisLimits,
    Encoders,
    EncoderSettings,
    FaultInjection,
    LegServos,
    MotionRefusedError,
    ServoSettings,
    path_from_points,
    settings_from_params,
)
from positioning_cell.statics import Payload, Structure, actuator_efforts

_SERVO, _ENCODER = ServoSettings(), EncoderSettings()


def _axis_specs(kind: str, limits: AxisLimits, unit: str) -> list[ParamSpec]:
    return [ParamSpec(f'{kind}.max_velocity', limits.velocity, f'{unit}/s', 1e-6, 100.0,
                      read_only=True),
            ParamSpec(f'{kind}.max_acceleration', limits.acceleration, f'{unit}/s^2', 1e-6,
                      1000.0, read_only=True),
            ParamSpec(f'{kind}.following_error_limit', limits.following_error,
                      f'|setpoint - position| that faults the drive, {unit}', 1e-9, 10.0,
                      read_only=True)]


SPECS = [
    *mechanism_specs(),
    *block_specs('payload', Payload().to_params(), 'payload carried by the platform'),
    *block_specs('structure', Structure().to_params(), 'stiffness and masses of the machine'),
    ParamSpec('effort_rate', 20.0, 'rate of the payload-load (effort) update, Hz', 1.0, 200.0),
    ParamSpec('physics_rate', 250.0, 'servo integration timer, Hz', 10.0, 2000.0, read_only=True),
    ParamSpec('publish_rate', 200.0, 'joint_states rate, Hz', 1.0, 1000.0, read_only=True),
    ParamSpec('diagnostics_period', 1.0, 'periodic /diagnostics, s', 0.1, 60.0, read_only=True),
    ParamSpec('enabled_at_start', True, 'drives enabled at start', read_only=True),
    ParamSpec('initial_at_home', True, 'start at the home pose (else initial_positions)',
              read_only=True),
    ParamSpec('initial_positions', [0.2, 0.2, 0.2, 0.0, 0.0, 0.0],
              'start positions in JOINT_NAMES order, m and rad', read_only=True),
    ParamSpec('servo.position_gain', _SERVO.position_gain, 'P gain K_p, 1/s', 0.1, 1000.0,
              read_only=True),
    ParamSpec('servo.velocity_lag', _SERVO.velocity_lag, 'velocity-loop time constant, s',
              1e-4, 1.0, read_only=True),
    ParamSpec('servo.max_step', _SERVO.max_step, 'largest integration step, s', 1e-4, 0.05,
              read_only=True),
    *_axis_specs('linear', _SERVO.linear, 'm'),
    *_axis_specs('rotary', _SERVO.rotary, 'rad'),
    ParamSpec('encoder.linear_resolution', _ENCODER.linear_resolution, 'm per count', 1e-9,
              1e-3, read_only=True),
    ParamSpec('encoder.rotary_counts_per_rev', _ENCODER.rotary_counts, 'counts per revolution',
              16, 2**31, read_only=True),
    ParamSpec('encoder.linear_noise', 2e-7, 'noise sigma, m', 0.0, 1e-3, read_only=True),
    ParamSpec('encoder.rotary_noise', 2e-6, 'noise sigma, rad', 0.0, 0.1, read_only=True),
    ParamSpec('encoder.seed', 0, 'seed of the encoder noise generator', 0, 2**31 - 1,
              read_only=True),
    ParamSpec('fault.encoder_dropout', '', 'encoders that fail: joint names or indices 0-5'),
    ParamSpec('fault.encoder_dropout_mode', 'freeze', 'a failed encoder freezes or reads NaN',
              choices=('freeze', 'missing')),
    ParamSpec('fault.stuck_axis', '', 'jammed axes: joint names or indices 0-5'),
    ParamSpec('fault.noise_burst', [1.0, 0.0], '[noise sigma scale >= 1, duration s] from set'),
]


class LegDriverNode(Node):
    """Six simulated servo axes with encoders (positioning_cell.servo.LegServos, Encoders)."""

    def __init__(self) -> None:
        super().__init__('leg_driver')
        self.params = Parameters(self, SPECS, validate=self._check, on_change=self._apply)
        values = self.params.values
        self.settings, encoder = settings_from_params(values)
        mech = mechanism_from(values)
        kinematics.warm_up()  # compiled FK ready before the first command
        home = kinematics.inverse(mech, mech.home_position, mech.home_quaternion)
        start = (np.concatenate([home.lengths[0], home.thetas[0]]) if values['initial_at_home']
                 else np.asarray(values['initial_positions'], dtype=float))
        self._t0 = self.get_clock().now().nanoseconds
        self.servos = LegServos(self.settings, start, self._now(),
                                enabled=values['enabled_at_start'])
        self.encoders = Encoders(encoder, np.random.default_rng(values['encoder.seed']))
        self._burst_start = 0.0
        self._event = 'started'
        self._apply(values)
        self.add_post_set_parameters_callback(self._on_set)
        self._states = self.create_publisher(JointState, 'legs/joint_states', STREAM_QOS)
        self._truth = self.create_publisher(JointState, 'sim/legs/true_joint_states', STREAM_QOS)
        self._diagnostics = self.create_publisher(DiagnosticArray, '/diagnostics', STREAM_QOS)
        self.create_subscription(JointTrajectory, 'legs/joint_trajectory', self._on_trajectory,
                                 COMMAND_QOS)
        self.create_service(SetBool, '~/enable', self._on_enable)
        self.create_timer(1.0 / values['physics_rate'], self._advance)
        self.create_timer(1.0 / values['publish_rate'], self._publish)
        # Effort: leg forces (N) and θ torques (N·m) that hold the configured payload at the
        # drives' current pose (issue 6: statics by the Jacobian transpose).
        self._mech = mech
        self._payload = Payload.from_params(flat_block(values, 'payload'))
        self._structure = Structure.from_params(flat_block(values, 'structure'))
        self._effort: np.ndarray | Sequence[float] = ()
        self._phis: np.ndarray | None = None
        self.create_timer(1.0 / values['effort_rate'], self._update_effort)
        self.create_timer(values['diagnostics_period'], self._report)
        self._report()

    # -- time ------------------------------------------------------------------------------
    def _now(self) -> float:
        """Seconds since the node started (the servo time base)."""
        return (self.get_clock().now().nanoseconds - self._t0) * 1e-9

    def _stamp(self, t: float):
        return Time(nanoseconds=self._t0 + round(t * 1e9)).to_msg()

    # -- parameters ------------------------------------------------------------------------
    def _check(self, values) -> None:
        if len(values['initial_positions']) != len(JOINT_NAMES):
            raise ConfigError(f'initial_positions = {values["initial_positions"]!r}: expected '
                              f'{len(JOINT_NAMES)} values ({", ".join(JOINT_NAMES)})')
        FaultInjection.from_params(values, settings_from_params(values)[1])

    def _apply(self, values) -> None:
        self.faults = FaultInjection.from_params(values)
        if hasattr(self, 'servos'):
            self.servos.stuck = self.faults.stuck

    def _on_set(self, params) -> None:
        if any(p.name == 'fault.noise_burst' for p in params):
            self._burst_start = self._now()
        self._report(f'fault injection set: {", ".join(p.name for p in params)}')

    # -- callbacks -------------------------------------------------------------------------
    def _advance(self) -> None:
        fault = self.servos.advance(self._now())
        if fault is not None:
            self.get_logger().error(f'{fault.message()}; motion stopped')
            self._report(f'fault: {fault.message()}')

    def _publish(self) -> None:
        s, faults = self.servos, self.faults
        reading = self.encoders.read(s.state, dropout=faults.dropout, missing=faults.missing,
                                     noise_scale=faults.noise_scale(s.time - self._burst_start))
        stamp = self._stamp(s.time)
        self._states.publish(joint_state(JOINT_NAMES, stamp, reading.position, reading.velocity,
                                         self._effort))
        self._truth.publish(joint_state(JOINT_NAMES, stamp, s.state.position, s.state.velocity,
                                        self._effort))

    def _update_effort(self) -> None:
        q = self.servos.state.position
        fk = kinematics.forward(self._mech, q[:3], q[3:], self._phis)
        if fk.converged[0]:
            self._phis = fk.phis
            self._effort = actuator_efforts(self._mech, fk.position, fk.quaternion,
                                            self._payload, self._structure)[0]

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        now = self._now()
        self.servos.advance(now)
        if not msg.points:
            self.servos.stop()
            self._report('stop: empty trajectory, controlled deceleration')
            return
        try:
            path = path_from_points(
                msg.joint_names,
                [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points],
                [p.positions for p in msg.points], [p.velocities for p in msg.points],
                self.settings)
            stamp = Time.from_msg(msg.header.stamp).nanoseconds
            self.servos.command(path, now if stamp == 0 else (stamp - self._t0) * 1e-9)
        except (InputError, MotionRefusedError) as err:
            self.get_logger().warning(f'trajectory refused: {err}')
            self._report(f'trajectory refused: {err}', 'warn')
            return
        self._report(f'trajectory accepted: {len(msg.points)} points, {path.duration:.3f} s')

    def _on_enable(self, request: SetBool.Request, response: SetBool.Response):
        self.servos.advance(self._now())
        cleared = self.servos.fault
        self.servos.enable(request.data)
        response.success = True
        response.message = ('drives enabled' if request.data else 'drives disabled, axes hold') + (
            f' (fault cleared: {cleared.message()})' if cleared and request.data else '')
        self._report(response.message)
        return response

    def _report(self, event: str | None = None, level: str | None = None) -> None:
        """/diagnostics: the drives' mode, fault axis and following errors; ``event`` is the
        latest thing that happened (kept for the periodic reports)."""
        s = self.servos
        self._event = event or self._event
        mode = s.mode
        level = level or {'fault': 'error', 'disabled': 'warn'}.get(mode, 'ok')
        message = s.fault.message() if s.fault else (event or mode)
        values = {'state': mode, 'enabled': s.enabled, 'moving': s.moving,
                  'fault_axis': s.fault.name if s.fault else '', 'last_event': self._event,
                  **{f'following_error.{n}': f'{e:.3e}'
                     for n, e in zip(JOINT_NAMES, s.following_error, strict=True)}}
        self._diagnostics.publish(diagnostic('leg_driver', level, message, values,
                                             self._stamp(s.time), hardware_id='leg_drives'))


def main(args: list[str] | None = None) -> int:
    """Entry point of ``leg_driver_node``."""
    return run(LegDriverNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
