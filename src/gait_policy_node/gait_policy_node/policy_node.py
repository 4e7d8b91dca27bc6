"""gait_policy node: the 20 Hz gait policy. /cmd_vel and /odom in, /gait/params out.

The policy comes from the ``policy`` parameter (see policy.make_policy): ``learned`` (the trained
policy shipped with this package, the default), a learned policy file (.npz from train_es), a gait
table (.csv: the gait against commanded speed), the hand-tuned gaits scheduled by speed
(``scheduled``), or one hand-tuned gait by name.
The desired velocity the policy sees is /cmd_vel as the controller tracks it (a1_common.command's
CommandShaper with the controller's ``max_acceleration``, ``cmd_vel_timeout`` and /cmd_vel clamp
``max_forward_speed`` / ``max_lateral_speed``, as set in config/convex_mpc.yaml): the policy was
trained on commands that change at most at the paper's 1 m/s^2, so a step in /cmd_vel must not ask
it for the gait of a speed the robot is not at yet. The measured velocity is /odom's twist
(base_link frame) turned into the yaw-aligned frame, the frame the policy was trained in.
Runs on sim time under a sim bridge (``use_sim_time``), like the rest of the graph.

Bad input: /cmd_vel and /odom with NaN/inf are ignored (the last good value stays); finite values
are clamped (documented clamp): the desired velocity as the controller clamps /cmd_vel (3 m/s
forward, 1 m/s sideways by default), the measured one to |v| <= 10 m/s per axis (the estimator
flags faster estimates as diverging), so that no input can drive a policy outside the range it was
made for. Gait parameters are validated before they are published; an invalid output is dropped
and counted (the controller then falls back to its hand-tuned gaits). /diagnostics at 1 Hz: the
policy, its inputs and last gait, the counts. Parameters are read at start-up only: runtime changes are refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from a1_common.command import CommandShaper
from a1_common.config import (
    ConfigError,
    recording_constraints,
    require_range,
    setting,
)
from a1_common.kinematics import heading_frame, quat_to_matrix
from a1_common.node_support import constrain_parameters, declare_settings, diagnostic_array, run_node
from a1_interface.contract import COMMAND_QOS, CONTROL_QOS
from convex_mpc_node.supervisor import load_supervisor_config
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node

from a1_interface import contract
from gait_msgs.msg import GaitParams as GaitParamsMsg
from gait_policy_node.learned_policy import SHIPPED_POLICY
from gait_policy_node.policy import make_policy


@dataclass(frozen=True)
class NodeParameters:
    policy: str = setting(SHIPPED_POLICY, "learned (the shipped trained policy) | a policy .npz from train_es | "
                                          "a gait table .csv | scheduled | walk | slow_trot | rapid_trot | fly_trot")
    rate: float = setting(20.0, "policy rate, /gait/params per second [Hz]")
    cmd_vel_stamped: bool = setting(False, "read /cmd_vel as geometry_msgs/TwistStamped instead of Twist")


PARAMETERS = NodeParameters()
MAX_MEASURED_VELOCITY = 10.0  # [m/s] per axis


class GaitPolicyNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("gait_policy", **node_kwargs)
        with recording_constraints() as constraints:
            params = declare_settings(self, PARAMETERS)
            rate = require_range("rate", params["rate"], 1.0, 500.0)
            self.policy = make_policy(params["policy"])
            supervisor = load_supervisor_config()
            self.shaper = CommandShaper(supervisor.max_acceleration, supervisor.cmd_vel_timeout)
            # [m/s] x, y: the controller's /cmd_vel clamp, so the policy sees the speed the robot is sent to
            self.max_desired = np.array([supervisor.max_forward_speed, supervisor.max_lateral_speed])
        constrain_parameters(self, params, constraints)  # all read-only: read at start-up
        self.desired = np.zeros(2)  # [m/s] x, y as the controller tracks them (the policy's input)
        self._last_tick: float | None = None  # [s] node clock
        self.measured = np.zeros(3)
        self.policy_name = params["policy"]
        self.ignored_inputs = 0  # /cmd_vel or /odom messages with NaN/inf or no orientation
        self.invalid_outputs = 0  # policy outputs outside the gait parameter ranges, not published
        self.odom_received = False
        self.last_gait = None
        self.pub = self.create_publisher(GaitParamsMsg, contract.GAIT_PARAMS, COMMAND_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.DIAGNOSTICS_QOS)
        if params["cmd_vel_stamped"]:
            self.create_subscription(TwistStamped, contract.CMD_VEL, lambda m: self._on_cmd(m.twist), COMMAND_QOS)
        else:
            self.create_subscription(Twist, contract.CMD_VEL, self._on_cmd, COMMAND_QOS)
        self.create_subscription(Odometry, contract.ODOM, self._on_odom, CONTROL_QOS)
        self.create_timer(1.0 / rate, self._tick)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f"gait policy '{params['policy']}' at {rate:g} Hz")

    def _on_cmd(self, twist: Twist) -> None:
        values = np.array([twist.linear.x, twist.linear.y], dtype=float)
        if np.all(np.isfinite(values)):
            target = np.clip(values, -self.max_desired, self.max_desired)
            self.shaper.set_target(np.array([target[0], target[1], 0.0]), self._now())
        else:
            self.ignored_inputs += 1
            self.get_logger().warning("ignored /cmd_vel with NaN/inf", throttle_duration_sec=1.0)

    def _on_odom(self, msg: Odometry) -> None:
        v = msg.twist.twist.linear  # base_link frame
        q = msg.pose.pose.orientation
        orientation = np.array([q.x, q.y, q.z, q.w])
        v_body = np.array([v.x, v.y, v.z])
        norm = np.linalg.norm(orientation)
        if np.all(np.isfinite(v_body)) and np.isfinite(norm) and norm > 0.5:
            orientation = orientation / norm
            v_body = np.clip(v_body, -MAX_MEASURED_VELOCITY, MAX_MEASURED_VELOCITY)
            self.measured = heading_frame(orientation).T @ quat_to_matrix(orientation) @ v_body
            self.odom_received = True
        else:
            self.ignored_inputs += 1
            self.get_logger().warning("ignored /odom with NaN/inf or without a unit orientation",
                                      throttle_duration_sec=1.0)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _tick(self) -> None:
        stamp = self.get_clock().now()  # the gait's time, and the desired velocity's
        now = stamp.nanoseconds * 1e-9
        if self._last_tick is not None and now < self._last_tick:  # sim time went back: a new run
            self.shaper.reset()
            self._last_tick = None
        dt = 0.0 if self._last_tick is None else now - self._last_tick
        self._last_tick = now
        self.desired = self.shaper.update(now, dt)[:2]
        try:
            params = self.policy(self.desired, self.measured).validated()
        except ConfigError as exc:
            self.invalid_outputs += 1
            self.get_logger().error(f"policy output not published: {exc}", throttle_duration_sec=1.0)
            return
        self.last_gait = params
        msg = GaitParamsMsg()
        msg.header.stamp = stamp.to_msg()
        msg.header.frame_id = "base_link"
        msg.stepping_frequency = params.stepping_frequency
        msg.swing_ratio = params.swing_ratio
        msg.phase_offsets = list(params.phase_offsets)
        self.pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        status = DiagnosticStatus(name="gait_policy", hardware_id="a1")
        if not self.odom_received:
            status.level, status.message = DiagnosticStatus.WARN, "waiting for /odom (policy sees zero velocity)"
        elif self.invalid_outputs:
            status.level, status.message = DiagnosticStatus.WARN, "policy outputs dropped (out of range)"
        else:
            status.level, status.message = DiagnosticStatus.OK, "publishing /gait/params"
        gait = self.last_gait
        values = {
            "policy": self.policy_name, "desired_velocity": np.round(self.desired, 3).tolist(),
            "requested_velocity": np.round(self.shaper.target[:2], 3).tolist(),
            "measured_velocity": np.round(self.measured, 3).tolist(),
            "stepping_frequency_hz": f"{gait.stepping_frequency:.2f}" if gait else "n/a",
            "swing_ratio": f"{gait.swing_ratio:.2f}" if gait else "n/a",
            "ignored_inputs": self.ignored_inputs, "invalid_outputs": self.invalid_outputs,
        }
        self.pub_diag.publish(diagnostic_array(self, status, values))


def main(args: list[str] | None = None) -> None:
    run_node("gait_policy", GaitPolicyNode, args)


if __name__ == "__main__":
    main()
