"""Benchmark the simulation core and the sim bridge node on this machine.

Measures (1) the cost of one A1Sim.step in-process (median, p99), (2) the /joint_states rate the
sim bridge node achieves in realtime mode (target 500 Hz) and (3) its lockstep throughput with
joint_hold answering every step from another process. Prints a table, then one JSON line.

Usage: source scripts/env.sh && python benchmarks/sim_bridge_rate.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def sim_step_cost(steps: int) -> tuple[float, float]:
    from a1_common.command import JointCommand
    from a1_sim_bridge.sim import A1Sim

    with A1Sim() as sim:
        hold = JointCommand.hold(sim.robot)
        costs = np.empty(steps)
        for i in range(steps):
            t0 = time.perf_counter()
            sim.step(hold)
            costs[i] = time.perf_counter() - t0
    return float(np.median(costs)), float(np.percentile(costs, 99))


def executable(pkg: str, exe: str) -> str:
    path = ROOT / "install" / pkg / "lib" / pkg / exe
    if not path.exists():
        sys.exit(f"{path} missing: run scripts/setup.sh first")
    return str(path)


def node_rate(clock_mode: str, seconds: float) -> tuple[float, float]:
    """Start sim_bridge (+ joint_hold) as processes; return (joint_states rate [Hz], sim/wall ratio)."""
    import rclpy
    from a1_interface.contract import CONTROL_QOS
    from a1_interface.conversions import ns_from_stamp
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    params = ["--ros-args", "--params-file", str(ROOT / "config" / "a1_sim_bridge.yaml"),
              "-p", f"clock_mode:={clock_mode}"]
    procs = [subprocess.Popen([executable("a1_sim_bridge", "sim_bridge"), *params], start_new_session=True,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL),
             subprocess.Popen([executable("a1_sim_bridge", "joint_hold")], start_new_session=True,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    rclpy.init()
    node = Node("rate_probe")
    arrivals: list[tuple[float, int]] = []
    node.create_subscription(JointState, "/joint_states",
                             lambda m: arrivals.append((time.monotonic(), ns_from_stamp(m.header.stamp))),
                             CONTROL_QOS)
    try:
        deadline = time.monotonic() + 60.0
        while len(arrivals) < 200 and time.monotonic() < deadline:  # start-up and discovery
            rclpy.spin_once(node, timeout_sec=0.05)
        start = len(arrivals)
        end_time = time.monotonic() + seconds
        while time.monotonic() < end_time:
            rclpy.spin_once(node, timeout_sec=0.05)
    finally:
        node.destroy_node()
        rclpy.shutdown()
        for p in procs:
            os.killpg(p.pid, signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
    window = arrivals[start:]
    if len(window) < 2:
        return 0.0, 0.0
    wall = window[-1][0] - window[0][0]
    sim = (window[-1][1] - window[0][1]) * 1e-9
    return (len(window) - 1) / wall, sim / wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="measurement window per mode [s]")
    parser.add_argument("--steps", type=int, default=5000, help="in-process sim steps to time")
    args = parser.parse_args()
    if not 1.0 <= args.seconds <= 600.0:
        parser.error("--seconds must be in [1, 600]")
    median, p99 = sim_step_cost(args.steps)
    rt_rate, rt_ratio = node_rate("realtime", args.seconds)
    ls_rate, ls_ratio = node_rate("lockstep", args.seconds)
    rows = [
        ("A1Sim.step median", f"{median * 1e3:.3f} ms"),
        ("A1Sim.step p99", f"{p99 * 1e3:.3f} ms"),
        ("realtime /joint_states rate (target 500 Hz)", f"{rt_rate:.1f} Hz"),
        ("realtime sim time / wall time", f"{rt_ratio:.3f}"),
        ("lockstep /joint_states rate (with joint_hold)", f"{ls_rate:.1f} Hz"),
        ("lockstep sim time / wall time", f"{ls_ratio:.3f}"),
    ]
    width = max(len(r[0]) for r in rows)
    print(f"{'figure':<{width}}  value\n{'-' * width}  -----")
    for name, value in rows:
        print(f"{name:<{width}}  {value}")
    print(json.dumps({
        "sim_step_median_s": median, "sim_step_p99_s": p99,
        "realtime_joint_states_rate_hz": rt_rate, "realtime_sim_to_wall_ratio": rt_ratio,
        "lockstep_joint_states_rate_hz": ls_rate, "lockstep_sim_to_wall_ratio": ls_ratio,
    }))


if __name__ == "__main__":
    main()
