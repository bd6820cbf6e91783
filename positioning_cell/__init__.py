"""positioning_cell: a 3-UPS aircraft-panel positioner, its clearance model and its cell.

Everything outside ``positioning_cell.nodes`` (and the tools' one ROS module,
``positioning_cell.ros.client``) is a pure library (numpy, scipy, numba, PyYAML, rosbags; no
rclpy), so every rule is reachable from a unit test without DDS. The folders name the
concepts: ``core`` (the machine and its kinematics), ``clearance``, ``mechanics``, ``motion``,
``limits``, ``frames``, ``accuracy``, ``metrology``, ``calibration``, ``sim`` (the simulated
machine: the only code that knows the truth), ``prediction``, ``tolerance``, ``bag``,
``analysis``, ``watch``, ``testing``, ``nodes``, ``tools``; ``names`` holds every topic,
service, frame and node name, ``parameters`` the way settings are declared.

The short forms ``from positioning_cell import Mechanism, kinematics, clearance`` work too.
"""

from __future__ import annotations

from typing import Any

__version__ = '0.1.0'


def __getattr__(name: str) -> Any:
    """The short forms, imported on first use (so ``import positioning_cell.bag`` does not
    load numba)."""
    if name == 'kinematics':
        from positioning_cell.core import kinematics

        return kinematics
    if name == 'Mechanism':
        from positioning_cell.core.mechanism import Mechanism

        return Mechanism
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
