"""The estimator node over real rclpy: sensor topics in, /odom out, bad samples rejected."""

from __future__ import annotations

import numpy as np
import pytest
from a1_sim_bridge.conversions import ns_from_stamp
from a1_sim_bridge.joint_hold_node import JointHoldNode
from a1_sim_bridge.node import CONTROL_QOS, SimBridgeNode
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_helpers import spin_until
from sensor_msgs.msg import JointState
from state_estimator_node.node import StateEstimatorNode


@pytest.mark.ros
def test_odometry_from_the_sim_bridge(rclpy_context):
    bridge = SimBridgeNode(context=rclpy_context, parameter_overrides=[Parameter("settle_time", value=0.3)])
    hold = JointHoldNode(context=rclpy_context)
    estimator = StateEstimatorNode(context=rclpy_context)
    listener = Node("odom_listener", context=rclpy_context)
    odoms, joints = [], []
    listener.create_subscription(Odometry, "/odom", odoms.append, CONTROL_QOS)
    listener.create_subscription(JointState, "/joint_states", joints.append, CONTROL_QOS)
    executor = SingleThreadedExecutor(context=rclpy_context)
    for n in (bridge, hold, estimator, listener):
        executor.add_node(n)
    try:
        assert spin_until(executor, lambda: len(odoms) >= 300, timeout_s=60.0)
        last = odoms[-1]
        assert last.header.frame_id == "odom" and last.child_frame_id == "base_link"
        # Stamped like the joint states it was computed from.
        assert ns_from_stamp(last.header.stamp) in {ns_from_stamp(m.header.stamp) for m in joints}
        v = np.array([last.twist.twist.linear.x, last.twist.twist.linear.y, last.twist.twist.linear.z])
        assert np.linalg.norm(v) < 0.05  # standing still
        cov = np.array(last.twist.covariance).reshape(6, 6)
        assert np.all(np.isfinite(cov)) and np.all(np.diag(cov)[:3] > 0)
        assert last.pose.pose.position.z == pytest.approx(0.28, abs=0.04)  # COM height from the legs
        assert estimator.estimator.rejected_samples == 0

        # A joint state with NaN velocities is rejected and counted, not published.
        executor.remove_node(hold)
        executor.remove_node(bridge)
        bad = joints[-1]
        bad.velocity = [float("nan")] * 12
        pub = listener.create_publisher(JointState, "/joint_states", CONTROL_QOS)

        def rejected() -> bool:
            if estimator.estimator.rejected_samples == 0:
                pub.publish(bad)
            return estimator.estimator.rejected_samples > 0

        assert spin_until(executor, rejected, timeout_s=10.0)
    finally:
        executor.shutdown()
        bridge.shutdown()
        for n in (bridge, hold, estimator, listener):
            n.destroy_node()
