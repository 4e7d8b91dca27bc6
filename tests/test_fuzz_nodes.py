"""Hostile messages into real nodes over DDS, and runtime parameter changes (``ros2 param set``).

Each node runs in this process on its own rclpy context; a driver node publishes what hypothesis
generates (NaN, inf, huge, negative, wrong array lengths) on the node's input topics and checks
what comes out: the node keeps running, every /motor_command it sends passes the JointCommand
check (finite, gains in range), every /gait/params is inside the paper's ranges, every /odom is
finite. Parameter changes go through ``set_parameters``, the path the parameter service (and so
``ros2 param set``) takes, plus one call over the real service.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import rclpy
from a1_common.command import JointCommand, MotorMode
from a1_common.robot import a1
from a1_interface.contract import COMMAND_QOS, CONTROL_QOS
from a1_interface.conversions import ns_from_stamp, stamp_from_ns
from a1_sim_bridge.node import SimBridgeNode
from convex_mpc_node.gait import GaitParams
from convex_mpc_node.node import ConvexMpcNode
from convex_mpc_node.supervisor import load_supervisor_config
from diagnostic_msgs.msg import DiagnosticArray
from gait_policy_node.learned_policy import NetworkPolicy, load_policy, save_policy
from gait_policy_node.policy_node import GaitPolicyNode
from gait_policy_node.train_config import TrainConfig
from gait_policy_node.velocity_command import VelocityCommandNode
from geometry_msgs.msg import Twist
from hypothesis import example, given, settings
from hypothesis import strategies as st
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from ros_helpers import spin_until
from sensor_msgs.msg import Imu, JointState
from state_estimator_node.node import StateEstimatorNode
from std_srvs.srv import SetBool

from a1_interface import wire
from gait_msgs.msg import FootContacts, MotorCommand
from gait_msgs.msg import GaitParams as GaitParamsMsg


def decoded_command(msg: MotorCommand) -> JointCommand:
    """The command a bridge applies for ``msg``: decoded from its bytes, as the bridges do."""
    return wire.decode_motor_command(serialize_message(msg))[0]

pytestmark = pytest.mark.ros
# Examples that exchange DDS messages cost milliseconds each (more on a loaded machine): a third of
# the profile's count for those; the library cores behind them get the full count elsewhere.
dds_examples = settings(max_examples=max(10, settings.default.max_examples // 3))

ROBOT = a1()
STEP_NS = 2_000_000
hostile_float = st.one_of(st.floats(width=64), st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308]))


def floats_list(size):
    return st.lists(hostile_float, min_size=size, max_size=size)


def any_length_list(max_size=14):
    return st.integers(0, max_size).flatmap(floats_list)


class Graph:
    """A node under test, a driver node and an executor on a private rclpy context."""

    def __init__(self, make_node) -> None:
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = make_node(self.context)
        self.driver = Node("fuzz_driver", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.driver)

    def spin_until(self, done, timeout_s: float = 5.0) -> bool:
        return spin_until(self.executor, done, timeout_s)

    def connect(self, *publishers, timeout_s: float = 10.0) -> None:
        assert self.spin_until(lambda: all(p.get_subscription_count() > 0 for p in publishers), timeout_s)

    def close(self) -> None:
        self.executor.shutdown()
        if hasattr(self.node, "shutdown"):
            self.node.shutdown()
        self.node.destroy_node()
        self.driver.destroy_node()
        self.context.try_shutdown()


def set_parameter(node, name, value):
    return node.set_parameters([Parameter(name, value=value)])[0]


# Values ROS parameters can hold (homogeneous lists only, integers within int64).
parameter_values = st.one_of(
    st.booleans(), st.integers(-2**63, 2**63 - 1), st.floats(), st.text(max_size=10),
    st.lists(st.floats(), min_size=1, max_size=4), st.lists(st.integers(-10, 10), min_size=1, max_size=4),
    st.lists(st.text(max_size=4), min_size=1, max_size=3),
    st.sampled_from(["walk", "stand", "damping", "step", "flat"]))


# --- convex_mpc: /cmd_vel, /gait/params and the sensor topics -------------------------------------
class SensorDriver:
    """Publishes one sensor set per 2 ms step (what a bridge and the estimator would) and collects
    the /motor_command answering it."""

    def __init__(self, graph: Graph) -> None:
        d = graph.driver
        self.graph = graph
        self.pubs = {"imu": d.create_publisher(Imu, "/imu/data", CONTROL_QOS),
                     "contacts": d.create_publisher(FootContacts, "/foot_contacts", CONTROL_QOS),
                     "joints": d.create_publisher(JointState, "/joint_states", CONTROL_QOS),
                     "odom": d.create_publisher(Odometry, "/odom", CONTROL_QOS)}
        self.cmd_vel = d.create_publisher(Twist, "/cmd_vel", COMMAND_QOS)
        self.gait = d.create_publisher(GaitParamsMsg, "/gait/params", COMMAND_QOS)
        self.commands: dict[int, MotorCommand] = {}
        self.diagnostics: list[DiagnosticArray] = []
        d.create_subscription(MotorCommand, "/motor_command",
                              lambda m: self.commands.__setitem__(ns_from_stamp(m.header.stamp), m), CONTROL_QOS)
        d.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, 10)
        self.k = 0
        graph.connect(*self.pubs.values(), self.cmd_vel, self.gait)

    @staticmethod
    def messages(stamp) -> dict:
        joints = JointState(name=list(ROBOT.joint_names), position=ROBOT.nominal_joint_angles.tolist(),
                            velocity=[0.0] * 12, effort=[0.0] * 12)
        imu = Imu()
        imu.orientation.w = 1.0
        imu.linear_acceleration.z = 9.81
        contacts = FootContacts(contact=[True] * 4, normal_force=[30.0] * 4)
        odom = Odometry()
        odom.pose.pose.orientation.w = 1.0
        msgs = {"imu": imu, "contacts": contacts, "joints": joints, "odom": odom}
        for m in msgs.values():
            m.header.stamp = stamp
        return msgs

    def step(self, hostile=None) -> MotorCommand:
        """One control step with ``hostile(msgs)`` applied to its sensor messages; its command."""
        self.k += 1
        stamp = stamp_from_ns(self.k * STEP_NS)
        msgs = self.messages(stamp)
        if hostile is not None:
            hostile(msgs)
        done = lambda: self.k * STEP_NS in self.commands  # noqa: E731
        for attempt in range(60):
            # Joints, IMU and contacts first (again now and then, in case one was lost), then /odom,
            # which triggers the step once the node holds all four (topics are not ordered, so
            # /odom is offered again until the command comes).
            if attempt % 10 == 0:
                for name in ("imu", "contacts", "joints"):
                    self.pubs[name].publish(msgs[name])
                self.graph.spin_until(lambda: False, timeout_s=0.005)
            self.pubs["odom"].publish(msgs["odom"])
            if self.graph.spin_until(done, timeout_s=0.05):
                return self.commands[self.k * STEP_NS]
        raise AssertionError(f"no /motor_command for step {self.k}")


def assert_motor_safe(msg: MotorCommand) -> None:
    decoded_command(msg).validated()  # raises CommandError on NaN/inf or gains out of range


@pytest.fixture(scope="class")  # one graph alive at a time: no cross-talk
def mpc():
    graph = Graph(lambda ctx: ConvexMpcNode(context=ctx, parameter_overrides=[Parameter("stand_time", value=0.02)]))
    driver = SensorDriver(graph)
    try:
        for _ in range(30):  # stand up (20 ms), then walk in place
            cmd = driver.step()
        assert cmd.mode == MotorMode.HYBRID and np.any(np.asarray(cmd.torque) != 0), "not walking"
        yield graph, driver
    finally:
        graph.close()


def _vector(obj, path: str, values: list[float], names="xyz") -> None:
    target = obj
    for p in path.split("."):
        target = getattr(target, p)
    for n, v in zip(names, values, strict=False):
        setattr(target, n, v)


sensor_attacks = st.one_of(
    st.tuples(st.just("joints"), st.integers(0, 14).flatmap(lambda n: st.tuples(floats_list(n), floats_list(n),
                                                                                floats_list(n)))),
    st.tuples(st.just("imu.orientation"), floats_list(4)),
    st.tuples(st.just("imu.angular_velocity"), floats_list(3)),
    st.tuples(st.just("odom.twist.twist.linear"), floats_list(3)),
    st.tuples(st.just("odom.pose.pose.orientation"), floats_list(4)),
    st.tuples(st.just("contacts.normal_force"), floats_list(4)),
)
command_attacks = st.one_of(
    st.none(),
    st.tuples(st.just("cmd_vel"), floats_list(6)),
    st.tuples(st.just("gait"), st.tuples(hostile_float | st.floats(0, 5), hostile_float | st.floats(0, 1),
                                         floats_list(4))),
)


class TestConvexMpcNode:
    """The convex_mpc node: hostile topics in, /motor_command out; runtime parameters."""

    @dds_examples
    @given(sensor=st.none() | sensor_attacks, command=command_attacks)
    @example(sensor=("joints", ([math.nan] * 12, [0.0] * 12, [0.0] * 12)), command=None)
    @example(sensor=("joints", ([0.0] * 5, [0.0] * 5, [0.0] * 5)), command=None)
    @example(sensor=("odom.twist.twist.linear", [math.inf, 0.0, 0.0]), command=("cmd_vel", [math.nan] * 6))
    @example(sensor=("imu.orientation", [0.0, 0.0, 0.0, 0.0]), command=("cmd_vel", [1e308, -1e308, 0, 0, 0, 1e308]))
    @example(sensor=None, command=("gait", (1e9, -1.0, [math.nan, 0.0, 0.0, 0.0])))
    def test_convex_mpc_node_never_sends_a_bad_motor_command(self, mpc, fuzz_cases, sensor, command):
        _, driver = mpc
        if command is not None and command[0] == "cmd_vel":
            twist = Twist()
            _vector(twist, "linear", command[1][:3])
            _vector(twist, "angular", command[1][3:])
            driver.cmd_vel.publish(twist)
        elif command is not None:
            f, p, offsets = command[1]
            driver.gait.publish(GaitParamsMsg(stepping_frequency=f, swing_ratio=p, phase_offsets=offsets))

        def attack(msgs) -> None:
            if sensor is None:
                return
            where, values = sensor
            if where == "joints":
                msgs["joints"].position, msgs["joints"].velocity, msgs["joints"].effort = values
            elif where == "contacts.normal_force":
                msgs["contacts"].normal_force = values
            else:
                topic, _, path = where.partition(".")
                _vector(msgs[topic], path, values, "xyzw" if path.endswith("orientation") else "xyz")

        cmd = driver.step(attack)
        fuzz_cases["convex_mpc node: hostile step -> /motor_command"][
            "damping" if cmd.mode == MotorMode.DAMPING else "hybrid"] += 1
        assert_motor_safe(cmd)
        assert_motor_safe(driver.step())  # and the next, clean step too


    def test_convex_mpc_node_counts_what_it_rejected(self, mpc):
        """After the fuzzing above, /diagnostics reports the rejected /cmd_vel and /gait/params."""
        graph, driver = mpc
        driver.diagnostics.clear()

        def reported() -> bool:
            for msg in driver.diagnostics:
                for status in msg.status:
                    values = {kv.key: kv.value for kv in status.values}
                    if status.name == "convex_mpc" and int(values.get("rejected_cmd_vel", 0)) > 0 \
                            and int(values.get("rejected_gait_params", 0)) > 0:
                        return True
            return False

        assert graph.spin_until(reported, timeout_s=5.0)


    @given(name=st.sampled_from(["mode", "stand_time", "max_forward_speed", "body_height", "mpc_horizon",
                                 "cmd_vel_stamped"]), value=parameter_values)
    @example(name="mode", value="run")
    @example(name="mode", value=3)
    @example(name="max_forward_speed", value=1e9)
    def test_convex_mpc_runtime_parameters_are_validated(self, mpc, fuzz_cases, name, value):
        graph, _ = mpc
        result = set_parameter(graph.node, name, value)
        fuzz_cases["convex_mpc: ros2 param set"]["accepted" if result.successful else "refused"] += 1
        assert result.successful == (name == "mode" and value in ("stand", "walk", "damping"))
        if not result.successful:
            assert name in result.reason
            if name == "mode":
                assert "['stand', 'walk', 'damping']" in result.reason or "string" in result.reason
        set_parameter(graph.node, "mode", "walk")


    def test_ros2_param_set_over_the_parameter_service_is_refused_with_the_reason(self, mpc):
        from rclpy.parameter_client import AsyncParameterClient

        graph, _ = mpc
        client = AsyncParameterClient(graph.driver, "convex_mpc")
        assert client.wait_for_services(timeout_sec=5.0) or graph.spin_until(client.services_are_ready, 5.0)
        future = client.set_parameters([Parameter("mode", value="fly"), Parameter("max_yaw_rate", value=-1.0)])
        assert graph.spin_until(future.done, timeout_s=5.0)
        results = future.result().results
        assert not results[0].successful and "mode must be one of" in results[0].reason
        assert not results[1].successful and "read-only parameter: max_yaw_rate" in results[1].reason
        assert graph.node.get_parameter("mode").value == "walk"


def test_convex_mpc_node_survives_joint_states_without_efforts():
    graph = Graph(lambda ctx: ConvexMpcNode(context=ctx))
    try:
        driver = SensorDriver(graph)
        driver.step()

        def no_effort(msgs) -> None:
            msgs["joints"].effort = []

        assert_motor_safe(driver.step(no_effort))
        assert_motor_safe(driver.step())
    finally:
        graph.close()


# --- gait_policy: /cmd_vel and /odom ------------------------------------------------------------------
@pytest.fixture(scope="module")
def policy_file(tmp_path_factory):
    config = TrainConfig()
    policy = NetworkPolicy.from_config(config)
    policy.set_params(np.random.default_rng(7).normal(0, 1.0, policy.num_params))  # input-sensitive
    path = tmp_path_factory.mktemp("policy") / "fuzz_policy.npz"
    save_policy(path, policy, config)
    return path


@pytest.fixture(scope="class")  # one graph alive at a time: no cross-talk
def gait_policy(policy_file):
    overrides = [Parameter("policy", value=str(policy_file)), Parameter("rate", value=200.0)]
    graph = Graph(lambda ctx: GaitPolicyNode(context=ctx, parameter_overrides=overrides))
    out: list[GaitParamsMsg] = []
    graph.driver.create_subscription(GaitParamsMsg, "/gait/params", out.append, COMMAND_QOS)
    cmd = graph.driver.create_publisher(Twist, "/cmd_vel", COMMAND_QOS)
    odom = graph.driver.create_publisher(Odometry, "/odom", CONTROL_QOS)
    graph.connect(cmd, odom)
    try:
        yield graph, cmd, odom, out
    finally:
        graph.close()


def _odometry(linear, orientation) -> Odometry:
    msg = Odometry()
    _vector(msg, "twist.twist.linear", linear)
    _vector(msg, "pose.pose.orientation", orientation, "xyzw")
    return msg


class TestGaitPolicyNode:
    """The gait_policy node: hostile /cmd_vel and /odom in, /gait/params out; runtime parameters."""

    @dds_examples
    @given(cmd=floats_list(6), linear=floats_list(3), orientation=floats_list(4) | st.just([0.0, 0.0, 0.0, 1.0]))
    @example(cmd=[1e308, -1e308, 0, 0, 0, 0], linear=[0.0] * 3, orientation=[0.0, 0.0, 0.0, 1.0])
    @example(cmd=[math.nan] * 6, linear=[math.inf, 0, 0], orientation=[0.0, 0.0, 0.0, 0.0])
    @example(cmd=[1.0, 0, 0, 0, 0, 0], linear=[1e300, -1e300, 1e300], orientation=[1e200, 1e200, 0.0, 0.0])
    def test_gait_policy_node_publishes_only_valid_gait_params(self, gait_policy, fuzz_cases, cmd, linear, orientation):
        graph, cmd_pub, odom_pub, out = gait_policy
        twist = Twist()
        _vector(twist, "linear", cmd[:3])
        _vector(twist, "angular", cmd[3:])
        cmd_pub.publish(twist)
        odom_pub.publish(_odometry(linear, orientation))
        n = len(out)
        assert graph.spin_until(lambda: len(out) >= n + 3, timeout_s=5.0), "the policy node stopped publishing"
        fuzz_cases["gait_policy node: hostile /cmd_vel + /odom"]["examples"] += 1
        assert graph.node.invalid_outputs == 0
        for msg in out[n:]:
            GaitParams(msg.stepping_frequency, msg.swing_ratio, tuple(msg.phase_offsets)).validated()


    def test_gait_policy_node_clamps_the_desired_velocity(self, gait_policy, policy_file):
        """The documented clamp: /cmd_vel x = 1e300, y = -1e300 act as the controller's
        max_forward_speed and -max_lateral_speed (config/convex_mpc.yaml), approached at the
        controller's acceleration, and the policy sees the shaped value."""
        graph, cmd_pub, odom_pub, out = gait_policy
        network, _ = load_policy(policy_file)
        limits = load_supervisor_config()
        max_forward = limits.max_forward_speed
        twist = Twist()
        twist.linear.x = 1e300
        twist.linear.y = -1e300
        odom = _odometry([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])

        def clamped() -> bool:
            cmd_pub.publish(twist)
            odom_pub.publish(odom)
            return (graph.node.shaper.target[0] == max_forward
                    and graph.node.shaper.target[1] == -limits.max_lateral_speed and graph.node.desired[0] > 0.0
                    and not np.any(graph.node.measured))

        assert graph.spin_until(clamped, timeout_s=5.0)
        inputs = []  # the desired velocity of each tick checked: the node sets it and publishes in one callback

        def last_tick_published() -> bool:
            """The /gait/params of the node's last tick has arrived and is the network's output for its
            shaped input. (The message may arrive a tick later than the node moved on: the shaped
            input still rises, so each tick's value is its own and is matched, not assumed.)"""
            desired = graph.node.desired.copy()
            inputs.append(desired[0])
            expected = network(np.concatenate([desired[:1], graph.node.measured]))
            return any(math.isclose(m.stepping_frequency, expected.stepping_frequency, abs_tol=1e-12)
                       and np.allclose(m.phase_offsets, expected.phase_offsets, atol=1e-12) for m in out[-5:])

        assert graph.spin_until(last_tick_published, timeout_s=5.0), f"no /gait/params for inputs {inputs[-5:]}"
        assert 0.0 < inputs[-1] <= max_forward


    @given(name=st.sampled_from(["policy", "rate", "cmd_vel_stamped"]), value=parameter_values)
    @example(name="rate", value=1e9)
    @example(name="policy", value="../../etc/passwd.npz")
    def test_gait_policy_runtime_parameters_are_refused(self, gait_policy, fuzz_cases, name, value):
        graph = gait_policy[0]
        result = set_parameter(graph.node, name, value)
        fuzz_cases["gait_policy: ros2 param set"]["accepted" if result.successful else "refused"] += 1
        assert not result.successful and name in result.reason and "read-only" in result.reason


