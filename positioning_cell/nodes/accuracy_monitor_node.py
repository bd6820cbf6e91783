"""accuracy_monitor_node (node ``accuracy_monitor``): commanded vs measured platform pose, ISO
9283 figures per commanded pose, a tolerance verdict on /diagnostics for each settled pose (its
errors with their expanded uncertainty U from the covariances the tracker's readings state, and
the decision of ``tolerance.decision_rule``: docs/howto/verdicts.md); with the simulation truth
published (fed in batches every ``TRUTH_BATCH_S``), the true pose against the target and the
tracker against the truth, reported apart. The tracker's registration (/metrology/registration,
latched) is the part of the readings' covariance averaging does not reduce. The rules:
:class:`positioning_cell.accuracy.monitor.Monitor`. A move end (a ``positioner: state``
status on /diagnostics, :func:`positioning_cell.accuracy.move_ended`) goes to the monitor: each
visit is judged on its final settled window (without an end, on its last stable window when
the next target comes). The recorder's status on /diagnostics says when recording stopped
(:func:`positioning_cell.recording.recording`): ``accuracy_monitor: recording`` every second
once a recorder was heard of and at once on a change (ERROR ``recording stopped: <reason>``
when the recorder failed or went silent, WARN when stopped; logged once). /accuracy_monitor/
report returns its JSON (:meth:`Monitor.report`, the publishers each input matched, the
recording's state); /accuracy_monitor/reset clears the statistics, not the current target.
"""

from __future__ import annotations

import json
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, Vector3Stamped
from rclpy.node import Node
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.accuracy import (
    Ignored,
    Monitor,
    MonitorSettings,
    PoseMessages,
    Visit,
    move_ended,
    stamp_seconds,
)
from positioning_cell.accuracy.monitor import TRUTH_BATCH_S
from positioning_cell.accuracy.verdicts import DECISION_LEVELS, Verdict, verdict_values
from positioning_cell.recording import STATUS_PERIOD_S, RecorderReport, Recording, recording
from positioning_cell.ros import messages as m
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, LATCHED_QOS, SERVICE_QOS, STREAM_QOS
from positioning_cell.ros.spin import NodeStart

_LEVELS = ('ok', 'warn', 'error')


def _pose(header: Any, pose: Any) -> tuple[float, str, Any, Any]:
    return (stamp_seconds(header.stamp.sec, header.stamp.nanosec), header.frame_id,
            *m.pose_arrays(pose))


