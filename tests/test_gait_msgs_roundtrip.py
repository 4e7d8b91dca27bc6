"""gait_msgs is built and every message survives a real DDS round trip between two nodes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import spin_until

from gait_msgs import msg as gait_msgs


def _stamp(msg, sec: int, nanosec: int, frame: str) -> None:
    msg.header.stamp.sec = sec
    msg.header.stamp.nanosec = nanosec
    msg.header.frame_id = frame


def make_gait_params():
    m = gait_msgs.GaitParams()
    _stamp(m, 12, 345, "base_link")
    m.stepping_frequency = 2.75
    m.swing_ratio = 0.6125
    m.phase_offsets = [0.0, math.pi, 0.5 * math.pi, 1.5 * math.pi]
    return m


def make_gait_state():
    m = gait_msgs.GaitState()
    _stamp(m, 3, 999_999_999, "base_link")
    m.phases = [0.1, 3.2, 1.7, 6.2]
    m.desired_contact = [True, False, False, True]
    m.leg_states = [
        gait_msgs.GaitState.LEG_STANCE,
        gait_msgs.GaitState.LEG_SWING,
        gait_msgs.GaitState.LEG_EARLY_CONTACT,
        gait_msgs.GaitState.LEG_LOST_CONTACT,
    ]
    m.params = make_gait_params()
    return m


def make_motor_command():
    m = gait_msgs.MotorCommand()
    _stamp(m, 7, 2_000_000, "")
    m.mode = gait_msgs.MotorCommand.MODE_DAMPING
    rng = np.random.default_rng(3)
    m.position = rng.uniform(-2, 2, 12)
    m.velocity = rng.uniform(-10, 10, 12)
    m.kp = rng.uniform(0, 100, 12)
    m.kd = rng.uniform(0, 5, 12)
    m.torque = rng.uniform(-33.5, 33.5, 12)
    return m


def make_foot_contacts():
    m = gait_msgs.FootContacts()
    _stamp(m, 1, 1, "base_link")
    m.contact = [True, True, False, True]
    m.normal_force = [40.5, 38.25, 0.0, 61.125]
    return m


def assert_same(sent, got, path: str = "") -> None:
    """Compare every field recursively (messages, arrays, scalars)."""
    if hasattr(sent, "get_fields_and_field_types"):
        assert type(got) is type(sent), path
        for name in sent.get_fields_and_field_types():
            assert_same(getattr(sent, name), getattr(got, name), f"{path}.{name}")
    elif isinstance(sent, np.ndarray | list | tuple):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(sent), err_msg=path)
    else:
        assert got == sent, path


@pytest.mark.ros
@pytest.mark.parametrize(
    "factory", [make_gait_params, make_gait_state, make_motor_command, make_foot_contacts],
    ids=lambda f: f.__name__.removeprefix("make_"),
)
def test_message_round_trip(rclpy_context, factory):
    sent = factory()
    msg_type = type(sent)
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    talker = Node("roundtrip_talker", context=rclpy_context)
    listener = Node("roundtrip_listener", context=rclpy_context)
    received = []
    topic = f"/test/{msg_type.__name__}"
    pub = talker.create_publisher(msg_type, topic, qos)
    listener.create_subscription(msg_type, topic, received.append, qos)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(talker)
    executor.add_node(listener)
    try:
        assert spin_until(executor, lambda: pub.get_subscription_count() > 0, 10.0), "no discovery"
        pub.publish(sent)
        assert spin_until(executor, lambda: len(received) > 0, 10.0), "message never arrived"
        assert_same(sent, received[0])
        # The message must carry what was put in, not defaults: check one non-default field.
        assert received[0].header.stamp.sec == sent.header.stamp.sec != 0
    finally:
        executor.shutdown()
        talker.destroy_node()
        listener.destroy_node()
