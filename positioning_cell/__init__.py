"""positioning_cell: a 3-UPS aircraft-panel positioner, its clearance model and its cell.

The package root and every module outside ``positioning_cell.nodes`` form a pure library
(numpy, scipy, PyYAML; no rclpy), so every formula is reachable from a unit test without DDS.
"""

__version__ = '0.1.0'
