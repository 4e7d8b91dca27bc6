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
from a1_common.config import recording_constraints
from a1_common.node_support import constrain_parameters, declare_settings, diagnostic_array, run_node
from a1_interface.contract import CONTROL_QOS, TF_QOS
from a1_interface.conversions import ns_from_stamp
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import Imu, JointState

from a1_interface import contract, wire
from gait_msgs.msg import FootContacts
from state_estimator_node.estimator import EstimatorConfig
from state_estimator_node.frontend import OdometryFrontend
from tf2_msgs.msg import TFMessage

TF_PERIOD_NS = 20_000_000  # /tf at 50 Hz of stamp time: plenty for RViz, and light beside the 500 Hz /odom


class OdometryPublisher:
    """/odom (as bytes, a1_interface.wire) and /tf ``odom -> base_link`` from it (REP-105), the
    transform at most every TF_PERIOD_NS of stamp time (and at once after time went back: a sim
    reset). Shared by the state_estimator node and the controller's embedded estimator."""

    def __init__(self, node: Node) -> None:
        self.pub_odom = node.create_publisher(Odometry, contract.ODOM, CONTROL_QOS)
        self.pub_tf = node.create_publisher(TFMessage, contract.TF, TF_QOS)
        self._encoder = wire.OdometryEncoder()
        self._last_tf_ns: int | None = None

    def publish(self, odom: wire.OdometryView) -> None:
        self.pub_odom.publish(self._encoder.encode(odom))
        stamp_ns = ns_from_stamp(odom.header.stamp)
        if self._last_tf_ns is not None and 0 <= stamp_ns - self._last_tf_ns < TF_PERIOD_NS:
            return
        self._last_tf_ns = stamp_ns
        t = TransformStamped()
        t.header.stamp, t.header.frame_id = odom.header.stamp, odom.header.frame_id
        t.child_frame_id = odom.child_frame_id
        p, q = odom.pose.pose.position, odom.pose.pose.orientation
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = p.x, p.y, p.z
        t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w = q
        self.pub_tf.publish(TFMessage(transforms=[t]))


def estimator_config_from_parameters(params: dict) -> EstimatorConfig:
    params = dict(params)
    for key in ("process_noise", "measurement_noise"):
        params[key] = tuple(float(v) for v in params[key])
    return EstimatorConfig(**params).validated()


class StateEstimatorNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("state_estimator", **node_kwargs)
        with recording_constraints() as constraints:
            params = declare_settings(self, EstimatorConfig())
            self.frontend = OdometryFrontend(estimator_config_from_parameters(params))
        constrain_parameters(self, params, constraints)  # all read-only: read at start-up
        self.estimator = self.frontend.estimator
        self._imu: Imu | None = None
        self._contacts: FootContacts | None = None
        self._last_wall = float("-inf")
        self._published = 0
        self.odom = OdometryPublisher(self)
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
        self.odom.publish(front.odometry(msg, self._imu, est))
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
