"""What the coordinated cell's watch window reads of the running cell, into a
:class:`~positioning_cell.watch.panel.PanelWatchState`: the coordinator's parameters (its cell
file and nominal machine, asked for until it answers and followed on /parameter_events) and
its status on /diagnostics, the panel's tracker, and per positioner of the cell file its set's
/diagnostics (positioner and drives) and joint states (encoders and load cells). Read-only:
nothing here publishes to the cell or sets anything. Used by ``cell watch --panel`` and the
live view's panel view."""

from __future__ import annotations

import threading
from collections.abc import Callable
from functools import partial

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.subscription import Subscription
from sensor_msgs.msg import JointState

from positioning_cell import names
from positioning_cell.coordinated.settings import CellCoordinatorSettings
from positioning_cell.errors import PositioningError
from positioning_cell.ros import messages as m
from positioning_cell.ros.qos import DIAGNOSTICS_QOS
from positioning_cell.ros.watch_inputs import WATCH_QOS, RemoteParameters
from positioning_cell.watch.panel import PanelSnapshot, PanelWatchState
from positioning_cell.watch.state import Status


def _status(node: Node, status: DiagnosticStatus) -> Status:
    now = node.get_clock().now().nanoseconds * 1e-9
    return Status(m.status_level(status), str(status.message), now, m.status_values(status))


class PanelWatchSource:
    """The panel watch's inputs on ``node`` (``on_panel()`` after each panel measurement,
    in the subscription's callback). The sets are subscribed to once the
    coordinator has said its cell file (a calibrated file it takes later has the same
    positioners: :func:`~positioning_cell.coordinated.settings.replacing`)."""

    def __init__(self, node: Node, on_panel: Callable[[], None] | None = None) -> None:
        self.node, self._on_panel = node, on_panel
        self.state = PanelWatchState()
        self._lock = threading.Lock()
        self._sets: tuple[str, ...] = ()
        self._closed = False
        self._subscriptions: list[Subscription] = [
            self.node.create_subscription(DiagnosticArray, names.DIAGNOSTICS, self._coordinator,
                                          DIAGNOSTICS_QOS),
            self.node.create_subscription(PoseWithCovarianceStamped, names.PANEL_MEASURED_POSE,
                                          self._panel, WATCH_QOS)]
        self.parameters = RemoteParameters(self.node, names.NODE_COORDINATOR,
                                           CellCoordinatorSettings, '', self._settings)

    def snapshot(self) -> PanelSnapshot:
        """The state now."""
        return self.state.snapshot()

    def close(self) -> None:
        """Stop asking the coordinator for its parameters and listening to the cell (the
        node may go on without it)."""
        self.parameters.close()
        with self._lock:
            subscriptions, self._subscriptions, self._closed = self._subscriptions, [], True
        for subscription in subscriptions:
            self.node.destroy_subscription(subscription)

    def _settings(self, settings: CellCoordinatorSettings) -> None:
        self.state.coordinator_settings(settings)
        with self._lock:
            if self._sets or self._closed:
                return
            try:
                self._sets = tuple(e.name for e in settings.cell().positioners)
            except PositioningError as err:
                self.node.get_logger().warning(f'the coordinator\'s cell file: {err}')
                return
            for name in self._sets:
                self._subscriptions += [
                    self.node.create_subscription(
                        DiagnosticArray, names.in_set(names.DIAGNOSTICS, name),
                        partial(self._set_diagnostics, name), DIAGNOSTICS_QOS),
                    self.node.create_subscription(
                        JointState, names.in_set(names.JOINT_STATES, name),
                        partial(self._joints, name), WATCH_QOS)]

    def _coordinator(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == names.STATUS_COORDINATOR:
                self.state.coordinator(_status(self.node, status))

    def _panel(self, msg: PoseWithCovarianceStamped) -> None:
        reading = m.measurement(msg)
        self.state.panel((reading.position, reading.quaternion), reading.stamp)
        if self._on_panel is not None:
            self._on_panel()

    def _set_diagnostics(self, name: str, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == names.STATUS_POSITIONER:
                self.state.set_status(name, positioner=_status(self.node, status))
            elif status.name == names.STATUS_DRIVER:
                self.state.set_status(name, drives=_status(self.node, status))

    def _joints(self, name: str, msg: JointState) -> None:
        joints = m.joint_values(msg, names.JOINT_NAMES)
        efforts = m.joint_values(msg, names.JOINT_NAMES, 'effort')
        if joints is not None and efforts is not None:
            self.state.joints(name, joints, efforts)


__all__ = ['PanelWatchSource']
