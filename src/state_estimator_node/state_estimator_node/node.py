"""State estimator node: VelocityEstimator behind the robot's sensor topics.

Subscribes /joint_states, /imu/data and /foot_contacts (any bridge, sim or hardware); on every
joint state it updates the filter with the newest IMU and contact readings and publishes /odom
(nav_msgs/Odometry, odom -> base_link per REP-105: pose in odom, twist in base_link, with the
filter's covariance). Health (stale, diverging, rejected samples) on /diagnostics at 1 Hz.
Times are the messages' stamps (sim time from a sim bridge, wall time from a hardware bridge).
"""

from __future__ import annotations

import time

import numpy as np
from a1_common.config import parameter_defaults
from a1_common.node_support import declare_parameters, run_node
from a1_sim_bridge.conversions import BASE_FRAME, ODOM_FRAME, ns_from_stamp
from a1_sim_bridge.node import CONTROL_QOS
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState

from gait_msgs.msg import FootContacts
from state_estimator_node.estimator import EstimatorConfig, SensorSample, VelocityEstimator

# IMU / contact readings older than this relative to the joint state are not used [s].
MAX_SENSOR_SKEW = 0.01
GYRO_VARIANCE = 1e-4  # [(rad/s)^2] reported for the angular part of the twist


class StateEstimatorNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("state_estimator", **node_kwargs)
        params = declare_parameters(self, parameter_defaults(EstimatorConfig()))
        for key in ("process_noise", "measurement_noise"):
            params[key] = tuple(float(v) for v in params[key])
        self.estimator = VelocityEstimator(EstimatorConfig(**params).validated())
        self.joint_names = list(self.estimator.robot.joint_names)
        self._imu: Imu | None = None
        self._contacts: FootContacts | None = None
        self._position = np.zeros(2)  # dead-reckoned x, y in odom [m]
        self._last_ns: int | None = None
        self._last_wall = float("-inf")
        self._skewed = 0
        self._published = 0
        self.pub_odom = self.create_publisher(Odometry, "/odom", CONTROL_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Imu, "/imu/data", lambda m: setattr(self, "_imu", m), CONTROL_QOS)
        self.create_subscription(FootContacts, "/foot_contacts", lambda m: setattr(self, "_contacts", m),
                                 CONTROL_QOS)
        self.create_subscription(JointState, "/joint_states", self._on_joints, CONTROL_QOS)
        self.create_timer(1.0, self._publish_diagnostics)

    def _on_joints(self, msg: JointState) -> None:
        imu, contacts = self._imu, self._contacts
        now_ns = ns_from_stamp(msg.header.stamp)
        if imu is None or contacts is None:
            return  # not all sensors seen yet
        if (abs(now_ns - ns_from_stamp(imu.header.stamp)) * 1e-9 > MAX_SENSOR_SKEW
                or abs(now_ns - ns_from_stamp(contacts.header.stamp)) * 1e-9 > MAX_SENSOR_SKEW):
            self._skewed += 1
            return
        if list(msg.name) != self.joint_names:
            self.estimator.rejected_samples += 1
            self.get_logger().warning("rejected /joint_states: joint names are not the A1's 12 joints "
                                      "in motor order", throttle_duration_sec=1.0)
            return
        o, w, a = imu.orientation, imu.angular_velocity, imu.linear_acceleration
        sample = SensorSample(
            time=now_ns * 1e-9, joint_position=np.asarray(msg.position, dtype=float),
            joint_velocity=np.asarray(msg.velocity, dtype=float), orientation=np.array([o.x, o.y, o.z, o.w]),
            angular_velocity=np.array([w.x, w.y, w.z]), linear_acceleration=np.array([a.x, a.y, a.z]),
            foot_contact=np.asarray(contacts.contact, dtype=bool),
            foot_force=np.asarray(contacts.normal_force, dtype=float))
        rejected_before = self.estimator.rejected_samples
        est = self.estimator.update(sample)
        if self.estimator.rejected_samples > rejected_before:
            self.get_logger().warning("rejected a sensor sample with NaN/inf or wrong sizes",
                                      throttle_duration_sec=1.0)
            return
        if self._last_ns is not None and now_ns > self._last_ns:
            self._position += est.velocity_world[:2] * (now_ns - self._last_ns) * 1e-9
        self._last_ns = now_ns
        self._last_wall = time.monotonic()
        self.pub_odom.publish(self._odometry(msg, est, w))
        self._published += 1

    def _odometry(self, joints: JointState, est, gyro) -> Odometry:
        odom = Odometry()
        odom.header.stamp = joints.header.stamp
        odom.header.frame_id = ODOM_FRAME
        odom.child_frame_id = BASE_FRAME
        pose = odom.pose.pose
        pose.position.x, pose.position.y = float(self._position[0]), float(self._position[1])
        pose.position.z = float(est.height) if est.height is not None else 0.0
        pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = (
            float(v) for v in est.orientation)
        twist = odom.twist.twist
        twist.linear.x, twist.linear.y, twist.linear.z = (float(v) for v in est.velocity_body)
        twist.angular.x, twist.angular.y, twist.angular.z = gyro.x, gyro.y, gyro.z
        cov = np.zeros((6, 6))
        cov[:3, :3] = est.covariance_body
        cov[3:, 3:] = np.eye(3) * GYRO_VARIANCE
        odom.twist.covariance = cov.ravel().tolist()
        pose_cov = np.full(6, -1.0)  # unknown pose covariance (dead reckoning), per REP-145 style
        odom.pose.covariance = np.diag(pose_cov).ravel().tolist()
        return odom

    def _publish_diagnostics(self) -> None:
        stamp_s = (self._last_ns or 0) * 1e-9
        est = self.estimator.estimate(stamp_s)
        status = DiagnosticStatus(name="state_estimator", hardware_id="a1")
        if self._last_ns is None:
            status.level = DiagnosticStatus.WARN
            status.message = "waiting for /joint_states, /imu/data, /foot_contacts"
        elif time.monotonic() - self._last_wall > max(self.estimator.config.stale_timeout, 1.0):
            status.level, status.message = DiagnosticStatus.WARN, "stale: no valid sensor sample for over 1 s"
        elif est.diverging:
            status.level, status.message = DiagnosticStatus.ERROR, "estimate diverging"
        else:
            status.level, status.message = DiagnosticStatus.OK, "tracking"
        values = {
            "published": self._published, "rejected_samples": self.estimator.rejected_samples,
            "skewed_samples": self._skewed, "feet_used": est.feet_used,
            "velocity_body": np.round(est.velocity_body, 3).tolist(),
            "covariance_trace": f"{np.trace(est.covariance_world):.2e}",
        }
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        self.pub_diag.publish(DiagnosticArray(status=[status]))


def main(args: list[str] | None = None) -> None:
    run_node("state_estimator", StateEstimatorNode, args)


if __name__ == "__main__":
    main()
