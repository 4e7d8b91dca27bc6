"""Benchmark the 500 Hz closed loop (sim core + estimator + controller, MPC solved every step).

For each case prints median and p99 of: QP build, QP solve (OSQP update + solve), whole controller
step, estimator update, physics step, the closed-loop step (physics + controller, the issue-4
figure) and the full step with the estimator, and the real-time factor (sim time / wall time of all
three).
Goal of issue 4: closed-loop step (physics + controller) median <= 1.0 ms on the 2-core machine.
Ends with one JSON line of the figures of the first case.

Usage: source scripts/env.sh && python benchmarks/control_step.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from convex_mpc_node.gait import load_hand_tuned_gaits
from gait_policy_node.rollout import run_closed_loop

from gait_policy_node import speed_profiles

CASES = (("slow_trot", 1.0), ("fly_trot", 2.5), ("walk", 0.5))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="sim seconds per case")
    args = parser.parse_args()
    if not 1.0 <= args.seconds <= 120.0:
        parser.error("--seconds must be in [1, 120]")
    gaits = load_hand_tuned_gaits()
    header = f"{'case':<18}{'figure':<22}{'median ms':>10}{'p99 ms':>10}"
    print(header)
    print("-" * len(header))
    first = None
    for name, speed in CASES:
        traj = run_closed_loop(lambda t, c, n=name: gaits[n], speed_profiles.ramp(speed), args.seconds)
        controller = np.asarray(traj.controller_time)
        physics = np.asarray(traj.physics_time)
        estimator = np.asarray(traj.estimator_time)
        figures = {
            "qp_build": np.asarray(traj.qp_build_time), "qp_solve": np.asarray(traj.qp_solve_time),
            "controller_step": controller, "estimator_update": estimator, "physics_step": physics,
            "closed_loop_step": controller + physics, "full_step": controller + physics + estimator,
        }
        case = f"{name} {speed} m/s"
        for key, values in figures.items():
            median, p99 = np.median(values) * 1e3, np.percentile(values, 99) * 1e3
            print(f"{case:<18}{key:<22}{median:>10.3f}{p99:>10.3f}")
        rtf = traj.time[-1] / float(np.sum(controller + physics + estimator))
        print(f"{case:<18}{'real-time factor':<22}{rtf:>10.2f}{'':>10}  (fell: {traj.fell}, "
              f"MPC fallbacks: {traj.mpc_fallbacks})")
        if first is None:
            first = {f"{key}_median_s": float(np.median(v)) for key, v in figures.items()}
            first.update({f"{key}_p99_s": float(np.percentile(v, 99)) for key, v in figures.items()})
            first.update({"case": case, "real_time_factor": rtf})
    print(json.dumps(first))


if __name__ == "__main__":
    main()