class AccuracyMonitorNode(Node):
    """The ``accuracy_monitor`` node (docs/conventions/interfaces.md)."""

    NAME = names.NODE_MONITOR
    SETTINGS = MonitorSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS, self._on_change)
        self.monitor = Monitor(self.params.settings)
        self.pub_position = self.create_publisher(Vector3Stamped, names.POSITION_ERROR,
                                                  STREAM_QOS)
        self.pub_orientation = self.create_publisher(Vector3Stamped, names.ORIENTATION_ERROR,
                                                     STREAM_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                              DIAGNOSTICS_QOS)
        self.inputs = {
            names.TARGET: self.create_subscription(PoseStamped, names.TARGET, self._on_target,
                                                   LATCHED_QOS),
            names.MEASURED_POSE: self.create_subscription(
                PoseWithCovarianceStamped, names.MEASURED_POSE, self._on_measured, STREAM_QOS),
            names.TRUE_POSE: self.create_subscription(PoseStamped, names.TRUE_POSE,
                                                      self._on_truth, STREAM_QOS),
            # latched: the tracker publishes where it located itself once, at its start
            names.TRACKER_REGISTRATION: self.create_subscription(
                PoseWithCovarianceStamped, names.TRACKER_REGISTRATION, self._on_registration,
                LATCHED_QOS)}
        self.create_service(Trigger, names.MONITOR_REPORT, self._report, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, names.MONITOR_RESET, self._reset, qos_profile=SERVICE_QOS)
        # The recorder's latest status (received on the wall clock, s) and what was told of it.
        self.recorder: RecorderReport | None = None
        self.recording: Recording | None = None
        self.create_subscription(DiagnosticArray, names.DIAGNOSTICS, self._on_diagnostics,
                                 DIAGNOSTICS_QOS)
        self.create_timer(STATUS_PERIOD_S, lambda: self._check_recording(periodic=True))
        self.create_timer(TRUTH_BATCH_S, self._flush_truth)

    def _on_change(self, settings: MonitorSettings, changed: frozenset[str]) -> None:
        self.monitor.tolerances = settings.tolerance

    def _ignored(self, item: object, stamp: Any) -> None:  # warns of an Ignored, else nothing
        if not isinstance(item, Ignored):
            return
        reason = f'{item.topic} message ignored: {item.reason}'
        self.get_logger().warning(reason, throttle_duration_sec=2.0)
        self.pub_diag.publish(m.diagnostic(names.STATUS_MONITOR_INPUT, 'warn', reason, {},
                                           stamp))

    def _on_target(self, msg: PoseStamped) -> None:
        fed = self.monitor.feed(targets=PoseMessages.one(*_pose(msg.header, msg.pose)))
        for _, ignored in fed.targets_ignored:
            self._ignored(ignored, msg.header.stamp)
        for _, visit, verdict in fed.closed:  # the visit before, on its last stable window
            self._verdict(visit, verdict, msg.header.stamp)

    def _on_measured(self, msg: PoseWithCovarianceStamped) -> None:
        result = self.monitor.measurement(*_pose(msg.header, msg.pose.pose),
                                          covariance=msg.pose.covariance)
        if isinstance(result, Ignored):
            self._ignored(result, msg.header.stamp)
            return
        update, stamp = result.update, msg.header.stamp
        if update.position_error is None or update.orientation_error is None:
            return  # no target yet
        self.pub_position.publish(m.vector3_stamped(update.position_error, stamp))
        self.pub_orientation.publish(m.vector3_stamped(update.orientation_error, stamp))
        if update.visit is not None and result.verdict is not None:
            self._verdict(update.visit, result.verdict, stamp)

    def _on_registration(self, msg: PoseWithCovarianceStamped) -> None:
        self._ignored(self.monitor.registration(*_pose(msg.header, msg.pose.pose),
                                                covariance=msg.pose.covariance), msg.header.stamp)

    def _on_truth(self, msg: PoseStamped) -> None:  # fed in batches: _flush_truth
        self.monitor.queue_truth(*_pose(msg.header, msg.pose))

    def _flush_truth(self) -> None:
        for ignored in self.monitor.flush_truth():
            self._ignored(ignored, self.get_clock().now().to_msg())

    def _verdict(self, visit: Visit, verdict: Verdict, stamp: Any) -> None:
        values = {'pose_key': visit.key, 'cycle': visit.cycle,
                  **verdict_values(verdict), **self.monitor.visit_values(visit)}
        message = f'pose {visit.key} cycle {visit.cycle}: {verdict.message()}'
        level = DECISION_LEVELS[verdict.decision]
        self.pub_diag.publish(m.diagnostic(names.STATUS_MONITOR_VERDICT, level, message,
                                           values, stamp))
        if level == 'ok':  # rclpy ties one severity to each logging call site
            self.get_logger().info(message)
        elif level == 'warn':
            self.get_logger().warning(message)
        else:
            self.get_logger().error(message)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == names.STATUS_POSITIONER and move_ended(m.status_values(status)):
                self._ignored(self.monitor.move_end(stamp_seconds(
                    msg.header.stamp.sec, msg.header.stamp.nanosec)), msg.header.stamp)
            if status.name == names.STATUS_RECORDER:
                self.recorder = RecorderReport(m.status_level(status), status.message,
                                               m.status_values(status), time.time())
                self._check_recording()

    def _check_recording(self, periodic: bool = False) -> None:
        """Publish the recording's state (periodically, and when it changed: the recorder
        failed, stopped or went silent, or recovers); log a stop once."""
        state = recording(self.recorder, time.time())
        changed = state != self.recording
        if state is None or not (changed or periodic):
            return
        self.recording = state
        self.pub_diag.publish(m.diagnostic(names.STATUS_MONITOR_RECORDING, _LEVELS[state.level],
                                           state.message, {'stopped': state.stopped},
                                           self.get_clock().now().to_msg()))
        if not changed:
            return
        if state.level >= 2:  # rclpy ties one severity to each logging call site
            self.get_logger().error(state.message)
        elif state.stopped:
            self.get_logger().warning(state.message)

    def _report(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        doc = self.monitor.report()
        # Publishers each input subscription has matched: a driver waits for these before the
        # first command, so that no early message reaches the monitor out of order.
        doc['publishers'] = {t: sub.get_publisher_count() for t, sub in self.inputs.items()}
        state = recording(self.recorder, time.time())
        doc['recording'] = None if state is None else state.to_dict()
        response.success, response.message = True, json.dumps(doc)
        return response

    def _reset(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        self.monitor.reset()
        response.success = True
        response.message = 'accuracy statistics cleared (the current target is kept)'
        return response


#: The entry point of ``accuracy_monitor_node`` (alone; ``cell_container`` hosts it with others).
main = NodeStart(AccuracyMonitorNode)


if __name__ == '__main__':
    raise SystemExit(main())
