"""Which sensor steps a bridge also announces on /clock (sim time), free of ROS.

A bridge stamps its 500 Hz sensors with the robot's time and publishes that time on /clock for the
nodes that run on sim time (``use_sim_time``). Each of those nodes handles every /clock message
(rclpy updates its clock and checks its timers), so at 500 Hz the clock alone cost the lockstep demo
graph about a quarter of its pace on 2 cores (docs/architecture.md, "Where the lockstep demo's time
goes"). None of them needs it that fine: their timers run at 1-20 Hz, and the 500 Hz chain works on
the sensors' own stamps. So a bridge publishes /clock once per ``clock_period`` of sim time. A
sim-time timer faster than 1 / ``clock_period`` (a ``rate`` over 100 Hz by default) then fires at
most once per clock message.
"""

from __future__ import annotations

from a1_common.config import ConfigError, require_range

# [s]: up to the gait policy's 20 Hz period; a slower clock would hold its timer (and the controller's
# gait_timeout on /gait/params) back.
CLOCK_PERIOD_RANGE = (0.001, 0.05)


def require_clock_period(value: float, time_step: float | None = None) -> float:
    """``clock_period`` [s] within CLOCK_PERIOD_RANGE and, given the sensors' ``time_step`` [s], a
    whole number of steps (so /clock carries exact step times and 20 Hz timers fire on time)."""
    period = require_range("clock_period", value, *CLOCK_PERIOD_RANGE)
    if time_step is not None:
        steps = period / time_step
        if steps < 1.0 - 1e-9 or abs(steps - round(steps)) > 1e-6:
            raise ConfigError(f"clock_period must be a multiple of time_step ({time_step} s), got {value}")
    return period


class ClockGate:
    """Says which stamps go out on /clock: the first stamp in each ``period_s`` of time.

    A stamp offered again (a held step) does not go out twice; one that goes back to an earlier
    period (a reset) does.
    """

    def __init__(self, period_s: float) -> None:
        self.period_ns = round(require_clock_period(period_s) * 1e9)
        self._last_slot: int | None = None

    def due(self, stamp_ns: int) -> bool:
        """True when ``stamp_ns`` [ns] should be published on /clock (and records that it was)."""
        slot = stamp_ns // self.period_ns
        if slot == self._last_slot:
            return False
        self._last_slot = slot
        return True
