"""sweep_gaits: the paper's hand-tuned baselines (section 5.2) and cost of transport against speed.

    sweep_gaits [--gaits walk slow_trot rapid_trot fly_trot] [--speeds 0.3 0.5 1.0 1.5 2.0 2.5]
                [--frequencies 1.0 1.5 2.0 2.5 3.0 3.5 4.0] [--swing-ratios 0.3 0.4 ...]
                [--lags -60 -30 0 30 ...] [--lag-pair both|FR-RL|FL-RR] [--policy a.npz ...]
                [--hold 4.0] [--workers N] [--out DIR]

For each hand-tuned gait (its phase offsets and swing ratio from config/gaits.yaml), at each speed,
every stepping frequency of the grid runs a constant-speed episode (ramp at 1 m/s^2, then
``--hold`` seconds); the frequency with the highest reward (config/train_es.yaml's reward, on the
mean speed and power of the last 3 s) is kept. With ``--swing-ratios`` every gait also runs at each
of those swing ratios instead of its own (the frequency and swing ratio with the highest reward
are kept): which footfall pattern is cheapest once its timing is tuned too. ``--lags`` adds the
one-parameter family between the trot and the four-beat walks (``lag_family_offsets``), one gait
per lag, each at every frequency and swing ratio of the grids; ``--lag-pair FR-RL`` (or FL-RR)
splits only that diagonal pair, the other a trot's (the learned policies' middle-speed gaits).
Learned policies run the same episodes. Writes sweep.csv (every run), best.csv (the table), cost_of_transport.png (CoT
against speed, one curve per gait and policy) into ``--out`` (default log/sweep/<time>/).
CoT = P / (m g v) with the reward's m. With ``--lags`` also cost_of_transport_by_lag.png.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import multiprocessing
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
from a1_common.config import ConfigError
from a1_common.files import new_timestamped_folder, save_png_atomically
from convex_mpc_node.gait import GaitParams, load_hand_tuned_gaits

from gait_policy_node.env import GaitEnv, make_profile, step_reward
from gait_policy_node.learned_policy import load_policy
from gait_policy_node.rollout import POLICY_PERIOD
from gait_policy_node.rollout_workers import run_episode
from gait_policy_node.train_config import ProfileConfig, TrainConfig, load_train_config, train_config_from_mapping

MEASURE_WINDOW = 3.0  # [s] at the end of each episode
ACCELERATION = 1.0  # [m/s^2]
TRACKING_TOLERANCE = 0.05  # relative speed error of a run that counts as tracking its speed

_ENV: GaitEnv | None = None


LAG_PAIRS = ("both", "FR-RL", "FL-RR")  # which diagonal pairs a lag splits


def lag_family_offsets(lag_deg: float, pair: str = "both") -> tuple[float, float, float, float]:
    """Phase offsets [rad] of FR, FL, RR, RL for a diagonal lag [deg]: FR 0, FL pi, RR pi + lag, RL lag.

    Lag 0 is the trot; each diagonal pair then splits by ``lag``: +90 is the paper's walk (swing
    order RR, FL, RL, FR: a hind leg, then the fore leg of the other side), -90 the walk in the
    other order (RL, FL, RR, FR: a hind leg, then the fore leg of its own side). Every lag other
    than 0 and +-180 gives four footfalls a cycle. ``pair`` "FR-RL" or "FL-RR" splits only that
    pair (RL lag, or RR pi + lag) and keeps the other a trot's: the learned policies' middle gaits."""
    if not -180.0 <= lag_deg <= 180.0:
        raise ConfigError(f"--lags must be in [-180, 180] deg, got {lag_deg}")
    if pair not in LAG_PAIRS:
        raise ConfigError(f"--lag-pair must be one of {', '.join(LAG_PAIRS)}, got {pair!r}")
    lag = math.radians(lag_deg)
    rr = (math.pi + lag) % (2 * math.pi) if pair != "FR-RL" else math.pi
    rl = lag % (2 * math.pi) if pair != "FL-RR" else 0.0
    return 0.0, math.pi, rr, rl


def lag_name(lag_deg: float, pair: str = "both") -> str:
    """The gait's name in tables and plots: lag+30, lag-45, ...; FR-RL-30 with one pair split."""
    return f"lag{lag_deg:+g}" if pair == "both" else f"{pair}{lag_deg:+g}"


def _init_worker(config_dict: dict) -> None:
    global _ENV
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    config = train_config_from_mapping(config_dict)
    _ENV = GaitEnv(config.env, config.reward)


