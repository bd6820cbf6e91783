"""panel_simulator_node (node ``panel_simulator``): the coordinated cell's panel as it really
is (simulation truth, :mod:`positioning_cell.sim.panel`).

It takes each positioner's true platform pose (/<name>/sim/platform/true_pose, for every
positioner of ``cell_file``) and, at ``rate_hz`` once every one has come, publishes to each
set the wrench the panel puts on its platform (/<name>/sim/platform/panel_wrench,
geometry_msgs/WrenchStamped, frame ``base``, about the platform origin: what the set's leg
driver adds to its load and its load cells read), the cell tracker's reading of the panel's
targets (/panel/metrology/pose, geometry_msgs/PoseWithCovarianceStamped, frame ``cell``: what
the cell's calibration measures), and for judging only the panel's internal forces
(/sim/panel/internal_forces, std_msgs/String JSON: each pair's force N and stretch µm, the
largest force at one attachment) and its true pose (/sim/panel/true_pose), all at the latest
instant every set's true pose has reached (stamped with it). The cell is as installed
(``installation.*``: bases and sockets off the cell file,
:mod:`positioning_cell.sim.cell_installation`). The positioners and the coordinator never
read the truth."""

from __future__ import annotations

import json
import threading
from functools import partial
from typing import Any

from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped, WrenchStamped
from rclpy.node import Node
from std_msgs.msg import String

from positioning_cell import names
from positioning_cell.ros import messages as m
from positioning_cell.ros.parameters import NodeParameters
from positioning_cell.ros.qos import STREAM_QOS
from positioning_cell.ros.spin import NodeStart
from positioning_cell.sim.panel_simulator import PanelSimulator, PanelSimulatorSettings


class PanelSimulatorNode(Node):
    """The ``panel_simulator`` node (module docstring)."""

    NAME = names.NODE_PANEL_SIMULATOR
    SETTINGS = PanelSimulatorSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(self.NAME, **kwargs)
        self.params = NodeParameters(self, self.SETTINGS)
        settings = self.params.settings
        self.sim = PanelSimulator(settings)  # ConfigError: no start
        self.cell = self.sim.cell
        self._lock = threading.Lock()
        self._wrench_pubs = {}
        for entry in self.cell.positioners:
            self.create_subscription(PoseStamped, names.in_set(names.TRUE_POSE, entry.name),
                                     partial(self._on_pose, entry.name), STREAM_QOS)
            self._wrench_pubs[entry.name] = self.create_publisher(
                WrenchStamped, names.in_set(names.PANEL_WRENCH, entry.name), STREAM_QOS)
        self._forces = self.create_publisher(String, names.PANEL_FORCES, STREAM_QOS)
        self._measured = self.create_publisher(PoseWithCovarianceStamped,
                                               names.PANEL_MEASURED_POSE, STREAM_QOS)
        self._true = self.create_publisher(PoseStamped, names.PANEL_TRUE_POSE, STREAM_QOS)
        self.create_timer(1.0 / settings.rate_hz, self._publish)

    def _on_pose(self, name: str, msg: PoseStamped) -> None:
        with self._lock:
            self.sim.true_pose(name, m.seconds(msg.header.stamp), *m.pose_arrays(msg.pose))

    def _publish(self) -> None:
        with self._lock:
            cycle = self.sim.cycle()
        if cycle is None:
            return
        stamp = m.stamp(cycle.stamp)  # the instant the true poses describe
        self._true.publish(m.pose_stamped(*cycle.state.panel.to_pq(), stamp, names.CELL_FRAME))
        self._measured.publish(m.pose_with_covariance(*cycle.reading, stamp, names.CELL_FRAME))
        for name, wrench in cycle.state.on_platforms.items():
            self._wrench_pubs[name].publish(m.wrench_stamped(wrench, stamp))
        self._forces.publish(String(data=json.dumps(cycle.forces_record())))


#: The entry point of ``panel_simulator_node`` (alone; ``cell_container`` hosts it too).
main = NodeStart(PanelSimulatorNode)


if __name__ == '__main__':
    raise SystemExit(main())
