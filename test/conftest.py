"""Test-wide settings: nothing depends on the caller's ROS environment."""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

from positioning_cell.config import config_path

_TMP = Path(os.environ.get('POSITIONING_CELL_TEST_TMP', tempfile.gettempdir())) / (
    f'positioning_cell_test_{os.getuid()}')
os.environ.setdefault('ROS_LOG_DIR', str(_TMP / 'ros_log'))
os.environ.setdefault('ROS_HOME', str(_TMP / 'ros_home'))
# Loopback only (docs/howto/network.md), as positioning_cell.ros.client.cell_environment gives the
# cell's processes: the shipped Fast DDS profile with discovery left to it (with LOCALHOST,
# rmw_fastrtps adds a transport on every interface); a caller's own profile with LOCALHOST.
_PROFILE = config_path('fastdds_loopback.xml').resolve()
os.environ.setdefault('FASTRTPS_DEFAULT_PROFILES_FILE', str(_PROFILE))
os.environ.pop('ROS_LOCALHOST_ONLY', None)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = (
    'SYSTEM_DEFAULT' if Path(os.environ['FASTRTPS_DEFAULT_PROFILES_FILE']).resolve() == _PROFILE
    else 'LOCALHOST')
os.environ.setdefault('AMENT_PREFIX_PATH', sys.prefix)
os.environ.setdefault('MPLBACKEND', 'Agg')
os.environ.pop('RMW_IMPLEMENTATION', None)

# Deterministic property tests: the same examples on every run and machine.
settings.register_profile('ci', derandomize=True, deadline=None, max_examples=150,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile('ci')


@pytest.fixture
def ros() -> Iterator[Any]:
    """The in-process tier's rclpy context: nodes built in the test process on a private
    domain (cell_harness.InProcess), all stopped at the end."""
    from cell_harness import in_process

    with in_process() as context:
        yield context