def run_constant_speed(env: GaitEnv, policy, speed: float, hold: float) -> dict:
    """Ramp to ``speed`` then hold; mean speed, power, CoT and reward over the last seconds."""
    steps = round((speed / ACCELERATION + hold) / POLICY_PERIOD)
    profile = make_profile(ProfileConfig(kind="ramp", target_speed=speed, acceleration=ACCELERATION))
    stats, record = run_episode(env, policy, seed=0, profile=profile, record=True, steps=steps)
    data = record.arrays()
    window = data["time"] >= data["time"][-1] - MEASURE_WINDOW
    v, power = float(np.mean(data["speed"][window])), float(np.mean(data["power"][window]))
    rc = env.reward_config
    terms = step_reward(rc, speed, v, power)
    return {"speed": v, "power": power, "fell": stats.fell,
            "cost_of_transport": power / (rc.mass * rc.gravity * max(v, rc.min_speed)),
            "reward": float("-inf") if stats.fell else terms.reward,
            "speed_error": abs(v - speed) / max(speed, rc.min_speed)}


def _run_task(task: tuple) -> dict:
    label, spec, speed, hold = task
    if isinstance(spec, str):
        policy = load_policy(spec)[0]
    else:
        gait = GaitParams(*spec)
        policy = lambda obs: gait  # noqa: E731
    result = run_constant_speed(_ENV, policy, speed, hold)
    learned = isinstance(spec, str)
    return {"name": label, "target_speed": speed, "frequency": float("nan") if learned else spec[0],
            "swing_ratio": float("nan") if learned else spec[1], **result}


def sweep(config: TrainConfig, gaits: list[str], speeds: list[float], frequencies: list[float],
          policies: list[str], hold: float, workers: int, swing_ratios: list[float] | None = None,
          lags: list[float] | None = None, lag_pair: str = "both") -> list[dict]:
    """Every (gait, speed, frequency[, swing ratio]) and (policy, speed) run, in parallel on
    ``workers`` processes; ``swing_ratios`` None: each gait's own. Each of ``lags`` [deg] adds the
    gait ``lag_family_offsets(lag, lag_pair)``, which needs ``swing_ratios``."""
    table = load_hand_tuned_gaits()
    unknown = [g for g in gaits if g not in table]
    if unknown:
        raise ConfigError(f"--gaits: unknown {unknown}; allowed: {sorted(table)}")
    for f in frequencies:
        if not 0 < f <= 4.0:
            raise ConfigError(f"--frequencies must be in (0, 4] Hz, got {f}")
    for s in speeds:
        if not 0 < s <= 3.5:
            raise ConfigError(f"--speeds must be in (0, 3.5] m/s, got {s}")
    for p in policies:
        load_policy(p)  # fail early on a bad file
    tasks = [(g, (f, r, table[g].phase_offsets), s, hold)
             for g in gaits for s in speeds for f in frequencies for r in (swing_ratios or [table[g].swing_ratio])]
    if lags and not swing_ratios:
        raise ConfigError("--lags needs --swing-ratios (the lag family has no swing ratio of its own)")
    if lag_pair != "both" and not lags:
        raise ConfigError(f"--lag-pair {lag_pair} needs --lags (the lags that pair is split by)")
    tasks += [(lag_name(lag, lag_pair), (f, r, lag_family_offsets(lag, lag_pair)), s, hold)
              for lag in lags or [] for s in speeds for f in frequencies for r in swing_ratios]
    for _, (f, r, offsets), _, _ in tasks:
        try:
            GaitParams(f, r, offsets).validated()
        except ValueError as exc:
            raise ConfigError(f"--swing-ratios: {exc}") from None
    tasks += [(Path(p).stem, p, s, hold) for p in policies for s in speeds]
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(workers, initializer=_init_worker, initargs=(config.to_dict(),)) as pool:
        results = []
        for i, r in enumerate(pool.imap(_run_task, tasks, chunksize=1), 1):
            results.append(r)
            outcome = "fell" if r["fell"] else f"CoT {r['cost_of_transport']:.2f}"
            print(f"\r[{i}/{len(tasks)}] {r['name']} {r['target_speed']:.1f} m/s f={r['frequency']:.1f} "
                  f"p_swing={r['swing_ratio']:.2f}: "
                  f"{outcome}      ", end="", flush=True)
        print()
    return results


