"""The gait_policy node over real rclpy with a learned policy file: /cmd_vel and /odom in, the
network's gait on /gait/params out; a bad file stops the node with the reason."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from a1_common.config import ConfigError
from a1_interface.contract import COMMAND_QOS, CONTROL_QOS
from convex_mpc_node.supervisor import load_supervisor_config
from gait_policy_node.demo_report import DemoReportNode
from gait_policy_node.learned_policy import NetworkPolicy, save_policy
from gait_policy_node.policy_node import GaitPolicyNode
from gait_policy_node.train_config import TrainConfig
from geometry_msgs.msg import Twist, Vector3
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_helpers import spin_until
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

from gait_msgs.msg import GaitParams as GaitParamsMsg
from gait_msgs.msg import GaitState


@pytest.mark.ros
def test_learned_policy_file_drives_gait_params(rclpy_context, tmp_path):
    config = TrainConfig()
    network = NetworkPolicy.from_config(config)
    network.set_params(np.random.default_rng(2).normal(0, 0.2, network.num_params))
    path = tmp_path / "policy.npz"
    save_policy(path, network, config)
    node = GaitPolicyNode(context=rclpy_context, parameter_overrides=[Parameter("policy", value=str(path))])
    io = Node("policy_io", context=rclpy_context)
    received: list[GaitParamsMsg] = []
    io.create_subscription(GaitParamsMsg, "/gait/params", received.append, COMMAND_QOS)
    cmd_pub = io.create_publisher(Twist, "/cmd_vel", COMMAND_QOS)
    odom_pub = io.create_publisher(Odometry, "/odom", CONTROL_QOS)
    # Robot yawed by 90 degrees, moving 1.2 m/s forward in its own (base_link) frame.
    odom = Odometry()
    odom.pose.pose.orientation.z, odom.pose.pose.orientation.w = math.sin(math.pi / 4), math.cos(math.pi / 4)
    odom.twist.twist.linear.x = 1.2
    cmd = Twist()
    cmd.linear.x = 1.5
    expected = network(np.array([1.5, 1.2, 0.0, 0.0]))  # yaw-aligned frame: forward is forward
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    executor.add_node(io)

    def arrived() -> bool:
        cmd_pub.publish(cmd)
        odom_pub.publish(odom)
        # Every output: the node's shaped command approaches 1.5 m/s, and near saturation some
        # outputs match while others still move (once f matched and p_swing was 1e-7 off; once
        # f and p_swing matched and two phase offsets had not).
        return bool(received) and all(
            math.isclose(getattr(received[-1], key), getattr(expected, key), rel_tol=1e-6)
            for key in ("stepping_frequency", "swing_ratio")) and np.allclose(
            received[-1].phase_offsets, expected.phase_offsets, rtol=0.0, atol=1e-9)

    try:
        assert spin_until(executor, arrived, timeout_s=20.0), received[-1:] or "no /gait/params"
        last = received[-1]
        assert last.swing_ratio == pytest.approx(expected.swing_ratio)
        np.testing.assert_allclose(last.phase_offsets, expected.phase_offsets, atol=1e-9)
    finally:
        executor.shutdown()
        node.destroy_node()
        io.destroy_node()


@pytest.mark.ros
def test_the_policy_sees_a_cmd_vel_step_as_the_controller_tracks_it(rclpy_context):
    """A step in /cmd_vel (0 -> 1.2 m/s, then back to 0) reaches the policy as the controller's
    supervisor shapes it (config/convex_mpc.yaml's max_acceleration), never as a step: the
    policy was trained on commands that change at most at 1 m/s^2."""
    node = GaitPolicyNode(context=rclpy_context, parameter_overrides=[Parameter("policy", value="scheduled"),
                                                                      Parameter("rate", value=100.0)])
    io = Node("policy_io", context=rclpy_context)
    cmd_pub = io.create_publisher(Twist, "/cmd_vel", COMMAND_QOS)
    acceleration = load_supervisor_config().max_acceleration
    seen: list[tuple[float, float]] = []  # (node clock [s], desired vx the policy saw [m/s])
    publisher = node.pub

    class Recorder:
        """Pairs each /gait/params stamp with the desired speed of the same tick. Read on receipt
        instead, node.desired may already be a later tick's when the executor runs two ticks first."""

        def publish(self, msg: GaitParamsMsg) -> None:
            seen.append((msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, float(node.desired[0])))
            publisher.publish(msg)

    node.pub = Recorder()
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    executor.add_node(io)

    def step_to(speed: float) -> bool:
        cmd = Twist()
        cmd.linear.x = speed
        cmd_pub.publish(cmd)
        return bool(seen) and seen[-1][1] == speed

    try:
        assert spin_until(executor, lambda: step_to(1.2), timeout_s=20.0), seen[-3:]
        assert spin_until(executor, lambda: step_to(0.0), timeout_s=20.0), seen[-3:]
        times, desired = np.array(seen).T
        assert desired.max() == pytest.approx(1.2) and 0.0 < np.median(desired) < 1.2  # ramps, both ways
        rate = np.abs(np.diff(desired)) / np.maximum(np.diff(times), 1e-9)
        # 1e-3: the stamps are doubles of about 1.8e9 s (epoch), good to about 0.2 us
        assert rate.max() <= acceleration * (1 + 1e-3), f"desired speed changed at {rate.max():.3f} m/s^2"
    finally:
        executor.shutdown()
        node.destroy_node()
        io.destroy_node()


@pytest.mark.ros
def test_a_corrupt_policy_file_is_refused_with_the_reason(rclpy_context, tmp_path):
    path = tmp_path / "broken.npz"
    path.write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(ConfigError, match=r"policy file .*broken\.npz"):
        GaitPolicyNode(context=rclpy_context, parameter_overrides=[Parameter("policy", value=str(path))])


@pytest.mark.ros
def test_demo_report_prints_a_line_per_second_of_sim_time(rclpy_context, capsys, tmp_path):
    report = DemoReportNode(context=rclpy_context, parameter_overrides=[
        Parameter("duration", value=100.0), Parameter("output", value=str(tmp_path / "gait.png"))])
    try:
        truth = Odometry()
        truth.twist.twist.linear.x, truth.pose.pose.position.z = 1.23, 0.30
        report.truth = truth
        report.joints = JointState(velocity=[0.0] * 12, effort=[0.0] * 12)
        report._on_cmd(Twist(linear=Vector3(x=1.25)))
        for k in range(126):  # 2.5 s of steps of 20 ms
            state = GaitState()
            state.header.stamp.sec, state.header.stamp.nanosec = divmod(k * 20_000_000, 1_000_000_000)
            state.params.stepping_frequency, state.params.swing_ratio = 2.0, 0.45
            state.params.phase_offsets = [0.0, math.pi, math.pi, 0.0]
            report._on_state(state)
    finally:
        report.destroy_node()
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("t ")]
    assert len(lines) == 3  # at 0, 1 and 2 s
    assert lines[1].split()[:7] == ["t", "1.0", "s", "command", "1.25", "m/s", "actual"]
    assert "trot" in lines[1] and "f 2.00 Hz" in lines[1] and "missed deadlines n/a" in lines[1]


