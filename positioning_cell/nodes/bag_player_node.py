"""bag_player: publishes a recorded bag back onto its topics with the recorded timing.

The bag is read by :func:`positioning_cell.bag.open_bag`: an MCAP bag of any layout (indexed
or not, chunked or not, any chunk compression, split) or a rosbag2 sqlite3 bag.

Each selected topic gets a publisher of its recorded type with the QoS its publishers offered
(reliable; transient-local for latched topics such as /positioner/target). Playback waits up
to ``wait_for_subscribers_s`` for every topic to have a subscriber, then publishes the stored
CDR bytes at bag time / ``rate`` (a monotonic clock, waiting for each due time), from
``start_offset_s`` into the bag, looping if asked. Each pass logs how many messages it played
and how long after its start the last one left (never early: late ones leave at once). At the
end of a non-looping playback the node waits for the subscribers to acknowledge and exits
(status 0).
"""

from __future__ import annotations

import sys
import threading
import time
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node

from positioning_cell import names
from positioning_cell.bag import (
    BagError,
    PlaybackTiming,
    PlayerSettings,
    RawMessage,
    open_bag,
    play,
    playback_qos,
)
from positioning_cell.errors import ConfigError, InputError
from positioning_cell.ros.messages import message_class
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import profile_from_qos
from positioning_cell.ros.spin import NodeStart

ACK_TIMEOUT_S = 5.0


class BagPlayerNode(Node):
    """Node ``bag_player``: see the module docstring."""

    NAME = names.NODE_PLAYER
    SETTINGS = PlayerSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.settings = p = NodeParameters(self, self.SETTINGS).settings
        if not p.bag:
            raise ConfigError('bag: the bag directory to play is required')
        self._reader = open_bag(p.bag)
        try:
            self._topics = list(p.topics) or sorted(self._reader.topics)
            self._timing = PlaybackTiming.starting(self._reader.start_ns, p.rate,
                                                   p.start_offset_s)
            self._outputs = {t: self._publisher(t) for t in self._topics}
        except (InputError, BagError) as err:
            self._reader.close()
            raise ConfigError(f'{p.bag}: {err}') from err
        self._stop = threading.Event()
        self._last_publish = 0.0  # time.monotonic() of the last message published
        self._thread = threading.Thread(target=self._playback, name='playback', daemon=True)
        self._thread.start()

    def _publisher(self, topic: str) -> Any:
        info = self._reader.topics.get(topic)
        if info is None:
            raise InputError(f'no topic {topic} in the bag (it has: '
                             f'{", ".join(sorted(self._reader.topics))})')
        qos = profile_from_qos(playback_qos(info.qos, self.settings.queue_depth))
        return self.create_publisher(message_class(info.msgtype), topic, qos)

    def _publish(self, message: RawMessage) -> None:
        self._outputs[message.topic].publish(message.data)
        self._last_publish = time.monotonic()

    def _playback(self) -> None:
        log = self.get_logger()
        deadline = time.monotonic() + self.settings.wait_for_subscribers_s
        while (any(pub.get_subscription_count() == 0 for pub in self._outputs.values())
               and time.monotonic() < deadline):
            if self._stop.wait(0.02):
                return
        missing = [t for t, pub in self._outputs.items() if pub.get_subscription_count() == 0]
        if missing:
            log.warning(f'no subscriber after {self.settings.wait_for_subscribers_s} s on '
                        f'{", ".join(missing)}: playing anyway')
        try:
            while not self._stop.is_set():
                # The pacing as played (never early: the last message at least its due
                # time after the start; late ones are published at once)
                start = self._last_publish = time.monotonic()
                count = play(self._reader.raw_messages(self._topics, self._timing.origin_ns),
                             self._timing, self._publish, self._stop.wait)
                log.info(f'played {count} messages of {self._reader.path} '
                         f'at rate {self._timing.rate}, the last '
                         f'{self._last_publish - start:.3f} s after the start')
                if not self.settings.loop:
                    break
            for pub in self._outputs.values():
                pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
        except BagError as err:
            log.error(f'playback stopped: {err}')
        except Exception as err:  # a shutdown mid-publish (rclpy raises several types)
            if not self._stop.is_set():
                log.error(f'playback stopped: {err!r}')
        if not self._stop.is_set():
            rclpy.try_shutdown(context=self.context)  # done: the node exits

    def close(self) -> None:
        """Stop playback and release the bag (idempotent)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=ACK_TIMEOUT_S + 1.0)
        self._reader.close()


#: The entry point: play until the end of the bag (or Ctrl-C / SIGTERM when looping).
main = NodeStart(BagPlayerNode, imports=())


if __name__ == '__main__':
    sys.exit(main())
