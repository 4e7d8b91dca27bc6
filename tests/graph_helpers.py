"""Start the stack's nodes as real processes (the installed executables) for end-to-end tests."""

from __future__ import annotations

import argparse
import itertools
import os
import re
import signal
import socket
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
from a1_bringup.graph import CHAIN_PRIORITY, composed, describe, namespace_remaps
from a1_common.config import load_node_parameters
from a1_common.robot import a1
from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import spin_until
from std_srvs.srv import SetBool

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config"
# From the files the nodes read, so a retuned config cannot leave the tests checking the old values.
DAMPING_KD = a1().damping_kd  # config/a1_robot.yaml [N m s/rad]
MOTOR_TORQUE_LIMIT = a1().motor_torque_limit  # [N m]
SIM_DT = float(load_node_parameters(CONFIG / "a1_sim_bridge.yaml", "sim_bridge")["time_step"])  # [s]
# Probes' subscriptions to the 500 Hz topics: a test process is slower than the nodes, so it keeps a
# deep queue (the graph's own depth 1 would drop samples whenever pytest falls behind).
PROBE_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def executable(pkg: str, exe: str) -> str:
    path = ROOT / "install" / pkg / "lib" / pkg / exe
    assert path.exists(), f"{path} missing: run scripts/setup.sh"
    return str(path)


# Who publishes each topic a fault relay can sit on, and its message type.
TOPICS = {
    "/joint_states": ("sim_bridge", "sensor_msgs/msg/JointState"),
    "/imu/data": ("sim_bridge", "sensor_msgs/msg/Imu"),
    "/foot_contacts": ("sim_bridge", "gait_msgs/msg/FootContacts"),
    "/odom": ("state_estimator", "nav_msgs/msg/Odometry"),
    "/motor_command": ("convex_mpc", "gait_msgs/msg/MotorCommand"),
    "/gait/params": ("gait_policy", "gait_msgs/msg/GaitParams"),
}


