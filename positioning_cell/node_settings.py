"""Each node's settings type: what its section of a parameter file (``config/cell.yaml``) holds
and what it declares as ROS parameters, by node name, in the order of
:data:`positioning_cell.names.NODE_EXECUTABLES`. The nodes declare these
(``test/test_ros_parameters.py`` checks it); the tests of the configuration and the docs'
parameter reference read them here, without ROS."""

from __future__ import annotations

from positioning_cell import names
from positioning_cell.accuracy.monitor import MonitorSettings
from positioning_cell.bag.settings import PlayerSettings, RecorderSettings
from positioning_cell.calibration.settings import CalibratorSettings
from positioning_cell.coordinated.settings import CellCoordinatorSettings
from positioning_cell.motion.settings import PositionerSettings
from positioning_cell.sim.drives import DriverSettings
from positioning_cell.sim.panel_simulator import PanelSimulatorSettings
from positioning_cell.sim.pose_measurement import PoseMeasurementSettings
from positioning_cell.watch.settings import LiveViewSettings

_BY_NAME: dict[str, type] = {
    names.NODE_POSITIONER: PositionerSettings, names.NODE_DRIVER: DriverSettings,
    names.NODE_MEASUREMENT: PoseMeasurementSettings, names.NODE_MONITOR: MonitorSettings,
    names.NODE_RECORDER: RecorderSettings, names.NODE_PLAYER: PlayerSettings,
    names.NODE_CALIBRATOR: CalibratorSettings, names.NODE_LIVE_VIEW: LiveViewSettings,
    names.NODE_COORDINATOR: CellCoordinatorSettings,
    names.NODE_PANEL_SIMULATOR: PanelSimulatorSettings}

#: Node name → its settings type (a dataclass of ``setting(...)`` and ``group(...)`` fields).
NODE_SETTINGS: dict[str, type] = {node.name: _BY_NAME[node.name]
                                  for node in names.NODE_EXECUTABLES}
