"""Unitree A1 low-level UDP protocol, hardware bridge node and virtual A1 (protocol and cores need no ROS)."""
