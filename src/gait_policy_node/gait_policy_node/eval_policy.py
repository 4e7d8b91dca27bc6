"""eval_policy: run one gait policy on a speed profile and report it per speed band.

    eval_policy POLICY [--profile ramp|constant|steps|random] [--speed V] [--target-speed V]
                [--acceleration A] [--duration S] [--world flat|step|rough|soft|slope] [--seed N]
                [--stack-conditions] [--out DIR] [--format csv|npz]

POLICY is ``learned`` (the trained policy this package ships), a policy file from train_es (.npz),
a gait table (.csv, the gait against commanded speed: policy.GaitTable), ``scheduled`` (the
hand-tuned gaits by speed) or a hand-tuned gait name (walk, slow_trot, rapid_trot, fly_trot). The
run uses the policy file's training config (observation, reward, controller inputs) or, for the
others, config/train_es.yaml; the options above replace its
profile and world. ``--stack-conditions`` runs a policy trained in other conditions (e.g. the
reference's friction) where the stack runs it: the sim bridge's ground friction and payload, and the
deployed controller (config/convex_mpc.yaml alone). Writes per control step data (steps.csv or
steps.npz), the gait diagram (gait_diagram.png) and summary.json into ``--out`` (default
log/eval/<policy>-<time>/) and prints per speed band: tracking error, power, cost of transport, f,
p_swing, offsets and the gait class, then the gait transitions.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
from a1_common.config import ConfigError
from a1_common.files import new_timestamped_folder
from a1_sim_bridge.sim import SimConfig
from a1_sim_bridge.worlds import WORLD_NAMES
from convex_mpc_node.gait import GaitParams

from gait_policy_node.env import GaitEnv
from gait_policy_node.gait_analysis import format_band_table, plot_gait_diagram, summarise_bands, transition_speeds
from gait_policy_node.learned_policy import SHIPPED_POLICY, load_policy
from gait_policy_node.policy import make_policy
from gait_policy_node.rollout import POLICY_PERIOD
from gait_policy_node.rollout_workers import EpisodeStats, run_episode
from gait_policy_node.train_config import TrainConfig, load_train_config, train_config_from_mapping

ObservationPolicy = Callable[[np.ndarray], GaitParams]


def resolve_policy(spec: str, config_path: str | None = None) -> tuple[ObservationPolicy, TrainConfig]:
    """A policy on the env's observation, and the training config to evaluate it with."""
    if spec == SHIPPED_POLICY or spec.endswith(".npz"):
        network, config = load_policy(spec)
        return network, config
    hand_tuned = make_policy(spec)
    config = load_train_config(config_path)
    if config.env.observation != "basic":
        config = dataclasses.replace(config, env=dataclasses.replace(config.env, observation="basic"))
    return (lambda obs: hand_tuned(np.array([obs[0], 0.0]), obs[1:4])), config


def in_stack_conditions(config: TrainConfig) -> TrainConfig:
    """``config`` with the ground friction and payload the sim bridge uses and no controller overrides:
    the conditions of the node graph, whatever the policy was trained in."""
    bridge = SimConfig()
    env = dataclasses.replace(config.env, ground_friction=bridge.ground_friction, payload_mass=bridge.payload_mass,
                              controller={})
    return train_config_from_mapping(dataclasses.replace(config, env=env).to_dict())


def with_profile(config: TrainConfig, overrides: dict, world: str | None, duration: float | None) -> TrainConfig:
    """``config`` with its speed profile fields, world and episode length replaced where given."""
    profile = dataclasses.replace(config.env.profile, **{k: v for k, v in overrides.items() if v is not None})
    env = dataclasses.replace(config.env, profile=profile, world=world or config.env.world)
    if duration is not None:
        env = dataclasses.replace(env, episode_steps=max(1, round(duration / POLICY_PERIOD)))
    return train_config_from_mapping(dataclasses.replace(config, env=env).to_dict())


def evaluate(policy: ObservationPolicy, config: TrainConfig, seed: int = 0) -> tuple[EpisodeStats, dict]:
    """One recorded episode; returns its stats and the per control step arrays."""
    env = GaitEnv(config.env, config.reward)
    try:
        stats, record = run_episode(env, policy, seed, record=True)
    finally:
        env.close()
    return stats, record.arrays()


