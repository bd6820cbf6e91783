"""recorder: records the cell's topics into a rosbag2 MCAP bag (positioning_cell.bag).

Raw (CDR) subscriptions, created as matching topics appear (graph polled every
``discovery_period_s``), reliable and transient-local where the publishers are; message log
time = receive time (system clock), header stamps untouched. Chunks are flushed every
``flush_period_s``, so a SIGKILL loses at most that much (``recover_bag`` restores the rest);
SIGINT / SIGTERM close the bag with its index and metadata.yaml. Spun by rclpy's
EventsExecutor (several times the throughput of the default executors).

Its status on /diagnostics (``recorder``, every second) carries the free space of the bag's
filesystem, WARN below the ``disk.*`` margins. When the disk fails (any OSError at a write,
flush, split or close: ENOSPC, EFBIG, EIO ...) the writer closes the bag with what it has; the
recorder logs one line (errno, file, what the bag holds), publishes ERROR ``recording stopped:
...`` and exits with :data:`EXIT_WRITE_FAILED`. The logic: :class:`positioning_cell.recording.
recorder.Recorder`.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.duration import Duration
from rclpy.node import Node
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.bag import BagError, RecorderSettings, TopicSelection, recording_qos
from positioning_cell.bag.writer import BagWriteError
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.recording.recorder import Recorder
from positioning_cell.recording.status import STATUS_PERIOD_S
from positioning_cell.ros.messages import diagnostic, message_class
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import (
    DIAGNOSTICS_QOS,
    SERVICE_QOS,
    profile_from_qos,
    qos_from_profile,
)
from positioning_cell.ros.spin import NodeStart

#: Exit status when writing the bag failed (sysexits' EX_IOERR; 2: it could not start).
EXIT_WRITE_FAILED = 74
#: Longest wait for the last status to be acknowledged when stopping, s (it is sent at once,
#: reliably: this only gives a lost packet a chance).
LAST_STATUS_WAIT_S = 0.3
_LEVELS = ('ok', 'warn', 'error')


class RecorderNode(Node):
    """Node ``recorder``: see the module docstring; services ``~/pause``, ``~/resume``.
    ``exit_status`` is set (:data:`EXIT_WRITE_FAILED`) once writing failed: the spin ends."""

    NAME = names.NODE_RECORDER
    SETTINGS = RecorderSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.settings = p = NodeParameters(self, self.SETTINGS).settings
        try:
            self._selection = TopicSelection.from_params(list(p.topics), p.topic_pattern)
        except InputError as err:
            raise ConfigError(str(err)) from err
        self.recorder = Recorder(p)
        self._writer = self.recorder.writer
        self.exit_status: int | None = None
        self._recorded: dict[str, Any] = {}
        self._ignored: set[str] = set()
        self._diagnostics = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                                  DIAGNOSTICS_QOS)
        self.create_service(Trigger, names.RECORDER_PAUSE,
                            lambda _, r: self._set_paused(True, r), qos_profile=SERVICE_QOS)
        self.create_service(Trigger, names.RECORDER_RESUME,
                            lambda _, r: self._set_paused(False, r), qos_profile=SERVICE_QOS)
        self.create_timer(p.discovery_period_s, self._discover)
        self.create_timer(p.flush_period_s, self._flush)
        self.create_timer(STATUS_PERIOD_S, self._publish_diagnostics)
        self._discover()
        self.get_logger().info(f'recording into {self._writer.path}')

    def _discover(self) -> None:
        """Subscribe to every selected topic that has a publisher and no subscription yet."""
        if self._writer.closed:
            return
        for topic, types in self.get_topic_names_and_types():
            if (topic in self._recorded or topic in self._ignored
                    or not self._selection.matches(topic)):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far: wait for a publisher to match its QoS
            offered = [qos_from_profile(info.qos_profile) for info in publishers]
            msgtype = types[0]
            try:
                msg_class = message_class(msgtype)
                self._writer.add_topic(topic, msgtype, offered)
            except (InputError, BagError) as err:
                self._ignored.add(topic)
                self.get_logger().error(f'not recording {topic}: {err}')
                continue
            if len(types) > 1:
                self.get_logger().warning(f'{topic} has several types {types}; recording '
                                          f'{msgtype} only')
            qos = profile_from_qos(recording_qos(offered, self.settings.queue_depth))
            self._recorded[topic] = self.create_subscription(
                msg_class, topic, self._receiver(topic, msgtype), qos, raw=True)
            self.get_logger().info(f'recording {topic} ({msgtype}, {qos.reliability.name}, '
                                   f'{qos.durability.name})')

    def _receiver(self, topic: str, msgtype: str):
        record = self.recorder.record

        def on_message(data: bytes) -> None:
            error = record(topic, msgtype, data, time.time_ns())
            if isinstance(error, BagWriteError):
                self._failed()
            elif error is not None and self.recorder.write_errors == 1:
                self.get_logger().error(f'cannot write {topic}: {error}')
        return on_message

    def _flush(self) -> None:
        self.recorder.flush()
        self._failed()

    def _failed(self) -> None:
        """If writing failed (the writer closed the bag): say so (one log line, the ERROR
        status) and end the run with :data:`EXIT_WRITE_FAILED`."""
        failure = self.recorder.failure
        if failure is None or self.exit_status is not None:
            return
        self.get_logger().error(f'recording stopped: {failure.line()}')
        self._publish_diagnostics()
        self.exit_status = EXIT_WRITE_FAILED

    def _set_paused(self, paused: bool, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self.recorder.pause(paused)
        self._failed()
        self.get_logger().info(response.message)
        return response

    def _publish_diagnostics(self) -> None:
        if not self._writer.closed:
            self.recorder.check_disk(time.monotonic())
        status, values = self.recorder.status()
        values.update({'topics': len(self._recorded),
                       'ignored_topics': ' '.join(sorted(self._ignored))})
        self._diagnostics.publish(diagnostic(names.STATUS_RECORDER, _LEVELS[status.level],
                                             status.message, values,
                                             self.get_clock().now().to_msg()))

    def _drain(self) -> int:
        """Take what the subscriptions received but no callback ran for yet (a shutdown ends
        the spin with messages queued in the DDS readers): recorded, not dropped."""
        taken = 0
        for subscription in self._recorded.values():
            callback = subscription.callback
            with subscription.handle:
                while (item := subscription.handle.take_message(subscription.msg_type,
                                                                True)) is not None:
                    callback(item[0])
                    taken += 1
        return taken

    def close(self) -> None:
        """Record what is still queued, then finish the bag: index, summary, metadata.yaml
        (idempotent); the last status (stopped, or the failure) goes out to the watchers."""
        if self._writer.closed:
            return
        try:
            drained = self._drain()
        except Exception as err:  # closing the bag comes first, whatever rclpy raised
            self.get_logger().error(f'could not drain the subscriptions: {err!r}')
        else:
            if drained:
                self.get_logger().info(f'recorded {drained} queued messages at shutdown')
        if self._writer.closed or self.recorder.close() is not None:  # failed (or draining)
            self._failed()
            return
        self.get_logger().info(f'closed {self._writer.path}: {self._writer.message_count} '
                               f'messages, {len(self._writer.files)} file(s)')
        self._publish_diagnostics()

    def destroy_node(self) -> None:
        """Give the last status up to :data:`LAST_STATUS_WAIT_S` to reach the watchers."""
        self._diagnostics.wait_for_all_acked(Duration(seconds=LAST_STATUS_WAIT_S))
        super().destroy_node()


#: The entry point: record until SIGINT / SIGTERM, then close the bag: exit 0; 2: the bag
#: could not be created; :data:`EXIT_WRITE_FAILED`: writing failed (the bag was closed
#: with what it had).
main = NodeStart(RecorderNode, imports=())


if __name__ == '__main__':
    sys.exit(main())
