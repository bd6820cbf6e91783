"""rclpy nodes of the cell: thin layers over the pure library."""
