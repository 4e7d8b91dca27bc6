"""Benchmark the gait-policy environment: policy steps per second per core, episodes per core-hour.

One policy step = 25 control steps (sim + estimator + MPC controller) + one network evaluation.
Measures one process alone, then a local process pool on every core (what train_es uses), with
the paper's 256-unit policy at small random weights on the paper's ramp profile. Episodes per
core-hour assume full 400-step episodes (no early falls). Prints a table, then one JSON line.

Usage: source scripts/env.sh && python benchmarks/env_throughput.py [--steps 100] [--episodes 2]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from gait_policy_node.learned_policy import NetworkPolicy
from gait_policy_node.rollout_workers import ProcessEvaluator, RolloutTask, SerialEvaluator
from gait_policy_node.train_config import load_train_config

FULL_EPISODE_STEPS = 400


def measure(evaluator, tasks: list[RolloutTask]) -> tuple[float, int]:
    """Wall time [s] to run the tasks (episode resets included) and the policy steps they ran."""
    start = time.perf_counter()
    results = evaluator.evaluate(tasks)
    return time.perf_counter() - start, sum(r.policy_steps for r in results)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=100, help="policy steps per episode")
    parser.add_argument("--episodes", type=int, default=2, help="episodes per core")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    if not 1 <= args.steps <= 10_000 or not 1 <= args.episodes <= 1000 or args.workers < 1:
        parser.error("--steps must be in [1, 10000], --episodes in [1, 1000], --workers >= 1")
    config = load_train_config(overrides=[f"env.episode_steps={args.steps}"])
    num_params = NetworkPolicy.from_config(config).num_params
    rng = np.random.default_rng(0)

    def tasks(n: int) -> list[RolloutTask]:
        return [RolloutTask(rng.normal(0, 0.03, num_params), i) for i in range(n)]

    serial = SerialEvaluator(config)
    try:
        measure(serial, tasks(1))  # warm-up: imports, first world
        wall_1, steps_1 = measure(serial, tasks(args.episodes))
    finally:
        serial.close()
    pool = ProcessEvaluator(config, args.workers)
    try:
        measure(pool, tasks(args.workers))  # warm-up: spawn, imports
        wall_n, steps_n = measure(pool, tasks(args.workers * args.episodes))
    finally:
        pool.close()
    single = steps_1 / wall_1
    aggregate = steps_n / wall_n
    per_core = aggregate / args.workers
    print(f"{'case':<34}{'policy steps/s':>15}{'per core':>10}{'episodes/core-h':>17}")
    print(f"{'1 process':<34}{single:>15.1f}{single:>10.1f}{3600 * single / FULL_EPISODE_STEPS:>17.1f}")
    print(f"{f'pool of {args.workers} processes':<34}{aggregate:>15.1f}{per_core:>10.1f}"
          f"{3600 * per_core / FULL_EPISODE_STEPS:>17.1f}")
    print(f"parallel efficiency {per_core / single:.2f}; one 400-step episode takes "
          f"{FULL_EPISODE_STEPS / single:.1f} s on one core; a CMA-ES iteration of 32 + 1 episodes takes "
          f"about {33 * FULL_EPISODE_STEPS / aggregate:.0f} s on this machine")
    print(json.dumps({
        "env_policy_steps_per_s_single_process": single,
        "env_policy_steps_per_s_per_core_pool": per_core,
        "env_episodes_per_core_hour_single_process": 3600 * single / FULL_EPISODE_STEPS,
        "env_episodes_per_core_hour_pool": 3600 * per_core / FULL_EPISODE_STEPS,
        "pool_workers": args.workers,
        "pool_parallel_efficiency": per_core / single,
    }))


if __name__ == "__main__":
    main()
