"""scripts/bringup.sh --bridge: the hardware bridge (and the virtual A1) from the same bring-up script."""

from __future__ import annotations

import os
import signal
import subprocess
import time

import pytest
from a1_interface.contract import CONTROL_QOS
from a1_interface.conversions import ns_from_stamp
from graph_helpers import ROOT
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from ros_helpers import spin_until
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

BRINGUP = ROOT / "scripts" / "bringup.sh"


@pytest.mark.parametrize(("args", "message"), [
    (["--bridge", "hardware", "--clock", "lockstep"], "--bridge hardware needs --clock realtime"),
    (["--bridge", "hardware", "--world", "step"], "--world applies to --bridge sim and virtual"),
    (["--bridge", "robot"], "--bridge must be one of: sim hardware virtual; got 'robot'"),
])
def test_bridge_choices_are_checked_before_anything_starts(args, message):
    result = subprocess.run(["bash", str(BRINGUP), *args], capture_output=True, text=True, timeout=30, check=False)
    assert result.returncode == 2
    assert message in result.stderr
    assert "[nodes] started" not in result.stdout


@pytest.fixture
def virtual_bringup():
    """bringup.sh --bridge virtual --clock lockstep; yields it and its nodes' pids; nothing outlives the test."""
    proc = subprocess.Popen(["bash", str(BRINGUP), "--bridge", "virtual", "--clock", "lockstep"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    started: dict[str, int] = {}
    deadline = time.monotonic() + 60
    while len(started) < 3 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if "started" in line and "(pid " in line:
            started[line.split("started ")[1].split(" ")[0]] = int(line.split("(pid ")[1].split(",")[0])
    yield proc, started
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    for pid in started.values():
        try:
            os.killpg(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


@pytest.mark.ros
def test_bringup_virtual_a1_in_lockstep_runs_on_robot_time_and_stops_clean(virtual_bringup, rclpy_context):
    proc, started = virtual_bringup
    # The default form: hw_bridge, state_estimator and convex_mpc composed in one control_chain.
    assert sorted(started) == ["a1_bringup/control_chain", "a1_hw_bridge/virtual_a1", "gait_policy_node/gait_policy"]
    listener = Node("bringup_listener", context=rclpy_context)
    joints: list[JointState] = []
    clock: list[Clock] = []
    listener.create_subscription(JointState, "/joint_states", joints.append, CONTROL_QOS)
    listener.create_subscription(Clock, "/clock", clock.append, CONTROL_QOS)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(listener)
    published = spin_until(executor, lambda: len(joints) > 50 and len(clock) >= 3, 90.0)
    executor.shutdown()
    listener.destroy_node()
    assert published, "the hardware bridge never published"
    # Lockstep: stamped with the virtual robot's tick (seconds since its start), not the wall clock,
    # and only after the bridge's 1.5 s stand-up.
    first_stamp = ns_from_stamp(joints[0].header.stamp) * 1e-9
    assert 1.5 <= first_stamp < 60.0 and clock
    # /clock once per clock_period (10 ms in config/a1_hw_bridge.yaml) of the robot's 2 ms ticks: the
    # first tick of each 10 ms, so within one tick after a multiple of 10 ms (every tick would put four
    # in five elsewhere; the listener's depth-1 queue may drop some, so no gap is asserted). The very
    # first is the first state the bridge saw, wherever in its 10 ms that fell, so it is left out.
    times = sorted({ns_from_stamp(m.clock) for m in clock})
    assert len(times) >= 3 and all(t % 10_000_000 < 2_000_000 for t in times[1:]), times[:10]
    os.kill(proc.pid, signal.SIGTERM)
    assert proc.wait(timeout=30) != 0  # the script reports that it was stopped
    alive = []
    for name, pid in started.items():
        try:
            os.killpg(pid, 0)
            alive.append(name)
        except ProcessLookupError:
            pass
    assert not alive, f"still running after SIGTERM: {alive}"
