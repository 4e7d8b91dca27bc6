"""Benchmark the Kalman-filter velocity estimator: cost of one update (predict + stance-leg updates).

Samples come from a simulated trot (two feet in contact) and from standing (four feet).
Prints a table, then one JSON line.

Usage: source scripts/env.sh && python benchmarks/estimator_update.py [--samples 5000]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np
from a1_common.command import JointCommand
from a1_interface.sensors import SensorReadings
from a1_sim_bridge.sim import A1Sim
from state_estimator_node.estimator import VelocityEstimator, load_estimator_config


def samples_from_sim(count: int) -> list[SensorReadings]:
    with A1Sim() as sim:
        hold = JointCommand.hold(sim.robot)
        out = []
        for _ in range(count):
            r = sim.step(hold)
            out.append(r)
        return out


def time_updates(samples: list[SensorReadings]) -> np.ndarray:
    est = VelocityEstimator(load_estimator_config())
    costs = np.empty(len(samples))
    for i, s in enumerate(samples):
        t0 = time.perf_counter()
        est.update(s)
        costs[i] = time.perf_counter() - t0
    return costs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=5000)
    args = parser.parse_args()
    if not 100 <= args.samples <= 1_000_000:
        parser.error("--samples must be in [100, 1000000]")
    standing = samples_from_sim(args.samples)
    trot = [dataclasses.replace(s, foot_contact=np.array([True, False, False, True])) for s in standing]
    rows = {"four feet in contact": time_updates(standing), "two feet in contact": time_updates(trot)}
    print(f"{'case':<24}{'median ms':>10}{'p99 ms':>10}")
    for name, costs in rows.items():
        print(f"{name:<24}{np.median(costs) * 1e3:>10.4f}{np.percentile(costs, 99) * 1e3:>10.4f}")
    four, two = rows["four feet in contact"], rows["two feet in contact"]
    print(json.dumps({
        "estimator_update_4_feet_median_s": float(np.median(four)),
        "estimator_update_4_feet_p99_s": float(np.percentile(four, 99)),
        "estimator_update_2_feet_median_s": float(np.median(two)),
        "estimator_update_2_feet_p99_s": float(np.percentile(two, 99)),
    }))


if __name__ == "__main__":
    main()
