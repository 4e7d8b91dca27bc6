"""robot_state_monitor: print the robot's state a few times a second (a terminal dashboard).

Reads only the robot contract (/joint_states, /imu/data, /foot_contacts) plus, when a simulator
publishes it, /sim/ground_truth/odom. Stops by itself after ``duration`` seconds of sensor time
when ``duration`` > 0, printing a one-line summary, so scripts can use it as a check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from a1_common.config import recording_constraints, require_range, setting
from a1_common.node_support import constrain_parameters, declare_settings, run_node
from a1_interface.contract import CONTROL_QOS
from a1_interface.conversions import ns_from_stamp
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState

from a1_interface import contract
from gait_msgs.msg import FootContacts


def roll_pitch(q) -> tuple[float, float]:
    """Roll and pitch [rad] of a quaternion (x, y, z, w)."""
    x, y, z, w = q.x, q.y, q.z, q.w
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    return roll, pitch


@dataclass(frozen=True)
class NodeParameters:
    print_period: float = setting(0.5, "print a line every this much sensor time [s]")
    duration: float = setting(0.0, "stop after this much sensor time [s] (0: run until stopped)")


PARAMETERS = NodeParameters()


class MonitorNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("robot_state_monitor", **node_kwargs)
        with recording_constraints() as constraints:
            params = declare_settings(self, PARAMETERS)
            self.period = require_range("print_period", params["print_period"], 0.0, 3600.0, low_open=True)
            self.duration = require_range("duration", params["duration"], 0.0, 1e6)
        constrain_parameters(self, params, constraints)  # all read-only: read at start-up
        self.joints = self.imu = self.contacts = self.truth = None
        self.first_ns = None
        self.last_print_ns = None
        self.count = 0
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joints, CONTROL_QOS)
        self.create_subscription(Imu, contract.IMU, lambda m: setattr(self, "imu", m), CONTROL_QOS)
        self.create_subscription(FootContacts, contract.FOOT_CONTACTS, lambda m: setattr(self, "contacts", m),
                                 CONTROL_QOS)
        self.create_subscription(Odometry, contract.GROUND_TRUTH, lambda m: setattr(self, "truth", m),
                                 CONTROL_QOS)

    def _on_joints(self, msg: JointState) -> None:
        self.joints = msg
        self.count += 1
        now = ns_from_stamp(msg.header.stamp)
        if self.first_ns is None or now < self.first_ns:
            self.first_ns = self.last_print_ns = now
        if (now - self.last_print_ns) * 1e-9 >= self.period:
            self.last_print_ns = now
            print(self.line(now), flush=True)
        if self.duration > 0 and (now - self.first_ns) * 1e-9 >= self.duration:
            print(f"robot_state_monitor: received {self.count} joint states over {self.duration:.1f} s "
                  f"of sensor time; last: {self.line(now)}", flush=True)
            self.context.try_shutdown()  # ends run_node's spin

    def line(self, now_ns: int) -> str:
        parts = [f"t={now_ns * 1e-9:7.3f}s"]
        if self.truth is not None:
            p = self.truth.pose.pose.position
            v = self.truth.twist.twist.linear
            parts.append(f"base z={p.z:.3f}m x={p.x:+.3f}m vx={v.x:+.2f}m/s")
        if self.imu is not None:
            r, pt = roll_pitch(self.imu.orientation)
            parts.append(f"roll={math.degrees(r):+5.1f}° pitch={math.degrees(pt):+5.1f}°")
        if self.contacts is not None:
            legs = "".join("X" if c else "." for c in self.contacts.contact)
            force = " ".join(f"{f:5.1f}" for f in self.contacts.normal_force)
            parts.append(f"contacts(FR FL RR RL)={legs} force=[{force}]N")
        if self.joints is not None:
            tau = max(abs(t) for t in self.joints.effort) if self.joints.effort else float("nan")
            parts.append(f"|tau|max={tau:4.1f}Nm")
        return "  ".join(parts)


def main(args: list[str] | None = None) -> None:
    run_node("robot_state_monitor", MonitorNode, args)


if __name__ == "__main__":
    main()
