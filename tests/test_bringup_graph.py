"""The graph description (a1_bringup.graph) that bring-up, demo, tests and benchmarks start from."""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys

import pytest
from a1_bringup.control_chain import (
    LINK_SWITCH_INTERVAL,
    connect_chain,
    parse_settings,
    prepare_process,
    use_realtime_priority,
)
from a1_bringup.graph import CHAIN_PRIORITY, composed, describe, main, namespace_remaps, with_settings
from graph_helpers import CONFIG, ROOT, add_scheduling_options, scheduling_from_args


def _names(nodes) -> list[str]:
    return [n.name for n in nodes]


def test_lockstep_runs_the_estimator_as_its_own_process_and_every_stack_node_on_sim_time():
    nodes = describe("lockstep")
    assert _names(nodes) == ["sim_bridge", "state_estimator", "convex_mpc", "gait_policy"]
    assert all(n.params["use_sim_time"] == "true" for n in nodes[1:])
    assert nodes[0].params == {"clock_mode": "lockstep"}
    assert nodes[2].param_files == ["convex_mpc.yaml"]


def test_realtime_embeds_the_estimator_with_the_realtime_overlay_on_the_wall_clock():
    nodes = describe("realtime")
    assert _names(nodes) == ["sim_bridge", "convex_mpc", "gait_policy"]
    assert nodes[1].param_files == ["convex_mpc.yaml", "convex_mpc_realtime.yaml"]
    assert all(n.params["use_sim_time"] == "false" for n in nodes[1:])


def test_lockstep_with_the_embedded_estimator_and_the_bridges():
    nodes = describe("lockstep", embedded_estimator=True)
    assert _names(nodes) == ["sim_bridge", "convex_mpc", "gait_policy"]
    assert nodes[1].params["embedded_estimator"] == "true"
    assert _names(describe("lockstep", "virtual"))[:2] == ["virtual_a1", "hw_bridge"]
    assert _names(describe("realtime", "hardware"))[0] == "hw_bridge"
    with pytest.raises(ValueError, match="bridge hardware needs clock realtime"):
        describe("lockstep", "hardware")
    with pytest.raises(ValueError, match="clock must be one of"):
        describe("fast")


def test_every_file_and_executable_it_names_exists():
    for clock, bridge in [("lockstep", "sim"), ("realtime", "sim"), ("lockstep", "virtual"), ("realtime", "hardware")]:
        for node in [*describe(clock, bridge), *composed(describe(clock, bridge))]:
            assert all((CONFIG / f).is_file() for f in node.param_files), node
            assert (ROOT / "install" / node.package / "lib" / node.package / node.executable).exists(), node


