"""Benchmark the whole node graph in realtime mode: control rate, missed deadlines, latency.

Starts the realtime graph (config/convex_mpc_realtime.yaml: the estimator embedded, the MPC
asynchronous) in the form asked: ``composed`` (the 500 Hz chain, sim bridge and controller, as one
control_chain process: what scripts/bringup.sh starts in realtime), ``separate`` (one process a
node) or ``both`` (one after the other, side by side in one table: the machine's noise hits both).
It ramps the command as the demo does (0 -> ``--top-speed`` at ``--acceleration``, then held) and
reads the sim bridge's own counts from /diagnostics for ``--seconds`` of wall time (this probe
subscribes to nothing else, so it takes no CPU from the graph it measures):
- control rate: /motor_command messages the bridge accepted per second (goal 500 Hz);
- missed deadlines: share of the bridge's 2 ms steps applied with no new command since the step
  before (the robot then gets the previous command again), or, with the sim bridge, with one sent
  (DDS source time) only after that step's deadline (since 2026-12-05; before, a command that came
  late but before the next step counted as on time), and periods the bridge skipped after falling
  over 0.1 s behind (a whole-process stall; counted since the twelfth session of 2026-12-05);
- longest command gap: the longest time between two steps with a new command (2 ms: none missed);
- sensor-to-command latency: wall time from the bridge publishing step k's sensors to it receiving
  the command stamped k; the median of the per-second medians, and the worst per-second p99;
- the bridge's achieved step rate, and whether the robot stayed up (lowest base height);
- each process's CPU use over the window, in cores, its worker processes included (from /proc:
  where the 2 cores go).
``--bridge virtual``: the hardware bridge against the virtual A1 over UDP (the robot process
apart; composed: hw_bridge and controller in one process), read from the hardware bridge's counts.
``--joiners N`` starts and stops a separate subscriber process on /joint_states N times during the
window (a user's ``ros2 topic echo``: a new DDS participant joining and leaving the graph).
Goals (issue 26): under 1 % missed deadlines and latency p99 under 1.5 ms for 60 s at full speed,
no command gap over 20 ms while subscribers come and go, no fall. Prints one line a second (the
bridge's misses, longest gap and watchdog dampings in that second, the controller's state, step and
QP medians, MPC plan delay and stopgap steps), a table, then JSON.

Scheduling experiments, without editing code (docs/architecture.md, "Realtime on a small computer"):
- ``--fifo sim_bridge=50`` (repeatable; ``control_chain`` is the composed process, ``probe`` this
  one) puts a process at SCHED_FIFO right after it starts, before it creates its DDS threads, so all
  its threads inherit the priority;
- ``--dds-transports UDPv4`` sets Fast DDS's FASTDDS_BUILTIN_TRANSPORTS for every process (the
  default uses shared memory between processes on one machine). rmw_fastrtps ignores it with
  ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST (scripts/env.sh's default), so the option refuses to run
  there: source env.sh with ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET to use it.

Usage: source scripts/env.sh && python benchmarks/graph_realtime.py [--seconds 60] [--form both] [--joiners 10]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from graph_helpers import (  # noqa: E402
    Graph,
    add_scheduling_options,
    apply_fifo,
    cpu_seconds,
    fifo_priority,
    scheduling_from_args,
)

FORMS = ("composed", "separate")
JOINER = """
import sys, time, rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState
rclpy.init()
node = Node("echo_joiner")
node.create_subscription(JointState, "/joint_states", lambda m: None, 10)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
"""


def command_speed(t: float, top_speed: float, acceleration: float) -> float:
    """The demo's profile: from 0 at ``acceleration`` [m/s^2] to ``top_speed`` [m/s], then held."""
    return min(top_speed, acceleration * t)


