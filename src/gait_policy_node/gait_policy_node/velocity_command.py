"""velocity_command: publish /cmd_vel (geometry_msgs/Twist) for machines without the ros2 CLI.

Interchangeable with ``ros2 topic pub /cmd_vel geometry_msgs/msg/Twist ...``. Profiles:
- constant: vx, vy, yaw_rate from the parameters;
- ramp: forward speed 0 -> ``speed`` at ``acceleration`` (the paper's 0 -> 2.5 m/s at 1 m/s^2), held;
- steps: ``steps`` = "t0:v0,t1:v1,..." forward speed v_i from time t_i [s].
Time is the node's clock (sim time with use_sim_time), counted from the first tick; nothing but
zero is sent for the first ``start_delay`` seconds (the controller stands up meanwhile); with
``duration`` > 0 it publishes zero and exits after that many seconds.
Every value is range-checked at start-up (a bad one ends the node with its name and range); the
parameters are read at start-up only, so runtime changes are refused.
"""

from __future__ import annotations

from a1_common.config import ConfigError, require_range
from a1_common.node_support import declare_parameters, guard_runtime_parameters, run_node
from geometry_msgs.msg import Twist
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

PROFILES = ("constant", "ramp", "steps")
PARAMETERS = {"profile": "ramp", "speed": 2.5, "lateral": 0.0, "yaw_rate": 0.0, "acceleration": 1.0,
              "steps": "0:0.0", "rate": 20.0, "duration": 0.0, "start_delay": 0.0}
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
        p = declare_parameters(self, PARAMETERS)
        if p["profile"] not in PROFILES:
            raise ConfigError(f"profile must be one of {list(PROFILES)}, got {p['profile']!r}")
        self.profile = p["profile"]
        self.speed = require_range("speed", p["speed"], -MAX_SPEED, MAX_SPEED)
        self.lateral = require_range("lateral", p["lateral"], -1.0, 1.0)
        self.yaw_rate = require_range("yaw_rate", p["yaw_rate"], -2.0, 2.0)
        self.acceleration = require_range("acceleration", p["acceleration"], 0.0, 20.0, low_open=True)
        self.steps = parse_steps(p["steps"])
        self.duration = require_range("duration", p["duration"], 0.0, 1e6)
        self.start_delay = require_range("start_delay", p["start_delay"], 0.0, 3600.0)
        rate = require_range("rate", p["rate"], 1.0, 1000.0)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(Twist, "/cmd_vel", reliable)
        self._start = None
        self.create_timer(1.0 / rate, self._tick)
        guard_runtime_parameters(self, PARAMETERS)

    def command_at(self, t: float) -> Twist:
        msg = Twist()
        if self.profile == "constant":
            msg.linear.x, msg.linear.y, msg.angular.z = self.speed, self.lateral, self.yaw_rate
        elif self.profile == "ramp":
            msg.linear.x = min(abs(self.speed), self.acceleration * t) * (1 if self.speed >= 0 else -1)
        else:
            msg.linear.x = next((v for t0, v in reversed(self.steps) if t >= t0), 0.0)
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
