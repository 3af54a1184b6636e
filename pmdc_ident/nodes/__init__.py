"""Thin rclpy nodes: the only layer that imports rclpy and message packages."""