def measure(form: str, args: argparse.Namespace, fifo: dict[str, int]) -> dict:
    """One realtime graph in ``form``, measured over ``args.seconds``; its figures."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Twist
    from rclpy.node import Node

    graph = Graph(Path(tempfile.mkdtemp(prefix=f"graph_realtime_{form}_")))
    policy = (f"policy:={args.policy}",)
    graph.chain_priority = args.chain_priority
    if args.bridge == "sim":
        graph.start_stack("realtime", 0.5, *args.controller_param, real_time_factor=args.real_time_factor,
                          policy_params=policy, composed_chain=form == "composed")
    else:  # hw_bridge <-UDP-> virtual_a1: the hardware bridge's own counts, the robot's lowest base
        graph.start_hil("realtime", composed_chain=form == "composed", policy_params=policy,
                        controller_params=tuple(args.controller_param))
    apply_fifo(graph, fifo)
    rclpy.init(args=[])  # not sys.argv: --controller-param values are no ROS arguments
    node = Node("realtime_probe")
    reports: list[dict[str, str]] = []
    controller: dict[str, str] = {}
    started = time.monotonic()

    robot: dict[str, str] = {}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if status.name == "convex_mpc":
                controller.update(values)
            elif status.name == "virtual_a1":
                robot.update(values)
            elif status.name == "a1_hw_bridge" and "sends" in values:  # as the sim bridge names them
                values = {**values, "steps": values["sends"], "deadline_periods": values["sends"],
                          "uncommanded_steps": values["uncommanded_sends"],
                          "lowest_base_height_m": robot.get("lowest_base_height_m", "n/a")}
                status.name = "a1_sim_bridge"
            if status.name == "a1_sim_bridge":
                if reports:  # one line a second: where a run goes wrong, and when
                    periods = int(values["deadline_periods"]) - int(reports[-1]["deadline_periods"])
                    missed = int(values["uncommanded_steps"]) - int(reports[-1]["uncommanded_steps"])
                    damped = int(values["damping_fallbacks"]) - int(reports[-1]["damping_fallbacks"])
                    share = 100 * missed / max(periods, 1)
                    print(f"{form} t={time.monotonic() - started:5.1f} s  missed {share:5.1f} %"
                          f"  gap {values['longest_command_gap_ms']:>3} ms  watchdog damped {damped}x  lowest base "
                          f"{values['lowest_base_height_m']} m  controller {controller.get('state', '?')}, step "
                          f"median {controller.get('step_median_ms', '?')} ms, QP median "
                          f"{controller.get('qp_solve_median_ms', '?')} ms, plan delay "
                          f"{controller.get('mpc_plan_delay_median_ms', '?')} ms, stopgap steps "
                          f"{controller.get('mpc_stopgap_steps', '?')}, gait "
                          f"{controller.get('stepping_frequency_hz', '?')} Hz "
                          f"swing {controller.get('swing_ratio', '?')}",
                          flush=True)
                reports.append(values)

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    cmd_pub = node.create_publisher(Twist, "/cmd_vel", 10)
    joiners: list[subprocess.Popen] = []
    try:
        deadline = time.monotonic() + 60
        # Start-up, discovery, stand-up: until the bridge has been commanded for a whole second.
        while time.monotonic() < deadline and not (
                reports and int(reports[-1]["commanded_steps_window"]) > 0 and len(reports) >= 3):
            rclpy.spin_once(node, timeout_sec=0.05)
        first = len(reports)
        start = time.monotonic()
        cpu_start = {name: cpu_seconds(proc.pid) for name, proc in graph.procs.items()}
        chain = graph.procs.get("control_chain")
        chain_priority = fifo_priority(chain.pid) if chain is not None else None
        # Joiners: each lives 2 s, started evenly over the window after the ramp's first 2 s.
        join_at = list(np.linspace(2.0, args.seconds - 3.0, args.joiners)) if args.joiners else []
        last_cmd = 0.0
        while time.monotonic() - start < args.seconds:
            rclpy.spin_once(node, timeout_sec=0.05)
            now = time.monotonic()
            if now - last_cmd > 0.1:
                msg = Twist()
                msg.linear.x = command_speed(now - start, args.top_speed, args.acceleration)
                cmd_pub.publish(msg)
                last_cmd = now
            if join_at and now - start >= join_at[0]:
                join_at.pop(0)
                joiners.append(subprocess.Popen([sys.executable, "-c", JOINER, "2.0"], stdout=subprocess.DEVNULL,
                                                stderr=subprocess.DEVNULL))
        window_reports = reports[first:]
        cpu = {name: (cpu_seconds(proc.pid) - cpu_start[name]) / (time.monotonic() - start)
               for name, proc in graph.procs.items()}
        alive = graph.alive()
    finally:
        for proc in joiners:
            proc.wait(timeout=30)
        node.destroy_node()
        rclpy.try_shutdown()  # SIGTERM may have shut the context down already
        graph.stop()
    if len(window_reports) < 2:
        sys.exit(f"too few /diagnostics from the sim bridge ({len(window_reports)}); logs in {graph.log_dir}")
    if not all(alive.values()):
        sys.exit(f"{form}: nodes died: {[k for k, v in alive.items() if not v]} (logs in {graph.log_dir})")
    a, b = window_reports[0], window_reports[-1]
    window = float(len(window_reports) - 1)  # the bridge reports once a second
    steps = int(b["steps"]) - int(a["steps"])
    periods = int(b["deadline_periods"]) - int(a["deadline_periods"])  # steps, and any the bridge skipped
    medians = [float(r["latency_median_ms"]) * 1e-3 for r in window_reports[1:] if r["latency_median_ms"] != "n/a"]
    p99s = [float(r["latency_p99_ms"]) * 1e-3 for r in window_reports[1:] if r["latency_p99_ms"] != "n/a"]
    heights = [float(r["lowest_base_height_m"]) for r in window_reports
               if r["lowest_base_height_m"] not in ("n/a", "inf")]
    return {
        "form": form, "window_s": window, "bridge_step_rate_hz": steps / window,
        "control_rate_hz": (int(b["commands_accepted"]) - int(a["commands_accepted"])) / window,
        "missed_deadline_fraction": (int(b["uncommanded_steps"]) - int(a["uncommanded_steps"])) / max(periods, 1),
        "longest_command_gap_s": max(float(r["longest_command_gap_ms"]) for r in window_reports[1:]) * 1e-3,
        "sensor_to_command_latency_median_s": float(np.median(medians)) if medians else None,
        "sensor_to_command_latency_p99_s": max(p99s) if p99s else None,
        "lowest_base_height_m": min(heights) if heights else None,
        "joiners": args.joiners,
        **{f"cpu_{name}_cores": share for name, share in cpu.items()},
        "fall_records": [str(p) for p in graph.fall_records()],
        "control_chain_fifo_priority": chain_priority,  # as applied (0: normal scheduling)
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="measurement window, wall time [s]")
    parser.add_argument("--form", choices=(*FORMS, "both"), default="composed",
                        help="composed (bring-up's realtime default), separate (a process a node), or both")
    parser.add_argument("--bridge", choices=("sim", "virtual"), default="sim",
                        help="sim: the sim bridge; virtual: the hardware bridge and a virtual A1 over UDP")
    parser.add_argument("--top-speed", type=float, default=2.5, help="commanded speed held after the ramp [m/s]")
    parser.add_argument("--acceleration", type=float, default=1.0, help="of the command's ramp [m/s^2]")
    parser.add_argument("--joiners", type=int, default=0,
                        help="start and stop a /joint_states subscriber process this many times in the window")
    parser.add_argument("--policy", default="learned",
                        help="gait_policy's policy: learned (its default), scheduled, a hand-tuned gait, or a .npz")
    parser.add_argument("--controller-param", action="append", default=[], metavar="NAME:=VALUE",
                        help="extra convex_mpc parameter, e.g. embedded_estimator:=true (repeatable)")
    add_scheduling_options(parser)
    args = parser.parse_args()
    if not 5.0 <= args.seconds <= 3600.0:
        parser.error("--seconds must be in [5, 3600]")
    if not 0.0 <= args.top_speed <= 3.0:
        parser.error(f"--top-speed must be in [0, 3] m/s, got {args.top_speed}")
    if not 0.0 < args.acceleration <= 5.0:
        parser.error(f"--acceleration must be in (0, 5] m/s^2, got {args.acceleration}")
    if not 0 <= args.joiners <= max(0, int((args.seconds - 5.0) / 2.0)):
        parser.error(f"--joiners must be in [0, (seconds - 5) / 2] = [0, {max(0, int((args.seconds - 5) / 2))}]")
    fifo = scheduling_from_args(parser, args)
    os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
    results = [measure(form, args, fifo) for form in (FORMS if args.form == "both" else (args.form,))]

    def row(label: str, key: str, fmt) -> tuple[str, ...]:
        return (label, *(fmt(r[key]) if r.get(key) is not None else "n/a" for r in results))

    rows = [
        ("form", *(r["form"] for r in results)),
        row("window (bridge reports)", "window_s", lambda v: f"{v:.0f} s"),
        row("bridge step rate", "bridge_step_rate_hz", lambda v: f"{v:.1f} Hz"),
        row("control rate (commands accepted)", "control_rate_hz", lambda v: f"{v:.1f} Hz"),
        row("missed deadlines", "missed_deadline_fraction", lambda v: f"{100 * v:.2f} %"),
        row("longest command gap", "longest_command_gap_s", lambda v: f"{v * 1e3:.0f} ms"),
        row("sensor-to-command latency median", "sensor_to_command_latency_median_s", lambda v: f"{v * 1e3:.2f} ms"),
        row("sensor-to-command latency p99 (worst 1 s)", "sensor_to_command_latency_p99_s",
            lambda v: f"{v * 1e3:.2f} ms"),
        row("lowest base height", "lowest_base_height_m", lambda v: f"{v:.3f} m"),
        *(row(f"CPU of {key[4:-6]}", key, lambda v: f"{v:.2f} cores")
          for key in dict.fromkeys(k for r in results for k in r if k.startswith("cpu_"))),
    ]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        print("  ".join(f"{cell:<{w}}" for cell, w in zip(r, widths, strict=True)))
    print(json.dumps({
        "forms": results, "bridge": args.bridge, "policy": args.policy, "top_speed_mps": args.top_speed,
        "acceleration_mps2": args.acceleration,
        "fifo_priorities": fifo, "dds_transports": args.dds_transports or "fastdds-default",
        "real_time_factor": args.real_time_factor,
    }))


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    main()
