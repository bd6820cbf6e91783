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

_TMP = Path(os.environ.get('POSITIONING_CELL_TEST_TMP', tempfile.gettempdir())) / (
    f'positioning_cell_test_{os.getuid()}')
os.environ.setdefault('ROS_LOG_DIR', str(_TMP / 'ros_log'))
os.environ.setdefault('ROS_HOME', str(_TMP / 'ros_home'))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
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