def test_settings_and_the_shell_lines(capsys, tmp_path):
    with pytest.raises(ValueError, match="no node 'state_estimator'"):
        with_settings(describe("realtime"), ["state_estimator.max_gap=0.1"])
    with pytest.raises(ValueError, match=r"node\.parameter=value"):
        with_settings(describe("realtime"), ["policy=learned"])
    config = tmp_path / "a config"  # a path with a space survives the shell quoting
    assert main(["--clock", "lockstep", "--config", str(config), "--set", "gait_policy.policy=a b.npz"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 4
    policy = shlex.split(lines[-1])
    assert policy[:2] == ["gait_policy_node", "gait_policy"]
    assert policy[2:] == ["--ros-args", "--params-file", str(config / "gait_policy.yaml"),
                          "-p", "use_sim_time:=true", "-p", "policy:=a b.npz"]
    assert main(["--clock", "lockstep", "--bridge", "hardware", "--config", "config"]) == 2


def test_composed_puts_the_500_hz_chain_in_one_process_and_keeps_each_nodes_parameters():
    nodes = composed(with_settings(describe("lockstep", "virtual"), ["hw_bridge.robot_ip=10.0.0.2"]))
    assert _names(nodes) == ["virtual_a1", "control_chain", "gait_policy"]  # the robot and the policy stay apart
    chain = nodes[1]
    assert chain.nodes == ("hw_bridge", "state_estimator", "convex_mpc")
    assert chain.param_files == ["a1_hw_bridge.yaml", "state_estimator.yaml", "convex_mpc.yaml"]
    assert chain.params == {}  # a plain -p would set every node of the process
    args = chain.arguments(CONFIG)
    assert args[:3] == ["--bridge", "hardware", "--estimator"]
    assert "hw_bridge.robot_ip=10.0.0.2" in args and "convex_mpc.use_sim_time=true" in args
    assert args.index("--ros-args") > args.index("convex_mpc.use_sim_time=true")
    realtime = composed(describe("realtime"))
    assert _names(realtime) == ["control_chain", "gait_policy"]
    assert realtime[0].arguments(CONFIG)[:2] == ["--bridge", "sim"] and "--estimator" not in realtime[0].options
    assert realtime[0].param_files == ["a1_sim_bridge.yaml", "convex_mpc.yaml", "convex_mpc_realtime.yaml"]
    assert describe("realtime")[1].nodes == ("convex_mpc",)


def test_the_realtime_chain_asks_for_fifo_and_nothing_else_does():
    for bridge in ("sim", "virtual", "hardware"):
        chain = composed(describe("realtime", bridge))[-2]
        assert chain.name == "control_chain"
        args = chain.arguments(CONFIG)
        assert args[args.index("--realtime-priority") + 1] == str(CHAIN_PRIORITY) and 0 < CHAIN_PRIORITY < 100
        assert args.index("--realtime-priority") < args.index("--ros-args")
    for nodes in (composed(describe("lockstep")), composed(describe("lockstep", "virtual")), describe("realtime"),
                  describe("realtime", "virtual")):
        assert not any("--realtime-priority" in n.arguments(CONFIG) for n in nodes)  # the separate form too


_PRIORITY_PROBE = """
import os, sys, threading
from a1_bringup.control_chain import use_realtime_priority
seen, go = [], threading.Event()
def fifo():
    seen.append(os.sched_getscheduler(0) == os.SCHED_FIFO)
earlier = threading.Thread(target=lambda: (go.wait(), fifo()))
earlier.start()
set_it = use_realtime_priority(int(sys.argv[1]))
go.set()
earlier.join()
later = threading.Thread(target=fifo)
later.start()
later.join()
print(set_it, os.sched_getscheduler(0) == os.SCHED_FIFO, *seen)
"""


def _probe(priority: int) -> tuple[list[str], str]:
    done = subprocess.run([sys.executable, "-c", _PRIORITY_PROBE, str(priority)], capture_output=True, text=True,
                          timeout=60, check=True)
    return done.stdout.split(), done.stderr


def test_realtime_priority_is_fifo_for_every_thread_or_a_message_and_normal_scheduling():
    """The main thread, one started before (as importing rclpy does) and one started after."""
    assert _probe(0) == (["False", "False", "False", "False"], "")
    out, err = _probe(5)
    if out[0] == "True":  # permitted here (root, CAP_SYS_NICE or an rtprio limit)
        assert out == ["True", "True", "True", "True"] and err == ""
    else:
        assert out == ["False", "False", "False", "False"] and "not permitted" in err and "normal priority" in err


def test_with_the_hardware_bridge_the_gil_changes_hands_within_half_a_millisecond():
    default = sys.getswitchinterval()
    try:
        prepare_process("sim", 0)  # one Python thread in the step: Python's default stays
        assert sys.getswitchinterval() == default
        prepare_process("hardware", 0)  # the link thread beside the executor's
        assert sys.getswitchinterval() == pytest.approx(LINK_SWITCH_INTERVAL) and LINK_SWITCH_INTERVAL < 0.002
    finally:
        sys.setswitchinterval(default)


class _Topic:
    """A publisher or subscription as connect_chain sees it: its resolved topic name."""

    def __init__(self, topic_name: str) -> None:
        self.topic_name = topic_name


class _Sensors:
    def __init__(self) -> None:
        self.on_wire = True

    def take(self, imu: bytes, contacts: bytes, joints: bytes) -> None:
        """Never called here: connect_chain only wires it to the bridge."""

    def leave_wire(self) -> None:
        """Records that the controller left the sensors' wire copies."""
        self.on_wire = False


def _chain(remapped: str = "", sim: bool = True) -> tuple[argparse.Namespace, argparse.Namespace]:
    """A bridge and a controller as connect_chain sees them, ``remapped``: the topic whose publisher
    a fault relay took (its publisher then publishes on /fault_in<topic>)."""
    def topic(name: str) -> _Topic:
        return _Topic(f"/fault_in{name}" if name == remapped else name)

    sensor_topics = ("/imu/data", "/foot_contacts", "/joint_states")
    bridge = argparse.Namespace(pub_imu=topic("/imu/data"), pub_contacts=topic("/foot_contacts"),
                                pub_joints=topic("/joint_states"), subscriptions=[_Topic("/motor_command")],
                                take_command=lambda raw: None)
    if sim:
        bridge.sensor_sinks, bridge.own_thread = [], False
    controller = argparse.Namespace(pub_command=topic("/motor_command"), command_sinks=[], sensors=_Sensors(),
                                    subscriptions=[_Topic(t) for t in (*sensor_topics, "/cmd_vel")])
    return bridge, controller


def test_the_chain_hands_over_only_what_the_wire_links_and_a_fault_relay_keeps_its_topic():
    bridge, controller = _chain()
    connect_chain([bridge, controller], estimator=False)
    assert controller.command_sinks == [bridge.take_command]
    assert bridge.sensor_sinks == [controller.sensors.take] and not controller.sensors.on_wire
    bridge, controller = _chain()
    connect_chain([bridge, argparse.Namespace(), controller], estimator=True)  # the controller waits for /odom
    assert controller.command_sinks and not bridge.sensor_sinks and controller.sensors.on_wire
    bridge, controller = _chain(sim=False)  # the hardware bridge: commands only
    connect_chain([bridge, controller], estimator=False)
    assert controller.command_sinks and controller.sensors.on_wire
    bridge, controller = _chain(remapped="/motor_command")  # a relay drops or delays commands
    connect_chain([bridge, controller], estimator=False)
    assert not controller.command_sinks and bridge.sensor_sinks
    bridge, controller = _chain(remapped="/imu/data")  # a relay freezes the IMU
    connect_chain([bridge, controller], estimator=False)
    assert controller.command_sinks and not bridge.sensor_sinks and controller.sensors.on_wire


def test_a_refused_realtime_priority_is_said_and_the_chain_goes_on(monkeypatch, capsys):
    def refuse(tid, policy, param):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    assert use_realtime_priority(50) is False
    assert "SCHED_FIFO 50 is not permitted here" in capsys.readouterr().err
    set_for = []

    def gone(tid, policy, param):  # a thread that ended between the listing and the call
        if tid != os.getpid():
            raise ProcessLookupError(3, "No such process")
        set_for.append(tid)

    monkeypatch.setattr(os, "sched_setscheduler", gone)
    assert use_realtime_priority(50) is True and set_for == [os.getpid()]


def test_benchmark_scheduling_options_refuse_what_would_not_apply(monkeypatch, capsys):
    parser = argparse.ArgumentParser()
    add_scheduling_options(parser)
    monkeypatch.delenv("FASTDDS_BUILTIN_TRANSPORTS", raising=False)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # rmw_fastrtps's own transports then
    with pytest.raises(SystemExit):
        scheduling_from_args(parser, parser.parse_args(["--dds-transports", "UDPv4"]))
    assert "no effect with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST" in capsys.readouterr().err
    assert "FASTDDS_BUILTIN_TRANSPORTS" not in os.environ
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "SUBNET")
    assert scheduling_from_args(parser, parser.parse_args(["--dds-transports", "UDPv4", "--fifo", "probe=5"])) == \
        {"probe": 5}
    assert os.environ["FASTDDS_BUILTIN_TRANSPORTS"] == "UDPv4"
    with pytest.raises(SystemExit):
        scheduling_from_args(parser, parser.parse_args(["--fifo", "probe=100"]))
    assert "PRIORITY must be an integer in [1, 99]" in capsys.readouterr().err
    args = parser.parse_args(["--fifo", "control_chain=40"])  # control_chain sets its own: one source
    assert scheduling_from_args(parser, args) == {} and args.chain_priority == 40
    with pytest.raises(SystemExit):
        scheduling_from_args(parser, parser.parse_args(["--fifo", "control_chain=40", "--chain-priority", "0"]))
    assert "disagree" in capsys.readouterr().err


def test_chain_settings_are_typed_per_node_and_bad_ones_name_the_item():
    overrides = parse_settings(["sim_bridge.real_time_factor=0.5", "convex_mpc.use_sim_time=true",
                                "sim_bridge.flight_recorder_dir=/tmp/a b"], ["sim_bridge", "convex_mpc"])
    assert [(p.name, p.value) for p in overrides["sim_bridge"]] == [("real_time_factor", 0.5),
                                                                    ("flight_recorder_dir", "/tmp/a b")]
    assert [(p.name, p.value) for p in overrides["convex_mpc"]] == [("use_sim_time", True)]
    with pytest.raises(ValueError, match="no node 'gait_policy' in this chain"):
        parse_settings(["gait_policy.policy=learned"], ["sim_bridge", "convex_mpc"])
    with pytest.raises(ValueError, match=r"node\.parameter=value"):
        parse_settings(["real_time_factor=0.5"], ["sim_bridge"])


def test_the_namespace_rule_is_the_describers_for_graph_lines_and_tools_alike(capsys):
    assert namespace_remaps("") == []
    assert namespace_remaps("/a1_2") == ["-r", "__ns:=/a1_2", "-r", "/clock:=clock"]  # the graph's own sim time
    for bad in ("a1_2", "/a1-2", "/", "/2a"):
        with pytest.raises(ValueError, match="namespace must look like /a1_2"):
            namespace_remaps(bad)
    assert main(["--clock", "realtime", "--config", "config", "--namespace", "/a1_2"]) == 0
    lines = [shlex.split(line) for line in capsys.readouterr().out.splitlines()]
    assert lines and all(line[-4:] == namespace_remaps("/a1_2") for line in lines)
    assert main(["--remaps-only", "--namespace", "/a1_2"]) == 0  # what scripts/lib/nodes.sh adds to a tool's node
    assert shlex.split(capsys.readouterr().out) == namespace_remaps("/a1_2")
    assert main(["--remaps-only", "--namespace", "a1_2"]) == 2
    assert "namespace must look like /a1_2" in capsys.readouterr().err
