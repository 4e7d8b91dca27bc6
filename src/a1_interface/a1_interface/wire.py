"""The 500 Hz messages as bytes: encode and decode their CDR form without rosidl's Python objects.

Why: at 500 Hz on a 2-core computer, building and converting rosidl Python messages is a large
share of a node's CPU. Measured on this machine (3 messages a step at 500 Hz, DirectExecutor):
taking a message costs 165 us of CPU as a Python message and 99 us as bytes; publishing the three
costs 436 us a step as messages and 185 us as bytes.

What goes over the wire is unchanged: the standard sensor_msgs/JointState, sensor_msgs/Imu,
nav_msgs/Odometry and the gait_msgs FootContacts and MotorCommand, in the CDR encoding every rmw
uses (little endian; each primitive aligned to its size, counted from the end of the 4-byte
encapsulation header). Any node that publishes or subscribes the ordinary messages talks to these.
Encoders start from a template serialized by rclpy itself and only overwrite the stamp and the
numbers; decoders return light views with the messages' field names (``msg.header.stamp``,
``msg.position``, ``msg.orientation.x``) so that code written for the messages reads them
unchanged. tests/test_wire.py checks both directions against rclpy's serializer. No rclpy import
here beyond rclpy.serialization.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
from a1_common.command import JointCommand
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu, JointState

from a1_interface import contract
from a1_interface.conversions import ns_from_stamp, stamp_from_ns
from a1_interface.sensors import GroundTruth, SensorReadings
from gait_msgs.msg import FootContacts, MotorCommand

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian
_HEADER = 4  # bytes before the payload; alignment counts from here
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: sec, nanosec
_U32 = struct.Struct("<I")


class Header(NamedTuple):
    stamp: Time
    frame_id: str


class Vector3(NamedTuple):
    x: float
    y: float
    z: float


class Quaternion(NamedTuple):
    x: float
    y: float
    z: float
    w: float


class JointStateView(NamedTuple):
    header: Header
    name: list[str]
    position: np.ndarray  # [rad]
    velocity: np.ndarray  # [rad/s]
    effort: np.ndarray  # [N m]


class ImuView(NamedTuple):
    header: Header
    orientation: Quaternion
    angular_velocity: Vector3  # [rad/s], IMU frame
    linear_acceleration: Vector3  # [m/s^2], IMU frame


class FootContactsView(NamedTuple):
    header: Header
    contact: np.ndarray  # bool, FR FL RR RL
    normal_force: np.ndarray  # [N]


class Pose(NamedTuple):
    position: Vector3  # [m]
    orientation: Quaternion


class PoseWithCovariance(NamedTuple):
    pose: Pose
    covariance: np.ndarray  # (36,) row-major 6x6


class Twist(NamedTuple):
    linear: Vector3  # [m/s]
    angular: Vector3  # [rad/s]


class TwistWithCovariance(NamedTuple):
    twist: Twist
    covariance: np.ndarray  # (36,) row-major 6x6


class OdometryView(NamedTuple):
    """nav_msgs/Odometry: pose in ``header.frame_id``, twist in ``child_frame_id`` (REP-105)."""

    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


_NO_COVARIANCE = np.zeros(36)
_NO_COVARIANCE.flags.writeable = False


def odometry_view(stamp: Time, frame_id: str, child_frame_id: str, position, orientation, linear, angular,
                  pose_covariance: np.ndarray = _NO_COVARIANCE,
                  twist_covariance: np.ndarray = _NO_COVARIANCE) -> OdometryView:
    """An OdometryView from vectors: position [m] and orientation (x, y, z, w) in ``frame_id``,
    linear [m/s] and angular [rad/s] velocity in ``child_frame_id``; covariances row-major 6x6
    (zeros: unknown, as in a default message)."""
    return OdometryView(
        Header(stamp, frame_id), child_frame_id,
        PoseWithCovariance(Pose(Vector3(*(float(v) for v in position)), Quaternion(*(float(v) for v in orientation))),
                           pose_covariance),
        TwistWithCovariance(Twist(Vector3(*(float(v) for v in linear)), Vector3(*(float(v) for v in angular))),
                            twist_covariance))


def ground_truth_odometry(truth: GroundTruth, stamp_ns: int) -> OdometryView:
    """The simulator's ground truth as /sim/ground_truth/odom: pose in the world (as ``odom``),
    twist in ``base_link`` (REP-105); no covariance."""
    return odometry_view(stamp_from_ns(stamp_ns), contract.ODOM_FRAME, contract.BASE_FRAME, truth.base_position,
                         truth.base_orientation, truth.base_linear_velocity_body, truth.base_angular_velocity_body)


class CdrReader:
    """Reads a CDR buffer front to back; ``pos`` is the next byte. Raises ValueError past its end."""

    def __init__(self, buffer: bytes | bytearray, what: str) -> None:
        if bytes(buffer[:_HEADER]) != ENCAPSULATION:
            raise ValueError(f"{what}: not little-endian CDR (encapsulation {bytes(buffer[:_HEADER]).hex()})")
        self.buffer, self.pos, self.what = buffer, _HEADER, what

    def take(self, size: int, align: int) -> int:
        """Step over ``size`` bytes aligned to ``align``; returns where they start."""
        start = self.pos + (-(self.pos - _HEADER) % align)
        if start + size > len(self.buffer):
            raise ValueError(f"{self.what}: truncated ({len(self.buffer)} bytes)")
        self.pos = start + size
        return start

    def u32(self) -> int:
        return _U32.unpack_from(self.buffer, self.take(4, 4))[0]

    def stamp(self) -> Time:
        sec, nanosec = _STAMP.unpack_from(self.buffer, self.take(8, 4))
        return Time(sec=sec, nanosec=nanosec)

    def string_bytes(self) -> bytes:
        """A string's bytes without its terminating NUL (the length counts the NUL)."""
        length = self.u32()
        start = self.take(length, 1)
        return bytes(self.buffer[start:start + max(length - 1, 0)])

    def header(self) -> Header:
        return Header(self.stamp(), self.string_bytes().decode())

    def skip_string_sequence(self) -> bytes:
        """Skip a sequence<string>; returns its raw bytes (names repeat, so callers cache on them)."""
        start = self.pos
        for _ in range(self.u32()):
            self.string_bytes()
        return bytes(self.buffer[start:self.pos])

    def f64(self, count: int) -> np.ndarray:
        if count == 0:  # no element, no alignment padding
            return np.empty(0)
        return np.frombuffer(self.buffer, "<f8", count, self.take(8 * count, 8)).copy()

    def f64_sequence(self) -> np.ndarray:
        return self.f64(self.u32())

    def u8(self, count: int) -> np.ndarray:
        return np.frombuffer(self.buffer, np.uint8, count, self.take(count, 1)).copy()


