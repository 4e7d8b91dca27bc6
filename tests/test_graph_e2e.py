"""End-to-end over real processes: the node graph walks on /cmd_vel, fails safe, and shuts down clean.

Every node is its own process (the installed executables), the sim bridge in lockstep so runs are
deterministic; this test process only publishes /cmd_vel and watches topics.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time

import numpy as np
import pytest
from a1_interface.contract import CONTROL_QOS, TF_QOS
from a1_interface.conversions import ns_from_stamp
from bag_recorder.bag import read_bag
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from graph_helpers import PROBE_QOS, ROOT, SIM_DT, Graph, damping_onset, run_until, set_sim_paused
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import spin_until
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from a1_interface import contract
from gait_msgs.msg import MotorCommand
from tf2_msgs.msg import TFMessage


class Watcher(Node):
    """Publishes /cmd_vel at about 20 Hz (wall) and records ground truth, commands and joints."""

    def __init__(self, context, namespace: str = "") -> None:
        super().__init__("e2e_watcher", context=context, namespace=namespace)  # topics: relative, in it
        self.speed: float | None = 0.0  # None: publish nothing
        self.truth: list[tuple[float, float, float]] = []  # (sim time, v_x body, z)
        self.truth_x: list[tuple[float, float]] = []  # (sim time, base x in the world [m])
        self.commands: list[float] = []  # stamps of /motor_command [s]
        self.joints: list[tuple[float, np.ndarray, np.ndarray]] = []  # (t, velocity, effort)
        self.diagnostics: dict[str, list[float]] = {}  # status name -> header stamps [s]
        self.bridge_report: dict[str, str] = {}  # the sim bridge's latest /diagnostics values
        self.transforms: list[tuple[str, str, float, float]] = []  # /tf: (parent, child, x, stamp [s])
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diagnostics, reliable)
        self.create_subscription(TFMessage, contract.TF, lambda m: self.transforms.extend(
            (t.header.frame_id, t.child_frame_id, t.transform.translation.x, ns_from_stamp(t.header.stamp) * 1e-9)
            for t in m.transforms), TF_QOS)
        self._pub = self.create_publisher(Twist, contract.CMD_VEL, reliable)
        self._last_pub = 0.0
        self._truth_sub = self.create_subscription(Odometry, contract.GROUND_TRUTH, self._on_truth, PROBE_QOS)

    def watch_joints_and_commands(self) -> None:
        """Also record /motor_command stamps and /joint_states: 1000 messages/s more for this
        process, which shares the 2 cores with the graph, so only for the tests that need them."""
        self.create_subscription(MotorCommand, contract.MOTOR_COMMAND,
                                 lambda m: self.commands.append(ns_from_stamp(m.header.stamp) * 1e-9), PROBE_QOS)
        self.create_subscription(JointState, contract.JOINT_STATES, self._on_joints, PROBE_QOS)

    def _on_truth(self, m: Odometry) -> None:
        t = ns_from_stamp(m.header.stamp) * 1e-9
        self.truth.append((t, m.twist.twist.linear.x, m.pose.pose.position.z))
        self.truth_x.append((t, m.pose.pose.position.x))
        if self.speed is not None and time.monotonic() - self._last_pub > 0.05:
            msg = Twist()
            msg.linear.x = self.speed
            self._pub.publish(msg)
            self._last_pub = time.monotonic()

    def _on_diagnostics(self, m: DiagnosticArray) -> None:
        for status in m.status:
            self.diagnostics.setdefault(status.name, []).append(ns_from_stamp(m.header.stamp) * 1e-9)
            if status.name == "a1_sim_bridge":
                self.bridge_report = {kv.key: kv.value for kv in status.values}

    def _on_joints(self, m: JointState) -> None:
        self.joints.append((ns_from_stamp(m.header.stamp) * 1e-9, np.array(m.velocity), np.array(m.effort)))

    def hears_ground_truth(self) -> bool:
        """The ground truth subscription has matched a publisher."""
        return self._truth_sub.get_publisher_count() > 0

    def sim_time(self) -> float:
        return self.truth[-1][0] if self.truth else 0.0

    def mean_speed(self, start: float, end: float) -> float:
        return float(np.mean([v for t, v, _ in self.truth if start <= t <= end]))

    def lowest(self) -> float:
        return min(z for _, _, z in self.truth)


@pytest.fixture
def graph(tmp_path, rclpy_context):
    watcher = Watcher(rclpy_context)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(watcher)
    g = Graph(tmp_path, heard_by=(executor, watcher))  # each graph test's run starts once it is heard
    yield g, watcher, executor
    g.stop()
    executor.shutdown()
    watcher.destroy_node()


@pytest.mark.ros
@pytest.mark.slow
def test_two_namespaced_lockstep_graphs_walk_side_by_side(tmp_path, rclpy_context):
    """Two whole graphs at once, /a1_1 and /a1_2 (``-r __ns:=...``, the parameter files' ``/**/``
    keys, each graph's own /clock), /a1_1 in the composed form (its chain one process) and /a1_2
    a process a node: each robot walks at its own commanded speed, and nothing of either lands in
    the root namespace."""
    speeds = {"/a1_1": 0.5, "/a1_2": 1.0}
    composed_forms = {"/a1_1": True, "/a1_2": False}
    watchers = {ns: Watcher(rclpy_context, namespace=ns) for ns in speeds}
    executor = SingleThreadedExecutor(context=rclpy_context)
    for ns, watcher in watchers.items():
        executor.add_node(watcher)
        watcher.speed = speeds[ns]
    graphs = {ns: Graph(tmp_path / ns.strip("/"), namespace=ns, heard_by=(executor, watchers[ns])) for ns in speeds}
    try:
        for ns, g in graphs.items():
            (tmp_path / ns.strip("/")).mkdir()
            g.start_stack("lockstep", 0.5, composed_chain=composed_forms[ns])
        assert sorted(graphs["/a1_1"].procs) == ["control_chain", "gait_policy"]
        for ns, g in graphs.items():
            run_until(executor, watchers[ns], g, 6.5, wall_timeout=400)
        for ns, watcher in watchers.items():
            assert watcher.lowest() > 0.18, f"{ns} fell"
            # Stand-up 1 s, then 1 m/s^2: both are at their speed by t = 3 s.
            assert watcher.mean_speed(4.5, 6.5) == pytest.approx(speeds[ns], rel=0.15), ns
            assert {"a1_sim_bridge", "convex_mpc", "gait_policy", "state_estimator"} <= set(watcher.diagnostics)
        root = {name for name, _ in watchers["/a1_1"].get_topic_names_and_types()
                if name.count("/") == 1 and name not in ("/rosout", "/parameter_events")}
        assert not root & {"/joint_states", "/motor_command", "/odom", "/clock", "/cmd_vel"}, root
    finally:
        for g in graphs.values():
            g.stop()
        executor.shutdown()
        for watcher in watchers.values():
            watcher.destroy_node()


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize(("controller_params", "composed_chain"),
                         [((), False), (("embedded_estimator:=true", "mpc_period_steps:=2"), False), ((), True),
                          (("embedded_estimator:=true",), True)],
                         ids=["estimator_node", "embedded_estimator_mpc_every_2nd_step", "composed_chain",
                              "composed_chain_sensors_handed_over"])
def test_cmd_vel_1_mps_walks_within_10_percent(graph, controller_params, composed_chain):
    """composed_chain: bridge, estimator and controller in one control_chain process, and what this
    process (another one) sees of their 500 Hz traffic is what the separate nodes publish; with the
    estimator embedded the bridge hands the sensors to the controller in the process, and their wire
    copies still go out."""
    g, watcher, executor = graph
    if composed_chain:
        watcher.watch_joints_and_commands()
    g.start_stack("lockstep", 0.5, *controller_params, composed_chain=composed_chain)
    watcher.speed = 1.0
    run_until(executor, watcher, g, 7.0, wall_timeout=240)
    if composed_chain:
        assert sorted(g.procs) == ["control_chain", "gait_policy"]
        # One command and one joint state a step, over the last 2 s (this process's subscriptions are
        # matched by discovery some time after the graph starts, so not from t = 0).
        steps = round(2.0 / SIM_DT)
        assert len({t for t in watcher.commands if t >= 5.0}) >= 0.9 * steps
        assert len({t for t, _, _ in watcher.joints if t >= 5.0}) >= 0.9 * steps
    assert watcher.lowest() > 0.18, "fell"
    # Stand-up 1 s, then 1 m/s^2 to 1.0 m/s: 5 s into walking is about t = 6..7 s.
    assert watcher.mean_speed(6.0, 7.0) == pytest.approx(1.0, rel=0.10)
    # /tf odom -> base_link from whichever node publishes /odom, following the robot forward.
    assert watcher.transforms and {t[:2] for t in watcher.transforms} == {("odom", "base_link")}
    # It follows the robot: from its first transform of t >= 5 s to one of t >= 6.9 s that the
    # ground truth read so far covers (waited for: the two topics are taken in no set order, and
    # the sim runs on meanwhile), odom's x moves as the ground truth's does. Not the absolute x: when
    # the walk starts depends on discovery (the composed chain's robot was at x 0.86 m at t = 5 s,
    # the separate nodes' at 3.40 m, in one run).
    def covered() -> list[tuple[str, str, float, float]]:
        return [tf for tf in watcher.transforms if tf[3] <= watcher.sim_time()]
    assert spin_until(executor, lambda: covered() and covered()[-1][3] >= 6.9, 10.0), \
        f"no /tf of t >= 6.9 s within the ground truth's {watcher.sim_time():.3f} s; last {watcher.transforms[-1]}"
    first, last = next(tf for tf in watcher.transforms if tf[3] >= 5.0), covered()[-1]
    assert last[3] - first[3] >= 1.0, (first, last)
    truth_t, truth_x = np.array(watcher.truth_x).T
    assert truth_t[0] <= first[3], f"the ground truth starts at {truth_t[0]:.3f} s, after the first /tf used"
    truth_moved = np.interp(last[3], truth_t, truth_x) - np.interp(first[3], truth_t, truth_x)
    assert last[2] - first[2] == pytest.approx(truth_moved, rel=0.10), \
        f"/tf does not follow the robot: {first} -> {last}, ground truth moved {truth_moved:.3f} m"
    # Every node reports on /diagnostics, stamped on its (sim) clock.
    nodes = {"a1_sim_bridge", "convex_mpc", "gait_policy"} | ({"state_estimator"} if not controller_params else set())
    assert nodes <= set(watcher.diagnostics), watcher.diagnostics
    for name in nodes:  # (the bridge reports t = 0 until the first command starts its sim)
        stamps = watcher.diagnostics[name]
        assert 0.0 < stamps[-1] <= watcher.sim_time() + 1.0 and stamps == sorted(stamps), (name, stamps)


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize("clock", ["lockstep", "realtime"])
def test_reset_after_seconds_of_walking_stands_up_and_walks_again(graph, clock):
    """``ros2 service call /sim_bridge/reset std_srvs/srv/Trigger`` on a graph that has walked for
    seconds: the sim starts over, and the robot stands up and walks on the next /cmd_vel."""
    g, watcher, executor = graph
    g.start_stack(clock, 0.5, real_time_factor=0.25 if clock == "realtime" else 1.0,
                  composed_chain=clock == "lockstep")  # composed: the sim is stepped by the executor's poll
    watcher.speed = 1.0
    run_until(executor, watcher, g, 2.0, wall_timeout=300)  # the controller keeps 0.1 s of sensor steps
    assert watcher.lowest() > 0.18, "fell before the reset"
    client = watcher.create_client(Trigger, "/sim_bridge/reset")
    assert client.wait_for_service(timeout_sec=10.0)
    future = client.call_async(Trigger.Request())
    assert spin_until(executor, future.done, 10.0) and future.result().success
    spin_until(executor, lambda: bool(watcher.truth) and watcher.truth[-1][0] < 1.0, 30.0)
    watcher.truth = [sample for sample in watcher.truth if sample[0] < 1.0]  # the new run's, from t = 0
    run_until(executor, watcher, g, 5.0, wall_timeout=120)  # stand-up 1 s, then 1 m/s^2 to 1 m/s
    assert watcher.lowest() > 0.18, "fell after the reset"
    assert watcher.mean_speed(4.0, 5.0) == pytest.approx(1.0, rel=0.15)


@pytest.mark.ros
@pytest.mark.slow
def test_paper_acceleration_profile_stays_up(graph):
    g, watcher, executor = graph
    # Composed (the demo's form), embedded estimator: the estimator process and the separate form
    # are covered by the 1 m/s test and the fault scenarios.
    g.start_stack("lockstep", 0.5, "embedded_estimator:=true", composed_chain=True)
    g.start_velocity_ramp(speed=2.5, acceleration=1.0, start_delay=1.5)
    watcher.speed = None  # velocity_command drives
    run_until(executor, watcher, g, 20.0, wall_timeout=480)
    assert watcher.lowest() > 0.18, "fell"
    assert watcher.mean_speed(18.0, 20.0) == pytest.approx(2.5, rel=0.15)


@pytest.mark.ros
@pytest.mark.slow
def test_controller_killed_damps_within_50_ms_then_recovers(graph):
    g, watcher, executor = graph
    watcher.watch_joints_and_commands()
    g.start_stack("lockstep", 0.05, "embedded_estimator:=true")
    watcher.speed = 1.0
    run_until(executor, watcher, g, 3.0, wall_timeout=180)
    watcher.speed = 0.0  # slow to trotting in place, so the damped robot sinks rather than tumbles
    run_until(executor, watcher, g, 5.0, wall_timeout=180)
    damped_before = int(watcher.bridge_report.get("damping_fallbacks", 0))
    g.kill("convex_mpc")
    killed_at = watcher.sim_time()
    run_until(executor, watcher, g, killed_at + 0.1, wall_timeout=60)
    # The last command as the bridge accepted it (its report once it has damped): the watcher may
    # not have the killed process's last commands.
    assert spin_until(executor, lambda: int(watcher.bridge_report.get("damping_fallbacks", 0)) > damped_before, 10.0)
    received = float(watcher.bridge_report["last_command_received_s"])
    damping_start = damping_onset(watcher.joints, received)
    assert damping_start is not None, "the bridge never went to damping"
    assert damping_start - received <= 0.05 + SIM_DT + 1e-6  # 50 ms of sim time (+ the step it is applied over)
    # Hold the sim while the new process boots (its wall-clock start-up time must not decide how
    # long the robot lies in damping), then let it run again.
    set_sim_paused(executor, watcher, True)
    g.restart("convex_mpc")
    set_sim_paused(executor, watcher, False)
    restarted_at = watcher.sim_time()
    watcher.speed = 1.0
    run_until(executor, watcher, g, restarted_at + 6.0, wall_timeout=240)
    assert max(z for t, _, z in watcher.truth if t > restarted_at + 1.0) > 0.24, "did not stand up"
    assert watcher.mean_speed(restarted_at + 5.0, restarted_at + 6.0) > 0.8, "did not walk again"
    assert min(z for t, _, z in watcher.truth if t > restarted_at + 3.0) > 0.18, "fell after restarting"


@pytest.mark.ros
@pytest.mark.parametrize("record", [False, True], ids=["plain_composed", "record_separate"])
def test_bringup_script_leaves_no_process_after_sigterm(rclpy_context, tmp_path, record):
    """The default form (control_chain and gait_policy), and ``--form separate`` (a process a node)
    with --record, which adds the bag recorder, whose bag SIGTERM closes: metadata.yaml, and the
    graph's topics read back with the library; that one in a namespace, the recorder's node too."""
    env = {**os.environ}
    bag = tmp_path / "bag"
    ns = "/a1_3" if record else ""
    extra = ["--form", "separate", "--record", str(bag), "--namespace", ns] if record else []
    proc = subprocess.Popen(["bash", str(ROOT / "scripts" / "bringup.sh"), "--clock", "lockstep", *extra], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    pids = []
    nodes = 5 if record else 2
    deadline = time.monotonic() + 60
    while len(pids) < nodes and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if "started" in line and "(pid " in line:
            pids.append(int(line.split("(pid ")[1].split(",")[0].rstrip(")")))
    assert len(pids) == nodes, f"bring-up did not start {nodes} nodes: {pids}"
    listener = Node("bringup_listener", context=rclpy_context)
    seen = []
    listener.create_subscription(JointState, f"{ns}/joint_states", seen.append, CONTROL_QOS)
    written: dict[str, str] = {}  # the recorder's /diagnostics: messages written per topic
    listener.create_subscription(DiagnosticArray, f"{ns}/diagnostics", lambda m: written.update(
        {kv.key: kv.value for st in m.status if st.name == "bag_recorder" for kv in st.values}), 10)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(listener)
    try:
        assert spin_until(executor, lambda: len(seen) > 10, 60.0), "graph never published"
        if record:
            assert spin_until(executor, lambda: int(written.get(f"{ns}/joint_states", 0)) > 10, 60.0), written
        os.kill(proc.pid, signal.SIGTERM)
        proc.wait(timeout=30)
    finally:
        executor.shutdown()
        listener.destroy_node()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.killpg(pid, 0)  # the node's whole process group is gone
    if record:
        assert (bag / "metadata.yaml").is_file()
        stamps = [t for topic, _, t, _ in read_bag(bag) if topic == f"{ns}/joint_states"]
        assert len(stamps) > 10 and stamps == sorted(stamps)
