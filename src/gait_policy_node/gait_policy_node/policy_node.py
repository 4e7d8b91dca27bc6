"""gait_policy node: the 20 Hz gait policy. /cmd_vel and /odom in, /gait/params out.

The policy comes from the ``policy`` parameter (see policy.make_policy): a learned policy file
(.npz from train_es), the hand-tuned gaits scheduled by speed, or one hand-tuned gait by name.
The measured velocity is /odom's twist (base_link frame) turned into the yaw-aligned frame, the
frame the policy was trained in.
Runs on sim time under a sim bridge (``use_sim_time``), like the rest of the graph.
"""

from __future__ import annotations

import numpy as np
from a1_common.config import require_range
from a1_common.kinematics import quat_to_matrix
from a1_common.node_support import declare_parameters, run_node
from a1_sim_bridge.node import CONTROL_QOS
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from gait_msgs.msg import GaitParams as GaitParamsMsg
from gait_policy_node.policy import make_policy
from gait_policy_node.rollout import heading_frame

COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


class GaitPolicyNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("gait_policy", **node_kwargs)
        params = declare_parameters(self, {"policy": "scheduled", "rate": 20.0, "cmd_vel_stamped": False})
        rate = require_range("rate", params["rate"], 1.0, 500.0)
        self.policy = make_policy(params["policy"])
        self.desired = np.zeros(2)
        self.measured = np.zeros(3)
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
        q = msg.pose.pose.orientation
        orientation = np.array([q.x, q.y, q.z, q.w])
        v_body = np.array([v.x, v.y, v.z])
        norm = np.linalg.norm(orientation)
        if np.all(np.isfinite(v_body)) and np.isfinite(norm) and norm > 0.5:
            orientation = orientation / norm
            self.measured = heading_frame(orientation).T @ quat_to_matrix(orientation) @ v_body

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
