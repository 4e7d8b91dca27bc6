"""Kalman-filter base-velocity estimator: library core (no ROS) and node."""
