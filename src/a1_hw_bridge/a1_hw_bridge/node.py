"""hw_bridge node: the Unitree A1 (or the virtual A1) behind the sim bridge's contract.

Publishes /joint_states, /imu/data, /foot_contacts (same messages, frames and QoS as the sim
bridge, encoded by a1_interface.wire) and /diagnostics; subscribes /motor_command, and
/gait/state for the contact recalibration. In lockstep mode (virtual A1 only) it also publishes
/clock from the robot's tick. Everything else is in a1_hw_bridge.bridge (no rclpy).
"""

from __future__ import annotations

import numpy as np
from a1_common.command import JointCommand
from a1_common.config import recording_constraints
from a1_common.node_support import constrain_parameters, declare_settings, diagnostic_array, run_node
from a1_common.robot import a1
from a1_interface.contract import BASE_FRAME, CONTROL_QOS, IMU_FRAME, LATCHED_QOS
from a1_interface.sensors import SensorReadings
from a1_sim_bridge.description import robot_description
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String

from a1_hw_bridge.bridge import BridgeConfig, HardwareBridge, Phase
from a1_interface import contract, wire
from a1_interface import conversions as cv
from gait_msgs.msg import FootContacts, GaitState, MotorCommand

NO_STATE_ERROR_AGE = 0.5  # [s] without a valid state from the robot -> diagnostics ERROR


class HardwareBridgeNode(Node):
    def __init__(self, **node_kwargs) -> None:
        """``node_kwargs`` go to rclpy's Node (tests pass ``context`` and ``parameter_overrides``)."""
        super().__init__("hw_bridge", **node_kwargs)
        with recording_constraints() as constraints:
            params = declare_settings(self, BridgeConfig())
            config = BridgeConfig(**params).validated()
        constrain_parameters(self, params, constraints)  # all read-only: read at start-up
        self.joint_names = list(a1().joint_names)
        self.encoders = wire.SensorEncoders(self.joint_names, BASE_FRAME, IMU_FRAME)
        self.pub_joints = self.create_publisher(JointState, contract.JOINT_STATES, CONTROL_QOS)
        self.pub_imu = self.create_publisher(Imu, contract.IMU, CONTROL_QOS)
        self.pub_contacts = self.create_publisher(FootContacts, contract.FOOT_CONTACTS, CONTROL_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.DIAGNOSTICS_QOS)
        self.pub_description = self.create_publisher(String, contract.ROBOT_DESCRIPTION, LATCHED_QOS)
        self.pub_description.publish(String(data=robot_description()))  # as the sim bridge: RViz sees the robot
        self.pub_clock = (self.create_publisher(Clock, contract.CLOCK, CONTROL_QOS)
                          if config.clock_mode == "lockstep" else None)
        self.bridge = HardwareBridge(
            config, publish=self._publish, clock_ns=lambda: self.get_clock().now().nanoseconds,
            publish_clock=self._publish_clock if self.pub_clock is not None else None, on_failure=self._on_failure)
        self._taken: bytes | None = None  # the last command a controller in this process handed over
        self._taken_stamp_ns = -1  # ... and its stamp (-1: none handed over)
        self.create_subscription(MotorCommand, contract.MOTOR_COMMAND, self._on_command, CONTROL_QOS, raw=True)
        if config.swing_recalibration:
            self.create_subscription(GaitState, contract.GAIT_STATE, self._on_gait_state, CONTROL_QOS)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(
            f"A1 link {self.bridge.link.local_address[0]}:{self.bridge.link.local_address[1]} -> "
            f"{config.robot_ip}:{config.robot_port}, clock_mode={config.clock_mode}, "
            f"command_timeout={config.command_timeout}s; standing up once the robot answers")
        scheduling = self.bridge.start()
        if config.realtime_priority and not scheduling.startswith("SCHED_FIFO"):
            self.get_logger().warning(f"realtime_priority {config.realtime_priority} not applied: {scheduling}; "
                                      "the damping deadline is then at the mercy of the CPU load")

    @property
    def failure(self) -> Exception | None:
        """Set when the link thread died (run_node then exits non-zero)."""
        return self.bridge.failure

    def _on_failure(self, exc: Exception) -> None:
        self.get_logger().fatal(f"A1 link thread failed, motors sent to damping, stopping the node: {exc!r}")
        self.context.try_shutdown()  # ends spin() in main(), which exits non-zero

    def take_command(self, raw: bytes) -> None:
        """A /motor_command's CDR bytes handed over by a controller in this process as it sends
        them (a1_bringup.control_chain): offered to the link at once, not after the executor's next
        wait. The copy that then comes over the wire is dropped (_on_command)."""
        command, stamp_ns = wire.decode_motor_command(raw)
        self._taken, self._taken_stamp_ns = raw, stamp_ns
        self._offer(command, stamp_ns)

    def _on_command(self, raw: bytes) -> None:
        """A /motor_command as its CDR bytes (a1_interface.wire: this runs 500 times a second)."""
        if raw == self._taken:  # the wire copy of the command take_command offered
            return
        command, stamp_ns = wire.decode_motor_command(raw)
        if stamp_ns < self._taken_stamp_ns:  # the late wire copy of an earlier handed-over command:
            return  # never over a newer one
        self._offer(command, stamp_ns)

    def _offer(self, command: JointCommand, stamp_ns: int) -> None:
        result = self.bridge.offer_command(command, stamp_ns)
        if result == "rejected":
            self.get_logger().warning(f"rejected /motor_command: {self.bridge.logic.watchdog.last_error}",
                                      throttle_duration_sec=1.0)

    def _on_gait_state(self, msg: GaitState) -> None:
        self.bridge.observe_gait_state(cv.ns_from_stamp(msg.header.stamp), np.asarray(msg.desired_contact))

    def _publish(self, readings: SensorReadings, stamp_ns: int) -> None:
        joints, imu, contacts = self.encoders.encode(readings, stamp_ns)
        self.pub_imu.publish(imu)
        self.pub_contacts.publish(contacts)
        # Joint states last: the controller takes them as "this step's sensors are out".
        self.pub_joints.publish(joints)

    def _publish_clock(self, stamp_ns: int) -> None:
        self.pub_clock.publish(Clock(clock=cv.stamp_from_ns(stamp_ns)))

    def _publish_diagnostics(self) -> None:
        values = self.bridge.diagnostics()
        status = DiagnosticStatus(name="a1_hw_bridge", hardware_id=str(values["robot"]))
        phase = self.bridge.logic.phase
        if phase == Phase.FAULT:
            status.level, status.message = DiagnosticStatus.ERROR, str(values["fault"])
        elif float(values["state_age_s"]) > NO_STATE_ERROR_AGE:
            status.level, status.message = DiagnosticStatus.ERROR, "no valid state from the robot"
        elif phase != Phase.RUNNING:
            status.level, status.message = DiagnosticStatus.WARN, phase.value
        elif values["in_damping"]:
            status.level, status.message = DiagnosticStatus.WARN, "damping: no valid /motor_command"
        else:
            status.level, status.message = DiagnosticStatus.OK, "commanded"
        self.pub_diag.publish(diagnostic_array(self, status, values))

    def shutdown(self) -> None:
        """Stop the link thread; the last datagrams sent put the motors in damping."""
        self.bridge.stop()


def main(args: list[str] | None = None) -> None:
    run_node("hw_bridge", HardwareBridgeNode, args)


if __name__ == "__main__":
    main()
