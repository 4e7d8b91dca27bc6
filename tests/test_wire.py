"""The byte-level codecs of the 500 Hz messages (a1_interface.wire) against rclpy's serializer."""

from __future__ import annotations

import numpy as np
import pytest
from a1_common.command import JointCommand, MotorMode
from a1_interface.contract import BASE_FRAME, IMU_FRAME
from a1_interface.sensors import GroundTruth, SensorReadings
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu, JointState

from a1_interface import contract, wire
from a1_interface import conversions as cv
from gait_msgs.msg import FootContacts, MotorCommand

NAMES = [f"{leg}_{joint}_joint" for leg in ("FR", "FL", "RR", "RL") for joint in ("hip", "thigh", "calf")]
STAMP_NS = 12_345_678_902


@pytest.fixture
def readings() -> SensorReadings:
    rng = np.random.default_rng(3)
    return SensorReadings(
        time=STAMP_NS * 1e-9, joint_position=rng.normal(size=12), joint_velocity=rng.normal(size=12),
        joint_torque=rng.normal(size=12), imu_orientation=rng.normal(size=4), imu_angular_velocity=rng.normal(size=3),
        imu_linear_acceleration=rng.normal(size=3), foot_contact=np.array([True, False, False, True]),
        foot_force=rng.normal(size=4))


def test_encoders_give_what_the_ordinary_messages_give(readings: SensorReadings) -> None:
    stamp = cv.stamp_from_ns(STAMP_NS)
    for _ in range(2):  # the second encode reuses the template
        joints = deserialize_message(wire.JointStateEncoder(NAMES, BASE_FRAME).encode(
            STAMP_NS, readings.joint_position, readings.joint_velocity, readings.joint_torque), JointState)
        assert joints == cv.joint_state_msg(readings, stamp, NAMES)
        imu = deserialize_message(wire.ImuEncoder(IMU_FRAME).encode(
            STAMP_NS, readings.imu_orientation, readings.imu_angular_velocity, readings.imu_linear_acceleration), Imu)
        assert imu == cv.imu_msg(readings, stamp)
        contacts = deserialize_message(wire.FootContactsEncoder(BASE_FRAME).encode(
            STAMP_NS, readings.foot_contact, readings.foot_force), FootContacts)
        assert contacts == cv.foot_contacts_msg(readings, stamp)


def test_motor_command_both_ways() -> None:
    rng = np.random.default_rng(4)
    command = JointCommand(MotorMode.HYBRID, *(rng.normal(size=12) for _ in range(5)))
    encoder = wire.MotorCommandEncoder()
    msg = deserialize_message(encoder.encode(command, STAMP_NS), MotorCommand)
    assert msg == cv.motor_command_msg(command, cv.stamp_from_ns(STAMP_NS))
    damping = encoder.encode(JointCommand.damping(), STAMP_NS + 2_000_000)
    decoded, stamp_ns = wire.decode_motor_command(serialize_message(cv.motor_command_msg(command, cv.stamp_from_ns(
        STAMP_NS))))
    assert stamp_ns == STAMP_NS and decoded.mode == MotorMode.HYBRID
    for field in ("position", "velocity", "kp", "kd", "torque"):
        np.testing.assert_array_equal(getattr(decoded, field), getattr(command, field))
    decoded, stamp_ns = wire.decode_motor_command(damping)
    assert (decoded.mode, stamp_ns) == (MotorMode.DAMPING, STAMP_NS + 2_000_000)


def test_decoders_read_what_rclpy_serializes(readings: SensorReadings) -> None:
    stamp = cv.stamp_from_ns(STAMP_NS)
    decode_joints = wire.JointStateDecoder()
    for frame in ("", "base_link", "a_longer_frame_id"):  # other bridges may name frames otherwise
        msg = cv.joint_state_msg(readings, stamp, NAMES)
        msg.header.frame_id = frame
        joints = decode_joints(serialize_message(msg))
        assert (joints.header.stamp, joints.header.frame_id, joints.name) == (stamp, frame, NAMES)
        np.testing.assert_array_equal(joints.position, readings.joint_position)
        np.testing.assert_array_equal(joints.velocity, readings.joint_velocity)
        np.testing.assert_array_equal(joints.effort, readings.joint_torque)
    other = JointState(name=["a", "bc"], position=[1.0, 2.0])  # other names, no velocity or effort
    joints = decode_joints(serialize_message(other))
    assert joints.name == ["a", "bc"] and joints.velocity.shape == (0,)
    imu = wire.decode_imu(serialize_message(cv.imu_msg(readings, stamp)))
    assert imu.header.stamp == stamp
    np.testing.assert_array_equal(imu.orientation, readings.imu_orientation)
    np.testing.assert_array_equal(imu.angular_velocity, readings.imu_angular_velocity)
    np.testing.assert_array_equal(imu.linear_acceleration, readings.imu_linear_acceleration)
    contacts = wire.decode_foot_contacts(serialize_message(cv.foot_contacts_msg(readings, stamp)))
    np.testing.assert_array_equal(contacts.contact, readings.foot_contact)
    np.testing.assert_array_equal(contacts.normal_force, readings.foot_force)


