"""The estimator's message-level core: one sensor step's messages (JointState, Imu, FootContacts)
-> a VelocityEstimator update -> nav_msgs/Odometry (as a1_interface.wire's light view). No rclpy:
shared by the state_estimator node and the convex_mpc node's embedded estimator (one process, no
/odom hop), and tested without ROS.
"""

from __future__ import annotations

import numpy as np
from a1_interface.contract import BASE_FRAME, ODOM_FRAME
from a1_interface.conversions import ns_from_stamp
from a1_interface.sensors import SensorReadings
from a1_interface.wire import OdometryView, odometry_view
from sensor_msgs.msg import Imu, JointState

from gait_msgs.msg import FootContacts
from state_estimator_node.estimator import Estimate, EstimatorConfig, VelocityEstimator

# IMU / contact readings older than this relative to the joint state are not used [s].
MAX_SENSOR_SKEW = 0.01
GYRO_VARIANCE = 1e-4  # [(rad/s)^2] reported for the angular part of the twist
# Dead reckoning has no pose covariance to give: -1 on the diagonal says "unknown" (REP-145 style).
POSE_COVARIANCE = np.diag(np.full(6, -1.0)).ravel()
POSE_COVARIANCE.flags.writeable = False


class OdometryFrontend:
    """One sensor step's messages -> a filter update -> /odom's content. No rclpy Node: shared by
    the state_estimator node and the convex_mpc node's embedded estimator (one process, no /odom hop)."""

    def __init__(self, config: EstimatorConfig) -> None:
        self.estimator = VelocityEstimator(config.validated())
        self.joint_names = list(self.estimator.robot.joint_names)
        self.position = np.zeros(2)  # dead-reckoned x, y in odom [m]
        self.last_ns: int | None = None
        self.skewed = 0
        self.wrong_names = 0

    def update(self, joints: JointState, imu: Imu, contacts: FootContacts) -> Estimate | None:
        """The estimate for this step (``odometry`` makes its /odom), or None when the step is refused
        (and counted): IMU or contacts more than MAX_SENSOR_SKEW from the joint state, wrong joint
        names, NaN/inf."""
        now_ns = ns_from_stamp(joints.header.stamp)
        if (abs(now_ns - ns_from_stamp(imu.header.stamp)) * 1e-9 > MAX_SENSOR_SKEW
                or abs(now_ns - ns_from_stamp(contacts.header.stamp)) * 1e-9 > MAX_SENSOR_SKEW):
            self.skewed += 1
            return None
        if list(joints.name) != self.joint_names:
            self.wrong_names += 1
            self.estimator.rejected_samples += 1
            return None
        o, w, a = imu.orientation, imu.angular_velocity, imu.linear_acceleration
        sample = SensorReadings(
            time=now_ns * 1e-9, joint_position=np.asarray(joints.position, dtype=float),
            joint_velocity=np.asarray(joints.velocity, dtype=float),
            joint_torque=np.asarray(joints.effort, dtype=float), imu_orientation=np.array([o.x, o.y, o.z, o.w]),
            imu_angular_velocity=np.array([w.x, w.y, w.z]), imu_linear_acceleration=np.array([a.x, a.y, a.z]),
            foot_contact=np.asarray(contacts.contact, dtype=bool),
            foot_force=np.asarray(contacts.normal_force, dtype=float))
        rejected_before = self.estimator.rejected_samples
        est = self.estimator.update(sample)
        if self.estimator.rejected_samples > rejected_before:
            return None
        if self.last_ns is not None and now_ns > self.last_ns:
            self.position += est.velocity_world[:2] * (now_ns - self.last_ns) * 1e-9
        elif self.last_ns is not None and now_ns < self.last_ns:
            self.position = np.zeros(2)  # time went back: a simulation reset put the robot at the origin
        self.last_ns = now_ns
        return est

    def odometry(self, joints: JointState, imu: Imu, est: Estimate) -> OdometryView:
        """/odom for the step of ``joints`` and ``imu`` with its estimate ``est``: dead-reckoned
        position and the filter's orientation in odom, velocity and gyro in base_link."""
        cov = np.zeros((6, 6))
        cov[:3, :3] = est.covariance_body
        cov[3:, 3:] = np.eye(3) * GYRO_VARIANCE
        position = (self.position[0], self.position[1], est.height if est.height is not None else 0.0)
        gyro = imu.angular_velocity
        return odometry_view(joints.header.stamp, ODOM_FRAME, BASE_FRAME, position, est.orientation,
                             est.velocity_body, (gyro.x, gyro.y, gyro.z), POSE_COVARIANCE, cov.ravel())
