"""accuracy_monitor: commanded vs measured platform pose, ISO 9283 figures per commanded pose,
a tolerance verdict on /diagnostics for each settled pose (positioning_cell.accuracy).

Also, when the simulation truth is published: the true pose against the target (the cell's
real accuracy) and the tracker against the truth (the tracker's own error), reported apart.

/accuracy_monitor/report returns JSON (SI: m, rad, s): ``tolerances``, ``settle`` (settings),
``target`` (current one or null), ``verdicts`` (counts ok / error), ``measured`` and ``truth``
(AccuracyResult.to_dict: settled ``visits`` and ISO 9283 ``poses``; truth null until a true
pose arrives), ``tracker`` (ErrorStatistics of measured − true, or null). /accuracy_monitor/reset
clears all of it but keeps the current target.
"""

from __future__ import annotations

import json
import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, Vector3Stamped
from rclpy.node import Node
from std_srvs.srv import Trigger

from positioning_cell import accuracy
from positioning_cell.errors import InputError
from positioning_cell.nodes.common import (
    BASE_FRAME,
    COMMAND_QOS,
    LATCHED_QOS,
    STREAM_QOS,
    Parameters,
    ParamSpec,
    diagnostic,
    flat_block,
    pose_arrays,
    run,
    vector3_stamped,
)

NAME = 'accuracy_monitor'
_DEFAULT = accuracy.SettleSettings()
SPECS = [
    ParamSpec('tolerance.position', accuracy.POSITION_TOLERANCE,
              'settled-pose position tolerance, m', low=1e-9, high=0.01),
    ParamSpec('tolerance.orientation', accuracy.ORIENTATION_TOLERANCE,
              'settled-pose orientation tolerance (rotation angle), rad', low=1e-9, high=0.1),
    ParamSpec('settle.window', _DEFAULT.window, 'stability window, s', 1e-3, 60.0,
              read_only=True),
    ParamSpec('settle.dwell', _DEFAULT.dwell, 'wait after a target change, s', 0.0, 600.0,
              read_only=True),
    ParamSpec('settle.position_threshold', _DEFAULT.position_threshold,
              'largest bounding-box diagonal of a stable window, m', 1e-9, 0.1, read_only=True),
    ParamSpec('settle.angle_threshold', _DEFAULT.angle_threshold,
              'largest bounding-box diagonal of the orientation errors, rad', 1e-9, 1.0,
              read_only=True),
    ParamSpec('settle.min_samples', _DEFAULT.min_samples, 'fewest samples in a window', 2,
              100000, read_only=True),
    ParamSpec('settle.key_position_tolerance', _DEFAULT.key_position_tolerance,
              'targets this close are one commanded pose, m', 1e-12, 0.01, read_only=True),
    ParamSpec('settle.key_angle_tolerance', _DEFAULT.key_angle_tolerance,
              'targets this close are one commanded pose, rad', 1e-12, 0.1, read_only=True),
    ParamSpec('truth.max_stamp_difference', 1e-3,
              'largest stamp difference of a measurement and a true pose that pair, s',
              1e-9, 1.0, read_only=True),
]


def _settings(values: dict[str, Any]) -> accuracy.SettleSettings:
    return accuracy.SettleSettings.from_params(flat_block(values, 'settle'))


def _tolerances(values: dict[str, Any]) -> accuracy.Tolerances:
    return accuracy.Tolerances(values['tolerance.position'], values['tolerance.orientation'])


def _validate(values: dict[str, Any]) -> None:
    _settings(values)
    _tolerances(values)


def _pose_input(header, pose) -> tuple[float, Any, Any]:
    """(time s, position, quaternion) of a pose message in the base frame."""
    if header.frame_id != BASE_FRAME:
        raise InputError(f'frame_id {header.frame_id!r}: expected {BASE_FRAME!r}')
    p, q = pose_arrays(pose)
    return accuracy.stamp_seconds(header.stamp.sec, header.stamp.nanosec), p, q


