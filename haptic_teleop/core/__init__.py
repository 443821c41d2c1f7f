"""Pure discrete-time building blocks: no rclpy, no I/O, no wall clock."""
