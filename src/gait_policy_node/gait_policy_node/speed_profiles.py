"""Desired velocity against time: the profiles every episode, tool and the velocity_command node
drive the robot with. No ROS.

One home, so that the training episodes (``env.make_profile``), the in-process tools and tests
(``rollout.run_closed_loop``), and the node that publishes /cmd_vel on a running graph ask for the
same thing when they say "ramp". Speeds in the yaw-aligned frame [m/s], time from the start of the
profile [s].
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from a1_common.command import VelocityCommand

SpeedProfile = Callable[[float], VelocityCommand]


def constant(vx: float, vy: float = 0.0, yaw_rate: float = 0.0) -> SpeedProfile:
    """The same command at every time."""
    return lambda t: VelocityCommand(vx=vx, vy=vy, yaw_rate=yaw_rate)


def ramp(target: float, acceleration: float = 1.0) -> SpeedProfile:
    """Forward speed 0 -> ``target`` at ``acceleration`` [m/s^2], then held (the paper's profile:
    2.5 m/s at 1 m/s^2); a negative target ramps backwards."""
    sign = 1.0 if target >= 0 else -1.0
    return lambda t: VelocityCommand(vx=min(abs(target), acceleration * t) * sign)


def steps(table: Sequence[Sequence[float]]) -> SpeedProfile:
    """Forward speed ``v_i`` from time ``t_i`` on, for (t_i, v_i) in ``table`` (times increasing);
    0 before the first."""
    times = np.array([t for t, _ in table], dtype=float)
    speeds = np.array([0.0] + [v for _, v in table], dtype=float)
    return lambda t: VelocityCommand(vx=float(speeds[np.searchsorted(times, t, side="right")]))


def random_holds(speed_range: tuple[float, float], hold: float, acceleration: float, seed: int) -> SpeedProfile:
    """Forward speeds drawn uniformly in ``speed_range`` from ``seed``, each held for ``hold`` [s]
    and reached from the one before at ``acceleration`` (from 0 for the first)."""
    rng = np.random.default_rng([seed, 2])
    lo, hi = speed_range
    targets = rng.uniform(lo, hi, size=256)  # one per hold period; episodes end long before they run out

    def profile(t: float) -> VelocityCommand:
        k = min(int(t // hold), len(targets) - 1)
        start = targets[k - 1] if k > 0 else 0.0
        elapsed = t - k * hold
        step = np.clip(targets[k] - start, -acceleration * elapsed, acceleration * elapsed)
        return VelocityCommand(vx=float(start + step))

    return profile
