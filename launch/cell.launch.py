"""Start the positioning cell on a ROS 2 Jazzy install: `ros2 launch positioning_cell
cell.launch.py [params_file:=...] [record:=true] [live_view:=false] [calibrator:=false]`, on
loopback only unless your environment names its own Fast DDS profile (docs/howto/network.md).
(Here,
without ros2launch, `make run` starts the same processes.)"""

import os
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable, UnsetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription
from positioning_cell.names import CALIBRATOR, CELL_NODES, LIVE_VIEW, RECORDER
from positioning_cell.ros.processes import loopback_only


def generate_launch_description() -> LaunchDescription:
    default_params = str(Path(get_package_share_directory('positioning_cell')) / 'config' /
                         'cell.yaml')
    params = LaunchConfiguration('params_file')
    nodes = [Node(package='positioning_cell', executable=exe, name=name, output='screen',
                  parameters=[params]) for exe, name in CELL_NODES]
    nodes += [Node(package='positioning_cell', executable=node.executable, name=node.name,
                   output='screen', parameters=[params],
                   condition=IfCondition(LaunchConfiguration(argument)))
              for node, argument in ((RECORDER, 'record'), (LIVE_VIEW, 'live_view'),
                                     (CALIBRATOR, 'calibrator'))]
    env = dict(os.environ)
    loopback_only(env)
    network = [SetEnvironmentVariable(k, v) for k, v in env.items() if os.environ.get(k) != v]
    network += [UnsetEnvironmentVariable(k) for k in os.environ if k not in env]
    return LaunchDescription([
        *network,
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='ROS 2 parameter file of the cell'),
        DeclareLaunchArgument('record', default_value='true',
                              description='record the run to an MCAP bag'),
        DeclareLaunchArgument('live_view', default_value='false',
                              description='the Foxglove live view on ws://127.0.0.1:8765'),
        DeclareLaunchArgument('calibrator', default_value='false',
                              description='the Calibrate action (calibrator_node)'),
        *nodes,
    ])