class _Template:
    """A message serialized by rclpy once; encode() writes the stamp and numbers into a copy."""

    def __init__(self, msg) -> None:
        self.buffer = bytearray(serialize_message(msg))

    def f64_view(self, offset: int, count: int) -> np.ndarray:
        return np.frombuffer(self.buffer, "<f8", count, offset)

    def finish(self, stamp_ns: int) -> bytes:
        _STAMP.pack_into(self.buffer, _HEADER, stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)
        return bytes(self.buffer)


def _with_frame(msg, frame_id: str):
    msg.header.frame_id = frame_id
    return msg


class JointStateEncoder:
    """sensor_msgs/JointState with fixed joint names; positions [rad], velocities [rad/s], efforts [N m]."""

    def __init__(self, joint_names: list[str], frame_id: str) -> None:
        n = len(joint_names)
        self._template = _Template(_with_frame(JointState(name=list(joint_names), position=[0.0] * n,
                                                          velocity=[0.0] * n, effort=[0.0] * n), frame_id))
        reader = CdrReader(self._template.buffer, "JointState template")
        reader.header()
        reader.skip_string_sequence()
        views = []
        for _ in range(3):
            reader.u32()  # the sequence's length, n
            views.append(self._template.f64_view(reader.take(8 * n, 8), n))
        self._position, self._velocity, self._effort = views

    def encode(self, stamp_ns: int, position: np.ndarray, velocity: np.ndarray, effort: np.ndarray) -> bytes:
        self._position[:] = position
        self._velocity[:] = velocity
        self._effort[:] = effort
        return self._template.finish(stamp_ns)


