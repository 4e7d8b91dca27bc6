"""What a robot reports (SensorReadings) and what only a simulator knows (GroundTruth): the data the
bridges turn into messages (conversions.py, wire.py) and the in-process closed loop passes around.
Numpy arrays, SI units; frames as in contract.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class SensorReadings:
    """What the real A1 reports, and nothing more."""

    time: float  # time since reset [s]
    joint_position: np.ndarray  # (12,) [rad]
    joint_velocity: np.ndarray  # (12,) [rad/s]
    joint_torque: np.ndarray  # (12,) torque actually applied, after the motor clip [N m]
    imu_orientation: np.ndarray  # (4,) base orientation quaternion (x, y, z, w), world frame
    imu_angular_velocity: np.ndarray  # (3,) base frame [rad/s]
    imu_linear_acceleration: np.ndarray  # (3,) specific force, base frame [m/s^2] (+g up at rest)
    foot_contact: np.ndarray  # (4,) bool
    foot_force: np.ndarray  # (4,) normal force [N]


@dataclass
class GroundTruth:
    """Simulator-only state, for evaluation and rewards. Never an input to the controller."""

    time: float  # [s]
    base_position: np.ndarray  # (3,) COM position, world frame [m]
    base_orientation: np.ndarray  # (4,) (x, y, z, w)
    base_linear_velocity: np.ndarray  # (3,) world frame [m/s]
    base_linear_velocity_body: np.ndarray  # (3,) base frame [m/s]
    base_angular_velocity_body: np.ndarray  # (3,) base frame [rad/s]
