"""How well a gait policy rides out a frozen IMU, in-process and deterministic (sim core + Kalman
estimator + controller + policy, no ROS), so that policies can be compared on the fault that the
realtime scenario `test_topic_fault_keeps_robot_up_and_no_nan_reaches_motors[imu_frozen_200ms-realtime]`
injects, without minutes of graph runs per sample.

Each run: the policy's env (its own observation and estimator), the speed ramped up at 1 m/s^2 and
held for SETTLE s, then the IMU's content frozen for --freeze-ms (ClosedLoop.hold_imu: orientation,
rates and acceleration stay those of the freeze's first reading, as fault_injection's freeze does),
starting at one of --offsets successive 50 ms policy steps (together about a gait cycle, so the
freeze meets every phase of it), then AFTER s more. A run counts as a fall by the training's test
(tilt over 30 deg or base below the fall height). Prints one table and one JSON line.

``--realtime-controller``: the controller with config/convex_mpc_realtime.yaml over
config/convex_mpc.yaml, as realtime graphs run it (MPC every 5 steps, smoother forces), the solve
in line rather than in a worker (deterministic). It predicts the realtime scenario better than the
lockstep values: measured 2026-12-03, docs/results/RESULTS.md.

Usage: source scripts/env.sh && python benchmarks/imu_freeze_margin.py
       [--policies learned,training/cmaes-walk-init/best_policy.npz,rapid_trot] [--speeds 1.0,1.5,2.0]
       [--freeze-ms 200] [--offsets 10] [--workers 2] [--realtime-controller]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from a1_common.config import config_dir
from convex_mpc_node.controller import ControllerConfig, load_controller_config
from gait_policy_node.env import GaitEnv
from gait_policy_node.eval_policy import in_stack_conditions, resolve_policy
from gait_policy_node.rollout import POLICY_PERIOD

from gait_policy_node import speed_profiles

ACCELERATION = 1.0  # [m/s^2] the paper's ramp
SETTLE = 1.0  # [s] at speed before the first freeze
AFTER = 1.5  # [s] after the freeze ends; the realtime scenario asks for recovery within 1.5 s


def realtime_controller_config() -> ControllerConfig:
    """The controller as realtime graphs configure it, its MPC solved in line (no worker process)."""
    config = load_controller_config(overlays=(config_dir() / "convex_mpc_realtime.yaml",))
    return dataclasses.replace(config, mpc_async=False)


def run(spec: str, speed: float, offset: int, freeze_steps: int,
        controller: ControllerConfig | None = None) -> tuple[float | None, float]:
    """(sim time of the fall [s] or None, lowest base height from the freeze on [m], sampled every
    policy step) for one freeze starting ``offset`` policy steps after the settle; ``controller``
    None: config/convex_mpc.yaml's. The graph's conditions, whatever the policy was trained in."""
    policy, config = resolve_policy(spec)
    config = in_stack_conditions(config)
    env = GaitEnv(config.env, config.reward, controller_config=controller)
    try:
        obs = env.reset(seed=0, profile=speed_profiles.ramp(speed, ACCELERATION))
        start = round((speed / ACCELERATION + SETTLE) / POLICY_PERIOD) + offset
        end = start + freeze_steps
        lowest = math.inf
        for i in range(end + round(AFTER / POLICY_PERIOD)):
            if i == start:
                env.loop.hold_imu(env.loop.readings)
            elif i == end:
                env.loop.hold_imu(None)
            obs, _, _, info = env.step(policy(obs))
            if i >= start:
                lowest = min(lowest, float(env.loop.truth.base_position[2]))
            if info.fell:
                return round(env.loop.sim.time, 3), lowest
        return None, lowest
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policies", default="learned,rapid_trot",
                        help="comma-separated: learned, a .npz, or a hand-tuned gait name")
    parser.add_argument("--speeds", default="1.0,1.5,2.0", help="held speeds [m/s], comma-separated")
    parser.add_argument("--freeze-ms", type=float, default=200.0, help="freeze length [ms], a multiple of 50")
    parser.add_argument("--offsets", type=int, default=10, help="freeze starts, 50 ms apart (1-40)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (1-64)")
    parser.add_argument("--realtime-controller", action="store_true",
                        help="the realtime overlay's controller values (MPC in line, not in a worker)")
    args = parser.parse_args()
    try:
        speeds = [float(v) for v in args.speeds.split(",") if v.strip()]
    except ValueError:
        parser.error(f"--speeds: comma-separated numbers, got {args.speeds!r}")
    if not speeds or any(not 0.0 < s <= 3.0 for s in speeds):
        parser.error(f"--speeds: each in (0, 3] m/s, got {args.speeds!r}")
    freeze_steps = round(args.freeze_ms / 1000.0 / POLICY_PERIOD)
    if not 0.0 < args.freeze_ms <= 2000.0 or abs(freeze_steps * POLICY_PERIOD * 1000.0 - args.freeze_ms) > 1e-6:
        parser.error(f"--freeze-ms: a multiple of {POLICY_PERIOD * 1000:g} in (0, 2000], got {args.freeze_ms:g}")
    if not 1 <= args.offsets <= 40:
        parser.error(f"--offsets: 1-40, got {args.offsets}")
    if not 1 <= args.workers <= 64:
        parser.error(f"--workers: 1-64, got {args.workers}")
    policies = [p.strip() for p in args.policies.split(",") if p.strip()]
    for spec in policies:
        try:
            resolve_policy(spec)
        except (ValueError, OSError) as exc:
            parser.error(f"--policies: {spec!r}: {exc}")

    controller = realtime_controller_config() if args.realtime_controller else None
    jobs = [(spec, speed, offset) for spec in policies for speed in speeds for offset in range(args.offsets)]
    print(f"IMU frozen {args.freeze_ms:g} ms at {args.offsets} phases, {SETTLE:g} s after the ramp "
          f"({ACCELERATION:g} m/s^2); {len(jobs)} runs on {args.workers} workers; controller: "
          f"{'realtime overlay, MPC in line' if controller else 'config/convex_mpc.yaml'}")
    header = f"{'policy':<48}{'speed':>7}{'falls':>8}{'lowest base min/median [m]':>30}"
    print(header)
    print("-" * len(header))
    results: dict[str, dict] = {}
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = {job: pool.submit(run, *job, freeze_steps, controller) for job in jobs}
        for spec in policies:
            results[spec] = {}
            for speed in speeds:
                outcomes = [futures[(spec, speed, o)].result() for o in range(args.offsets)]
                falls = [t for t, _ in outcomes if t is not None]
                lowest = np.array([z for _, z in outcomes])
                print(f"{spec[-48:]:<48}{speed:>7.2f}{len(falls):>5}/{args.offsets:<2}"
                      f"{lowest.min():>17.3f} / {np.median(lowest):.3f}", flush=True)
                results[spec][f"{speed:g}"] = {
                    "falls": len(falls), "runs": args.offsets, "fall_times_s": falls,
                    "lowest_base_min_m": round(float(lowest.min()), 4),
                    "lowest_base_median_m": round(float(np.median(lowest)), 4)}
    print(json.dumps({"imu_freeze_s": args.freeze_ms / 1000.0, "realtime_controller": bool(controller),
                      "by_policy_and_speed_m_per_s": results}))


if __name__ == "__main__":
    main()
