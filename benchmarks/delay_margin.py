"""How much loop delay the controller survives, in-process and deterministic (sim core + Kalman
estimator + controller, no ROS), so that a change meant to make it delay-tolerant can be measured
in minutes rather than by 10-minute realtime soaks.

The hand-tuned gaits (rapid trot at SPEED), or with ``--policy`` a learned policy file or ``learned``
(the shipped one, the graph's default gait policy), ramped to SPEED at 1 m/s^2. The learned
policy's observation takes the commanded velocity as the measured one (this loop has no 20 Hz
estimate to hand it; at a steady 1.5 m/s they differ by a few per cent). From FAULT_AT on, one of
two faults:

- sustained latency: every joint command reaches the motors ``latency`` late (the motors hold the
  last one they had meanwhile), as the realtime scenario's 20 ms /motor_command delay;
- stalls: the controller process misses ``stall`` seconds of steps about every STALL_EVERY s (the
  motors hold its last command, the estimator sees no samples), then resumes and its gait clock
  catches up (``elapsed``), as the realtime graph's 20-40 ms command gaps under CPU contention.

Each for several MPC periods (solve every N control steps; the realtime overlay uses 5) and MPC
force weights (alpha: config/convex_mpc.yaml's 1e-6, the realtime overlay's 3e-5). A run survives
if it does not fall (tilt or height, rollout.tilted_or_low) before FAULT_AT + HOLD. Prints two
tables, then one JSON line.

Usage: source scripts/env.sh && python benchmarks/delay_margin.py [--periods 1,5]
       [--force-weights 1e-6,3e-5] [--latencies-ms 0,10,20] [--stalls-ms 20,40] [--policy learned]
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np
from a1_common.command import VelocityCommand
from a1_common.config import ConfigError
from convex_mpc_node.controller import load_controller_config
from convex_mpc_node.gait import GaitParams, gait_for_speed, load_hand_tuned_gaits
from gait_policy_node.policy import make_policy
from gait_policy_node.rollout import GaitSchedule, run_with_late_commands

from gait_policy_node import speed_profiles

SPEED = 1.5  # [m/s]
FAULT_AT = 3.0  # [s] sim time: 1.5 s of ramp, 1.5 s of steady trot
HOLD = 3.0  # [s] the fault lasts this long; surviving it is passing
STALL_EVERY = 0.5  # [s] mean time between stalls (uniform 0.5x-1.5x, seeded)


def gait_schedule(policy: str) -> GaitSchedule:
    """``scheduled``: the hand-tuned gait for the commanded speed; else a learned policy (make_policy's
    spec), observing the command as the measured velocity."""
    if policy == "scheduled":
        gaits = load_hand_tuned_gaits()
        return lambda t, c: gait_for_speed(c.vx, gaits)
    learned = make_policy(policy)

    def schedule(t: float, c: VelocityCommand) -> GaitParams:
        return learned(np.array([c.vx, c.vy]), np.array([c.vx, c.vy, 0.0]))

    return schedule


def run(schedule: GaitSchedule, mpc_period: int, force_weight: float, latency: float = 0.0,
        stall: float = 0.0) -> float | None:
    """Sim time [s] of the fall, or None if the robot is up at FAULT_AT + HOLD."""
    base = load_controller_config()
    config = dataclasses.replace(base, mpc_period_steps=mpc_period,
                                 mpc=dataclasses.replace(base.mpc, force_weight=force_weight))
    return run_with_late_commands(schedule, speed_profiles.ramp(SPEED), FAULT_AT + HOLD,
                                  controller_config=config, fault_at=FAULT_AT, latency=latency, stall=stall,
                                  stall_every=STALL_EVERY)


def sweep(schedule: GaitSchedule, title: str, rows: list[tuple[int, float]], values_ms: list[float],
          kind: str) -> dict:
    """One table: rows are (MPC period, force weight), columns the fault sizes; cells 'up' or the
    fall time."""
    print(f"\n{title}")
    header = f"{'MPC period':<11}{'alpha':>7}" + "".join(f"{v:>10.0f}ms" for v in values_ms)
    print(header)
    print("-" * len(header))
    results = {}
    for period, force_weight in rows:
        falls = {}
        cells = f"{period:<11}{force_weight:>7.0e}"
        for value in values_ms:
            fell = run(schedule, period, force_weight, **{kind: value / 1000.0})
            falls[f"{value / 1000.0:g}"] = fell
            cells += f"{'up' if fell is None else f'fell {fell:.2f}':>12}"
            print(f"\r{cells}", end="", flush=True)
        print()
        survived = [float(v) for v, fell in falls.items() if fell is None]
        results[f"mpc_period_{period}_steps_force_weight_{force_weight:g}"] = {
            "fall_time_s_by_fault_s": falls, "largest_survived_s": max(survived) if survived else None}
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--periods", default="1,5", help="MPC periods [control steps], comma-separated")
    parser.add_argument("--force-weights", default="1e-6,3e-5", help="MPC force weights (alpha), comma-separated")
    parser.add_argument("--latencies-ms", default="0,16,20,24,30", help="sustained command latencies [ms]")
    parser.add_argument("--stalls-ms", default="20,40,60", help="controller stalls [ms]")
    parser.add_argument("--policy", default="scheduled",
                        help="scheduled (the hand-tuned gaits by speed: rapid trot at 1.5 m/s) | learned | "
                             "a policy .npz | a hand-tuned gait name (walk, slow_trot, rapid_trot, fly_trot)")
    args = parser.parse_args()

    def numbers(text: str, name: str, low: float, high: float, cast=float) -> list:
        try:
            values = [cast(v) for v in text.split(",") if v.strip()]
        except ValueError:
            parser.error(f"{name}: comma-separated numbers, got {text!r}")
        if not values or any(not low <= v <= high for v in values):
            parser.error(f"{name}: each value must be in [{low}, {high}], got {text!r}")
        return values

    periods = numbers(args.periods, "--periods", 1, 25, int)
    force_weights = numbers(args.force_weights, "--force-weights", 1e-9, 1.0)
    rows = [(period, weight) for period in periods for weight in force_weights]
    latencies = numbers(args.latencies_ms, "--latencies-ms", 0.0, 100.0)
    stalls = numbers(args.stalls_ms, "--stalls-ms", 0.0, 100.0)
    try:
        schedule = gait_schedule(args.policy)
    except (ConfigError, OSError) as exc:
        parser.error(f"--policy: {exc}")
    print(f"gait policy {args.policy!r}, {schedule(FAULT_AT, VelocityCommand(vx=SPEED))} at {SPEED} m/s, ramped "
          f"to it; fault from {FAULT_AT} s for {HOLD} s; 'up' = survived")
    results = {
        "gait_policy": args.policy, "speed_m_per_s": SPEED, "fault_duration_s": HOLD,
        "sustained_command_latency": sweep(schedule, "Sustained command latency (every command this late):",
                                           rows, latencies, "latency"),
        "controller_stalls": sweep(schedule, f"Controller stalls (about every {STALL_EVERY} s, motors hold the "
                                   "last command):", rows, stalls, "stall"),
    }
    print(json.dumps(results))


if __name__ == "__main__":
    main()
