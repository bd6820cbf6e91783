"""Start the positioning cell on a ROS 2 Jazzy install: `ros2 launch positioning_cell
cell.launch.py [params_file:=...] [record:=true] [live_view:=false] [calibrator:=false]`, on
loopback only unless your environment names its own Fast DDS profile (docs/howto/network.md).
(Here,
without ros2launch, `cell up` starts the same processes: names.OPTIONAL_NODES.)"""

import os
from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable, UnsetEnvironmentVariable
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription
from positioning_cell.names import CELL_NODES, OPTIONAL_NODES
from positioning_cell.ros.processes import loopback_only


def generate_launch_description() -> LaunchDescription:
    default_params = str(Path(get_package_share_directory('positioning_cell')) / 'config' /
                         'cell.yaml')
    params = LaunchConfiguration('params_file')
    nodes = [Node(package='positioning_cell', executable=exe, name=name, output='screen',
                  parameters=[params]) for exe, name in CELL_NODES]
    nodes += [Node(package='positioning_cell', executable=node.executable, name=node.name,
                   output='screen', parameters=[params],
                   condition=IfCondition(LaunchConfiguration(switch)))
              for node, switch, _ in OPTIONAL_NODES]
    env = dict(os.environ)
    loopback_only(env)
    network = [SetEnvironmentVariable(k, v) for k, v in env.items() if os.environ.get(k) != v]
    network += [UnsetEnvironmentVariable(k) for k in os.environ if k not in env]
    return LaunchDescription([
        *network,
        DeclareLaunchArgument('params_file', default_value=default_params,
                              description='ROS 2 parameter file of the cell'),
        *[DeclareLaunchArgument(switch, default_value=str(on).lower(),
                                description=f'start {node.executable} (as cell up does)')
          for node, switch, on in OPTIONAL_NODES],
        *nodes,
    ])
