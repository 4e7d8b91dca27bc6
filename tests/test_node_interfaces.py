"""What every node of the stack shows the graph: its topics, types and QoS are the contract's
(a1_interface.contract), the nodes a robot runs load no simulator, and every parameter is described
(``ros2 param describe``: a description, the range its validator accepts, ``read_only`` unless the
node applies a runtime change).

The ranges come from the validators themselves (a1_common.config.recording_constraints), the
descriptions from the config dataclasses (a1_common.config.setting): checked here against the
validators' own refusals, so a range shown is the range enforced.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import pytest
from a1_common.config import (
    ConfigError,
    Constraint,
    parameter_descriptions,
    recording_constraints,
    require_choice,
    require_integer,
    require_numbers,
    require_range,
    setting,
)
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import DescribeParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from ros_helpers import spin_until

from a1_interface import contract

pytestmark = pytest.mark.ros
RUNTIME = {"convex_mpc": {"mode", "inject_qp_failures"}, "sim_bridge": {"world", "seed"}}
NUMBER_TYPES = {ParameterType.PARAMETER_DOUBLE, ParameterType.PARAMETER_INTEGER}


# --- the ROS-free pieces ------------------------------------------------------------------------
def test_recording_collects_what_each_validator_accepts_with_a_prefix_for_sub_configs():
    with recording_constraints() as outer:
        require_range("body_height", 0.26, 0.1, 0.5)
        with recording_constraints(prefix="mpc_") as inner:
            require_integer("horizon", 10, 1, 50)
        require_numbers("raibert_clip", (0.1, 0.1), 2, 0.0, 0.5)
        require_choice("mode", "walk", ("stand", "walk"))
        with pytest.raises(ConfigError):
            require_range("fall_tilt", 9.0, 0.3, 1.5, low_open=True)  # a refusal is recorded too
    assert set(inner) == {"mpc_horizon"}
    assert outer == {
        "body_height": Constraint(0.1, 0.5), "mpc_horizon": Constraint(1, 50, integer=True),
        "raibert_clip": Constraint(0.0, 0.5, count=2), "mode": Constraint(choices=("stand", "walk")),
        "fall_tilt": Constraint(0.3, 1.5, low_open=True)}
    assert str(outer["fall_tilt"]) == "a number in (0.3, 1.5]"
    assert str(outer["mpc_horizon"]) == "an integer in [1, 50]"
    assert str(outer["raibert_clip"]) == "2 numbers, each in [0, 0.5]"
    assert str(outer["mode"]) == "one of stand | walk"
    require_range("outside", 1.0, 0.0, 2.0)  # no recording open: nothing kept, nothing raised


def test_a_config_field_without_a_description_is_an_error_naming_it():
    @dataclasses.dataclass
    class Partly:
        described: float = setting(1.0, "a described value [m]")
        bare: int = 3

    with pytest.raises(ValueError, match=r"Partly.bare has no description"):
        parameter_descriptions(Partly())
    assert parameter_descriptions(Partly(), prefix="p_", skip=("bare",)) == {"p_described": "a described value [m]"}


# --- the nodes ------------------------------------------------------------------------------------
def _nodes(context, tmp_path):
    """(node, runtime parameter names) for every node of the stack, built in this process."""
    from a1_hw_bridge.node import HardwareBridgeNode
    from a1_hw_bridge.virtual_a1_node import VirtualA1Node
    from a1_sim_bridge.joint_hold_node import JointHoldNode
    from a1_sim_bridge.monitor_node import MonitorNode
    from a1_sim_bridge.node import SimBridgeNode
    from bag_recorder.node import RecorderNode
    from convex_mpc_node.node import ConvexMpcNode
    from fault_injection.node import FaultRelayNode
    from gait_policy_node.demo_report import DemoReportNode
    from gait_policy_node.policy_node import GaitPolicyNode
    from gait_policy_node.teleop_node import TeleopNode
    from gait_policy_node.velocity_command import VelocityCommandNode
    from state_estimator_node.node import StateEstimatorNode

    def p(**values):
        return [Parameter(k, value=v) for k, v in values.items()]

    makers = [
        lambda: ConvexMpcNode(context=context), lambda: SimBridgeNode(context=context),
        lambda: StateEstimatorNode(context=context), lambda: GaitPolicyNode(context=context),
        lambda: VelocityCommandNode(context=context), lambda: TeleopNode(context=context),
        lambda: RecorderNode(context=context, parameter_overrides=p(output=str(tmp_path / "bag"))),
        lambda: MonitorNode(context=context), lambda: JointHoldNode(context=context),
        lambda: DemoReportNode(context=context, parameter_overrides=p(output=str(tmp_path / "d.png"))),
        lambda: FaultRelayNode(context=context, parameter_overrides=p(topic="/imu/data",
                                                                      message_type="sensor_msgs/msg/Imu")),
        lambda: VirtualA1Node(context=context, parameter_overrides=p(port=0, settle_time=0.0)),
        lambda: HardwareBridgeNode(context=context, parameter_overrides=p(
            robot_ip="127.0.0.1", local_ip="127.0.0.1", local_port=0)),
    ]
    nodes = []
    try:
        for make in makers:
            nodes.append(make())
    except BaseException:
        _close(nodes)
        raise
    return nodes


def _close(nodes) -> None:
    for node in nodes:
        if hasattr(node, "shutdown"):
            node.shutdown()
        node.destroy_node()


@pytest.fixture(scope="module")
def stack_nodes(tmp_path_factory):
    import rclpy

    context = rclpy.context.Context()
    rclpy.init(context=context)
    nodes = _nodes(context, tmp_path_factory.mktemp("nodes"))
    yield context, nodes
    _close(nodes)
    context.try_shutdown()


def _declared(node) -> list[str]:
    return sorted(node.list_parameters([], 0).names)


# Modules a robot computer runs: the hardware bridge and the stack's nodes (not the sim bridge).
ROBOT_NODE_MODULES = ("a1_hw_bridge.node", "convex_mpc_node.node", "state_estimator_node.node",
                      "gait_policy_node.policy_node")
ROS_OWN_TOPICS = {"/parameter_events", "/rosout"}


@pytest.mark.parametrize("module", ROBOT_NODE_MODULES)
def test_the_nodes_a_robot_runs_do_not_import_pybullet(module):
    report = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"],
                            capture_output=True, text=True, check=True).stderr
    imported = {line.split("|")[-1].strip() for line in report.splitlines() if line.startswith("import time:")}
    assert module in imported  # the report is what we think it is
    assert not {m for m in imported if m.split(".")[0] in ("pybullet", "pybullet_utils")}, module


def test_the_composed_hardware_chain_does_not_import_pybullet():
    """control_chain --bridge hardware loads hw_bridge, state_estimator and convex_mpc, not the sim."""
    code = "from a1_bringup.control_chain import chain_nodes; chain_nodes('hardware', True)"
    report = subprocess.run([sys.executable, "-X", "importtime", "-c", code],
                            capture_output=True, text=True, check=True).stderr
    imported = {line.split("|")[-1].strip() for line in report.splitlines() if line.startswith("import time:")}
    assert {"a1_hw_bridge.node", "state_estimator_node.node", "convex_mpc_node.node"} <= imported
    assert not {m for m in imported if m.split(".")[0] in ("pybullet", "pybullet_utils")}


def test_every_topic_of_every_node_has_the_contracts_type_and_qos(stack_nodes):
    _, nodes = stack_nodes
    by_name = {"/" + t.name: t for t in contract.TOPICS}  # the nodes run in the root namespace here
    checked = set()
    for node in nodes:
        if node.get_name() == "bag_recorder":  # subscribes to whatever it discovers, with its own depth
            continue
        endpoints = [*node.publishers, *node.subscriptions]
        for endpoint in endpoints:
            name = endpoint.topic_name
            if name in ROS_OWN_TOPICS or name.startswith("/fault_in/"):  # rclpy's own; the relay's input
                continue
            assert name in by_name, f"{node.get_name()}: {name} is not in a1_interface.contract.TOPICS"
            topic = by_name[name]
            cls = endpoint.msg_type
            declared = f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"
            if name == contract.CMD_VEL:
                assert declared in (topic.type, "geometry_msgs/msg/TwistStamped"), (node.get_name(), name)
            else:
                assert declared == topic.type, (node.get_name(), name, declared)
            qos = endpoint.qos_profile
            assert (qos.reliability, qos.durability, qos.depth) == (
                topic.qos.reliability, topic.qos.durability, topic.qos.depth), (node.get_name(), name)
            checked.add(name)
    assert checked >= {"/" + n for n in (
        contract.JOINT_STATES, contract.IMU, contract.FOOT_CONTACTS, contract.MOTOR_COMMAND, contract.ODOM,
        contract.CMD_VEL, contract.GAIT_PARAMS, contract.GAIT_STATE, contract.DIAGNOSTICS,
        contract.ROBOT_DESCRIPTION, contract.TF, contract.ESTOP)}


def test_every_parameter_of_every_node_has_a_description_and_read_only_unless_applied_at_runtime(stack_nodes):
    _, nodes = stack_nodes
    assert len({n.get_name() for n in nodes}) == len(nodes) == 13
    for node in nodes:
        runtime = RUNTIME.get(node.get_name(), set())
        for name in _declared(node):
            if name == "start_type_description_service":  # rclpy's, read-only and described by rclpy
                continue
            d = node.describe_parameter(name)
            where = f"{node.get_name()}.{name}"
            assert d.description.strip(), f"{where} has no description"
            assert d.read_only == (name not in runtime), where
            assert ("read at start-up" in d.additional_constraints) == d.read_only, where


def test_numeric_ranges_are_the_validators_own(stack_nodes):
    """Each number with a range refuses a start-up value just outside it (the validator's error),
    and the descriptor shows that range; integers get an integer range."""
    _, nodes = stack_nodes
    ranged = 0
    for node in nodes:
        for name in _declared(node):
            d = node.describe_parameter(name)
            if d.type not in NUMBER_TYPES:
                assert not d.floating_point_range and not d.integer_range, name
                continue
            ranges = d.integer_range or d.floating_point_range
            if not ranges:
                continue
            ranged += 1
            if d.integer_range:
                assert d.type == ParameterType.PARAMETER_INTEGER, name
            high = ranges[0].to_value
            if math.isfinite(high) and high < 1e6:
                assert "in [" in d.additional_constraints or "in (" in d.additional_constraints, name
    assert ranged >= 120  # most of the stack's numbers have a range


def test_a_range_shown_is_the_range_enforced_at_start_up(rclpy_context):
    from convex_mpc_node.node import ConvexMpcNode

    node = ConvexMpcNode(context=rclpy_context)
    try:
        shown = node.describe_parameter("body_height").floating_point_range[0]
        horizon = node.describe_parameter("mpc_horizon").integer_range[0]
    finally:
        node.shutdown()
        node.destroy_node()
    assert (shown.from_value, shown.to_value) == (0.1, 0.5)
    assert (horizon.from_value, horizon.to_value) == (1, 50)
    with pytest.raises(ConfigError, match=r"body_height must be in \[0.1, 0.5\]"):
        ConvexMpcNode(context=rclpy_context, parameter_overrides=[Parameter("body_height", value=0.51)])
    with pytest.raises(ConfigError, match=r"horizon must be an integer in \[1, 50\]"):
        ConvexMpcNode(context=rclpy_context, parameter_overrides=[Parameter("mpc_horizon", value=51)])


def test_runtime_set_read_only_refused_range_refused_runtime_applied(rclpy_context):
    from convex_mpc_node.node import ConvexMpcNode

    node = ConvexMpcNode(context=rclpy_context)
    try:
        refused = node.set_parameters([Parameter("max_yaw_rate", value=1.0)])[0]
        assert not refused.successful and "read-only" in refused.reason and "max_yaw_rate" in refused.reason
        assert node.get_parameter("max_yaw_rate").value == 2.0
        out_of_range = node.set_parameters([Parameter("inject_qp_failures", value=-1)])[0]
        assert not out_of_range.successful and "out of range" in out_of_range.reason
        assert node.set_parameters([Parameter("mode", value="stand")])[0].successful
        assert node.supervisor.requested.value == "stand"
    finally:
        node.shutdown()
        node.destroy_node()


def test_a_batch_with_one_bad_value_changes_nothing(rclpy_context):
    """Validated in on_set, applied in post_set: ``set_parameters_atomically`` (the service behind a
    parameter file loaded at runtime) with a bad second value leaves the first unapplied."""
    from convex_mpc_node.node import ConvexMpcNode

    node = ConvexMpcNode(context=rclpy_context)
    try:
        result = node.set_parameters_atomically([Parameter("mode", value="stand"),
                                                 Parameter("inject_qp_failures", value=2.5)])
        assert not result.successful and "inject_qp_failures must be an integer" in result.reason
        assert node.supervisor.requested.value == "walk" and node.get_parameter("mode").value == "walk"
        assert node.controller.stance.qp_failure_steps == 0
        assert node.set_parameters_atomically([Parameter("mode", value="stand"),
                                               Parameter("inject_qp_failures", value=3)]).successful
        assert node.supervisor.requested.value == "stand" and node.controller.stance.qp_failure_steps == 3
    finally:
        node.shutdown()
        node.destroy_node()


def test_ros2_param_describe_over_the_parameter_service(rclpy_context):
    """What ``ros2 param describe /convex_mpc mode body_height`` asks: the describe service."""
    from convex_mpc_node.node import ConvexMpcNode

    node = ConvexMpcNode(context=rclpy_context)
    client_node = Node("describe_client", context=rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    executor.add_node(client_node)
    try:
        client = client_node.create_client(DescribeParameters, "/convex_mpc/describe_parameters")
        assert spin_until(executor, client.service_is_ready, 10.0)
        future = client.call_async(DescribeParameters.Request(names=["mode", "body_height"]))
        assert spin_until(executor, future.done, 10.0)
        mode, body_height = future.result().descriptors
        assert "stand | walk | damping" in mode.description and not mode.read_only
        assert "[m]" in body_height.description and body_height.read_only
        assert body_height.floating_point_range[0].to_value == 0.5
    finally:
        executor.shutdown()
        client_node.destroy_node()
        node.shutdown()
        node.destroy_node()


def test_each_base_parameter_file_holds_the_nodes_own_defaults(stack_nodes):
    """config/<node>.yaml lists each node's parameters for --params-file and describes them; the
    defaults themselves live once, in the config dataclasses (a1_common.config.setting). A value in a
    base file that differs from the default the node declares is a second source: refused here. The
    realtime overlay (convex_mpc_realtime.yaml) holds deployment choices, not defaults."""
    from a1_bringup.graph import describe
    from a1_common.config import config_dir, load_node_parameters

    _, nodes = stack_nodes
    by_name = {n.get_name(): n for n in nodes}
    overridden = {"virtual_a1": {"port", "settle_time"}, "hw_bridge": {"robot_ip", "local_ip", "local_port"}}
    base_files = {spec.name: spec.param_files[0]
                  for clock, bridge in (("lockstep", "sim"), ("lockstep", "virtual"), ("realtime", "sim"))
                  for spec in describe(clock, bridge, embedded_estimator=False)}
    assert set(base_files) == {"sim_bridge", "virtual_a1", "hw_bridge", "state_estimator", "convex_mpc", "gait_policy"}
    for node_name, file_name in base_files.items():
        node = by_name[node_name]
        values = load_node_parameters(config_dir() / file_name, node_name)
        assert set(values) == set(_declared(node)) - {"use_sim_time", "start_type_description_service"}, file_name
        for key, value in values.items():
            if key in overridden.get(node_name, set()):
                continue
            declared = node.get_parameter(key).value
            if isinstance(declared, (list, tuple)) or hasattr(declared, "tolist"):  # array parameters
                declared = list(declared)
            assert declared == value, f"{file_name}: {key} is {value!r}, the node's default {declared!r}"
