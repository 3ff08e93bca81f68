"""Thin rclpy nodes: the calibrator and the bag replay node."""
