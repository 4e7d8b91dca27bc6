"""fault_relay node: sits between one topic's publisher and its subscribers and injects faults.

Start the publisher with its topic remapped to the relay's input (``-r /imu/data:=/fault_in/imu/data``),
then the relay with ``-p topic:=/imu/data -p message_type:=sensor_msgs/msg/Imu`` and the faults
(parameters: those of faults.FaultConfig). The subscribers notice nothing but the faults.
Counts go to /diagnostics once a second. Topics of the graph are stamped, and the faults' windows
are in the messages' own time (sim time under a sim bridge).
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass

from a1_common.config import ConfigError, parameter_defaults, recording_constraints, setting
from a1_common.node_support import constrain_parameters, declare_settings, diagnostic_array, run_node
from a1_interface.contract import CONTROL_QOS
from a1_interface.conversions import ns_from_stamp
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from a1_interface import contract
from fault_injection.faults import FaultConfig, FaultInjector


@dataclass(frozen=True)
class NodeParameters:
    """The relay's own parameters; the faults are FaultConfig's."""

    topic: str = setting("", "the topic the relay publishes, an absolute name such as /imu/data")
    message_type: str = setting("", "its message type, such as sensor_msgs/msg/Imu")
    input_topic: str = setting("", "the topic the relay reads ('': /fault_in<topic>)")


INPUT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)  # no loss the relay did not choose


def message_class(name: str) -> type:
    """``pkg/msg/Type`` -> the message class, or ConfigError naming the parameter."""
    parts = name.split("/")
    if len(parts) != 3 or parts[1] != "msg" or not all(parts):
        raise ConfigError(f"message_type must look like 'sensor_msgs/msg/Imu', got {name!r}")
    try:
        cls = getattr(importlib.import_module(f"{parts[0]}.msg"), parts[2])
    except (ImportError, AttributeError):
        raise ConfigError(f"message_type {name!r}: no such message is installed") from None
    if "header" not in cls.get_fields_and_field_types():
        raise ConfigError(f"message_type {name!r} has no header: the relay times faults by header stamps")
    return cls


class FaultRelayNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("fault_relay", **node_kwargs)
        fault_defaults = parameter_defaults(FaultConfig())
        with recording_constraints() as constraints:
            params = declare_settings(self, FaultConfig(), NodeParameters())
            topic = params["topic"]
            if not topic.startswith("/"):
                raise ConfigError(f"topic must be an absolute topic name like /imu/data, got {topic!r}")
            cls = message_class(params["message_type"])
            self.injector = FaultInjector(FaultConfig(**{k: params[k] for k in fault_defaults}))
        constrain_parameters(self, params, constraints)  # all read-only: read at start-up
        self.topic = topic
        self.input_topic = params["input_topic"] or "/fault_in" + topic
        self.pub = self.create_publisher(cls, topic, CONTROL_QOS)
        self.create_subscription(cls, self.input_topic, self._on_message, INPUT_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.DIAGNOSTICS_QOS)
        if self.injector.config.delay > 0 and self.injector.config.delay_mode == "wall":
            self.create_timer(0.001, lambda: self._publish(self.injector.due(time.monotonic())))
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f"relaying {self.input_topic} -> {topic} with {self.injector.config}")

    def _on_message(self, msg) -> None:
        self._publish(self.injector.on_message(msg, ns_from_stamp(msg.header.stamp) * 1e-9, time.monotonic()))

    def _publish(self, msgs: list) -> None:
        for msg in msgs:
            self.pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        status = DiagnosticStatus(name=f"fault_relay {self.topic}", hardware_id="fault_injection",
                                  level=DiagnosticStatus.OK, message="injecting faults")
        self.pub_diag.publish(diagnostic_array(self, status, vars(self.injector.counts)))


def main(args: list[str] | None = None) -> None:
    run_node("fault_relay", FaultRelayNode, args)


if __name__ == "__main__":
    main()