def write_steps(path: Path, data: dict[str, np.ndarray]) -> None:
    if path.suffix == ".npz":
        np.savez(path, **data)
        return
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        header = ["time", "desired_speed", "speed", "estimated_speed", "power", "frequency", "swing_ratio",
                  *[f"offset_{leg}" for leg in ("FR", "FL", "RR", "RL")],
                  *[f"contact_{leg}" for leg in ("FR", "FL", "RR", "RL")]]
        writer.writerow(header)
        for i in range(len(data["time"])):
            writer.writerow([f"{data[k][i]:.6g}" for k in header[:7]]
                            + [f"{v:.6g}" for v in data["phase_offsets"][i]] + [int(c) for c in data["contacts"][i]])


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="eval_policy", description=__doc__.split("\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("policy", help="learned | policy .npz | gait table .csv | scheduled | walk | slow_trot "
                                       "| rapid_trot | fly_trot")
    parser.add_argument("--profile", choices=("ramp", "constant", "steps", "random"))
    parser.add_argument("--speed", type=float, help="constant profile speed [m/s]")
    parser.add_argument("--target-speed", type=float, help="ramp end speed [m/s]")
    parser.add_argument("--acceleration", type=float, help="ramp / random acceleration [m/s^2]")
    parser.add_argument("--duration", type=float, help="episode length [s] (default: the config's)")
    parser.add_argument("--world", choices=WORLD_NAMES)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--config", help="config for hand-tuned gaits (default config/train_es.yaml)")
    parser.add_argument("--stack-conditions", action="store_true",
                        help="the sim bridge's friction and payload, the deployed controller (not the training ones)")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--format", choices=("csv", "npz"), default="csv")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    try:
        policy, config = resolve_policy(args.policy, args.config)
        profile = {"kind": args.profile, "speed": args.speed, "target_speed": args.target_speed,
                   "acceleration": args.acceleration}
        config = with_profile(config, profile, args.world, args.duration)
        config = in_stack_conditions(config) if args.stack_conditions else config
    except ConfigError as exc:
        print(f"eval_policy: {exc}", file=sys.stderr)
        return 2
    name = Path(args.policy).stem
    out = args.out or new_timestamped_folder(Path("log") / "eval", name)
    out.mkdir(parents=True, exist_ok=True)
    env = config.env
    print(f"eval_policy: {args.policy} on {env.world} ground (friction {env.ground_friction}"
          f"{f', payload {env.payload_mass} kg' if env.payload_mass else ''}"
          f"{', controller ' + str(env.controller) if env.controller else ''}), {env.profile.kind} profile, "
          f"{env.episode_steps * POLICY_PERIOD:.1f} s", flush=True)
    stats, data = evaluate(policy, config, args.seed)
    rows = summarise_bands(data, config.reward.mass, config.reward.gravity)
    print(format_band_table(rows))
    changes = transition_speeds(data)
    print("gait transitions: " + (", ".join(f"{a} -> {b} at {s:.2f} m/s" for s, a, b in changes) or "none"))
    print(f"episode: return {stats.episode_return:.1f} over {stats.policy_steps} policy steps, "
          f"{'FELL' if stats.fell else 'no fall'}, speed error (reward term) {stats.speed_error:.4f}, "
          f"CoT {stats.cost_of_transport:.3f} (m = {config.reward.mass} kg)")
    write_steps(out / f"steps.{args.format}", data)
    plot_gait_diagram(out / "gait_diagram.png", data, f"{name}: foot contact (measured) during the run")
    summary = {"policy": args.policy, "episode": dataclasses.asdict(stats),
               "bands": [{**r, "band": list(r["band"]), "phase_offsets": list(map(float, r["phase_offsets"]))}
                         for r in rows],
               "transitions": [{"speed": s, "from": a, "to": b} for s, a, b in changes],
               "config": config.to_dict()}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(f"wrote {out}/steps.{args.format}, gait_diagram.png, summary.json")
    return 1 if stats.fell else 0


if __name__ == "__main__":
    sys.exit(main())
