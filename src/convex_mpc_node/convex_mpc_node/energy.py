"""Energy model of the paper (appendix B) and the cost of transport.

Electrical power of one motor is modelled as p = max(tau * omega + alpha * tau^2, 0) [W]: mechanical
power plus Joule heating (alpha = 0.3 for the A1's motors), with no regeneration. The cost of
transport divides the total by m g v (dimensionless).
"""

from __future__ import annotations

import numpy as np

JOULE_HEATING_COEFFICIENT = 0.3  # alpha [W / (N m)^2]


def motor_power(torque: np.ndarray, velocity: np.ndarray,
                alpha: float = JOULE_HEATING_COEFFICIENT) -> np.ndarray:
    """Per-motor power [W] from joint torque [N m] and joint velocity [rad/s]."""
    torque = np.asarray(torque, dtype=float)
    return np.maximum(torque * np.asarray(velocity, dtype=float) + alpha * torque**2, 0.0)


def cost_of_transport(total_power: float, mass: float, speed: float, gravity: float = 9.81,
                      min_speed: float = 1e-3) -> float:
    """Sum of motor powers [W] / (m [kg] g [m/s^2] v [m/s]); speed is floored at ``min_speed``."""
    if mass <= 0:
        raise ValueError(f"mass must be > 0 kg, got {mass}")
    return float(total_power) / (mass * gravity * max(abs(float(speed)), min_speed))