class Graph:
    """Processes in their own sessions, logs under ``log_dir``; ``stop`` ends every one of them.

    ``faults`` maps a topic of TOPICS to fault_relay parameters (``name: value``): its publisher
    is remapped to the relay's input and a relay process injects the faults. ``heard_by=(executor,
    node)``: ``start_stack`` holds the simulation at t = 0 (``start_paused``) until ``node`` is
    matched with the graph (``wait_until_matched``), so a test node sees the run from its start and
    its /cmd_vel counts from t = 0; a busy graph can take seconds of its run to match a new
    participant.
    """

    def __init__(self, log_dir: Path, faults: dict[str, dict] | None = None, namespace: str = "",
                 heard_by: tuple[Executor, Node] | None = None) -> None:
        self.log_dir = log_dir
        self.heard_by = heard_by
        self.namespace = namespace  # "": the root namespace; else every node runs in it
        self.procs: dict[str, subprocess.Popen] = {}
        self.commands: dict[str, list[str]] = {}
        self.faults = faults or {}
        self.sim_time = "true"
        self.realtime = False
        self.chain_priority: int | None = None  # the composed chain's SCHED_FIFO priority; None: the description's
        self.publishers = {topic: publisher for topic, (publisher, _) in TOPICS.items()}
        unknown = set(self.faults) - set(TOPICS)
        assert not unknown, f"no fault relay for {unknown}; topics: {sorted(TOPICS)}"

    def start(self, name: str, pkg: str, exe: str, *args: str, nodes: tuple[str, ...] = ()) -> subprocess.Popen:
        """Start process ``name`` running the rclpy ``nodes`` (default: the one node ``name``)."""
        # Node-scoped remaps: in a composed process only the publishing node's topic moves.
        remaps = [a for topic in self.faults if self.publishers[topic] in (nodes or (name,))
                  for a in ("-r", f"{self.publishers[topic]}:{topic}:=/fault_in{topic}")]
        remaps += namespace_remaps(self.namespace)
        if remaps:
            args = (*args, *([] if "--ros-args" in args else ["--ros-args"]), *remaps)
        self.commands[name] = [executable(pkg, exe), *args]
        return self.restart(name)

    def restart(self, name: str) -> subprocess.Popen:
        """Start ``name`` again with the command line it had (after a kill)."""
        log = open(self.log_dir / f"{name}.log", "a")
        proc = subprocess.Popen(self.commands[name], stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        self.procs[name] = proc
        return proc

    def start_stack(self, clock: str = "lockstep", lockstep_timeout: float = 0.5, *controller_params: str,
                    policy_params: tuple[str, ...] = (), real_time_factor: float = 1.0,
                    composed_chain: bool = False) -> None:
        """The graph a1_bringup.graph describes for ``clock`` with the sim bridge (and any fault
        relays); ``controller_params`` and ``policy_params`` are extra ``name:=value`` (with
        ``embedded_estimator:=true`` no state_estimator process starts, and the controller
        publishes /odom); ``composed_chain``: bridge, estimator and controller as one
        control_chain process; held until the graph's ``heard_by`` node is matched, if it has one."""
        self.realtime = clock == "realtime"
        embedded = self.realtime or "embedded_estimator:=true" in controller_params
        self.sim_time = "true" if clock == "lockstep" else "false"
        if embedded:
            self.publishers["/odom"] = "convex_mpc"
        for topic, params in self.faults.items():
            message_type = TOPICS[topic][1]
            name = "fault_relay" + topic.replace("/", "_")
            relay = ["--ros-args", "-r", f"__node:={name}", "-p", f"topic:={topic}",
                     "-p", f"message_type:={message_type}",
                     *[a for key, value in params.items() for a in ("-p", f"{key}:={value}")]]
            self.start(name, "fault_injection", "fault_relay", *relay)
        bridge = {"sim_bridge": {"lockstep_timeout": lockstep_timeout, "real_time_factor": real_time_factor,
                                 "flight_recorder_dir": self.log_dir,  # a fall: its last seconds, see fall_records
                                 "start_paused": self.heard_by is not None}}
        self._start_described(describe(clock, "sim", embedded_estimator=embedded), bridge, controller_params,
                              policy_params, composed_chain)
        if self.heard_by is not None:
            executor, node = self.heard_by
            wait_until_matched(executor, node)
            set_sim_paused(executor, node, False, self.namespace)

    def start_hil(self, clock: str = "lockstep", packet_loss: float = 0.0, lockstep_timeout: float = 0.5,
                  composed_chain: bool = False, policy_params: tuple[str, ...] = (),
                  controller_params: tuple[str, ...] = (), robot_started: Callable[[], object] | None = None) -> None:
        """The graph a1_bringup.graph describes for the virtual bridge (hw_bridge <-UDP-> virtual_a1)
        on a free loopback port; ``composed_chain``: hw_bridge and controller in one process.
        ``robot_started()`` runs once virtual_a1 is up, before anything talks to it (so before its
        first tick in lockstep): e.g. a watcher waiting to hear its ground truth from t = 0."""
        port = free_udp_port()
        bridge = {"virtual_a1": {"port": port, "packet_loss": packet_loss, "loss_seed": 7, "settle_time": 0.0},
                  "hw_bridge": {"robot_port": port, "local_port": 0, "state_timeout": 0.02,
                                "lockstep_timeout": lockstep_timeout}}
        self.realtime = clock == "realtime"
        self._start_described(describe(clock, "virtual"), bridge, controller_params, policy_params, composed_chain,
                              after={"virtual_a1": robot_started} if robot_started else {})

    def _start_described(self, nodes: list, bridge: dict[str, dict], controller_params: tuple[str, ...],
                         policy_params: tuple[str, ...], composed_chain: bool,
                         after: dict[str, Callable[[], object]] | None = None) -> None:
        """Start a graph description with the ``bridge`` nodes' extra parameters and the controller's
        and policy's ``name:=value`` ones; ``composed_chain``: in the composed form; ``after``:
        process name -> what to run once it is started, before the next one starts."""
        after = after or {}
        extra = {**bridge, "convex_mpc": dict(p.split(":=", 1) for p in controller_params),
                 "gait_policy": dict(p.split(":=", 1) for p in policy_params)}
        for node in nodes:
            node.params.update({k: str(v) for k, v in extra.get(node.name, {}).items()})
            if node.priority and self.chain_priority is not None:
                node.priority = self.chain_priority
        processes = composed(nodes) if composed_chain else nodes
        names = [p.name for p in processes]
        assert set(after) <= set(names), f"after: {sorted(set(after) - set(names))} not in {names}"
        for process in processes:
            self.start(process.name, process.package, process.executable, *process.arguments(CONFIG),
                       nodes=process.nodes)
            if process.name in after:
                after[process.name]()

    def start_controller(self, *params: str) -> None:
        """The controller as the graph describes it for this graph's clock (after a kill, or next to
        a hand-started bridge), with extra ``name:=value`` parameters."""
        spec = next(n for n in describe("realtime" if self.realtime else "lockstep", "sim",
                                              embedded_estimator=self.realtime) if n.name == "convex_mpc")
        spec.params.update(p.split(":=", 1) for p in params)
        self.start(spec.name, spec.package, spec.executable, *spec.arguments(CONFIG))

    def start_velocity_ramp(self, speed: float = 2.5, acceleration: float = 1.0, start_delay: float = 1.5) -> None:
        """The demo's command (scripts/demo.sh): velocity_command on sim time, 0 -> ``speed`` [m/s] at
        ``acceleration`` [m/s^2] from ``start_delay`` [s] of sim time (after the stand-up), then held."""
        self.start("velocity_command", "gait_policy_node", "velocity_command", "--ros-args",
                   "-p", "use_sim_time:=true", "-p", "profile:=ramp", "-p", f"speed:={speed}",
                   "-p", f"acceleration:={acceleration}", "-p", f"start_delay:={start_delay}", "-p", "start_time:=0.0")

    def kill(self, name: str) -> None:
        proc = self.procs.pop(name)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)

    def alive(self) -> dict[str, bool]:
        return {name: proc.poll() is None for name, proc in self.procs.items()}

    def fall_records(self) -> list[Path]:
        """The sim bridge's flight recorder files, one per fall, each drawn next to it as a .png and
        named on stdout."""
        from a1_sim_bridge import flight_recorder

        records = sorted(self.log_dir.glob("fall_*.npz"))
        for path in records:
            flight_recorder.plot(flight_recorder.load(path), path.with_suffix(".png"), title=path.name)
            print(f"fall: flight recorder {path} (plot {path.with_suffix('.png')})")
        return records

    def log(self, name: str) -> str:
        return (self.log_dir / f"{name}.log").read_text(errors="replace")

    def stop(self) -> None:
        for proc in self.procs.values():
            try:
                os.killpg(proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        for proc in self.procs.values():
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
        self.procs.clear()


def damping_onset(joints: list[tuple[float, np.ndarray, np.ndarray]], after: float) -> float | None:
    """Sim time of the first step after ``after`` whose applied torques are damping's, or None.

    ``joints``: (stamp, joint velocity, joint effort) of /joint_states. Damping's signature: the
    torque applied over a step is -kd * (the joint velocity at its start), clipped to the motor limit,
    so only pairs of consecutive steps (stamps one SIM_DT apart) are judged; a probe that missed
    messages cannot be mistaken for, or mask, damping.
    """
    for (t0, dq0, _), (t1, _, tau1) in itertools.pairwise(joints):
        consecutive = abs(t1 - t0 - SIM_DT) < 0.25 * SIM_DT
        if t1 > after and consecutive and np.allclose(
                tau1, np.clip(-DAMPING_KD * dq0, -MOTOR_TORQUE_LIMIT, MOTOR_TORQUE_LIMIT), atol=1e-6):
            return t1
    return None


# rclpy's own endpoints of a node (/parameter_events always, /clock with use_sim_time): not the test's.
_HOUSEKEEPING_TOPICS = {"/parameter_events", "/clock"}
# The graph's nodes that must hear a test's /cmd_vel before its run counts (a1_bringup.graph: the
# controller ramps to it, the gait policy observes it).
CMD_VEL_SUBSCRIBERS = ("convex_mpc", "gait_policy")


def wait_until_matched(executor, node: Node, timeout: float = 60.0) -> None:
    """Spin until each of ``node``'s subscriptions has a matched publisher and each of its
    publishers is matched with a subscriber (a /cmd_vel publisher with CMD_VEL_SUBSCRIBERS'
    subscriptions, by node name); fail naming the unmatched topics."""
    wanted = {"cmd_vel": CMD_VEL_SUBSCRIBERS}  # by relative topic name

    def unmatched() -> list[str]:
        missing = [s.topic_name for s in node.subscriptions
                   if s.topic_name not in _HOUSEKEEPING_TOPICS and s.get_publisher_count() == 0]
        for p in node.publishers:
            if p.topic_name in _HOUSEKEEPING_TOPICS:
                continue
            names = wanted.get(p.topic_name.rsplit("/", 1)[-1], ())
            heard = {i.node_name for i in node.get_subscriptions_info_by_topic(p.topic_name)}
            if p.get_subscription_count() < max(1, len(names)) or not set(names) <= heard:
                missing.append(p.topic_name)
        return missing
    assert spin_until(executor, lambda: not unmatched(), timeout), f"{node.get_name()}: not matched on {unmatched()}"


def set_sim_paused(executor, node, paused: bool, namespace: str = "") -> float:
    """Pause or resume the sim bridge (its ~/pause service; in ``namespace``), e.g. while a killed
    node restarts; returns the sim time it holds at or resumes from [s] (from the service's reply)."""
    client = node.create_client(SetBool, f"{namespace}/sim_bridge/pause")
    assert client.wait_for_service(timeout_sec=10.0)
    future = client.call_async(SetBool.Request(data=paused))
    assert spin_until(executor, future.done, 10.0) and future.result().success
    node.destroy_client(client)
    reply = re.fullmatch(r"(?:paused at|running from) (\S+) s", future.result().message)
    assert reply, f"unexpected ~/pause reply: {future.result().message!r}"
    return float(reply.group(1))


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_until(executor, watcher, graph: Graph, sim_time: float, wall_timeout: float = 240.0) -> None:
    """Spin until ``watcher.sim_time()`` reaches ``sim_time``; fail naming dead nodes (with their
    logs' tails) or, on a timeout, the watcher's last /diagnostics if it records them."""
    ok = spin_until(executor, lambda: watcher.sim_time() >= sim_time or not all(graph.alive().values()),
                    wall_timeout)
    dead = [name for name, alive in graph.alive().items() if not alive]
    assert not dead, f"nodes died: {dead}\n" + "\n".join(graph.log(n)[-2000:] for n in dead)
    assert ok, (f"sim reached only {watcher.sim_time():.2f} s of {sim_time} s in {wall_timeout} s wall; "
                f"last /diagnostics: {getattr(watcher, 'diagnostics', 'not recorded')}")


# Node resources, worker processes included (benchmarks/graph_realtime.py, benchmarks/soak.py).
def process_tree(pid: int) -> list[int]:
    """``pid`` and its live descendants (a node's worker processes belong to the node)."""
    tree, i = [pid], 0
    while i < len(tree):
        try:
            for task in Path(f"/proc/{tree[i]}/task").iterdir():
                tree += [int(c) for c in (task / "children").read_text().split()]
        except OSError:  # gone meanwhile
            pass
        i += 1
    return tree


def rss_mib(pid: int) -> float | None:
    """Resident memory of ``pid`` and its descendants [MiB] from /proc, None if ``pid`` is gone."""
    total = None
    for p in process_tree(pid):
        try:
            lines = Path(f"/proc/{p}/status").read_text().splitlines()
        except OSError:
            continue
        kib = next((int(line.split()[1]) for line in lines if line.startswith("VmRSS:")), 0)
        total = (total or 0.0) + kib / 1024.0
    return total


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of ``pid`` and its live descendants [s] (0 once they are gone)."""
    total = 0.0
    for p in process_tree(pid):
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


# Scheduling experiments on realtime graphs (benchmarks/graph_realtime.py, benchmarks/soak.py);
# why: docs/architecture.md, "Realtime on a small computer".
# probe: the benchmark itself; virtual_a1: the robot's own loop (a real A1 runs it on its own computer)
FIFO_TARGETS = ("sim_bridge", "convex_mpc", "control_chain", "gait_policy", "virtual_a1", "probe")
DDS_TRANSPORTS = ("DEFAULT", "UDPv4", "SHM", "LARGE_DATA")


def add_scheduling_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--fifo", action="append", default=[], metavar="NODE=PRIORITY",
                        help=f"run NODE ({', '.join(FIFO_TARGETS)}) at SCHED_FIFO PRIORITY 1-99 (repeatable)")
    parser.add_argument("--chain-priority", type=int, default=None, metavar="N",
                        help=f"SCHED_FIFO priority of the composed chain (default: bring-up's, {CHAIN_PRIORITY} in "
                             "realtime; 0: normal scheduling)")
    parser.add_argument("--dds-transports", choices=DDS_TRANSPORTS,
                        help="Fast DDS builtin transports of every process (default: shared memory + UDP); "
                             "needs ROS_AUTOMATIC_DISCOVERY_RANGE other than LOCALHOST")
    parser.add_argument("--real-time-factor", type=float, default=1.0,
                        help="sim seconds per wall second, (0, 1]: under 1 gives every node more wall time per step")


def fifo_priority(pid: int) -> int:
    """The SCHED_FIFO priority of process ``pid``'s main thread, 0 if it is not FIFO (what a
    benchmark reports: the priority a process got, not the one asked for)."""
    return os.sched_getparam(pid).sched_priority if os.sched_getscheduler(pid) == os.SCHED_FIFO else 0


def scheduling_from_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> dict[str, int]:
    """{node: FIFO priority} from ``--fifo NODE=PRIORITY`` (a bad one ends the run with a clear
    message); sets ``--dds-transports`` in the environment, which every node started later inherits."""
    if not 0.0 < args.real_time_factor <= 1.0:
        parser.error(f"--real-time-factor must be in (0, 1], got {args.real_time_factor}")
    if args.chain_priority is not None and not 0 <= args.chain_priority <= 99:
        parser.error(f"--chain-priority must be in [0, 99], got {args.chain_priority}")
    fifo = {}
    for spec in args.fifo:
        name, _, value = spec.partition("=")
        if name not in FIFO_TARGETS:
            parser.error(f"--fifo {spec!r}: NODE must be one of {', '.join(FIFO_TARGETS)}")
        try:
            priority = int(value)
        except ValueError:
            priority = 0
        if not 1 <= priority <= 99:
            parser.error(f"--fifo {spec!r}: PRIORITY must be an integer in [1, 99]")
        fifo[name] = priority
    if "control_chain" in fifo:  # control_chain sets its own priority (--realtime-priority): one source
        priority = fifo.pop("control_chain")
        if args.chain_priority not in (None, priority):
            parser.error(f"--fifo control_chain={priority} and --chain-priority {args.chain_priority} disagree")
        args.chain_priority = priority
    if args.dds_transports:
        # With LOCALHOST discovery (scripts/env.sh's default) rmw_fastrtps sets its own transports,
        # shared memory included, and ignores this variable: the run would measure the default.
        if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "") == "LOCALHOST":
            parser.error("--dds-transports has no effect with ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (rmw_fastrtps "
                         "then picks its transports itself); source scripts/env.sh with "
                         "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET to use it")
        os.environ["FASTDDS_BUILTIN_TRANSPORTS"] = args.dds_transports
    return fifo


def apply_fifo(graph: Graph, fifo: dict[str, int]) -> None:
    """Right after ``start_stack``: each node's process at its priority while it still imports, before
    it creates its DDS threads, so all its threads inherit it. The probe (this process) is set here
    too, after the nodes were started, so none of them inherited its priority. Must run before this
    process calls rclpy.init."""
    for name, priority in fifo.items():
        try:
            os.sched_setscheduler(0 if name == "probe" else graph.procs[name].pid, os.SCHED_FIFO,
                                  os.sched_param(priority))
        except PermissionError:
            graph.stop()
            raise SystemExit(f"--fifo: SCHED_FIFO {priority} is not permitted here "
                             "(needs root, CAP_SYS_NICE or an rtprio limit)") from None
