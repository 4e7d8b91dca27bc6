"""bag_recorder: rosbag2 bags with MCAP storage, read back with the library (rosbags; mcap for a
killed recorder's file): topics, types, counts, stamps in order, messages as published."""

from __future__ import annotations

import os
import signal
import subprocess
import time

import pytest
from a1_common.config import ConfigError
from bag_recorder.bag import BagWriter, read_bag, read_mcap_messages
from diagnostic_msgs.msg import DiagnosticArray
from graph_helpers import executable
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from ros_helpers import spin_until
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from gait_msgs.msg import GaitParams

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def joint_state(k: int) -> JointState:
    msg = JointState(name=["FR_hip_joint"], position=[0.001 * k], velocity=[0.0], effort=[float(k)])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 2_000_000, 1_000_000_000)
    return msg


def test_bag_round_trip_with_the_stacks_own_message_type(tmp_path):
    bag = BagWriter(tmp_path / "bag")
    bag.add_topic("/joint_states", "sensor_msgs/msg/JointState")
    bag.add_topic("/gait/params", "gait_msgs/msg/GaitParams")  # from its installed .msg file
    gait = GaitParams(stepping_frequency=2.0, swing_ratio=0.45, phase_offsets=[0.0, 3.14, 3.14, 0.0])
    for k in range(20):
        bag.write("/joint_states", 1000 + k, serialize_message(joint_state(k)))
    bag.write("/gait/params", 1010, serialize_message(gait))
    bag.close()
    rows = list(read_bag(tmp_path / "bag"))
    assert [r[0] for r in rows].count("/joint_states") == 20 and [r[0] for r in rows].count("/gait/params") == 1
    assert {r[1] for r in rows} == {"sensor_msgs/msg/JointState", "gait_msgs/msg/GaitParams"}
    assert [r[2] for r in rows] == sorted(r[2] for r in rows)
    (back,) = [deserialize_message(r[3], GaitParams) for r in rows if r[0] == "/gait/params"]
    assert back.swing_ratio == 0.45 and list(back.phase_offsets) == [0.0, 3.14, 3.14, 0.0]
    assert (tmp_path / "bag" / "metadata.yaml").is_file() and (tmp_path / "bag" / "bag.mcap").is_file()
    with pytest.raises(ConfigError, match="already exists"):
        BagWriter(tmp_path / "bag")


@pytest.fixture
def publisher(rclpy_context):
    node = Node("bag_source", context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()


def start_recorder(bag) -> subprocess.Popen:
    return subprocess.Popen([executable("bag_recorder", "record"), "--ros-args", "-p", f"output:={bag}",
                             "-p", "discovery_period:=0.1"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)


def wait_for_subscriber(executor, pub) -> None:
    assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 30.0), "the recorder did not subscribe"


@pytest.mark.ros
@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl_c", "sigterm"])
def test_recorder_keeps_up_at_500_hz_and_closes_the_bag_on(publisher, tmp_path, stop):
    node, executor = publisher
    latched = node.create_publisher(String, "/robot_description", LATCHED)
    latched.publish(String(data="<robot name='a1'/>"))  # before the recorder: transient local reaches it
    joints = node.create_publisher(JointState, "/joint_states", RELIABLE)
    written: dict[str, str] = {}  # the recorder's /diagnostics: messages written per topic
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: written.update(
        {kv.key: kv.value for s in m.status if s.name == "bag_recorder" for kv in s.values}), 10)
    recorder = start_recorder(tmp_path / "bag")
    try:
        wait_for_subscriber(executor, joints)
        start = time.monotonic()
        for k in range(1000):  # 2 s at 500 Hz
            while time.monotonic() < start + 0.002 * k:
                executor.spin_once(timeout_sec=0.0)
            joints.publish(joint_state(k))
        assert spin_until(executor, lambda: written.get("/joint_states") == "1000", 30.0), written
        recorder.send_signal(stop)
        out, _ = recorder.communicate(timeout=30)
    finally:
        if recorder.poll() is None:
            os.killpg(recorder.pid, signal.SIGKILL)
    assert recorder.returncode == 0, out
    assert "/joint_states: 1000" in out, out
    rows = [r for r in read_bag(tmp_path / "bag") if r[0] in ("/joint_states", "/robot_description")]
    sent = [r for r in rows if r[0] == "/joint_states"]
    assert len(sent) == 1000  # every message published at 500 Hz was written
    assert [r[2] for r in sent] == sorted(r[2] for r in sent)
    decoded = [deserialize_message(r[3], JointState) for r in sent]
    assert [m.effort[0] for m in decoded] == [float(k) for k in range(1000)]  # each once, in order
    assert decoded[500].position[0] == joint_state(500).position[0]
    (description,) = [deserialize_message(r[3], String).data for r in rows if r[0] == "/robot_description"]
    assert description == "<robot name='a1'/>"


@pytest.mark.ros
def test_a_killed_recorder_leaves_its_written_chunks_readable(publisher, tmp_path):
    node, executor = publisher
    pub = node.create_publisher(String, "/big", RELIABLE)
    recorder = start_recorder(tmp_path / "bag")
    mcap = tmp_path / "bag" / "bag.mcap"
    payloads = [f"{k:06d}" + "x" * 8000 for k in range(600)]  # about 4.8 MB: several 1 MiB chunks
    try:
        wait_for_subscriber(executor, pub)
        for data in payloads:
            pub.publish(String(data=data))
            executor.spin_once(timeout_sec=0.0)
        # Three chunks on disk, then the kill: no index, no metadata.yaml.
        assert spin_until(executor, lambda: mcap.exists() and mcap.stat().st_size > 3 << 20, 30.0)
    finally:
        os.killpg(recorder.pid, signal.SIGKILL)
        recorder.wait(timeout=10)
    assert not (tmp_path / "bag" / "metadata.yaml").exists()
    got = [deserialize_message(data, String).data for topic, _, data in read_mcap_messages(tmp_path / "bag")
           if topic == "/big"]
    assert len(got) >= 300 and got == payloads[: len(got)]  # a prefix of what was published, intact
