"""Conversions between the robot-side data classes and ROS messages.

The bridges and the controller send the 500 Hz messages as bytes (wire.py); these
builders make the same messages as rosidl objects, for the slower nodes, the tests and as the
reference wire.py is checked against. No rclpy import: messages only.
"""

from __future__ import annotations

import numpy as np
from a1_common.command import JointCommand
from builtin_interfaces.msg import Time
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, JointState

from a1_interface.contract import BASE_FRAME, IMU_FRAME, ODOM_FRAME
from a1_interface.sensors import GroundTruth, SensorReadings
from gait_msgs.msg import FootContacts, MotorCommand


def stamp_from_ns(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def ns_from_stamp(stamp: Time) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _fill(target, values, fields: str = "xyz") -> None:
    """Copy a numpy vector into a geometry_msgs Vector3/Point/Quaternion field by field."""
    for name, value in zip(fields, values, strict=True):
        setattr(target, name, float(value))


def joint_state_msg(r: SensorReadings, stamp: Time, joint_names: list[str]) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp
    msg.header.frame_id = BASE_FRAME
    msg.name = joint_names
    msg.position = r.joint_position.tolist()
    msg.velocity = r.joint_velocity.tolist()
    msg.effort = r.joint_torque.tolist()
    return msg


def imu_msg(r: SensorReadings, stamp: Time) -> Imu:
    msg = Imu()
    msg.header.stamp = stamp
    msg.header.frame_id = IMU_FRAME
    _fill(msg.orientation, r.imu_orientation, "xyzw")
    _fill(msg.angular_velocity, r.imu_angular_velocity)
    _fill(msg.linear_acceleration, r.imu_linear_acceleration)
    return msg


def foot_contacts_msg(r: SensorReadings, stamp: Time) -> FootContacts:
    msg = FootContacts()
    msg.header.stamp = stamp
    msg.header.frame_id = BASE_FRAME
    msg.contact = [bool(c) for c in r.foot_contact]
    msg.normal_force = r.foot_force.tolist()
    return msg


def ground_truth_msg(gt: GroundTruth, stamp: Time) -> Odometry:
    """Pose in the world (as ``odom``), twist in ``base_link`` per REP-105."""
    msg = Odometry()
    msg.header.stamp = stamp
    msg.header.frame_id = ODOM_FRAME
    msg.child_frame_id = BASE_FRAME
    _fill(msg.pose.pose.position, gt.base_position)
    _fill(msg.pose.pose.orientation, gt.base_orientation, "xyzw")
    _fill(msg.twist.twist.linear, gt.base_linear_velocity_body)
    _fill(msg.twist.twist.angular, gt.base_angular_velocity_body)
    return msg


def motor_command_msg(cmd: JointCommand, stamp: Time) -> MotorCommand:
    msg = MotorCommand()
    msg.header.stamp = stamp
    msg.mode = int(cmd.mode)
    msg.position = np.asarray(cmd.position, dtype=float)
    msg.velocity = np.asarray(cmd.velocity, dtype=float)
    msg.kp = np.asarray(cmd.kp, dtype=float)
    msg.kd = np.asarray(cmd.kd, dtype=float)
    msg.torque = np.asarray(cmd.torque, dtype=float)
    return msg