class AccuracyMonitor(Node):
    """Node ``accuracy_monitor``; all callbacks in the default mutually exclusive group."""

    def __init__(self) -> None:
        super().__init__(NAME)
        self.params = Parameters(self, SPECS, _validate, self._on_change)
        values = self.params.values
        self.tolerances = _tolerances(values)
        self.measured = accuracy.AccuracyAccumulator(_settings(values))
        self.truth = accuracy.AccuracyAccumulator(_settings(values))
        self.tracker = accuracy.TrackerErrorAccumulator(values['truth.max_stamp_difference'])
        self.truth_seen = False
        self.verdicts = {'ok': 0, 'error': 0}
        self.pub_position = self.create_publisher(Vector3Stamped, '/accuracy/position_error',
                                                  STREAM_QOS)
        self.pub_orientation = self.create_publisher(
            Vector3Stamped, '/accuracy/orientation_error', STREAM_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', COMMAND_QOS)
        self.inputs = {
            '/positioner/target': self.create_subscription(
                PoseStamped, '/positioner/target', self._on_target, LATCHED_QOS),
            '/metrology/pose': self.create_subscription(
                PoseWithCovarianceStamped, '/metrology/pose', self._on_measured, STREAM_QOS),
            '/sim/platform/true_pose': self.create_subscription(
                PoseStamped, '/sim/platform/true_pose', self._on_truth, STREAM_QOS)}
        self.create_service(Trigger, '/accuracy_monitor/report', self._report)
        self.create_service(Trigger, '/accuracy_monitor/reset', self._reset)

    def _on_change(self, values: dict[str, Any]) -> None:
        self.tolerances = _tolerances(values)

    def _bad(self, what: str, err: Exception, stamp) -> None:
        reason = f'{what} message ignored: {err}'
        self.get_logger().warning(reason, throttle_duration_sec=2.0)
        self.pub_diag.publish(diagnostic(f'{NAME}: input', 'warn', reason, {}, stamp))

    def _on_target(self, msg: PoseStamped) -> None:
        try:
            t, p, q = _pose_input(msg.header, msg.pose)
            self.measured.add_target(t, p, q, clamp=True)
            self.truth.add_target(t, p, q, clamp=True)
        except InputError as err:
            self._bad('/positioner/target', err, msg.header.stamp)

    def _on_measured(self, msg: PoseWithCovarianceStamped) -> None:
        try:
            t, p, q = _pose_input(msg.header, msg.pose.pose)
            update = self.measured.add_sample(t, p, q)
            self.tracker.add_measured(t, p, q)
        except InputError as err:
            self._bad('/metrology/pose', err, msg.header.stamp)
            return
        if update.position_error is None or update.orientation_error is None:
            return  # no target yet
        stamp = msg.header.stamp
        self.pub_position.publish(vector3_stamped(update.position_error.tolist(), stamp))
        self.pub_orientation.publish(vector3_stamped(update.orientation_error.tolist(), stamp))
        if update.visit is not None:
            self._verdict(update.visit, stamp)

    def _on_truth(self, msg: PoseStamped) -> None:
        try:
            t, p, q = _pose_input(msg.header, msg.pose)
            self.truth.add_sample(t, p, q)
            self.tracker.add_truth(t, p, q)
        except InputError as err:
            self._bad('/sim/platform/true_pose', err, msg.header.stamp)
            return
        self.truth_seen = True

    def _verdict(self, visit: accuracy.Visit, stamp) -> None:
        verdict = accuracy.judge_visit(visit, self.tolerances)
        self.verdicts['ok' if verdict.ok else 'error'] += 1
        figures = next(f for f in self.measured.result().poses if f.key == visit.key)
        values = {'pose_key': visit.key, 'cycle': visit.cycle,
                  'position_error_um': f'{verdict.position_error * 1e6:.1f}',
                  'orientation_error_deg': f'{math.degrees(verdict.orientation_error):.4f}',
                  **figures.for_people()}
        message = f'pose {visit.key} cycle {visit.cycle}: {verdict.message()}'
        self.pub_diag.publish(diagnostic(f'{NAME}: settled pose',
                                         'ok' if verdict.ok else 'error', message, values, stamp))
        if verdict.ok:  # rclpy ties one severity to each logging call site
            self.get_logger().info(message)
        else:
            self.get_logger().error(message)

    def _report(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        target = self.measured.target
        stats = self.tracker.statistics()
        doc = {
            'tolerances': {'position': self.tolerances.position,
                           'orientation': self.tolerances.orientation},
            'settle': self.measured.settings.to_params(),
            'target': None if target is None else {
                'time': target[0], 'position': target[1].tolist(),
                'quaternion': target[2].tolist(), 'key': target[3]},
            'verdicts': dict(self.verdicts),
            'measured': self.measured.result().to_dict(),
            'truth': self.truth.result().to_dict() if self.truth_seen else None,
            'tracker': None if stats is None else stats.to_dict(),
            # Publishers each input subscription has matched: a driver waits for these before
            # the first command, so that no early message reaches the monitor out of order.
            'publishers': {t: sub.get_publisher_count() for t, sub in self.inputs.items()},
        }
        response.success = True
        response.message = json.dumps(doc)
        return response

    def _reset(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        self.measured.reset(keep_target=True)
        self.truth.reset(keep_target=True)
        self.tracker.reset()
        self.truth_seen = False
        self.verdicts = {'ok': 0, 'error': 0}
        response.success = True
        response.message = 'accuracy statistics cleared (the current target is kept)'
        return response


def main(args: list[str] | None = None) -> int:
    """Entry point of ``accuracy_monitor_node``."""
    return run(AccuracyMonitor, args)


if __name__ == '__main__':
    raise SystemExit(main())
