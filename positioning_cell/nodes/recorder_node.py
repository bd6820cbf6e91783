"""recorder: records the cell's topics into a rosbag2 MCAP bag (positioning_cell.bag).

Raw (CDR) subscriptions, created as matching topics appear (graph polled every
``discovery_period_s``), reliable and transient-local where the publishers are; message log
time = receive time (system clock), header stamps untouched. Chunks are flushed every
``flush_period_s``, so a SIGKILL loses at most that much (``recover_bag`` restores the rest);
SIGINT / SIGTERM close the bag with its index and metadata.yaml. Spun by rclpy's
EventsExecutor (several times the throughput of the default executors).
"""

from __future__ import annotations

import sys
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from std_srvs.srv import Trigger

from positioning_cell import names
from positioning_cell.bag import (
    BagError,
    BagWriter,
    RecorderSettings,
    TopicSelection,
    recording_qos,
)
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.nodes.messages import diagnostic, message_class
from positioning_cell.nodes.parameters import NodeParameters
from positioning_cell.nodes.qos import (
    DIAGNOSTICS_QOS,
    SERVICE_QOS,
    profile_from_qos,
    qos_from_profile,
)
from positioning_cell.nodes.spin import run


def default_output(now: datetime | None = None) -> Path:
    """``runs/<UTC timestamp>/bag`` relative to the working directory."""
    stamp = (now or datetime.now(timezone.utc)).strftime('%Y%m%dT%H%M%SZ')
    return Path('runs') / stamp / 'bag'


class RecorderNode(Node):
    """Node ``recorder``: see the module docstring; services ``~/pause``, ``~/resume``."""

    NAME = names.NODE_RECORDER
    SETTINGS = RecorderSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.settings = p = NodeParameters(self, self.SETTINGS).settings
        try:
            self._selection = TopicSelection.from_params(list(p.topics), p.topic_pattern)
        except InputError as err:
            raise ConfigError(str(err)) from err
        self._writer = BagWriter(
            p.output or default_output(), compression=p.compression,
            chunk_bytes=p.chunk_bytes, split_max_bytes=p.split.max_bytes,
            split_max_duration_s=p.split.max_duration_s)
        self._recorded: dict[str, Any] = {}
        self._ignored: set[str] = set()
        self._paused = False
        self._write_errors = 0
        self._dropped_paused = 0
        self._diagnostics = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                                  DIAGNOSTICS_QOS)
        self.create_service(Trigger, names.RECORDER_PAUSE,
                            lambda _, r: self._set_paused(True, r), qos_profile=SERVICE_QOS)
        self.create_service(Trigger, names.RECORDER_RESUME,
                            lambda _, r: self._set_paused(False, r), qos_profile=SERVICE_QOS)
        self.create_timer(p.discovery_period_s, self._discover)
        self.create_timer(p.flush_period_s, self._writer.flush)
        self.create_timer(1.0, self._publish_diagnostics)
        self._discover()
        self.get_logger().info(f'recording into {self._writer.path}')

    def _discover(self) -> None:
        """Subscribe to every selected topic that has a publisher and no subscription yet."""
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
        write = self._writer.write

        def on_message(data: bytes) -> None:
            if self._paused:
                self._dropped_paused += 1
                return
            try:
                write(topic, msgtype, data, time.time_ns())
            except (OSError, BagError) as err:
                self._write_errors += 1
                if self._write_errors == 1:
                    self.get_logger().error(f'cannot write {topic}: {err}')
        return on_message

    def _set_paused(self, paused: bool, response: Trigger.Response) -> Trigger.Response:
        was, self._paused = self._paused, paused
        if paused:
            self._writer.flush()
        response.success = True
        response.message = (f'{"paused" if paused else "recording"} '
                            f'(was {"paused" if was else "recording"}); '
                            f'{self._writer.message_count} messages in {self._writer.path}')
        self.get_logger().info(response.message)
        return response

    def _publish_diagnostics(self) -> None:
        level = 'error' if self._write_errors else ('warn' if self._paused else 'ok')
        message = ('write errors' if self._write_errors else
                   'paused' if self._paused else 'recording')
        self._diagnostics.publish(diagnostic(
            names.STATUS_RECORDER, level, message,
            {'bag': self._writer.path, 'messages': self._writer.message_count,
             'topics': len(self._recorded), 'files': len(self._writer.files),
             'dropped_while_paused': self._dropped_paused, 'write_errors': self._write_errors,
             'ignored_topics': ' '.join(sorted(self._ignored)), **self._writer.topic_counts},
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
        (idempotent)."""
        if not self._writer.closed:
            try:
                drained = self._drain()
            except Exception as err:  # closing the bag comes first, whatever rclpy raised
                self.get_logger().error(f'could not drain the subscriptions: {err!r}')
            else:
                if drained:
                    self.get_logger().info(f'recorded {drained} queued messages at shutdown')
            path = self._writer.close()
            self.get_logger().info(f'closed {path}: {self._writer.message_count} messages, '
                                   f'{len(self._writer.files)} file(s)')


def main(args: list[str] | None = None) -> int:
    """Record until SIGINT / SIGTERM, then close the bag (exit 2: it could not be created)."""
    return run(RecorderNode, args)


if __name__ == '__main__':
    sys.exit(main())
