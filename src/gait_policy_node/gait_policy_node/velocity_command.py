"""velocity_command: publish /cmd_vel (geometry_msgs/Twist) for machines without the ros2 CLI.

Interchangeable with ``ros2 topic pub /cmd_vel geometry_msgs/msg/Twist ...``. Profiles:
- constant: vx, vy, yaw_rate from the parameters;
- ramp: forward speed 0 -> ``speed`` at ``acceleration`` (the paper's 0 -> 2.5 m/s at 1 m/s^2), held;
- steps: ``steps`` = "t0:v0,t1:v1,..." forward speed v_i from time t_i [s] (0 before t0).
The profiles are ``speed_profiles``, the ones the training episodes and in-process tools use.
Time is the node's clock (sim time with use_sim_time), counted from the first tick, or from
``start_time`` of that clock when it is set (the demo: sim time 0, so that the ramp starts at the
same sim time however late this process hears its first /clock); nothing but zero is sent for the
first ``start_delay`` seconds (the controller stands up meanwhile); with ``duration`` > 0 it
publishes zero and exits that many seconds after the same start.
Every value is range-checked at start-up (a bad one ends the node with its name and range); the
parameters are read at start-up only, so runtime changes are refused.
"""

from __future__ import annotations

from dataclasses import dataclass

from a1_common.config import (
    ConfigError,
    recording_constraints,
    require_choice,
    require_range,
    setting,
)
from a1_common.node_support import constrain_parameters, declare_settings, run_node
from a1_interface.contract import COMMAND_QOS
from geometry_msgs.msg import Twist
from rclpy.node import Node

from a1_interface import contract
from gait_policy_node import speed_profiles

PROFILES = ("constant", "ramp", "steps")


@dataclass(frozen=True)
class NodeParameters:
    profile: str = setting("ramp", "constant: speed at once | ramp: to speed at acceleration | steps: the steps table")
    speed: float = setting(2.5, "forward speed of the constant and ramp profiles [m/s]")
    lateral: float = setting(0.0, "lateral speed [m/s]")
    yaw_rate: float = setting(0.0, "yaw rate [rad/s]")
    acceleration: float = setting(1.0, "ramp: acceleration to speed [m/s^2]")
    steps: str = setting("0:0.0", "steps profile: 'time:speed,...' [s:m/s], times increasing")
    rate: float = setting(20.0, "/cmd_vel publish rate [Hz]")
    duration: float = setting(0.0, "stop publishing after this long [s] (0: never)")
    start_delay: float = setting(0.0, "profile time starts this long after the first tick (or start_time) [s]")
    start_time: float = setting(-1.0, "count time from this time of the node's clock [s] (-1: from the first tick)")


PARAMETERS = NodeParameters()
MAX_SPEED = 3.0  # [m/s] forward speed of any profile (the controller's default limit)
MAX_STEP_TIME = 1e6  # [s]


def parse_steps(text: str) -> list[tuple[float, float]]:
    """ "0:0.5,5:1.0" -> [(0.0, 0.5), (5.0, 1.0)], times increasing; ConfigError otherwise.

    Times must be in [0, 1e6] s and speeds in [-3, 3] m/s, like the ``speed`` parameter.
    """
    steps = []
    for i, item in enumerate(text.split(",")):
        try:
            t, v = (float(x) for x in item.split(":"))
        except ValueError:
            raise ConfigError(f"steps must look like '0:0.5,5:1.0' (time s:speed m/s), got {text[:80]!r}") from None
        steps.append((require_range(f"steps[{i}] time", t, 0.0, MAX_STEP_TIME),
                      require_range(f"steps[{i}] speed", v, -MAX_SPEED, MAX_SPEED)))
    if [t for t, _ in steps] != sorted(t for t, _ in steps):
        raise ConfigError(f"steps times must increase, got {text[:80]!r}")
    return steps


class VelocityCommandNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("velocity_command", **node_kwargs)
        with recording_constraints() as constraints:
            p = declare_settings(self, PARAMETERS)
            self.profile = require_choice("profile", p["profile"], PROFILES)
            self.speed = require_range("speed", p["speed"], -MAX_SPEED, MAX_SPEED)
            self.lateral = require_range("lateral", p["lateral"], -1.0, 1.0)
            self.yaw_rate = require_range("yaw_rate", p["yaw_rate"], -2.0, 2.0)
            self.acceleration = require_range("acceleration", p["acceleration"], 0.0, 20.0, low_open=True)
            self.steps = parse_steps(p["steps"])
            self.duration = require_range("duration", p["duration"], 0.0, 1e6)
            self.start_delay = require_range("start_delay", p["start_delay"], 0.0, 3600.0)
            start_time = require_range("start_time", p["start_time"], -1.0, 1e9)
            if -1.0 < start_time < 0.0:
                raise ConfigError(f"start_time must be -1 (from the first tick) or in [0, 1e9] s, got {start_time}")
            rate = require_range("rate", p["rate"], 1.0, 1000.0)
        constrain_parameters(self, p, constraints)  # all read-only: read at start-up
        self.pub = self.create_publisher(Twist, contract.CMD_VEL, COMMAND_QOS)
        self._start = start_time if start_time >= 0.0 else None
        if self.profile == "constant":
            self._profile = speed_profiles.constant(self.speed, self.lateral, self.yaw_rate)
        elif self.profile == "ramp":
            self._profile = speed_profiles.ramp(self.speed, self.acceleration)
        else:
            self._profile = speed_profiles.steps(self.steps)
        self.create_timer(1.0 / rate, self._tick)

    def command_at(self, t: float) -> Twist:
        """The profile's command ``t`` seconds after it began, as a Twist."""
        command = self._profile(t)
        msg = Twist()
        msg.linear.x, msg.linear.y, msg.angular.z = command.vx, command.vy, command.yaw_rate
        return msg

    def _tick(self) -> None:
        now = self.get_clock().now().nanoseconds * 1e-9
        if self._start is None:
            self._start = now
        t = now - self._start
        if self.duration > 0 and t >= self.duration:
            self.pub.publish(Twist())
            self.get_logger().info(f"done after {t:.2f} s")
            self.context.try_shutdown()
            return
        self.pub.publish(self.command_at(t - self.start_delay) if t >= self.start_delay else Twist())


def main(args: list[str] | None = None) -> None:
    run_node("velocity_command", VelocityCommandNode, args)


if __name__ == "__main__":
    main()
