"""positioning_cell: ament_python package; installs the same way under colcon and pip."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'positioning_cell'

# Executables: `ros2 run positioning_cell <name>` on a ROS install, `<name>` on PATH in a venv.
CONSOLE_SCRIPTS = [
    'recorder_node = positioning_cell.ros.entry:recorder_node',
    'bag_player_node = positioning_cell.ros.entry:bag_player_node',
    'recover_bag = positioning_cell.tools.recover_bag:main',
    'predict_accuracy = positioning_cell.tools.predict_accuracy:main',
    'tolerance_analysis = positioning_cell.tools.tolerance_analysis:main',
    'leg_driver_node = positioning_cell.ros.entry:leg_driver_node',
    'pose_measurement_node = positioning_cell.ros.entry:pose_measurement_node',
    'kinematics_node = positioning_cell.ros.entry:kinematics_node',
    'accuracy_monitor_node = positioning_cell.ros.entry:accuracy_monitor_node',
    'calibrator_node = positioning_cell.ros.entry:calibrator_node',
    'live_view_node = positioning_cell.ros.entry:live_view_node',
    'cell_coordinator_node = positioning_cell.ros.entry:cell_coordinator_node',
    'panel_simulator_node = positioning_cell.ros.entry:panel_simulator_node',
    'cell_container = positioning_cell.ros.entry:cell_container',
    'analyze_bag = positioning_cell.tools.analyze_bag:main',
    'analyze_bags = positioning_cell.tools.analyze_bags:main',
    'run_cell = positioning_cell.tools.run_cell:main',
    'calibrate_cell = positioning_cell.tools.calibrate_cell:main',
    'calibrate_panel = positioning_cell.tools.calibrate_panel:main',
    'cell = positioning_cell.tools.cell:main',
    'cell_mobility = positioning_cell.tools.cell_mobility:main',
]

# ROS 2 Jazzy from PyPI wheels and the pinned libraries the cell runs on (make run / make test).
CELL = [
    'ros-jazzy-rclpy==7.1.6',
    'ros-jazzy-common-interfaces==5.3.6',
    'ros-jazzy-rmw-fastrtps-cpp==8.4.3',
    'numpy==2.4.6',
    'scipy==1.17.1',
    'numba==0.68.1',
    'llvmlite==0.50.0',
    'PyYAML==6.0.3',
    'rosbags==0.11.9',
    'ruamel.yaml==0.19.1',
    'mcap==1.6.0',
    'zstandard==0.25.0',
    'lz4==4.4.5',
    'mcap-ros2-support==0.6.0',
    'matplotlib==3.11.2',
    'foxglove-sdk==0.30.3',
    'rich==15.0.0',
    'dask==2026.8.0',
    'distributed==2026.8.0',
]
TEST = [
    'pytest==9.2.0',
    'pytest-timeout==2.4.0',
    # make test runs the suite in two workers (each node test takes its own ROS domain)
    'pytest-xdist==3.8.0',
    'execnet==2.1.2',
    'hypothesis==6.170.15',
    'ruff==0.17.6',
    'mypy==2.4.1',
    'types-PyYAML==6.0.12.20261113',
    'colcon-common-extensions==0.3.0',
    'websockets==17.4',
    'protobuf==7.36.2',
    # test/test_wheel.py builds the wheel without build isolation (no network): the bdist_wheel
    # command of a setuptools older than 70.1 (Python 3.11's venv has 65) is wheel's; 0.45.1 is
    # the last wheel that still carries it and defers to a newer setuptools' own
    'wheel==0.45.1',
    # The docs (docs/, built warning-free by test/test_docs.py and `make docs`): Sphinx with
    # MyST Markdown, the toolchain of rosdoc2. Sphinx 9 (Python 3.11 and later) builds them in
    # 25.6 s against 8.1's 31.3 s (test_docs, one run each): its autosummary no longer makes a
    # build environment for each member it sorts. 8.1 is the last line that runs on Python
    # 3.10, which the package still supports.
    'sphinx==9.0.4; python_version >= "3.11"',
    'myst-parser==5.2.0; python_version >= "3.11"',
    'sphinx==8.1.3; python_version < "3.11"',
    'myst-parser==4.0.1; python_version < "3.11"',
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    # PEP 561: the package's type hints are part of its interface.
    package_data={PACKAGE: ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', [f'resource/{PACKAGE}']),
        (f'share/{PACKAGE}', ['package.xml']),
        (f'share/{PACKAGE}/config', glob('config/*.yaml') + glob('config/*.xml')
         + glob('config/*.json')),
        (f'share/{PACKAGE}/launch', glob('launch/*.py')),
    ],
    # Every third-party runtime import (test/test_dependencies.py checks it against the code),
    # kept loose so that a ROS install's system packages satisfy it; the exact versions this
    # project tests with are the `cell` extra. ROS 2 itself (rclpy, the message packages)
    # comes from the ROS install or the `cell` extra's wheels.
    install_requires=['setuptools', 'numpy>=1.25', 'scipy>=1.11', 'numba>=0.59',
                      'PyYAML>=6', 'rosbags>=0.10', 'ruamel.yaml>=0.17', 'mcap>=1.1',
                      'zstandard>=0.20', 'lz4>=4',
                      'matplotlib>=3.6', 'foxglove-sdk>=0.30', 'rich>=13',
                      'dask[distributed]>=2024.1'],
    extras_require={'cell': CELL, 'test': TEST},
    zip_safe=True,
    maintainer='positioning_cell developers',
    maintainer_email='positioning-cell@example.org',
    description='3-UPS aircraft-panel positioner cell: kinematics, clearance compensation, '
                'simulated drives and tracker, ISO 9283 monitoring, MCAP recording',
    license='Apache-2.0',
    python_requires='>=3.10',
    entry_points={'console_scripts': CONSOLE_SCRIPTS},
)