class ImuEncoder:
    """sensor_msgs/Imu: orientation (x, y, z, w), angular velocity [rad/s], linear acceleration
    [m/s^2]; covariances stay as in the ordinary message (zeros: unknown)."""

    def __init__(self, frame_id: str) -> None:
        self._template = _Template(_with_frame(Imu(), frame_id))
        reader = CdrReader(self._template.buffer, "Imu template")
        reader.header()
        start = reader.take(8 * 37, 8)  # orientation, its covariance, gyro, its covariance, accel, its cov.
        self._orientation = self._template.f64_view(start, 4)
        self._angular_velocity = self._template.f64_view(start + 8 * 13, 3)
        self._linear_acceleration = self._template.f64_view(start + 8 * 25, 3)

    def encode(self, stamp_ns: int, orientation: np.ndarray, angular_velocity: np.ndarray,
               linear_acceleration: np.ndarray) -> bytes:
        self._orientation[:] = orientation
        self._angular_velocity[:] = angular_velocity
        self._linear_acceleration[:] = linear_acceleration
        return self._template.finish(stamp_ns)


class FootContactsEncoder:
    """gait_msgs/FootContacts: contact flags and normal forces [N], legs FR FL RR RL."""

    def __init__(self, frame_id: str) -> None:
        self._template = _Template(_with_frame(FootContacts(), frame_id))
        reader = CdrReader(self._template.buffer, "FootContacts template")
        reader.header()
        self._contact = np.frombuffer(self._template.buffer, np.uint8, 4, reader.take(4, 1))
        self._normal_force = self._template.f64_view(reader.take(32, 8), 4)

    def encode(self, stamp_ns: int, contact: np.ndarray, normal_force: np.ndarray) -> bytes:
        self._contact[:] = np.asarray(contact, dtype=bool)
        self._normal_force[:] = normal_force
        return self._template.finish(stamp_ns)


class MotorCommandEncoder:
    """gait_msgs/MotorCommand from a JointCommand (SI units, the A1's joint order)."""

    def __init__(self) -> None:
        self._template = _Template(MotorCommand())
        reader = CdrReader(self._template.buffer, "MotorCommand template")
        reader.header()
        self._mode = reader.take(1, 1)
        self._numbers = self._template.f64_view(reader.take(480, 8), 60).reshape(5, 12)

    def encode(self, command: JointCommand, stamp_ns: int) -> bytes:
        self._template.buffer[self._mode] = int(command.mode)
        numbers = self._numbers
        numbers[0], numbers[1], numbers[2] = command.position, command.velocity, command.kp
        numbers[3], numbers[4] = command.kd, command.torque
        return self._template.finish(stamp_ns)


# nav_msgs/Odometry's numbers after its two frame strings: position 3, orientation 4, pose
# covariance 36, linear 3, angular 3, twist covariance 36 (float64, contiguous).
_ODOMETRY_DOUBLES = 85