def _odometry_msg(view: wire.OdometryView) -> Odometry:
    """The rclpy message of ``view``, field by field (the reference the encoder is checked against)."""
    msg = Odometry()
    msg.header.stamp, msg.header.frame_id, msg.child_frame_id = view.header.stamp, view.header.frame_id, \
        view.child_frame_id
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = view.pose.pose.position
    q.x, q.y, q.z, q.w = view.pose.pose.orientation
    t = msg.twist.twist
    t.linear.x, t.linear.y, t.linear.z = view.twist.twist.linear
    t.angular.x, t.angular.y, t.angular.z = view.twist.twist.angular
    msg.pose.covariance, msg.twist.covariance = view.pose.covariance, view.twist.covariance
    return msg


def test_odometry_both_ways() -> None:
    rng = np.random.default_rng(5)
    truth = GroundTruth(time=STAMP_NS * 1e-9, base_position=rng.normal(size=3), base_orientation=rng.normal(size=4),
                        base_linear_velocity=rng.normal(size=3), base_linear_velocity_body=rng.normal(size=3),
                        base_angular_velocity_body=rng.normal(size=3))
    encoder = wire.OdometryEncoder()
    truth_view = wire.ground_truth_odometry(truth, STAMP_NS)
    assert deserialize_message(encoder.encode(truth_view), Odometry) == cv.ground_truth_msg(
        truth, cv.stamp_from_ns(STAMP_NS))
    estimate = wire.odometry_view(cv.stamp_from_ns(STAMP_NS + 2_000_000), "odom_2", "a_longer_child_frame", *(
        rng.normal(size=n) for n in (3, 4, 3, 3)), rng.normal(size=36), rng.normal(size=36))
    child_only = estimate._replace(child_frame_id="base_link")  # a rebuild must not look at frame_id alone
    for view in (estimate, truth_view, estimate, child_only):  # other frames: the template is rebuilt
        raw = encoder.encode(view)
        assert deserialize_message(raw, Odometry) == _odometry_msg(view)
        decoded = wire.decode_odometry(serialize_message(_odometry_msg(view)))
        assert (decoded.header, decoded.child_frame_id) == (view.header, view.child_frame_id)
        assert decoded.pose.pose == view.pose.pose and decoded.twist.twist == view.twist.twist
        np.testing.assert_array_equal(decoded.pose.covariance, view.pose.covariance)
        np.testing.assert_array_equal(decoded.twist.covariance, view.twist.covariance)
        assert encoder.encode(decoded) == raw


@pytest.mark.parametrize(("decode", "msg"), [
    (wire.JointStateDecoder(), JointState(name=NAMES, position=[0.0] * 12)), (wire.decode_imu, Imu()),
    (wire.decode_foot_contacts, FootContacts()), (wire.decode_motor_command, MotorCommand()),
    (wire.decode_odometry, Odometry())])
def test_truncated_or_foreign_bytes_are_a_clear_error(decode, msg) -> None:
    whole = serialize_message(msg)
    with pytest.raises(ValueError, match="truncated"):
        decode(whole[:40])
    with pytest.raises(ValueError, match="not little-endian CDR"):
        decode(b"\x00\x00\x00\x00" + whole[4:])


class _FakeNode:
    """Just what subscribe_sensors and subscribe_odometry use of an rclpy Node: the subscriptions
    they make, and the log."""

    def __init__(self) -> None:
        self.callbacks: dict[str, object] = {}
        self.errors: list[str] = []

    def create_subscription(self, msg_type, topic, callback, qos, raw=False):
        assert raw, f"{topic} must be taken as bytes"
        self.callbacks[topic] = callback

    def get_logger(self):
        return self

    def error(self, text: str, throttle_duration_sec: float = 0.0) -> None:
        self.errors.append(text)


def test_sensor_subscriptions_decode_and_drop_malformed_messages_loudly(readings: SensorReadings) -> None:
    node, got = _FakeNode(), []
    wire.subscribe_sensors(node, None, on_joints=got.append, on_imu=got.append, on_contacts=got.append)
    assert list(node.callbacks) == [contract.IMU, contract.FOOT_CONTACTS, contract.JOINT_STATES]  # joints last
    imu = serialize_message(cv.imu_msg(readings, cv.stamp_from_ns(STAMP_NS)))
    node.callbacks[contract.IMU](imu[:30])
    assert got == [] and len(node.errors) == 1 and "sensor_msgs/Imu: truncated" in node.errors[0]
    node.callbacks[contract.IMU](imu)
    assert len(got) == 1 and got[0].header.stamp == cv.stamp_from_ns(STAMP_NS)


def test_odometry_subscription_decodes_and_drops_malformed_messages_loudly() -> None:
    node, got = _FakeNode(), []
    wire.subscribe_odometry(node, None, got.append)
    raw = serialize_message(Odometry(child_frame_id="base_link"))
    node.callbacks[contract.ODOM](raw[:50])
    assert got == [] and len(node.errors) == 1 and "nav_msgs/Odometry: truncated" in node.errors[0]
    node.callbacks[contract.ODOM](raw)
    assert len(got) == 1 and got[0].child_frame_id == "base_link"
