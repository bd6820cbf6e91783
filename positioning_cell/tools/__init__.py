"""Command-line tools of the cell: thin wrappers around the pure library (no rclpy)."""