class OdometryEncoder:
    """nav_msgs/Odometry from an OdometryView (a 500 Hz /odom as a Python message costs several
    times its bytes). The template is rebuilt when the view's frames change."""

    def __init__(self) -> None:
        self._frames: tuple[str, str] | None = None

    def _build(self, frame_id: str, child_frame_id: str) -> None:
        msg = Odometry()
        msg.header.frame_id, msg.child_frame_id = frame_id, child_frame_id
        self._template = _Template(msg)
        reader = CdrReader(self._template.buffer, "Odometry template")
        reader.header()
        reader.string_bytes()
        self._numbers = self._template.f64_view(reader.take(8 * _ODOMETRY_DOUBLES, 8), _ODOMETRY_DOUBLES)
        self._frames = (frame_id, child_frame_id)

    def encode(self, odom: OdometryView) -> bytes:
        if self._frames != (odom.header.frame_id, odom.child_frame_id):
            self._build(odom.header.frame_id, odom.child_frame_id)
        numbers, pose, twist = self._numbers, odom.pose.pose, odom.twist.twist
        numbers[0:3] = pose.position
        numbers[3:7] = pose.orientation
        numbers[7:43] = odom.pose.covariance
        numbers[43:46] = twist.linear
        numbers[46:49] = twist.angular
        numbers[49:85] = odom.twist.covariance
        return self._template.finish(ns_from_stamp(odom.header.stamp))


class SensorEncoders:
    """A bridge's three sensor messages of one step, in the frames of contract.py."""

    def __init__(self, joint_names: list[str], base_frame: str, imu_frame: str) -> None:
        self.joints = JointStateEncoder(joint_names, base_frame)
        self.imu = ImuEncoder(imu_frame)
        self.contacts = FootContactsEncoder(base_frame)

    def encode(self, r: SensorReadings, stamp_ns: int) -> tuple[bytes, bytes, bytes]:
        """(joint states, IMU, foot contacts) stamped ``stamp_ns``."""
        return (self.joints.encode(stamp_ns, r.joint_position, r.joint_velocity, r.joint_torque),
                self.imu.encode(stamp_ns, r.imu_orientation, r.imu_angular_velocity, r.imu_linear_acceleration),
                self.contacts.encode(stamp_ns, r.foot_contact, r.foot_force))


class JointStateDecoder:
    """Decodes sensor_msgs/JointState; the joint names are decoded once per distinct name list."""

    def __init__(self) -> None:
        self._names_raw = b""
        self._names: list[str] = []

    def __call__(self, buffer: bytes) -> JointStateView:
        reader = CdrReader(buffer, "sensor_msgs/JointState")
        header = reader.header()
        names_start = reader.pos
        names_raw = reader.skip_string_sequence()
        if names_raw != self._names_raw:
            names_reader = CdrReader(buffer, "sensor_msgs/JointState")
            names_reader.pos = names_start
            self._names = [names_reader.string_bytes().decode() for _ in range(names_reader.u32())]
            self._names_raw = names_raw
        return JointStateView(header, list(self._names), reader.f64_sequence(), reader.f64_sequence(),
                              reader.f64_sequence())


def decode_imu(buffer: bytes) -> ImuView:
    reader = CdrReader(buffer, "sensor_msgs/Imu")
    header = reader.header()
    values = reader.f64(37).tolist()  # orientation, its covariance, gyro, its covariance, accel, ...
    return ImuView(header, Quaternion(*values[0:4]), Vector3(*values[13:16]), Vector3(*values[25:28]))


def decode_foot_contacts(buffer: bytes) -> FootContactsView:
    reader = CdrReader(buffer, "gait_msgs/FootContacts")
    header = reader.header()
    return FootContactsView(header, reader.u8(4).astype(bool), reader.f64(4))