@pytest.fixture(scope="class")  # one graph alive at a time: no cross-talk
def velocity_command():
    graph = Graph(lambda ctx: VelocityCommandNode(context=ctx))
    try:
        yield graph.node
    finally:
        graph.close()


class TestVelocityCommandNode:
    """The velocity_command tool: runtime parameters."""

    @given(name=st.sampled_from(["profile", "speed", "steps", "rate", "duration"]), value=parameter_values)
    def test_velocity_command_runtime_parameters_are_refused(self, velocity_command, fuzz_cases, name, value):
        result = set_parameter(velocity_command, name, value)
        fuzz_cases["velocity_command: ros2 param set"]["accepted" if result.successful else "refused"] += 1
        assert not result.successful and name in result.reason


# --- sim bridge: /motor_command -----------------------------------------------------------------------
@pytest.fixture(scope="class")  # one graph alive at a time: no cross-talk
def sim_bridge():
    overrides = [Parameter("clock_mode", value="lockstep"), Parameter("lockstep_timeout", value=0.02),
                 Parameter("settle_time", value=0.1)]
    graph = Graph(lambda ctx: SimBridgeNode(context=ctx, parameter_overrides=overrides))
    joints: list[JointState] = []
    graph.driver.create_subscription(JointState, "/joint_states", joints.append, CONTROL_QOS)
    pub = graph.driver.create_publisher(MotorCommand, "/motor_command", CONTROL_QOS)
    graph.connect(pub)
    assert graph.spin_until(lambda: len(joints) > 0, timeout_s=10.0)
    try:
        yield graph, pub, joints
    finally:
        graph.close()


