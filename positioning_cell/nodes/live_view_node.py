"""live_view_node (node ``live_view``): the cell live in Foxglove. A foxglove-sdk WebSocket
server (127.0.0.1:8765 by default; parameters ``host``, ``port``) in the node's process serves
the 3-D scene, the frame transforms, the 6-D deviation and the status
(:class:`~positioning_cell.nodes.live_view_messages.LiveChannels`), sent after each tracker
measurement up to ``rate_hz`` and at least once a second. Read-only: it subscribes to the
cell (:class:`~positioning_cell.ros.watch_inputs.WatchInputs`) and never commands it. Open
config/foxglove_layout.json in Foxglove (docs/howto/watch.md).

``view: panel``, a coordinated cell instead: the panel as its tracker measures it, each
positioner's base, the internal forces from the legs' load cells and the coordinator's and
sets' status (:mod:`~positioning_cell.nodes.live_view_panel`, from
:class:`~positioning_cell.ros.panel_watch_inputs.PanelWatchSource`), sent after each panel
measurement up to ``rate_hz``; config/foxglove_panel_layout.json."""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

import foxglove
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node

from positioning_cell import names
from positioning_cell.errors import ConfigError
from positioning_cell.nodes.live_view_messages import LiveChannels
from positioning_cell.ros import messages as m
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import DIAGNOSTICS_QOS
from positioning_cell.ros.spin import NodeStart, Spin
from positioning_cell.ros.watch_inputs import WatchInputs
from positioning_cell.watch.settings import LiveViewSettings
from positioning_cell.watch.state import WatchState
from positioning_cell.watch.throttle import Throttle

if TYPE_CHECKING:
    from positioning_cell.nodes.live_view_panel import PanelChannels
    from positioning_cell.ros.panel_watch_inputs import PanelWatchSource

#: Longest time between two sends while no measurement comes, s; the node's status period.
IDLE_PERIOD = 1.0


class LiveViewNode(Node):
    """The ``live_view`` node (module docstring)."""

    NAME = names.NODE_LIVE_VIEW
    SETTINGS = LiveViewSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS)
        settings = self.params.settings
        self.foxglove = foxglove.Context()
        try:
            self.server = foxglove.start_server(name='positioning_cell', host=settings.host,
                                                port=settings.port, context=self.foxglove)
        except RuntimeError as err:  # FoxgloveError: the address is taken or not this host's
            raise ConfigError(f'live_view: cannot serve on {settings.host}:{settings.port} '
                              f'(host, port): {err}') from None
        self.url = f'ws://{settings.host}:{self.server.port}'
        self._lock = threading.Lock()
        self._throttle = Throttle(settings.rate_hz)
        self._last_send = self._last_full = -IDLE_PERIOD
        self.sent = 0
        self.pub_diag = self.create_publisher(DiagnosticArray, names.DIAGNOSTICS,
                                              DIAGNOSTICS_QOS)
        self.panel: tuple[PanelWatchSource, PanelChannels] | None = None
        if settings.view == 'panel':  # imported only here: the coordinated cell's statics
            from positioning_cell.nodes.live_view_panel import PanelChannels
            from positioning_cell.ros.panel_watch_inputs import PanelWatchSource
            self.panel = (PanelWatchSource(self, on_panel=self._on_measurement),
                          PanelChannels(self.foxglove, settings.force_scale))
        else:
            self.state = WatchState(settings.mechanism)
            self.channels = LiveChannels(self.foxglove)
            self.inputs = WatchInputs(self, self.state, on_measurement=self._on_measurement)
        self.create_timer(IDLE_PERIOD, self._idle)
        self.get_logger().info(f'Foxglove live view on {self.url}')

    def _send(self, idle: bool) -> None:
        """Send a snapshot: after a measurement within ``rate_hz`` (:class:`~positioning_cell.
        watch.throttle.Throttle`), or (``idle``) when none went out for :data:`IDLE_PERIOD`;
        the whole scene (its static entities too, for clients that joined since) once per
        :data:`IDLE_PERIOD`."""
        settings = self.params.settings
        now = time.monotonic()
        with self._lock:
            if idle and now - self._last_send < IDLE_PERIOD:
                return
            if not idle and not self._throttle.allow(now):
                return
            full = now - self._last_full >= IDLE_PERIOD
            self._last_send = now
            self._last_full = now if full else self._last_full
            self.sent += 1
        if self.panel is not None:
            source, channels = self.panel
            channels.send(source.snapshot(), time.time())
        else:
            self.channels.send(self.inputs.snapshot(), settings.frame, settings.magnification,
                               time.time(), full=full)

    def _on_measurement(self) -> None:
        self._send(idle=False)

    def _idle(self) -> None:
        self._send(idle=True)
        waiting = (self.panel[0] if self.panel is not None else self.inputs).snapshot(
            ).waiting_for()
        message = f'serving {self.url}' + (f', waiting for {", ".join(waiting)}'
                                           if waiting else '')
        self.pub_diag.publish(m.diagnostic(
            names.STATUS_LIVE_VIEW, 'ok', message,
            {'url': self.url, 'port': self.server.port, 'sent': self.sent,
             'rejected': 0 if self.panel is not None else self.inputs.rejected},
            self.get_clock().now().to_msg()))

    def close(self) -> None:
        """Stop asking for parameters, stop the WebSocket server (clients are disconnected)."""
        (self.panel[0] if self.panel is not None else self.inputs).close()
        self.server.stop()


#: The entry point of ``live_view_node`` (alone; ``cell_container`` hosts it with others).
main = NodeStart(LiveViewNode, Spin.EVENTS)


if __name__ == '__main__':
    raise SystemExit(main())
