"""Node ``pose_measurement``: the machine's truth and a simulated laser tracker measuring it.

/sim/legs/true_joint_states → the true platform pose (truth.* parameters, at most
``truth_rate_hz``) on /sim/platform/true_pose, stamped with the joint state's time → at
``rate_hz`` a tracker reading of the SMRs, fitted pose and covariance on /metrology/pose,
stamped with the time of the truth it measured. Models: positioning_cell.metrology.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from positioning_cell import kinematics
from positioning_cell.errors import ConvergenceError, InputError
from positioning_cell.mechanism import JOINT_NAMES
from positioning_cell.metrology import (
    Simulation,
    TargetLayout,
    TooFewTargetsError,
    Tracker,
    observe,
)
from positioning_cell.nodes.common import (
    BASE_FRAME,
    STREAM_QOS,
    Parameters,
    ParamSpec,
    diagnostic,
    joint_values,
    mechanism_specs,
    pose_msg,
    pose_stamped,
    run,
)

NAME = 'pose_measurement'
_TRACKER = Tracker()
_OPTIONAL = ('delta_a1', 'delta_a2', 'delta_b1', 'delta_b2', 'u_offsets', 's_offsets')


def _specs() -> list[ParamSpec]:
    truth = 'simulation truth (read-only): '
    return [
        *mechanism_specs(),
        ParamSpec('truth.clearance.model', 'effective_length', truth + 'clearance model',
                  choices=('effective_length', 'vector', 'load', 'none'), read_only=True),
        ParamSpec('truth.clearance.r_a', Parameter.Type.DOUBLE,
                  truth + 'U-joint clearance, m (unset: mechanism.joint_clearance_u)',
                  read_only=True),
        ParamSpec('truth.clearance.r_b', Parameter.Type.DOUBLE,
                  truth + 'S-joint clearance, m (unset: mechanism.joint_clearance_s)',
                  read_only=True),
        *(ParamSpec(f'truth.clearance.{k}', Parameter.Type.DOUBLE_ARRAY,
                    truth + f'{k} (rad or m; unset: drawn from truth.clearance.seed)',
                    read_only=True) for k in _OPTIONAL),
        ParamSpec('truth.clearance.seed', 0, truth + 'seed of the clearance directions',
                  low=0, read_only=True),
        ParamSpec('truth.base_offsets', [0.0] * 9,
                  truth + 'U-centre errors, 3 legs x (x, y, z), m, base frame', read_only=True),
        ParamSpec('truth.platform_offsets', [0.0] * 9,
                  truth + 'S-centre errors, 3 legs x (x, y, z), m, platform frame',
                  read_only=True),
        ParamSpec('tracker.position', list(_TRACKER.position), 'tracker origin in base, m'),
        ParamSpec('tracker.orientation', list(_TRACKER.orientation),
                  'tracker frame in base, quaternion x, y, z, w'),
        ParamSpec('tracker.mpe_constant', _TRACKER.mpe_constant, 'MPE = a + b d: a, m',
                  low=0.0, high=1e-3),
        ParamSpec('tracker.mpe_proportional', _TRACKER.mpe_proportional,
                  'MPE = a + b d: b, m per m', low=0.0, high=1e-3),
        ParamSpec('tracker.coverage_factor', _TRACKER.coverage_factor, 'MPE = k sigma: k',
                  low=0.5, high=6.0),
        ParamSpec('targets.platform', [v for t in TargetLayout().points for v in t],
                  'SMR centres x, y, z per target (>= 4), m, platform frame'),
        ParamSpec('rate_hz', 20.0, 'tracker measurement rate, Hz', low=0.1, high=200.0,
                  read_only=True),
        ParamSpec('truth_rate_hz', 50.0, 'largest true-pose update rate, Hz', low=1.0,
                  high=500.0, read_only=True),
        ParamSpec('seed', 0, 'seed of the measurement noise and faults', low=0, read_only=True),
        ParamSpec('fault.occlusion_probability', 0.0, 'per target and reading', low=0.0,
                  high=1.0),
        ParamSpec('fault.outlier_probability', 0.0, 'per visible target and reading',
                  low=0.0, high=1.0),
        ParamSpec('fault.outlier_magnitude', 1e-3, 'outlier displacement, m', low=0.0,
                  high=0.1),
        ParamSpec('fit.reject_threshold', 5.0, 'outlier rejection, residual / sigma',
                  low=1.0, high=1000.0),
    ]


def check(values: dict[str, Any]) -> None:
    """Raise ConfigError if the parameter ``values`` do not make a valid simulation."""
    Simulation.from_params(values)


class PoseMeasurementNode(Node):
    """Truth model + simulated laser tracker (interfaces.md, node ``pose_measurement``)."""

    def __init__(self) -> None:
        super().__init__(NAME)
        self._params = Parameters(self, _specs(), validate=check, on_change=self._configure)
        self._setup = Simulation.from_params(self._params.values)
        kinematics.warm_up()  # compiled FK ready before the first truth update
        self._rng = np.random.default_rng(self._params['seed'])
        self._latest: tuple[np.ndarray, Any] | None = None  # joints (6,), stamp
        self._joints = np.full(6, np.nan)  # joints of the current truth (NaN: none)
        self._phis: np.ndarray | None = None
        self._true: tuple[np.ndarray, np.ndarray, Any] | None = None  # p, q, stamp
        self._stats: dict[str, Any] = {
            'targets_visible': 0, 'targets_used': 0, 'outliers_rejected': 0,
            'outliers_rejected_total': 0, 'fit_residual_rms_um': float('nan'),
            'measurements': 0, 'failed_measurements': 0, 'truth_updates': 0}
        self._problem: tuple[str, str] = ('warn', 'waiting for /sim/legs/true_joint_states')
        self._true_pub = self.create_publisher(PoseStamped, '/sim/platform/true_pose',
                                               STREAM_QOS)
        self._pose_pub = self.create_publisher(PoseWithCovarianceStamped, '/metrology/pose',
                                               STREAM_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', STREAM_QOS)
        self.create_subscription(JointState, '/sim/legs/true_joint_states', self._on_joints,
                                 STREAM_QOS)
        self.create_timer(1.0 / self._params['truth_rate_hz'], self._update_truth)
        self.create_timer(1.0 / self._params['rate_hz'], self._measure)
        self.create_timer(1.0, lambda: self._diag_pub.publish(self._diagnostics()))

    def _configure(self, values: dict[str, Any]) -> None:
        self._setup = Simulation.from_params(values)

    def _report(self, level: str, message: str) -> None:
        """Record the state shown on /diagnostics (published at 1 Hz); log problems."""
        if level != 'ok':
            self.get_logger().warning(message, throttle_duration_sec=2.0)
        self._problem = (level, message)

    def _on_joints(self, msg: JointState) -> None:
        values = joint_values(msg, JOINT_NAMES)
        if values is None or not np.all(np.isfinite(values)):
            self._report('warn', 'ignored a true joint state without finite positions of '
                         + ', '.join(JOINT_NAMES))
            return
        stamp = msg.header.stamp
        if stamp.sec == 0 and stamp.nanosec == 0:
            stamp = self.get_clock().now().to_msg()
        self._latest = (values, stamp)

    def _update_truth(self) -> None:
        if self._latest is None:
            return
        joints, stamp = self._latest
        self._latest = None
        if self._true is not None and np.array_equal(joints, self._joints):
            self._true = (*self._true[:2], stamp)  # the machine has not moved
        else:
            try:
                result = self._setup.truth.attained_pose(joints[:3], joints[3:], self._phis)
                if not result.converged[0]:
                    raise ConvergenceError('forward kinematics did not converge')
            except (InputError, ConvergenceError) as err:
                self._true = None
                self._report('error', f'no true pose for joints {joints.tolist()}: {err}')
                return
            self._joints, self._phis = joints, result.phis[0]
            self._true = (result.position[0], result.quaternion[0], stamp)
        self._stats['truth_updates'] += 1
        position, quaternion, _ = self._true
        self._true_pub.publish(pose_stamped(position.tolist(), quaternion.tolist(), stamp))

    def _measure(self) -> None:
        if self._true is None:
            return
        position, quaternion, stamp = self._true
        s = self._setup
        try:
            _, fit = observe(s.tracker, s.layout, position, quaternion, self._rng,
                             s.faults, reject_threshold=s.reject_threshold)
        except TooFewTargetsError as err:
            self._stats['failed_measurements'] += 1
            self._report('warn', f'no measurement: {err}')
            return
        msg = PoseWithCovarianceStamped()
        msg.header.stamp, msg.header.frame_id = stamp, BASE_FRAME
        msg.pose.pose = pose_msg(fit.position[0].tolist(), fit.quaternion[0].tolist())
        msg.pose.covariance = fit.covariance[0].ravel().tolist()
        self._pose_pub.publish(msg)
        rejected = int(fit.rejected[0])
        self._stats.update(
            targets_visible=int(fit.visible[0].sum()), targets_used=int(fit.inliers[0].sum()),
            outliers_rejected=rejected, fit_residual_rms_um=round(float(fit.rms[0]) * 1e6, 3),
            outliers_rejected_total=self._stats['outliers_rejected_total'] + rejected,
            measurements=self._stats['measurements'] + 1)
        self._report('ok', 'measuring')

    def _diagnostics(self) -> DiagnosticArray:
        level, message = self._problem
        if level == 'ok':
            st = self._stats
            message = (f'{st["targets_used"]}/{len(self._setup.layout.points)} targets, '
                       f'residual RMS {st["fit_residual_rms_um"]} um')
        return diagnostic(NAME, level, message, self._stats, self.get_clock().now().to_msg())


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the ``pose_measurement_node`` executable."""
    return run(PoseMeasurementNode, args)