motor_arrays = st.one_of(floats_list(12), st.lists(st.floats(-120, 1200), min_size=12, max_size=12))


def _pause(graph) -> None:
    """Pause the simulation through its ~/pause service, once."""
    if getattr(graph, "paused", False):
        return
    client = graph.driver.create_client(SetBool, "/sim_bridge/pause")
    assert client.wait_for_service(timeout_sec=10.0)
    future = client.call_async(SetBool.Request(data=True))
    assert graph.spin_until(future.done, timeout_s=10.0) and future.result().success
    graph.paused = True


class TestSimBridgeNode:
    """The sim bridge: hostile /motor_command in, sensors out; runtime parameters."""

    @dds_examples
    @given(mode=st.sampled_from([0, 0, 1, 2, 255]), arrays=st.fixed_dictionaries(
        {f: motor_arrays for f in ("position", "velocity", "kp", "kd", "torque")}))
    @example(mode=0, arrays={f: [math.nan] * 12 for f in ("position", "velocity", "kp", "kd", "torque")})
    @example(mode=0, arrays={"position": [0.0] * 12, "velocity": [0.0] * 12, "kp": [1000.0] * 12, "kd": [100.0] * 12,
                             "torque": [100.0] * 12})  # the largest valid command: applied, torques clipped
    def test_sim_bridge_rejects_bad_motor_commands_and_keeps_simulating(self, sim_bridge, fuzz_cases, mode, arrays):
        graph, pub, joints = sim_bridge
        bridge = graph.node
        wd = bridge.watchdog
        before = (wd.accepted, wd.rejected, bridge._late_commands)
        msg = MotorCommand(mode=mode, **arrays)

        def handled() -> bool:
            msg.header.stamp = stamp_from_ns(bridge.sim.steps * STEP_NS)  # for the step the bridge waits on
            pub.publish(msg)
            return (wd.accepted, wd.rejected, bridge._late_commands) != before

        assert graph.spin_until(handled, timeout_s=5.0)
        try:
            decoded_command(msg).validated()
            valid = True
        except ValueError:
            valid = False
        outcome = "rejected" if wd.rejected > before[1] else "accepted" if wd.accepted > before[0] else "late"
        fuzz_cases["sim_bridge: hostile /motor_command"][outcome] += 1
        assert (outcome == "rejected") == (not valid) or outcome == "late"
        n = len(joints)
        assert graph.spin_until(lambda: len(joints) > n, timeout_s=5.0), "the simulation stopped"
        assert bridge.failure is None
        last = joints[-1]
        assert np.all(np.isfinite(last.position)) and np.all(np.isfinite(last.velocity))
        assert np.all(np.abs(last.effort) <= ROBOT.motor_torque_limit + 1e-9)


    @given(name=st.sampled_from(["world", "seed", "time_step", "clock_mode", "command_timeout", "ground_friction"]),
           value=parameter_values)
    @example(name="world", value="lava")
    @example(name="seed", value=-1)
    @example(name="world", value="step")
    def test_sim_bridge_runtime_parameters_are_validated(self, sim_bridge, fuzz_cases, name, value):
        graph = sim_bridge[0]
        _pause(graph)  # (the simulation thread would only compete for the interpreter here)
        result = set_parameter(graph.node, name, value)
        fuzz_cases["sim_bridge: ros2 param set"]["accepted" if result.successful else "refused"] += 1
        valid = (name == "world" and value in ("flat", "step", "rough", "soft", "slope")) or (
            name == "seed" and isinstance(value, int) and not isinstance(value, bool) and value >= 0)
        assert result.successful == valid
        if not result.successful:
            assert name in result.reason


