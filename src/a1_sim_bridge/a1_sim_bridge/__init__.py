"""A1 simulation core (PyBullet, no ROS) and the sim bridge node that exposes it as the robot."""
