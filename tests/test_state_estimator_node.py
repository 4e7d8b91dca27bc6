"""The estimator node over real rclpy: sensor topics in, /odom out, bad samples rejected."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
from a1_interface.contract import CONTROL_QOS, LATCHED_QOS, TF_QOS
from a1_interface.conversions import ns_from_stamp
from a1_sim_bridge.joint_hold_node import JointHoldNode
from a1_sim_bridge.node import SimBridgeNode
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from ros_helpers import spin_until
from sensor_msgs.msg import JointState
from state_estimator_node.node import StateEstimatorNode
from std_msgs.msg import String

from tf2_msgs.msg import TFMessage


@pytest.mark.ros
def test_odometry_from_the_sim_bridge(rclpy_context):
    bridge = SimBridgeNode(context=rclpy_context, parameter_overrides=[Parameter("settle_time", value=0.3)])
    hold = JointHoldNode(context=rclpy_context)
    estimator = StateEstimatorNode(context=rclpy_context)
    listener = Node("odom_listener", context=rclpy_context)
    odoms, joints, tfs, descriptions = [], [], [], []
    listener.create_subscription(Odometry, "/odom", odoms.append, QoSProfile(depth=1000))
    listener.create_subscription(TFMessage, "/tf", tfs.append, TF_QOS)
    listener.create_subscription(String, "/robot_description", descriptions.append, LATCHED_QOS)
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
        # What RViz needs (REP-105): /tf odom -> base_link equal to /odom's pose at the same stamp,
        # and the latched URDF naming every joint of /joint_states, rooted at base_link.
        assert spin_until(executor, lambda: len(tfs) >= 3 and descriptions, timeout_s=10.0)
        poses = {ns_from_stamp(o.header.stamp): o.pose.pose for o in odoms}
        (t,) = tfs[-1].transforms
        assert (t.header.frame_id, t.child_frame_id) == ("odom", "base_link")
        pose = poses[ns_from_stamp(t.header.stamp)]
        assert [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z] == [
            pose.position.x, pose.position.y, pose.position.z]
        assert t.transform.rotation == pose.orientation
        gaps = np.diff([ns_from_stamp(m.transforms[0].header.stamp) for m in tfs]) * 1e-9
        assert np.all(gaps >= 0.02 - 1e-9)  # 50 Hz of sim time, not 500 Hz
        urdf = ET.fromstring(descriptions[0].data)
        joint_names = {j.get("name") for j in urdf.findall("joint")}
        assert set(joints[-1].name) <= joint_names
        children = {j.find("child").get("link") for j in urdf.findall("joint")}
        roots = {link.get("name") for link in urdf.findall("link")} - children
        assert roots == {"base_link"}
        assert all(m.get("filename").startswith("file:///") for m in urdf.iter("mesh"))

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