@pytest.mark.ros
def test_demo_report_starts_a_paused_sim_once_every_topic_has_a_publisher(rclpy_context, capsys, tmp_path):
    """scripts/demo.sh starts the sim paused; the report unpauses it (std_srvs/SetBool false) only
    when it can hear the whole run, asks again until it succeeds, and says so if it joined late anyway."""
    report = DemoReportNode(context=rclpy_context, parameter_overrides=[
        Parameter("output", value=str(tmp_path / "gait.png")), Parameter("start_sim", value="sim_bridge/pause")])
    graph = Node("sim_bridge", context=rclpy_context)
    calls: list[bool] = []

    def on_pause(request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        calls.append(request.data)
        response.success = len(calls) > 1  # the first request is refused: the report must ask again
        response.message = "running from 0.000000 s"
        return response

    graph.create_service(SetBool, "~/pause", on_pause)
    publishers = [graph.create_publisher(GaitState, "/gait/state", CONTROL_QOS),
                  graph.create_publisher(Odometry, "/sim/ground_truth/odom", CONTROL_QOS),
                  graph.create_publisher(JointState, "/joint_states", CONTROL_QOS)]
    executor = SingleThreadedExecutor(context=rclpy_context)
    for node in (report, graph):
        executor.add_node(node)
    try:
        # /cmd_vel has no publisher yet: 1 s of its wall-clock checks must not start the sim.
        assert not spin_until(executor, lambda: bool(calls), 1.0)
        publishers.append(graph.create_publisher(Twist, "/cmd_vel", COMMAND_QOS))
        assert spin_until(executor, report._start_timer.is_canceled, 10.0) and calls == [False, False]
        assert "started the simulation" in capsys.readouterr().out
        report.truth, report.joints = Odometry(), JointState(velocity=[0.0] * 12, effort=[0.0] * 12)
        late = GaitState()
        late.header.stamp.sec = 3
        report._on_state(late)
        assert "first sample at t = 3.0 s of sim time" in capsys.readouterr().out
    finally:
        executor.shutdown()
        report.destroy_node()
        graph.destroy_node()


@pytest.mark.ros
@pytest.mark.parametrize(("start_time", "expected"), [
    (-1.0, [0.0, 0.3, 0.5]),  # from the first tick (3.3 s): zero until 4.8 s, then the ramp
    (0.0, [1.8, 2.5, 2.5]),   # from t = 0: the ramp began at 1.5 s, whenever the first tick came
])
def test_velocity_command_counts_profile_time_from_its_first_tick_or_start_time(rclpy_context, start_time, expected):
    """The demo's ramp (start_delay 1.5 s, 1 m/s^2 to 2.5 m/s) ticked first at 3.3 s of its clock, as
    when the process hears its first /clock late: with start_time 0 it still follows the sim's t."""
    from gait_policy_node.velocity_command import VelocityCommandNode

    node = VelocityCommandNode(context=rclpy_context, parameter_overrides=[
        Parameter("start_delay", value=1.5), Parameter("start_time", value=start_time)])
    sent = []
    try:
        node.pub.publish = lambda msg: sent.append(msg.linear.x)
        for now in (3.3, 5.1, 5.3):
            node.get_clock = lambda now=now: SimpleNamespace(now=lambda: SimpleNamespace(nanoseconds=round(now * 1e9)))
            node._tick()
        assert sent == pytest.approx(expected)
    finally:
        node.destroy_node()


@pytest.mark.ros
def test_velocity_command_start_time_is_minus_one_or_a_time(rclpy_context):
    from gait_policy_node.velocity_command import VelocityCommandNode

    expected = r"start_time must be -1 \(from the first tick\) or in \[0, 1e9\] s, got -0.5"
    with pytest.raises(ConfigError, match=expected):
        VelocityCommandNode(context=rclpy_context, parameter_overrides=[Parameter("start_time", value=-0.5)])