def best_per_speed(results: list[dict]) -> list[dict]:
    """For each (name, speed), the run with the highest reward (learned policies have one run)."""
    best: dict[tuple, dict] = {}
    for r in results:
        key = (r["name"], r["target_speed"])
        if key not in best or r["reward"] > best[key]["reward"]:
            best[key] = r
    return list(best.values())


def compare_with_hand_tuned(best: list[dict], gaits: list[str], policies: list[str],
                            tolerance: float = TRACKING_TOLERANCE) -> list[dict]:
    """Per policy and speed: the policy's CoT against the lowest CoT of a hand-tuned gait (at its best
    frequency) that stayed up and tracked within ``tolerance``; ``wins`` when the policy also tracks
    within it and its CoT is no higher."""
    cell = {(r["name"], r["target_speed"]): r for r in best}
    out = []
    for name in policies:
        for speed in sorted({r["target_speed"] for r in best if r["name"] == name}):
            mine = cell[(name, speed)]
            rivals = [cell[(g, speed)] for g in gaits if (g, speed) in cell]
            rivals = [r for r in rivals if not r["fell"] and r["speed_error"] <= tolerance]
            rival = min(rivals, key=lambda r: r["cost_of_transport"], default=None)
            tracks = not mine["fell"] and mine["speed_error"] <= tolerance
            nan = float("nan")
            out.append({"policy": name, "target_speed": speed, "cost_of_transport": mine["cost_of_transport"],
                        "speed_error": mine["speed_error"], "fell": mine["fell"],
                        "best_gait": rival["name"] if rival else "",
                        "best_frequency": rival["frequency"] if rival else nan,
                        "best_cost_of_transport": rival["cost_of_transport"] if rival else nan,
                        "wins": tracks and (rival is None or mine["cost_of_transport"] <= rival["cost_of_transport"])})
    return out


