"""The ROS side of the parameters: the descriptors rclpy enforces, made from the library's one
declaration, and the nodes declaring the settings types test_config checks config/cell.yaml
against. rclpy loads here (no DDS): the ``nodes`` tier."""

from __future__ import annotations

import pytest
from rcl_interfaces.msg import ParameterDescriptor
from test_config import NODES as SETTINGS
from test_parameters import Outer

from positioning_cell import names
from positioning_cell.nodes.accuracy_monitor_node import AccuracyMonitorNode
from positioning_cell.nodes.bag_player_node import BagPlayerNode
from positioning_cell.nodes.calibrator_node import CalibratorNode
from positioning_cell.nodes.cell_coordinator_node import CellCoordinatorNode
from positioning_cell.nodes.kinematics_node import PositionerNode
from positioning_cell.nodes.leg_driver_node import LegDriverNode
from positioning_cell.nodes.live_view_node import LiveViewNode
from positioning_cell.nodes.panel_simulator_node import PanelSimulatorNode
from positioning_cell.nodes.pose_measurement_node import PoseMeasurementNode
from positioning_cell.nodes.recorder_node import RecorderNode
from positioning_cell.parameters import declarations
from positioning_cell.ros.parameters import descriptor

pytestmark = pytest.mark.nodes

NODES = (PositionerNode, LegDriverNode, PoseMeasurementNode, AccuracyMonitorNode, RecorderNode,
         BagPlayerNode, CalibratorNode, LiveViewNode, CellCoordinatorNode, PanelSimulatorNode)


def test_every_node_declares_the_settings_type_the_config_is_checked_against() -> None:
    assert {n.NAME: n.SETTINGS for n in NODES} == SETTINGS
    assert {n.NAME for n in NODES} == {n.name for n in names.NODE_EXECUTABLES}


def test_descriptors_carry_ranges_read_only_and_constraints() -> None:
    decl = {d.name: d for d in declarations(Outer)}
    speed = descriptor(decl['first.speed'])
    assert isinstance(speed, ParameterDescriptor) and not speed.read_only
    (fp,) = speed.floating_point_range
    assert (fp.from_value, fp.to_value) == (0.0, 5.0)
    assert speed.description == 'a speed, m/s'
    assert speed.additional_constraints == 'unit: m/s; in (0, 5]'
    count = descriptor(decl['first.count'])
    (ir,) = count.integer_range
    assert (ir.from_value, ir.to_value) == (1, 10) and count.read_only
    assert descriptor(decl['name']).additional_constraints == 'one of: a, b'
    one_sided = descriptor(decl['optional'])
    assert one_sided.floating_point_range[0].from_value == 0.0
    assert one_sided.floating_point_range[0].to_value > 1e300
