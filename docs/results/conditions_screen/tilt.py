"""Body tilt of the trot and the two four-beat splits (lag 0, -45, +45 deg), each at its best timing of
a sweep_gaits run, at 1.0, 1.5 and 2.0 m/s: would the paper's E2E orientation penalty
10 (roll^2 + pitch^2) tell them apart? Roll and pitch [rad] in the heading frame, sampled at every
policy step over the last 3 s of a ramp to the speed (1 m/s^2) and a 4 s hold, as sweep_gaits runs.

    python docs/results/conditions_screen/tilt.py <train_es config> <sweep_gaits --out folder>
"""

import csv
import math
import sys

import numpy as np
from a1_common.kinematics import heading_frame, quat_to_matrix
from convex_mpc_node.gait import GaitParams
from gait_policy_node.env import GaitEnv, make_profile
from gait_policy_node.rollout_workers import run_episode
from gait_policy_node.sweep_gaits import lag_family_offsets
from gait_policy_node.train_config import ProfileConfig, load_train_config

HOLD = 4.0  # [s] at the speed, as sweep_gaits --hold 4
WINDOW = 3.0  # [s] measured at the end


def main(config_path: str, sweep_dir: str) -> None:
    config = load_train_config(config_path)
    env = GaitEnv(config.env, config.reward)
    with open(f"{sweep_dir}/sweep.csv") as f:
        rows = [r for r in csv.DictReader(f) if r["fell"] == "False" and float(r["speed_error"]) <= 0.05]
    print(f"{'speed':>5} {'lag':>5} {'f/p_swing':>9} {'reward':>7} {'rms roll':>9} {'rms pitch':>9} "
          f"{'10(r^2+p^2)':>11}")
    for speed in (1.0, 1.5, 2.0):
        for lag in (0, -45, 45):
            candidates = [r for r in rows if r["name"] == f"lag{lag:+g}" and float(r["target_speed"]) == speed]
            if not candidates:
                continue
            best = max(candidates, key=lambda r: float(r["reward"]))
            gait = GaitParams(float(best["frequency"]), float(best["swing_ratio"]), lag_family_offsets(lag))
            samples = []

            def policy(obs: np.ndarray, gait: GaitParams = gait, samples: list = samples) -> GaitParams:
                q = env.loop.truth.base_orientation
                rot = heading_frame(q).T @ quat_to_matrix(q)
                samples.append((env.loop.sim.time, math.atan2(rot[2, 1], rot[2, 2]),
                                -math.asin(max(-1.0, min(1.0, rot[2, 0])))))
                return gait

            profile = make_profile(ProfileConfig(kind="ramp", target_speed=speed, acceleration=1.0))
            stats, _ = run_episode(env, policy, seed=0, profile=profile, steps=round((speed + HOLD) / 0.05))
            s = np.array(samples)
            w = s[s[:, 0] >= s[-1, 0] - WINDOW]
            roll, pitch = np.sqrt(np.mean(w[:, 1] ** 2)), np.sqrt(np.mean(w[:, 2] ** 2))
            print(f"{speed:5.1f} {lag:+5d} {best['frequency']:>4}/{best['swing_ratio']:<4} "
                  f"{float(best['reward']):7.3f} {math.degrees(roll):7.2f} d {math.degrees(pitch):7.2f} d "
                  f"{10 * (roll**2 + pitch**2):11.4f}"
                  f"{'  fell' if stats.fell else ''}", flush=True)
    env.close()


if __name__ == "__main__":
    main(*sys.argv[1:3])
