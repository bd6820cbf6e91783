"""Calibrating the machine from its own measurements: pure library (numpy/scipy, no rclpy)."""
