"""gait_policy node: the 20 Hz gait policy. /cmd_vel and /odom in, /gait/params out.

The policy comes from the ``policy`` parameter (see policy.make_policy): the hand-tuned gaits
scheduled by speed (default), one hand-tuned gait by name, or (with the learning issue) a file.
Runs on sim time under a sim bridge (``use_sim_time``), like the rest of the graph.
"""

from __future__ import annotations

import numpy as np
from a1_common.config import require_range
from a1_common.node_support import declare_parameters, run_node
from a1_sim_bridge.node import CONTROL_QOS
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from gait_msgs.msg import GaitParams as GaitParamsMsg
from gait_policy_node.policy import make_policy

COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


class GaitPolicyNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("gait_policy", **node_kwargs)
        params = declare_parameters(self, {"policy": "scheduled", "rate": 20.0, "cmd_vel_stamped": False})
        rate = require_range("rate", params["rate"], 1.0, 500.0)
        self.policy = make_policy(params["policy"])
        self.desired = np.zeros(2)
        self.measured = np.zeros(2)
        self.pub = self.create_publisher(GaitParamsMsg, "/gait/params", COMMAND_QOS)
        if params["cmd_vel_stamped"]:
            self.create_subscription(TwistStamped, "/cmd_vel", lambda m: self._on_cmd(m.twist), COMMAND_QOS)
        else:
            self.create_subscription(Twist, "/cmd_vel", self._on_cmd, COMMAND_QOS)
        self.create_subscription(Odometry, "/odom", self._on_odom, CONTROL_QOS)
        self.create_timer(1.0 / rate, self._tick)
        self.get_logger().info(f"gait policy '{params['policy']}' at {rate:g} Hz")

    def _on_cmd(self, twist: Twist) -> None:
        values = np.array([twist.linear.x, twist.linear.y])
        if np.all(np.isfinite(values)):
            self.desired = values

    def _on_odom(self, msg: Odometry) -> None:
        v = msg.twist.twist.linear  # base_link frame
        self.measured = np.array([v.x, v.y])

    def _tick(self) -> None:
        params = self.policy(self.desired, self.measured)
        msg = GaitParamsMsg()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id = "base_link"
        msg.stepping_frequency = params.stepping_frequency
        msg.swing_ratio = params.swing_ratio
        msg.phase_offsets = list(params.phase_offsets)
        self.pub.publish(msg)


def main(args: list[str] | None = None) -> None:
    run_node("gait_policy", GaitPolicyNode, args)


if __name__ == "__main__":
    main()
