"""Benchmark the 2 ms chain's floor: the bridge's three sensor messages out, one command back.

Two processes talk over the real topics, QoS, codecs (a1_interface.wire) and executor
(DirectExecutor) of the graph, with stand-ins for the work: the "bridge" spins ``--bridge-work``
of CPU per step (physics) and publishes the sensors at 500 Hz, the "controller" spins
``--controller-work`` per step and answers /joint_states with a /motor_command. Optionally a third
process burns ``--load`` of a core in 2 ms bursts (the MPC worker's QP solves, a browser, ...),
at ``--load-policy`` (other: SCHED_OTHER; idle: SCHED_IDLE, which any other task preempts).

Reports the round trip (sensors published -> command back) and the share over the budget a
realtime bridge leaves (``--budget``: 2 ms minus its own physics and publishing), i.e. what
graph_realtime.py counts as missed deadlines, without the rest of the graph. How far a real run
is from this floor tells whether a miss is the transport or the work (docs/architecture.md).

Usage: source scripts/env.sh && python benchmarks/transport_chain.py [--seconds 12] [--load 0.5]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time

import numpy as np

PERIOD = 0.002  # [s] the bridge's step


def spin_for(seconds: float) -> None:
    """Busy CPU for ``seconds`` (holding the GIL, as Python physics or control does)."""
    start = time.perf_counter()
    while time.perf_counter() - start < seconds:
        pass


def run_load(fraction: float, seconds: float) -> None:
    """Burn ``fraction`` of one core in 2 ms bursts."""
    burst = 0.002
    period = burst / fraction
    deadline = time.monotonic()
    end = deadline + seconds
    while time.monotonic() < end:
        spin_for(burst)
        deadline += period
        time.sleep(max(deadline - time.monotonic(), 0.0))


def run_node(role: str, seconds: float, work: float) -> None:
    import rclpy
    from a1_common.command import JointCommand
    from a1_common.node_support import DirectExecutor
    from a1_interface.contract import CONTROL_QOS
    from a1_interface.sensors import SensorReadings
    from rclpy.node import Node
    from sensor_msgs.msg import Imu, JointState

    from a1_interface import wire
    from gait_msgs.msg import FootContacts, MotorCommand

    rclpy.init(args=[])
    node = Node(f"transport_chain_{role}")
    executor = DirectExecutor()
    executor.add_node(node)
    if role == "controller":
        pub = node.create_publisher(MotorCommand, "/motor_command", CONTROL_QOS)
        encoder, decode = wire.MotorCommandEncoder(), wire.JointStateDecoder()
        command = JointCommand()

        def on_joints(raw: bytes) -> None:
            spin_for(work)
            stamp = decode(raw).header.stamp
            pub.publish(encoder.encode(command, stamp.sec * 1_000_000_000 + stamp.nanosec))

        node.create_subscription(JointState, "/joint_states", on_joints, CONTROL_QOS, raw=True)
        node.create_subscription(Imu, "/imu/data", lambda raw: None, CONTROL_QOS, raw=True)
        node.create_subscription(FootContacts, "/foot_contacts", lambda raw: None, CONTROL_QOS, raw=True)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_direct_once(0.1)
        return
    encoders = wire.SensorEncoders([f"joint_{i}" for i in range(12)], "base_link", "imu_link")
    pubs = [node.create_publisher(t, topic, CONTROL_QOS) for t, topic in
            ((Imu, "/imu/data"), (FootContacts, "/foot_contacts"), (JointState, "/joint_states"))]
    sent: dict[int, float] = {}
    round_trips: list[float] = []
    lock = threading.Lock()

    def on_command(raw: bytes) -> None:
        stamp_ns = wire.decode_motor_command(raw)[1]
        with lock:
            published = sent.pop(stamp_ns, None)
        if published is not None:
            round_trips.append(time.monotonic() - published)

    node.create_subscription(MotorCommand, "/motor_command", on_command, CONTROL_QOS, raw=True)
    threading.Thread(target=executor.spin, daemon=True).start()
    readings = SensorReadings(0.0, np.zeros(12), np.zeros(12), np.zeros(12), np.array([0.0, 0.0, 0.0, 1.0]),
                              np.zeros(3), np.array([0.0, 0.0, 9.81]), np.ones(4, bool), np.full(4, 30.0))
    time.sleep(2.0)  # discovery
    deadline, steps = time.monotonic(), 0
    end = deadline + seconds
    while time.monotonic() < end:
        spin_for(work)
        joints, imu, contacts = encoders.encode(readings, steps * 2_000_000)
        pubs[0].publish(imu)
        pubs[1].publish(contacts)
        with lock:
            sent[steps * 2_000_000] = time.monotonic()
        pubs[2].publish(joints)
        steps += 1
        deadline += PERIOD
        time.sleep(max(deadline - time.monotonic(), 0.0))
    time.sleep(0.1)
    print(json.dumps({"steps": steps, "round_trips_s": round_trips}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=12.0, help="measurement window [s], in [2, 600]")
    parser.add_argument("--bridge-work", type=float, default=0.0004, help="CPU per step in the bridge [s]")
    parser.add_argument("--controller-work", type=float, default=0.0005, help="CPU per step in the controller [s]")
    parser.add_argument("--budget", type=float, default=0.0013,
                        help="round trip that still makes the next step [s] (default: 2 ms - 0.7 ms of bridge)")
    parser.add_argument("--load", type=float, default=0.0, help="extra load in a third process [cores], in [0, 0.9]")
    parser.add_argument("--load-policy", choices=("other", "idle"), default="other")
    parser.add_argument("--role", choices=("bridge", "controller", "load"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == "load":
        run_load(args.load, args.seconds)
        return
    if args.role:
        run_node(args.role, args.seconds, args.bridge_work if args.role == "bridge" else args.controller_work)
        return
    if not 2.0 <= args.seconds <= 600.0:
        parser.error("--seconds must be in [2, 600]")
    for name in ("bridge_work", "controller_work"):
        if not 0.0 <= getattr(args, name) <= 0.0015:
            parser.error(f"--{name.replace('_', '-')} must be in [0, 0.0015] s")
    if not 0.0 <= args.load <= 0.9:
        parser.error("--load must be in [0, 0.9] cores")
    if not 0.0 < args.budget <= PERIOD:
        parser.error("--budget must be in (0, 0.002] s")

    env = {**os.environ, "ROS_DOMAIN_ID": os.environ.get("ROS_DOMAIN_ID", str(200 + os.getpid() % 30))}
    me = [sys.executable, __file__, "--seconds"]
    common = ["--bridge-work", str(args.bridge_work), "--controller-work", str(args.controller_work)]
    controller = subprocess.Popen([*me, str(args.seconds + 4), *common, "--role", "controller"], env=env)
    load = None
    if args.load > 0:
        load_cmd = [*me, str(args.seconds + 3), "--load", str(args.load), "--role", "load"]
        load = subprocess.Popen((["chrt", "-i", "0"] if args.load_policy == "idle" else []) + load_cmd)
    bridge = subprocess.run([*me, str(args.seconds), *common, "--role", "bridge"], env=env, capture_output=True,
                            text=True, check=True)
    controller.wait(timeout=30)
    if load is not None:
        load.wait(timeout=30)
    result = json.loads(bridge.stdout.strip().splitlines()[-1])
    trips = np.asarray(result["round_trips_s"])
    if trips.size == 0:
        sys.exit("no command came back: is DDS discovery blocked (ROS_LOCALHOST_ONLY, firewall)?")
    figures = {
        "steps": result["steps"], "answered_fraction": trips.size / result["steps"],
        "round_trip_median_s": float(np.median(trips)), "round_trip_p90_s": float(np.percentile(trips, 90)),
        "round_trip_p99_s": float(np.percentile(trips, 99)),
        "over_budget_fraction": float(np.mean(trips > args.budget)), "budget_s": args.budget,
        "bridge_work_s": args.bridge_work, "controller_work_s": args.controller_work,
        "load_cores": args.load, "load_policy": args.load_policy,
    }
    rows = [("steps published", f"{result['steps']}"), ("answered", f"{100 * figures['answered_fraction']:.1f} %"),
            ("round trip median", f"{figures['round_trip_median_s'] * 1e3:.3f} ms"),
            ("round trip p90", f"{figures['round_trip_p90_s'] * 1e3:.3f} ms"),
            ("round trip p99", f"{figures['round_trip_p99_s'] * 1e3:.3f} ms"),
            (f"over the {args.budget * 1e3:.1f} ms budget", f"{100 * figures['over_budget_fraction']:.1f} %"),
            ("extra load", f"{args.load:.2f} cores ({args.load_policy})")]
    for label, value in rows:
        print(f"{label:<32}{value}")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
