"""Shared, ROS-free pieces of the A1 stack: robot constants, config loading, the joint command."""
