"""record: every topic of the running graph into one rosbag2 bag with MCAP storage (bag.py), what
``ros2 bag record -a -s mcap`` makes on a full ROS install.

Its own process, never in the 2 ms chain: each topic is subscribed as its CDR bytes (nothing is
deserialised) with its publishers' reliability and durability and a deep queue (RECORD_DEPTH), and
written from this node's executor. Topics are looked up every ``discovery_period`` seconds, so a
node that starts later is recorded from then on. Messages are stamped with their receive time on
this node's clock (sim time with ``use_sim_time``: in steps of the bridge's ``clock_period``, 10 ms,
so 500 Hz topics are best plotted by their header stamps). Ctrl-C / SIGTERM close the bag (index and
metadata.yaml) and print what was written per topic; a kill -9 leaves every chunk written so far
readable (bag.read_mcap_messages). /diagnostics at 1 Hz: the messages written per topic.
Parameters: ``output`` (the bag folder, which must not exist;
default ``bag_<date>_<time>`` here), ``discovery_period`` [s].
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass

from a1_common.config import (
    ConfigError,
    recording_constraints,
    require_range,
    setting,
)
from a1_common.node_support import constrain_parameters, declare_settings, diagnostic_array, run_node
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from a1_interface import contract
from bag_recorder.bag import BagWriter, qos_of


@dataclass(frozen=True)
class NodeParameters:
    output: str = setting("", "bag directory to create ('': bag_<date>_<time> here)")
    discovery_period: float = setting(0.5, "look for new topics this often [s]")


PARAMETERS = NodeParameters()
RECORD_DEPTH = 1000  # messages each subscription holds while the writer is busy (2 s of a 500 Hz topic)


def message_class(msgtype: str):
    """``sensor_msgs/msg/JointState`` -> the generated Python class."""
    package, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


class RecorderNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("bag_recorder", **node_kwargs)
        with recording_constraints() as constraints:
            p = declare_settings(self, PARAMETERS)
            period = require_range("discovery_period", p["discovery_period"], 0.05, 60.0)
        constrain_parameters(self, p, constraints)  # all read-only: read at start-up
        self.bag = BagWriter(p["output"] or time.strftime("bag_%Y%m%d_%H%M%S"))
        self.skipped: dict[str, str] = {}  # topic -> why it is not recorded
        self.create_timer(period, self._discover)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.DIAGNOSTICS_QOS)
        self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(f"recording every topic into {self.bag.path.resolve()}")
        self._discover()

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if self.bag.has_topic(topic) or topic in self.skipped:
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers so far: its type and QoS come with its first publisher
            try:
                cls = message_class(types[0])
                offered = publishers[0].qos_profile
                self.bag.add_topic(topic, types[0], [qos_of(offered.history.value, offered.depth,
                                                            offered.reliability.value, offered.durability.value)])
            except (ImportError, AttributeError, ValueError, ConfigError) as exc:
                self.skipped[topic] = str(exc)
                self.get_logger().warning(f"not recording {topic} ({types[0]}): {exc}")
                continue
            reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in publishers)
            latched = all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in publishers)
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=RECORD_DEPTH,
                             reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)
            self.create_subscription(cls, topic, lambda data, t=topic: self._write(t, data), qos, raw=True)

    def _write(self, topic: str, data: bytes) -> None:
        self.bag.write(topic, self.get_clock().now().nanoseconds, data)

    def _publish_diagnostics(self) -> None:
        status = DiagnosticStatus(name="bag_recorder", hardware_id=str(self.bag.path), level=DiagnosticStatus.OK,
                                  message=f"recording {len(self.bag.counts)} topics")
        skipped = {f"not recorded {topic}": why for topic, why in self.skipped.items()}
        values = {"bag": str(self.bag.path.resolve()), "messages": sum(self.bag.counts.values()),
                  **dict(sorted(self.bag.counts.items())), **skipped}
        self.pub_diag.publish(diagnostic_array(self, status, values))

    def shutdown(self) -> None:
        """Close the bag (run_node calls this on Ctrl-C / SIGTERM) and say what it holds."""
        self.bag.close()
        total = sum(self.bag.counts.values())
        print(f"bag_recorder: wrote {total} messages on {len(self.bag.counts)} topics to {self.bag.path.resolve()}",
              flush=True)
        for topic, count in sorted(self.bag.counts.items()):
            print(f"  {topic}: {count}", flush=True)


def main(args: list[str] | None = None) -> None:
    run_node("bag_recorder", RecorderNode, args)


if __name__ == "__main__":
    main()
