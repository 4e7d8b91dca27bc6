"""Benchmark the lockstep graph's pace: sim seconds per wall second on the demo's profile, per form.

Starts the lockstep graph (sim bridge, estimator, controller, gait policy and the demo's
velocity_command ramp: 0 -> ``--top-speed`` at 1 m/s^2 from t = 1.5 s) in each variant asked, one
after the other and ``--repeats`` times in turn (the machine's pace drifts: alternating puts the
drift on every variant alike), and reads the sim bridge's own /diagnostics once a second of wall
time (this probe subscribes to nothing else). Per run: the wall time the graph took for ``--sim-seconds``
of sim time from the first commanded step, the pace (sim s / wall s; the demo's goal in issue 26
is at least 1.0), the lowest base height, and each process's CPU in cores. Variants:
- ``composed``: the bridge, estimator and controller in one control_chain process (the demo's form);
- ``separate``: a process a node;
- ``embedded``: composed, with the estimator inside the controller node and /odom every 10 steps
  (in lockstep the controller then acts on the same estimates as with the estimator node).
- ``lean``: ``embedded``, the estimate updated after the command and the MPC every 5 steps, as the
  realtime overlay (config/convex_mpc_realtime.yaml) has them: not the trained controller.
``--record`` adds the demo's bag recorder (every topic, its own process) to each run.

Usage: source scripts/env.sh && python benchmarks/lockstep_pace.py [--variants composed embedded] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from graph_helpers import Graph, cpu_seconds  # noqa: E402

VARIANTS = {  # name: (composed, extra controller parameters)
    "composed": (True, ()),
    "separate": (False, ()),
    "embedded": (True, ("embedded_estimator:=true", "odom_every_steps:=10")),
    # The realtime overlay's step in lockstep: not what the policy was trained with (the MPC every
    # step), so never the demo's; it shows how far the chain's own work is from 2 ms a step.
    "lean": (True, ("embedded_estimator:=true", "odom_every_steps:=10", "estimate_after_command:=true",
                    "mpc_period_steps:=5")),
}
RAMP_START = 1.5  # [s] of sim time: the demo's start_delay (stand-up first)


def run(variant: str, args: argparse.Namespace) -> dict:
    """One lockstep graph in ``variant`` until ``args.sim_seconds`` of sim time; its figures."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node

    composed, params = VARIANTS[variant]
    graph = Graph(Path(tempfile.mkdtemp(prefix=f"lockstep_pace_{variant}_")))
    graph.start_stack("lockstep", 0.5, *params, composed_chain=composed)
    graph.start_velocity_ramp(speed=args.top_speed, acceleration=1.0, start_delay=RAMP_START)
    if args.record:
        graph.start("bag_recorder", "bag_recorder", "record", "--ros-args", "-p",
                    f"output:={graph.log_dir / 'bag'}", "-p", "use_sim_time:=true")
    rclpy.init(args=[])
    node = Node("lockstep_pace_probe")
    samples: list[tuple[float, float, float]] = []  # (wall [s], sim time [s], lowest base since the last [m])

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == "a1_sim_bridge":
                values = {kv.key: kv.value for kv in status.values}
                lowest = values.get("lowest_base_height_m", "inf")
                samples.append((time.monotonic(), float(values["sim_time_s"]),
                                float(lowest) if lowest not in ("n/a", "inf") else float("inf")))

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    cpu_start: dict[str, float] = {}
    try:
        deadline = time.monotonic() + args.sim_seconds / 0.05 + 120.0  # slower than 0.05x: something is wrong
        while time.monotonic() < deadline and not (samples and samples[-1][1] >= args.sim_seconds):
            rclpy.spin_once(node, timeout_sec=0.1)
            if not cpu_start and any(s[1] > 0.0 for s in samples):  # the sim runs: the window starts
                cpu_start = {name: cpu_seconds(proc.pid) for name, proc in graph.procs.items()}
        cpu_end = {name: cpu_seconds(proc.pid) for name, proc in graph.procs.items()}
        alive = graph.alive()
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        graph.stop()
    moving = [s for s in samples if s[1] > 0.0]
    if len(moving) < 2 or moving[-1][1] < args.sim_seconds:
        sys.exit(f"{variant}: the sim reached {moving[-1][1] if moving else 0.0:.1f} s only "
                 f"(logs in {graph.log_dir})")
    if not all(alive.values()):
        sys.exit(f"{variant}: nodes died: {[k for k, v in alive.items() if not v]} (logs in {graph.log_dir})")
    (wall0, sim0, _), (wall1, sim1, _) = moving[0], moving[-1]
    pace = (sim1 - sim0) / (wall1 - wall0)
    return {
        "variant": variant, "record": args.record, "pace_sim_s_per_wall_s": pace,
        "wall_time_for_sim_seconds_s": args.sim_seconds / pace,
        "lowest_base_height_m": min(s[2] for s in moving[1:]),
        # Where the two cores went while the sim ran (about: from the first report of a moving sim).
        **{f"cpu_{name}_cores": (cpu_end[name] - cpu_start.get(name, 0.0)) / (wall1 - wall0) for name in cpu_end},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=["composed", "separate", "embedded"],
                        help="graph forms to run (lean only when asked: not the trained controller)")
    parser.add_argument("--repeats", type=int, default=2, help="runs of each variant, in turn")
    parser.add_argument("--sim-seconds", type=float, default=21.5, help="sim time per run (the demo's 21.5 s)")
    parser.add_argument("--top-speed", type=float, default=2.5, help="the ramp's end speed [m/s]")
    parser.add_argument("--record", action="store_true", help="also run the demo's bag recorder (every topic)")
    args = parser.parse_args()
    if not 1 <= args.repeats <= 20:
        parser.error(f"--repeats must be in [1, 20], got {args.repeats}")
    if not 3.0 <= args.sim_seconds <= 600.0:
        parser.error(f"--sim-seconds must be in [3, 600] s, got {args.sim_seconds}")
    if not 0.0 <= args.top_speed <= 3.0:
        parser.error(f"--top-speed must be in [0, 3] m/s, got {args.top_speed}")
    os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
    runs = []
    for repeat in range(args.repeats):
        for variant in args.variants:
            result = run(variant, args)
            runs.append(result)
            print(f"run {repeat + 1} {variant:<9} {result['wall_time_for_sim_seconds_s']:6.1f} s wall for "
                  f"{args.sim_seconds} s of sim time ({result['pace_sim_s_per_wall_s']:.2f}x real time), "
                  f"lowest base {result['lowest_base_height_m']:.3f} m", flush=True)
    print(f"\n{'variant':<10} {'runs':>4} {'wall s for ' + str(args.sim_seconds) + ' s sim':>22} "
          f"{'pace median':>12} {'lowest base':>12}")
    summary = {}
    for variant in args.variants:
        mine = [r for r in runs if r["variant"] == variant]
        walls = [r["wall_time_for_sim_seconds_s"] for r in mine]
        paces = [r["pace_sim_s_per_wall_s"] for r in mine]
        lowest = min(r["lowest_base_height_m"] for r in mine)
        summary[variant] = {"wall_time_s": walls, "pace_median": float(np.median(paces)),
                            "lowest_base_height_m": lowest}
        print(f"{variant:<10} {len(mine):>4} {', '.join(f'{w:.1f}' for w in walls):>22} "
              f"{np.median(paces):>11.2f}x {lowest:>10.3f} m")
    print(json.dumps({"sim_seconds": args.sim_seconds, "top_speed_mps": args.top_speed, "record": args.record,
                      "by_variant": summary, "runs": runs}))


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    main()