# --- state estimator --------------------------------------------------------------------------------
@pytest.fixture(scope="class")  # one graph alive at a time: no cross-talk
def estimator():
    graph = Graph(lambda ctx: StateEstimatorNode(context=ctx))
    odoms: list[Odometry] = []
    graph.driver.create_subscription(Odometry, "/odom", odoms.append, CONTROL_QOS)
    pubs = {"imu": graph.driver.create_publisher(Imu, "/imu/data", CONTROL_QOS),
            "contacts": graph.driver.create_publisher(FootContacts, "/foot_contacts", CONTROL_QOS),
            "joints": graph.driver.create_publisher(JointState, "/joint_states", CONTROL_QOS)}
    graph.connect(*pubs.values())
    try:
        yield graph, pubs, odoms
    finally:
        graph.close()


_ESTIMATOR_STEPS = itertools.count(1)


def _estimator_step(graph, pubs, odoms, k: int, hostile) -> list[Odometry]:
    """Publish a sensor set stamped step k: IMU and contacts, and once the node holds them (the
    topics are not ordered), the joint state that triggers the update. Returns the new /odom."""
    msgs = SensorDriver.messages(stamp_from_ns(k * STEP_NS))
    hostile(msgs)
    node = graph.node

    def holds(attr: str) -> bool:
        held = getattr(node, attr)
        return held is not None and ns_from_stamp(held.header.stamp) == k * STEP_NS

    def held() -> bool:
        if not holds("_imu"):
            pubs["imu"].publish(msgs["imu"])
        if not holds("_contacts"):
            pubs["contacts"].publish(msgs["contacts"])
        return holds("_imu") and holds("_contacts")

    assert graph.spin_until(held, timeout_s=5.0)
    n, rejected = len(odoms), node.estimator.rejected_samples

    def answered() -> bool:
        if node.estimator.rejected_samples > rejected:
            return True
        if any(ns_from_stamp(o.header.stamp) == k * STEP_NS for o in odoms[n:]):
            return True
        pubs["joints"].publish(msgs["joints"])  # (again: the first may precede discovery's last step)
        return False

    assert graph.spin_until(answered, timeout_s=5.0)
    return odoms[n:]