def decode_odometry(buffer: bytes) -> OdometryView:
    """nav_msgs/Odometry's bytes as an OdometryView (covariances as (36,) arrays)."""
    reader = CdrReader(buffer, "nav_msgs/Odometry")
    header = reader.header()
    child_frame_id = reader.string_bytes().decode()
    numbers = reader.f64(_ODOMETRY_DOUBLES)
    values = numbers[:7].tolist() + numbers[43:49].tolist()
    return OdometryView(header, child_frame_id,
                        PoseWithCovariance(Pose(Vector3(*values[0:3]), Quaternion(*values[3:7])), numbers[7:43]),
                        TwistWithCovariance(Twist(Vector3(*values[7:10]), Vector3(*values[10:13])), numbers[49:85]))


def decode_motor_command(buffer: bytes) -> tuple[JointCommand, int]:
    """The command (unvalidated: the bridge's watchdog validates) and its stamp [ns]."""
    reader = CdrReader(buffer, "gait_msgs/MotorCommand")
    stamp = reader.header().stamp
    mode = int(reader.u8(1)[0])
    position, velocity, kp, kd, torque = reader.f64(60).reshape(5, 12)
    return (JointCommand(mode=mode, position=position, velocity=velocity, kp=kp, kd=kd, torque=torque),
            stamp.sec * 1_000_000_000 + stamp.nanosec)


class SensorIntake:
    """A node's intake of a bridge's three sensor messages as bytes (subscribe_sensors): from its
    subscriptions, or handed over by a bridge in the same process (``take``)."""

    def __init__(self, node: Any, handlers: list[tuple[Any, str, Callable[[bytes], None]]], qos: Any) -> None:
        self._node = node
        self._handlers = [handler for _, _, handler in handlers]
        self.subscriptions = [node.create_subscription(msg_type, topic, handler, qos, raw=True)
                              for msg_type, topic, handler in handlers]

    def take(self, imu: bytes, contacts: bytes, joints: bytes) -> None:
        """One step's messages handed over in-process, decoded and handled as if off the wire."""
        for handler, raw in zip(self._handlers, (imu, contacts, joints), strict=True):
            handler(raw)

    def leave_wire(self) -> None:
        """Take the sensors only by hand-off from now on (a bridge in this process gives each step's):
        the wire copies would come again, later, and cost the executor their intake."""
        for subscription in self.subscriptions:
            self._node.destroy_subscription(subscription)
        self.subscriptions = []


def subscribe_sensors(node, qos, on_joints: Callable[[JointStateView], None], on_imu: Callable[[ImuView], None],
                      on_contacts: Callable[[FootContactsView], None]) -> SensorIntake:
    """Subscribe ``node`` (an rclpy Node) to a bridge's three sensor topics as bytes, decoded to views.

    In the order the bridges publish them, joint states last, so that within one executor wake-up a
    node that acts on /joint_states finds the same step's IMU and contacts already handed over. A
    malformed message (never one from an rmw publisher of the type) is dropped and logged.
    """
    return SensorIntake(node, [
        (Imu, contract.IMU, _decoding(node, decode_imu, on_imu)),
        (FootContacts, contract.FOOT_CONTACTS, _decoding(node, decode_foot_contacts, on_contacts)),
        (JointState, contract.JOINT_STATES, _decoding(node, JointStateDecoder(), on_joints))], qos)


def subscribe_odometry(node, qos, on_odom: Callable[[OdometryView], None]) -> None:
    """Subscribe ``node`` to /odom as bytes, decoded to OdometryView (malformed: dropped, logged)."""
    node.create_subscription(Odometry, contract.ODOM, _decoding(node, decode_odometry, on_odom), qos, raw=True)


def _decoding(node, decode: Callable[[bytes], Any], handler: Callable[[Any], None]) -> Callable[[bytes], None]:
    """A raw subscription's callback: ``decode`` then ``handler``; a malformed message is dropped
    with an error in ``node``'s log, never raised into the executor, where it would stop the node."""
    def on_raw(raw: bytes) -> None:
        try:
            msg = decode(raw)
        except ValueError as exc:
            node.get_logger().error(f"dropped a malformed message: {exc}", throttle_duration_sec=1.0)
            return
        handler(msg)
    return on_raw