def _plot_curves(curves: dict[str, list[tuple[float, float]]], xlabel: str, title: str, path: Path,
                 vline: float | None = None) -> None:
    """Cost of transport against ``xlabel``, one line per curve (its points sorted by x)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for label, pts in curves.items():
        if pts:
            ax.plot(*zip(*sorted(pts), strict=True), "o-", label=label)
    if vline is not None:
        ax.axvline(vline, color="0.6", lw=0.8)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("cost of transport")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_png_atomically(fig, path, dpi=110)
    plt.close(fig)


def plot_cost_of_transport(rows: list[dict], path: Path) -> None:
    """Cost of transport against speed, one curve per gait and policy."""
    curves = {name: [(r["target_speed"], r["cost_of_transport"]) for r in rows if r["name"] == name and not r["fell"]]
              for name in dict.fromkeys(r["name"] for r in rows)}
    _plot_curves(curves, "desired speed [m/s]",
                 "Cost of transport against speed (hand-tuned: best stepping frequency)", path)


def plot_cost_by_lag(rows: list[dict], lags: list[float], path: Path, pair: str = "both") -> None:
    """Cost of transport of the lag family against the lag, one curve per speed (best timing each)."""
    lag_of = {lag_name(lag, pair): lag for lag in lags}
    family = [r for r in rows if r["name"] in lag_of and not r["fell"]]
    curves = {f"{speed:g} m/s": [(lag_of[r["name"]], r["cost_of_transport"]) for r in family
                                 if r["target_speed"] == speed]
              for speed in sorted({r["target_speed"] for r in family})}
    if pair == "both":
        xlabel = "diagonal lag [deg]   (-90: walk, sequence RL FL RR FR;  0: trot;  +90: the paper's walk)"
        title = "Trot-to-walk family: best stepping frequency and swing ratio per point"
    else:
        xlabel = f"{pair} lag [deg], the other diagonal a trot's   (0: trot)"
        title = f"Trot with the {pair} pair split: best stepping frequency and swing ratio per point"
    _plot_curves(curves, xlabel, title, path, vline=0.0)


def write_csv(path: Path, rows: list[dict]) -> None:
    keys = ["name", "target_speed", "frequency", "swing_ratio", "speed", "speed_error", "power", "cost_of_transport",
            "reward", "fell"]
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(keys)
        for r in sorted(rows, key=lambda r: (r["name"], r["target_speed"], r["frequency"], r["swing_ratio"])):
            writer.writerow([f"{r[k]:.4g}" if isinstance(r[k], float) else r[k] for k in keys])


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="sweep_gaits", description=__doc__.split("\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--gaits", nargs="*", default=["walk", "slow_trot", "rapid_trot", "fly_trot"],
                        help="hand-tuned gaits of config/gaits.yaml (none: only --lags and --policy)")
    parser.add_argument("--speeds", nargs="+", type=float, default=[0.3, 0.5, 1.0, 1.5, 2.0, 2.5])
    parser.add_argument("--frequencies", nargs="+", type=float, default=[1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0])
    parser.add_argument("--swing-ratios", nargs="+", type=float,
                        help="run every gait at each of these swing ratios (default: each gait's own)")
    parser.add_argument("--lags", nargs="+", type=float, default=[],
                        help="also the trot-to-walk family at these diagonal lags [deg] (needs --swing-ratios)")
    parser.add_argument("--lag-pair", choices=LAG_PAIRS, default="both",
                        help="the diagonal pairs a lag splits (default both: the walks; FR-RL, FL-RR: that one)")
    parser.add_argument("--policy", action="append", default=[],
                        help="learned policy .npz, or 'learned' for the shipped one (repeatable)")
    parser.add_argument("--hold", type=float, default=4.0, help="seconds at the target speed (>= 3)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--config", help="reward and env config (default config/train_es.yaml)")
    parser.add_argument("--out", type=Path)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    try:
        if args.hold < MEASURE_WINDOW:
            raise ConfigError(f"--hold must be >= {MEASURE_WINDOW} s, got {args.hold}")
        if args.workers < 1:
            raise ConfigError(f"--workers must be >= 1, got {args.workers}")
        config = load_train_config(args.config)
        config = dataclasses.replace(config, env=dataclasses.replace(config.env, observation="basic"))
        start = time.monotonic()
        results = sweep(config, args.gaits, args.speeds, args.frequencies, args.policy, args.hold, args.workers,
                        args.swing_ratios, args.lags, args.lag_pair)
    except ConfigError as exc:
        print(f"sweep_gaits: {exc}", file=sys.stderr)
        return 2
    out = args.out or new_timestamped_folder(Path("log") / "sweep")
    out.mkdir(parents=True, exist_ok=True)
    best = best_per_speed(results)
    write_csv(out / "sweep.csv", results)
    write_csv(out / "best.csv", best)
    plot_cost_of_transport(best, out / "cost_of_transport.png")
    if args.lags:
        plot_cost_by_lag(best, args.lags, out / "cost_of_transport_by_lag.png", args.lag_pair)
    names = list(dict.fromkeys(r["name"] for r in best))
    speeds = sorted({r["target_speed"] for r in best})
    cell = {(r["name"], r["target_speed"]): r for r in best}
    timing = "best frequency [Hz] / swing ratio" if args.swing_ratios else "best frequency [Hz]"
    width = 20 if args.swing_ratios else 14  # of a table column
    print(f"cost of transport ({timing} in brackets); {time.monotonic() - start:.0f} s")
    print(f"{'':<12}" + "".join(f"{s:>{width}.1f}" for s in speeds))
    for n in names:
        line = f"{n:<12}"
        for s in speeds:
            r = cell.get((n, s))
            text = "fell" if r is None or r["fell"] else f"{r['cost_of_transport']:.2f}" + (
                f" [{r['frequency']:.1f}" + (f"/{r['swing_ratio']:.2f}" if args.swing_ratios else "") + "]"
                if not np.isnan(r["frequency"]) else "")
            line += f"{text:>{width}}"
        print(line)
    policies = [Path(p).stem for p in args.policy]
    for r in compare_with_hand_tuned(best, args.gaits + [lag_name(lag, args.lag_pair) for lag in args.lags], policies):
        rival = (f"{r['best_gait']} [{r['best_frequency']:.1f} Hz] CoT {r['best_cost_of_transport']:.3f}"
                 if r["best_gait"] else f"no hand-tuned gait tracks within {100 * TRACKING_TOLERANCE:.0f} %")
        mine = "fell" if r["fell"] else f"CoT {r['cost_of_transport']:.3f}, error {100 * r['speed_error']:.1f} %"
        print(f"{r['policy']} at {r['target_speed']:.1f} m/s: {mine}; best hand-tuned: {rival} -> "
              f"{'at most the best' if r['wins'] else 'NOT at most the best (or not tracking)'}")
    plots = "cost_of_transport.png" + (", cost_of_transport_by_lag.png" if args.lags else "")
    print(f"wrote {out}/sweep.csv, best.csv, {plots}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