estimator_attacks = st.one_of(
    st.tuples(st.just("joints"), st.integers(0, 14).flatmap(lambda n: st.tuples(floats_list(n), floats_list(n)))),
    st.tuples(st.just("imu.orientation"), floats_list(4).filter(lambda q: not all(map(math.isfinite, q))) |
              st.just([0.0, 0.0, 0.0, 0.0])),
    st.tuples(st.just("imu.angular_velocity"), floats_list(3)),
    st.tuples(st.just("imu.linear_acceleration"), floats_list(3)),
    st.tuples(st.just("contacts.normal_force"), floats_list(4)),
)


class TestStateEstimatorNode:
    """The state estimator: hostile sensor topics in, /odom out; runtime parameters."""

    @dds_examples
    @given(attack=estimator_attacks)
    @example(attack=("joints", ([math.nan] * 12, [0.0] * 12)))
    @example(attack=("joints", ([0.0] * 3, [0.0] * 3)))
    def test_estimator_node_publishes_only_finite_odometry(self, estimator, fuzz_cases, attack):
        graph, pubs, odoms = estimator
        where, values = attack

        def hostile(msgs) -> None:
            if where == "joints":
                msgs["joints"].position, msgs["joints"].velocity = values
            elif where == "contacts.normal_force":
                msgs["contacts"].normal_force = values
            else:
                topic, _, path = where.partition(".")
                _vector(msgs[topic], path, values, "xyzw" if path == "orientation" else "xyz")

        new = _estimator_step(graph, pubs, odoms, next(_ESTIMATOR_STEPS), hostile)
        fuzz_cases["state_estimator node: hostile sensors -> /odom"]["published" if new else "rejected"] += 1
        for odom in new:
            t = odom.twist.twist.linear
            assert all(math.isfinite(v) for v in (t.x, t.y, t.z))
        clean = _estimator_step(graph, pubs, odoms, next(_ESTIMATOR_STEPS), lambda msgs: None)
        assert clean, "the estimator stopped publishing after a hostile sample"
        t = clean[-1].twist.twist.linear
        assert all(math.isfinite(v) for v in (t.x, t.y, t.z))


    def test_estimator_runtime_parameters_are_refused(self, estimator):
        graph = estimator[0]
        result = set_parameter(graph.node, "process_noise", [-1.0, 0.0, 0.0])
        assert not result.successful and "process_noise" in result.reason


def test_joint_hold_runtime_parameters_are_refused(rclpy_context):
    from a1_sim_bridge.joint_hold_node import JointHoldNode

    node = JointHoldNode(context=rclpy_context)
    try:
        result = set_parameter(node, "ramp_time", -5.0)
        assert not result.successful and "ramp_time" in result.reason
    finally:
        node.destroy_node()
