"""joint_hold: hold the A1 in its standing pose with joint PD, answering every /joint_states.

A bring-up tool for the sim bridge and for a hardware bridge alike: it ramps the joint targets from
the pose it first sees to the nominal stance over ``ramp_time`` (as the A1's safe stand-up does),
then holds. Each command carries the stamp of the joint state it answers, which is what the sim
bridge's lockstep mode waits for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from a1_common.command import JointCommand
from a1_common.config import recording_constraints, require_range, setting
from a1_common.node_support import constrain_parameters, declare_settings, run_node
from a1_common.robot import a1
from a1_interface.contract import CONTROL_QOS
from a1_interface.conversions import motor_command_msg, ns_from_stamp
from rclpy.node import Node
from sensor_msgs.msg import JointState

from a1_interface import contract
from gait_msgs.msg import MotorCommand


@dataclass(frozen=True)
class NodeParameters:
    ramp_time: float = setting(1.0, "ramp from the first measured pose to the standing pose [s]")


PARAMETERS = NodeParameters()


class JointHoldNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("joint_hold", **node_kwargs)
        with recording_constraints() as constraints:
            params = declare_settings(self, PARAMETERS)
            self.ramp_time = require_range("ramp_time", params["ramp_time"], 0.0, 10.0)  # [s]
        constrain_parameters(self, params, constraints)  # all read-only: read at start-up
        self.robot = a1()
        self._start: tuple[int, np.ndarray] | None = None
        self._last_ns = -1
        self.pub = self.create_publisher(MotorCommand, contract.MOTOR_COMMAND, CONTROL_QOS)
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joints, CONTROL_QOS)

    def _on_joints(self, msg: JointState) -> None:
        now_ns = ns_from_stamp(msg.header.stamp)
        q = np.asarray(msg.position, dtype=float)
        if list(msg.name) != list(self.robot.joint_names) or q.shape != (12,) or not np.all(np.isfinite(q)):
            self.get_logger().warning("ignoring /joint_states without the 12 A1 joints in motor order "
                                      "and finite positions", throttle_duration_sec=1.0)
            return
        if self._start is None or now_ns <= self._last_ns:  # first message, or time went back (reset)
            self._start = (now_ns, q)
        self._last_ns = now_ns
        t0, q0 = self._start
        command = JointCommand.stand_up(self.robot, q0, (now_ns - t0) * 1e-9, self.ramp_time)
        self.pub.publish(motor_command_msg(command, msg.header.stamp))


def main(args: list[str] | None = None) -> None:
    run_node("joint_hold", JointHoldNode, args)


if __name__ == "__main__":
    main()
