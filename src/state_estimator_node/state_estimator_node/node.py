"""State estimator node: VelocityEstimator behind the robot's sensor contract.

Subscribes /joint_states, /imu/data and /foot_contacts (any bridge, sim or hardware); on every
joint state it updates the filter with the newest IMU and contact readings and publishes /odom
(nav_msgs/Odometry, odom -> base_link per REP-105: pose in odom, twist in base_link, with the
filter's covariance). Health (stale, diverging, rejected samples) on /diagnostics at 1 Hz.
Times are the messages' stamps (sim time from a sim bridge, wall time from a hardware bridge).
"""

from __future__ import annotations

import time

import numpy as np
from a1_common.config import parameter_defaults, parameter_descriptions, recording_constraints
from a1_common.node_support import constrain_parameters, declare_parameters, diagnostic_array, run_node
from a1_interface.contract import BASE_FRAME, CONTROL_QOS, ODOM_FRAME, TF_QOS
from a1_interface.conversions import ns_from_stamp
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState

from a1_interface import contract, wire
from gait_msgs.msg import FootContacts
from state_estimator_node.estimator import Estimate, EstimatorConfig, SensorSample, VelocityEstimator
from tf2_msgs.msg import TFMessage

# IMU / contact readings older than this relative to the joint state are not used [s].
MAX_SENSOR_SKEW = 0.01
GYRO_VARIANCE = 1e-4  # [(rad/s)^2] reported for the angular part of the twist
TF_PERIOD_NS = 20_000_000  # /tf at 50 Hz of stamp time: plenty for RViz, and light beside the 500 Hz /odom


class OdometryFrontend:
    """One sensor step's messages -> a filter update -> nav_msgs/Odometry. No rclpy Node: shared by
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
        sample = SensorSample(
            time=now_ns * 1e-9, joint_position=np.asarray(joints.position, dtype=float),
            joint_velocity=np.asarray(joints.velocity, dtype=float), orientation=np.array([o.x, o.y, o.z, o.w]),
            angular_velocity=np.array([w.x, w.y, w.z]), linear_acceleration=np.array([a.x, a.y, a.z]),
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

    def odometry(self, joints: JointState, imu: Imu, est: Estimate) -> Odometry:
        """/odom for the step of ``joints`` and ``imu`` with its estimate ``est``."""
        gyro = imu.angular_velocity
        odom = Odometry()
        odom.header.stamp = joints.header.stamp
        odom.header.frame_id = ODOM_FRAME
        odom.child_frame_id = BASE_FRAME
        pose = odom.pose.pose
        pose.position.x, pose.position.y = float(self.position[0]), float(self.position[1])
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


class OdomTransformPublisher:
    """/tf ``odom -> base_link`` from the /odom being published (REP-105), at most every TF_PERIOD_NS
    of stamp time (and at once after time went back: a sim reset)."""

    def __init__(self, node: Node) -> None:
        self.pub = node.create_publisher(TFMessage, contract.TF, TF_QOS)
        self._last_ns: int | None = None

    def publish(self, odom: Odometry) -> None:
        stamp_ns = ns_from_stamp(odom.header.stamp)
        if self._last_ns is not None and 0 <= stamp_ns - self._last_ns < TF_PERIOD_NS:
            return
        self._last_ns = stamp_ns
        t = TransformStamped()
        t.header = odom.header
        t.child_frame_id = odom.child_frame_id
        p, q = odom.pose.pose.position, odom.pose.pose.orientation
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = p.x, p.y, p.z
        t.transform.rotation = q
        self.pub.publish(TFMessage(transforms=[t]))


def estimator_config_from_parameters(params: dict) -> EstimatorConfig:
    params = dict(params)
    for key in ("process_noise", "measurement_noise"):
        params[key] = tuple(float(v) for v in params[key])
    return EstimatorConfig(**params).validated()


class StateEstimatorNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("state_estimator", **node_kwargs)
        with recording_constraints() as constraints:
            params = declare_parameters(self, parameter_defaults(EstimatorConfig()),
                                        parameter_descriptions(EstimatorConfig()))
            self.frontend = OdometryFrontend(estimator_config_from_parameters(params))
        constrain_parameters(self, params, constraints)  # all read-only: read at start-up
        self.estimator = self.frontend.estimator
        self._imu: Imu | None = None
        self._contacts: FootContacts | None = None
        self._last_wall = float("-inf")
        self._published = 0
        self.pub_odom = self.create_publisher(Odometry, contract.ODOM, CONTROL_QOS)
        self.tf = OdomTransformPublisher(self)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.DIAGNOSTICS_QOS)
        # The 500 Hz sensors arrive as bytes and are decoded to light views (a1_interface.wire).
        wire.subscribe_sensors(self, CONTROL_QOS, on_joints=self._on_joints,
                               on_imu=lambda m: setattr(self, "_imu", m),
                               on_contacts=lambda m: setattr(self, "_contacts", m))
        self.create_timer(1.0, self._publish_diagnostics)

    def _on_joints(self, msg: JointState) -> None:
        if self._imu is None or self._contacts is None:
            return  # not all sensors seen yet
        front = self.frontend
        names_before, rejected_before = front.wrong_names, self.estimator.rejected_samples
        est = front.update(msg, self._imu, self._contacts)
        if est is None:
            if front.wrong_names > names_before:
                self.get_logger().warning("rejected /joint_states: joint names are not the A1's 12 joints "
                                          "in motor order", throttle_duration_sec=1.0)
            elif self.estimator.rejected_samples > rejected_before:
                self.get_logger().warning("rejected a sensor sample with NaN/inf or wrong sizes",
                                          throttle_duration_sec=1.0)
            return
        self._last_wall = time.monotonic()
        odom = front.odometry(msg, self._imu, est)
        self.pub_odom.publish(odom)
        self.tf.publish(odom)
        self._published += 1

    def _publish_diagnostics(self) -> None:
        last_ns = self.frontend.last_ns
        stamp_s = (last_ns or 0) * 1e-9
        est = self.estimator.estimate(stamp_s)
        status = DiagnosticStatus(name="state_estimator", hardware_id="a1")
        if last_ns is None:
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
            "skewed_samples": self.frontend.skewed, "feet_used": est.feet_used,
            "velocity_body": np.round(est.velocity_body, 3).tolist(),
            "covariance_trace": f"{np.trace(est.covariance_world):.2e}",
        }
        self.pub_diag.publish(diagnostic_array(self, status, values))


def main(args: list[str] | None = None) -> None:
    run_node("state_estimator", StateEstimatorNode, args)


if __name__ == "__main__":
    main()
