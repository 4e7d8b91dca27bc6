"""virtual_a1: a simulated A1 that speaks the robot's low-level UDP protocol (for hardware-in-the-loop).

The robot's data go over UDP only (a1_hw_bridge.virtual_a1, no rclpy). This process is a ROS node
just to publish what a real robot cannot: /sim/ground_truth/odom (evaluation only, stamped with
robot time) and /diagnostics (datagram counts, injected losses).
"""

from __future__ import annotations

import threading
import traceback
from dataclasses import dataclass

from a1_common.config import parameter_defaults, recording_constraints, setting
from a1_common.node_support import constrain_parameters, declare_settings, diagnostic_array, run_node
from a1_interface.contract import CONTROL_QOS
from a1_sim_bridge.sim import SensorNoise, SimConfig
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Odometry
from rclpy.node import Node

from a1_hw_bridge.virtual_a1 import VirtualA1, VirtualA1Config, VirtualA1Server
from a1_interface import contract, wire


@dataclass(frozen=True)
class NodeParameters:
    """The node's own parameters; the rest configure the robot side and its simulation."""

    publish_ground_truth: bool = setting(True, "publish the true base state on /sim/ground_truth/odom")


class VirtualA1Node(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("virtual_a1", **node_kwargs)
        robot_defaults = parameter_defaults(VirtualA1Config())
        sim_defaults = {**parameter_defaults(SimConfig()), **parameter_defaults(SensorNoise())}
        with recording_constraints() as constraints:
            params = declare_settings(self, VirtualA1Config(), SimConfig(), SensorNoise(), NodeParameters())
            config = VirtualA1Config(**{k: params[k] for k in robot_defaults}).validated()
            sim_config = SimConfig.from_parameters({k: params[k] for k in sim_defaults})
            self.robot = VirtualA1(config, sim_config)
        constrain_parameters(self, params, constraints)  # all read-only: read at start-up
        self.publish_ground_truth = bool(params["publish_ground_truth"])
        self.pub_truth = self.create_publisher(Odometry, contract.GROUND_TRUTH, CONTROL_QOS)
        self._truth_encoder = wire.OdometryEncoder()  # as bytes, like the sim bridge's
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.DIAGNOSTICS_QOS)
        self._lowest_base_height = float("inf")  # [m] since the last /diagnostics (ground truth)
        self.server = VirtualA1Server(self.robot, on_tick=self._on_tick)
        self.failure: Exception | None = None
        self.create_timer(1.0, self._publish_diagnostics)
        host, port = self.server.address
        self.get_logger().info(
            f"virtual A1 on {host}:{port} (UDP), clock_mode={config.clock_mode}, world={sim_config.world}, "
            f"packet_loss={config.packet_loss}, on_command_loss={config.on_command_loss} "
            f"after {config.command_loss_timeout}s")
        self._thread = threading.Thread(target=self._serve, name="virtual_a1", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        try:
            self.server.serve()
        except Exception as exc:  # a dead robot loop must be loud
            self.failure = exc
            self.get_logger().fatal(f"virtual A1 loop failed: {exc!r}\n{traceback.format_exc()}")
            self.context.try_shutdown()

    def _on_tick(self) -> None:
        if self.publish_ground_truth:
            sim = self.robot.sim
            stamp_ns = sim.steps * round(sim.config.time_step * 1e9)
            truth = sim.ground_truth()
            self._lowest_base_height = min(self._lowest_base_height, float(truth.base_position[2]))
            self.pub_truth.publish(self._truth_encoder.encode(wire.ground_truth_odometry(truth, stamp_ns)))

    def _publish_diagnostics(self) -> None:
        r = self.robot
        lowest, self._lowest_base_height = self._lowest_base_height, float("inf")
        status = DiagnosticStatus(name="virtual_a1", hardware_id=f"{r.config.host}:{r.config.port}")
        status.level = DiagnosticStatus.OK if r.stats.accepted else DiagnosticStatus.WARN
        status.message = "commanded" if r.stats.accepted else "waiting for commands"
        c, s = r.counters, r.stats
        values = {
            "clock_mode": r.config.clock_mode, "robot_time_s": f"{r.sim.time:.3f}", "ticks": c.ticks,
            "commands_received": s.received, "commands_accepted": s.accepted, "dropped_wrong_size": s.wrong_size,
            "dropped_bad_crc": s.bad_crc, "dropped_not_low_level": s.bad_level, "states_sent": s.sent,
            "commands_lost_injected": c.commands_lost, "states_lost_injected": c.states_lost,
            "commands_refused": c.commands_refused, "last_refusal": r.last_error,
            "command_loss_fallbacks": c.command_loss_fallbacks, "realtime_overruns": self.server.pacer.overruns,
            "lowest_base_height_m": f"{lowest:.3f}" if self.publish_ground_truth else "n/a",
        }
        self.pub_diag.publish(diagnostic_array(self, status, values))

    def shutdown(self) -> None:
        self.server.stop()
        self._thread.join(timeout=2.0)
        if not self._thread.is_alive():
            self.robot.close()


def main(args: list[str] | None = None) -> None:
    run_node("virtual_a1", VirtualA1Node, args)


if __name__ == "__main__":
    main()
