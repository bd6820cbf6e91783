"""accuracy_monitor_node (node ``accuracy_monitor``): commanded vs measured platform pose, ISO
9283 figures per commanded pose, a tolerance verdict on /diagnostics for each settled pose (its
errors with their expanded uncertainty U from the covariances the tracker's readings state, and
the decision of ``tolerance.decision_rule``: docs/howto/verdicts.md); with the simulation truth
published, the true pose against the target and the tracker against the truth, reported apart.
The tracker's registration (/metrology/registration, latched) is the part of the readings'
covariance averaging does not reduce. The rules: :class:`positioning_cell.accuracy.monitor.
Monitor`; each visit is judged on its final settled window after the positioner's move end (a
``positioner: state`` status on /diagnostics, :func:`positioning_cell.accuracy.move_ended`).
Every ``RELEASE_PERIOD_S`` the streams (readings, true poses) are taken as they came since
(:class:`positioning_cell.ros.latest.Reader`: no wake-up per message) and the inputs go to it
in stamp order, as the offline analysis takes a bag (:class:`positioning_cell.accuracy.
stamp_order.MonitorInputs`): errors and verdicts come about ``HOLD_S`` after their readings.
``accuracy_monitor: recording`` on /diagnostics says whether the recorder records
(:func:`positioning_cell.recording.recording`: every second once one was heard of, and at once
on a change; a stop logged once). /accuracy_monitor/report returns its JSON
(:meth:`Monitor.report`, the publishers each input matched, the recording, the ``inputs`` held
and late); /accuracy_monitor/reset clears the statistics, not the target.
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
    MoveEnds,
    Visit,
    move_ended,
    stamp_seconds,
)
from positioning_cell.accuracy.stamp_order import HOLD_S, MonitorInputs
from positioning_cell.accuracy.verdicts import DECISION_LEVELS, Verdict, verdict_values
from positioning_cell.recording import STATUS_PERIOD_S, RecorderReport, Recording, recording
from positioning_cell.ros import messages as m
from positioning_cell.ros.latest import Reader
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import DIAGNOSTICS_QOS, LATCHED_QOS, SERVICE_QOS, STREAM_QOS
from positioning_cell.ros.spin import NodeStart

_LEVELS = ('ok', 'warn', 'error')
#: How often (s) the streams are taken and the monitor fed (70 messages/s: 10 feeds).
RELEASE_PERIOD_S = 0.1
#: The inputs taken as they come (latched: the tracker locates itself once, at its start) and
#: the streams: each its topic, type and input (a keyword of MonitorInputs.arrive).
EVENTS = ((names.TARGET, PoseStamped, 'targets'),
          (names.TRACKER_REGISTRATION, PoseWithCovarianceStamped, 'registrations'))
STREAMS = ((names.MEASURED_POSE, PoseWithCovarianceStamped, 'measured'),
           (names.TRUE_POSE, PoseStamped, 'truth'))


class AccuracyMonitorNode(Node):
    """The ``accuracy_monitor`` node (docs/conventions/interfaces.md)."""

    NAME = names.NODE_MONITOR
    SETTINGS = MonitorSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS, self._on_change)
        self.monitor = Monitor(self.params.settings)
        self.arrivals = MonitorInputs(self.monitor)
        self._arrived_at = time.monotonic()  # when the last message arrived
        self.pub_position = self.create_publisher(Vector3Stamped, names.POSITION_ERROR, STREAM_QOS)
        self.pub_orientation = self.create_publisher(Vector3Stamped, names.ORIENTATION_ERROR,
                                                     STREAM_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS, DIAGNOSTICS_QOS)
        self.inputs = {topic: self.create_subscription(kind, topic, self._input(name), LATCHED_QOS)
                       for topic, kind, name in EVENTS}
        self.streams = {topic: (name, Reader(self, kind, topic, STREAM_QOS))
                        for topic, kind, name in STREAMS}
        self.create_service(Trigger, names.MONITOR_REPORT, self._report, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, names.MONITOR_RESET, self._reset, qos_profile=SERVICE_QOS)
        # The recorder's latest status (received on the wall clock, s) and what was told of it.
        self.recorder: RecorderReport | None = None
        self.recording: Recording | None = None
        self.create_subscription(DiagnosticArray, names.DIAGNOSTICS, self._on_diagnostics,
                                 DIAGNOSTICS_QOS)
        self.create_timer(STATUS_PERIOD_S, lambda: self._check_recording(periodic=True))
        self.create_timer(RELEASE_PERIOD_S, self._release)

    def _on_change(self, settings: MonitorSettings, changed: frozenset[str]) -> None:
        self.monitor.tolerances = settings.tolerance

    def _ignored(self, item: Ignored) -> None:
        reason = f'{item.topic} message ignored: {item.reason}'
        self.get_logger().warning(reason, throttle_duration_sec=2.0)
        self.pub_diag.publish(m.diagnostic(names.STATUS_MONITOR_INPUT, 'warn', reason, {},
                                           m.stamp(item.time)))

    def _arrive(self, stamps: list[Any], **messages: Any) -> None:
        """Messages in (header ``stamps`` in rank order), held for :meth:`_release`."""
        self.arrivals.arrive(**messages, tags=stamps)
        self._arrived_at = time.monotonic()

    def _input(self, kind: str) -> Any:
        """The callback of a pose input (``kind``: a keyword of MonitorInputs.arrive)."""
        return lambda msg: self._arrive([msg.header.stamp], **{kind: m.pose_messages([msg])})

    def _take_streams(self) -> None:
        """The streams' messages since the last call, in together (:func:`m.pose_batches`)."""
        batches, stamps = m.pose_batches({kind: r.take() for kind, r in self.streams.values()})
        if stamps:
            self._arrive(stamps, **batches)

    def _release(self, flush: bool = False) -> None:
        """Feed the monitor what is released (everything held once nothing arrived for
        HOLD_S, or with ``flush``) and publish what it said, in its order."""
        self._take_streams()
        quiet = flush or time.monotonic() - self._arrived_at >= HOLD_S
        released = self.arrivals.release(flush=quiet and self.arrivals.held > 0)
        if released is None:
            return
        for item in released.ignored:
            self._ignored(item)
        for said in released.said():  # stamped with the header stamp of what said it
            if said.position_error is not None and said.orientation_error is not None:
                self.pub_position.publish(m.vector3_stamped(said.position_error, said.tag))
                self.pub_orientation.publish(m.vector3_stamped(said.orientation_error,
                                                               said.tag))
            if said.visit is not None and said.verdict is not None:
                self._verdict(said.visit, said.verdict, said.tag)

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
                self._arrive([msg.header.stamp], ends=MoveEnds.one(stamp_seconds(
                    msg.header.stamp.sec, msg.header.stamp.nanosec)))
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
        if changed and state.level >= 2:  # rclpy ties one severity to each logging call site
            self.get_logger().error(state.message)
        elif changed and state.stopped:
            self.get_logger().warning(state.message)

    def _report(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        doc = self.monitor.report()
        # Publishers each input subscription has matched: a driver waits for these before the
        # first command, so that no early message reaches the monitor out of order.
        doc['publishers'] = {**{t: sub.get_publisher_count() for t, sub in self.inputs.items()},
                             **{t: r.publisher_count() for t, (_, r) in self.streams.items()}}
        state = recording(self.recorder, time.time())
        doc['recording'] = None if state is None else state.to_dict()
        doc['inputs'] = self.arrivals.to_dict()  # held for their stamp order, late
        response.success, response.message = True, json.dumps(doc)
        return response

    def _reset(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        self._release(flush=True)  # what came before the reset is counted before it
        self.monitor.reset()
        response.success = True
        response.message = 'accuracy statistics cleared (the current target is kept)'
        return response


#: The entry point of ``accuracy_monitor_node``; it imports no scipy as it spins (test_node_start).
main = NodeStart(AccuracyMonitorNode, imports=())


if __name__ == '__main__':
    raise SystemExit(main())
