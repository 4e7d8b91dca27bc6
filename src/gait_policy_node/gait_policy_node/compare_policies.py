"""compare_policies: episode returns of gait policies over several seeds, side by side.

    compare_policies POLICY [POLICY ...] [--config RUN/config.yaml] [--seeds N] [--first-seed S]
                     [--workers N] [--lags DEG ... --below V [--timing BEST.csv ...]]
                     [--toward POLICY --fractions X ... --below V] [--above V] [--by-speed [--plot PNG]]

train_es keeps as "best" the mean whose one evaluation episode (seed 0) scored highest, so two
candidates an evaluation apart may differ by no more than one episode's luck. This runs every
POLICY (``learned``, a policy .npz, or a hand-tuned gait name, as eval_policy takes) on the same
seeds of one training config (``--config``, default: the first policy file's own) and prints each
one's return (mean, standard deviation and range over the seeds), falls, cost of transport and
speed error; the seed-to-seed spread is the noise any difference between them is measured against.
``--lags`` adds, for each policy and lag, the policy with its phase offsets replaced below the
commanded speed ``--below`` by the trot-to-walk family's (sweep_gaits.lag_family_offsets; its own
f and p_swing kept): whether a four-beat footfall at low speed would pay in this episode, i.e.
whether the optimiser is leaving return there. ``--timing`` takes f and p_swing for those variants
from sweep_gaits ``best.csv`` files instead (each lag's best of the grid, interpolated linearly over
the commanded speed and held beyond the swept speeds): the four-beat gait with the timing that made
it cheapest at steady speed. ``--toward B --fractions ...`` adds, for each policy and fraction x, the
policy whose gait below ``--below`` is x of the way to policy B's gait at the same observation
(f and p_swing linear, each phase offset along the shorter arc): the return along a straight path in
gait space from one optimum to another, i.e. whether a valley lies between them. ``--above V``
applies the ``--lags`` and ``--toward`` changes at commanded speeds from V up instead of below
``--below`` (e.g. a trot's offsets at the top: ``--lags 0 --above 1.75``). ``--by-speed``
also splits each policy's return by commanded-speed band (gait_analysis.SPEED_BANDS): per band the
policy steps, the return earned there and its speed and energy penalties (means over the seeds),
and how far each policy's band return is from the first's, beside the seed-to-seed spread: where
along the episode one gait earns more than another (``--plot PNG`` draws it, and the ``--toward``
paths). On flat ground without sensor noise and a fixed profile (ramp, steps, constant) an episode
does not depend on its seed, so one seed does; the spread matters for terrain, noise and ``random``. Ends with
one JSON line of the figures.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import re
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from a1_common.config import ConfigError, require_range
from a1_common.files import save_png_atomically
from convex_mpc_node.gait import GaitParams

from gait_policy_node.env import GaitEnv, StepInfo
from gait_policy_node.eval_policy import ObservationPolicy, resolve_policy
from gait_policy_node.gait_analysis import SPEED_BANDS, shortest_arc
from gait_policy_node.rollout_workers import EpisodeStats, run_episode
from gait_policy_node.sweep_gaits import lag_family_offsets, lag_name
from gait_policy_node.train_config import TrainConfig, load_train_config, train_config_from_mapping

# Stepping frequency [Hz] and swing ratio against commanded speed [m/s]: (speeds, f, p_swing), speeds increasing.
Timing = tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]


@dataclass(frozen=True)
class Variant:
    """A policy as it is, or changed below the commanded speed ``below`` [m/s] (from ``above`` up
    when that is given): its offsets the lag family's (``lag`` [deg], with ``timing`` or its own f
    and p_swing), or its gait ``fraction`` of the way to policy ``toward``'s."""

    spec: str
    below: float = 1.25
    lag: float | None = None
    timing: Timing | None = None
    toward: str | None = None
    fraction: float = 0.0
    above: float | None = None

    def where(self) -> str:
        return f"from {self.above:g} m/s" if self.above is not None else f"below {self.below:g} m/s"


def changed_at(speed: float, below: float, above: float | None = None) -> bool:
    """Whether a variant's change applies at commanded speed ``speed`` [m/s]: from ``above`` up when
    that is given, else under ``below``."""
    return speed >= above if above is not None else speed < below


def load_timing(paths: list[str], lag_deg: float) -> Timing:
    """The best frequency and swing ratio of ``lag_deg`` at each swept speed, from sweep_gaits
    ``best.csv`` files (rows named lag+30, lag-45, ...); one speed in two files: the later file wins."""
    by_speed: dict[float, tuple[float, float]] = {}
    for path in paths:
        with open(path, newline="", encoding="utf-8") as handle:
            try:
                for row in csv.DictReader(handle):
                    if row.get("name") == lag_name(lag_deg):
                        speed, f, p = float(row["target_speed"]), float(row["frequency"]), float(row["swing_ratio"])
                        require_range("target_speed", speed, -5.0, 5.0)
                        GaitParams(f, p, lag_family_offsets(lag_deg)).validated()  # f in (0, 4] Hz, p in (0, 1)
                        by_speed[speed] = (f, p)
            except (KeyError, ValueError) as exc:  # ConfigError is a ValueError: it names field and range
                raise ConfigError(f"--timing: {path}, row {lag_name(lag_deg)}: {exc}") from exc
    if not by_speed:
        raise ConfigError(f"--timing: no row named {lag_name(lag_deg)} in {', '.join(paths)}")
    speeds = sorted(by_speed)
    return tuple(speeds), tuple(by_speed[v][0] for v in speeds), tuple(by_speed[v][1] for v in speeds)


def with_lag(policy: ObservationPolicy, lag_deg: float, below: float, timing: Timing | None = None,
             above: float | None = None) -> ObservationPolicy:
    """``policy`` whose phase offsets, while the commanded speed (observation 0) [m/s] is under
    ``below`` (or from ``above`` up), are the lag family's for ``lag_deg``; its stepping frequency
    and swing ratio kept, or taken from ``timing`` at the commanded speed."""
    offsets = lag_family_offsets(lag_deg)

    def wrapped(obs: np.ndarray) -> GaitParams:
        gait = policy(obs)
        speed = abs(float(obs[0]))
        if not changed_at(speed, below, above):
            return gait
        if timing is None:
            return GaitParams(gait.stepping_frequency, gait.swing_ratio, offsets)
        speeds, frequencies, swing_ratios = timing
        return GaitParams(float(np.interp(speed, speeds, frequencies)), float(np.interp(speed, speeds, swing_ratios)),
                          offsets)
    return wrapped


def blend(a: GaitParams, b: GaitParams, fraction: float) -> GaitParams:
    """The gait ``fraction`` of the way from ``a`` to ``b``: f and p_swing linearly, each phase
    offset along the shorter arc [rad]."""
    arcs = shortest_arc(a.phase_offsets, b.phase_offsets)
    return GaitParams(a.stepping_frequency + fraction * (b.stepping_frequency - a.stepping_frequency),
                      a.swing_ratio + fraction * (b.swing_ratio - a.swing_ratio),
                      tuple(float(o) for o in np.mod(np.asarray(a.phase_offsets) + fraction * arcs, 2 * np.pi)))


def with_blend(policy: ObservationPolicy, other: ObservationPolicy, fraction: float, below: float,
               above: float | None = None) -> ObservationPolicy:
    """``policy`` whose gait, while the commanded speed (observation 0) [m/s] is under ``below`` (or
    from ``above`` up), is ``fraction`` of the way to ``other``'s gait for the same observation."""

    def wrapped(obs: np.ndarray) -> GaitParams:
        gait = policy(obs)
        return blend(gait, other(obs), fraction) if changed_at(abs(float(obs[0])), below, above) else gait
    return wrapped


def label(variant: Variant) -> str:
    v = variant
    if v.toward is not None:
        return f"{v.spec} -> {v.toward} x{v.fraction:g} {v.where()}"
    if v.lag is None:
        return v.spec
    return f"{v.spec} @ lag {v.lag:+g}{' swept timing' if v.timing else ''} {v.where()}"


# Columns of a band-terms array (one row per SPEED_BANDS band): sums over the band's policy steps.
BAND_COLUMNS = ("policy_steps", "return", "speed_penalty", "energy_penalty")


def band_of(speed: float) -> int | None:
    """Index of the SPEED_BANDS band holding commanded speed ``speed`` [m/s] (the last band's upper
    edge included: profiles reach it), None outside them."""
    last = len(SPEED_BANDS) - 1
    return next((i for i, (lo, hi) in enumerate(SPEED_BANDS) if lo <= speed < hi or (i == last and speed == hi)),
                None)


def policy_files(variants: list[Variant]) -> dict[str, str]:
    """The sha256 of every policy file the variants name: each episode loads its files anew, and a
    training run may replace a best_policy.npz between two episodes of one comparison."""
    files = {s for v in variants for s in (v.spec, v.toward) if s is not None and s.endswith(".npz")}
    return {path: hashlib.sha256(Path(path).read_bytes()).hexdigest() for path in sorted(files)}


def _episode(variant: Variant, config_dict: dict, seed: int,
             files: dict[str, str]) -> tuple[EpisodeStats, np.ndarray]:
    """One episode of a policy variant on ``config_dict``'s env and reward (runs in a worker
    process); its stats and its band terms (BAND_COLUMNS per SPEED_BANDS band). ConfigError if a
    policy file is no longer the one ``files`` fingerprinted."""
    for path, digest in files.items():
        if path in (variant.spec, variant.toward) and hashlib.sha256(Path(path).read_bytes()).hexdigest() != digest:
            raise ConfigError(f"{path} changed while compare_policies ran (a training run writing it?): "
                              "compare a copy of it")
    policy, _ = resolve_policy(variant.spec)
    if variant.lag is not None:
        policy = with_lag(policy, variant.lag, variant.below, variant.timing, variant.above)
    if variant.toward is not None:
        policy = with_blend(policy, resolve_policy(variant.toward)[0], variant.fraction, variant.below, variant.above)
    config = train_config_from_mapping(config_dict)
    env = GaitEnv(config.env, config.reward)
    bands = np.zeros((len(SPEED_BANDS), len(BAND_COLUMNS)))

    def on_step(reward: float, info: StepInfo) -> None:
        band = band_of(abs(info.desired_speed))
        if band is not None:
            bands[band] += (1.0, reward, info.terms.speed_penalty, info.terms.energy_penalty)

    try:
        return run_episode(env, policy, seed, on_step=on_step)[0], bands
    finally:
        env.close()


def compare(variants: list[Variant], config: TrainConfig, seeds: list[int],
            workers: int) -> dict[str, list[tuple[EpisodeStats, np.ndarray]]]:
    """Every policy variant on every seed; (stats, band terms) in seed order, per variant's label."""
    config_dict, files = config.to_dict(), policy_files(variants)
    jobs = [(variant, seed) for variant in variants for seed in seeds]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(_episode, variant, config_dict, seed, files) for variant, seed in jobs]
        results: dict[str, list[tuple[EpisodeStats, np.ndarray]]] = {label(v): [] for v in variants}
        for (variant, seed), future in zip(jobs, futures, strict=True):
            stats, bands = future.result()
            results[label(variant)].append((stats, bands))
            print(f"[compare_policies] {label(variant)} seed {seed}: return {stats.episode_return:.2f}"
                  f"{' (fell)' if stats.fell else ''}", flush=True)
    return results


def _std(values: np.ndarray) -> float:
    """Sample standard deviation; 0 for a single seed."""
    return float(values.std(ddof=1)) if len(values) > 1 else 0.0


def by_speed(results: dict[str, list[tuple[EpisodeStats, np.ndarray]]]) -> dict[str, list[dict]]:
    """Per policy, per band with policy steps: the means over the seeds of BAND_COLUMNS, the band
    return's seed-to-seed standard deviation, and (from the second policy on) the mean difference of
    the band return from the first policy's on the same seeds, with its standard deviation."""
    first = np.array([bands for _, bands in next(iter(results.values()))])  # (seeds, bands, columns)
    out = {}
    for spec, runs in results.items():
        terms = np.array([bands for _, bands in runs])
        rows = []
        for i, (lo, hi) in enumerate(SPEED_BANDS):
            if not terms[:, i, 0].any():
                continue
            returns = terms[:, i, 1]
            difference = returns - first[:, i, 1]
            rows.append({"band": [lo, hi], **{c: float(terms[:, i, k].mean()) for k, c in enumerate(BAND_COLUMNS)},
                         "return_std": _std(returns), "return_minus_first": float(difference.mean()),
                         "return_minus_first_std": _std(difference)})
        out[spec] = rows
    return out


def short_label(label: str) -> str:
    """A label with each ``<folder>/policy.npz`` or ``<folder>/best_policy.npz`` named by its folder."""
    return re.sub(r"(?:\S*/)?([^/\s]+)/(?:best_)?policy\.npz", r"\1", label)


def plot_by_speed(rows: dict[str, list[dict]], variants: list[Variant], path: Path) -> None:
    """Each policy's band return minus the first policy's, as bars per commanded-speed band; with
    ``--toward`` variants a second panel: the return change along the way against the fraction, in
    the bands where the gait changed (wholly under the variants' ``below``, or from their
    ``above``), in the others, and in all. PNG ``path``, replaced atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = [v for v in variants if v.toward is not None]
    plain = [label(v) for v in variants if v.toward is None][1:]
    fig, axes = plt.subplots(1, 2 if paths else 1, figsize=(13 if paths else 8, 4.8), squeeze=False)
    bands = [f"{lo:g}-{hi:g}" for lo, hi in SPEED_BANDS]
    width = 0.8 / max(len(plain), 1)
    for j, spec in enumerate(plain):
        by_band = {tuple(r["band"]): r["return_minus_first"] for r in rows[spec]}
        axes[0, 0].bar(np.arange(len(bands)) + (j - (len(plain) - 1) / 2) * width,
                       [by_band.get(b, 0.0) for b in SPEED_BANDS], width, label=short_label(spec))
    axes[0, 0].axhline(0.0, color="k", lw=0.8)
    axes[0, 0].set_xticks(np.arange(len(bands)), bands)
    axes[0, 0].set_xlabel("commanded speed band [m/s]")
    axes[0, 0].set_ylabel(f"episode return in the band, minus {short_label(label(variants[0]))}'s")
    axes[0, 0].grid(alpha=0.3, axis="y")
    if plain:
        axes[0, 0].legend(fontsize=8)
    if paths:
        ax = axes[0, 1]
        first = paths[0]  # all paths change the gait over the same speeds (one --below / --above)
        if first.above is not None:
            split = min((lo for lo, _ in SPEED_BANDS if lo >= first.above - 1e-9), default=SPEED_BANDS[-1][1])
            changed, where = (lambda lo: lo >= split), f"from {split:g} m/s"
        else:
            split = max((hi for _, hi in SPEED_BANDS if hi <= first.below + 1e-9), default=0.0)
            changed, where = (lambda lo: lo < split), f"below {split:g} m/s"
        for spec in dict.fromkeys(v.spec for v in paths):
            own = {tuple(r["band"]): r["return"] for r in rows[spec]}
            ways = sorted((v for v in paths if v.spec == spec), key=lambda v: v.fraction)
            parts = {"changed": [], "unchanged": [], "all": []}
            for v in ways:
                diff = [(r["band"][0], r["return"] - own.get(tuple(r["band"]), 0.0)) for r in rows[label(v)]]
                parts["changed"].append(sum(d for lo, d in diff if changed(lo)))
                parts["unchanged"].append(sum(d for lo, d in diff if not changed(lo)))  # the gait as its own
                parts["all"].append(sum(d for _, d in diff))
            fractions = [0.0] + [v.fraction for v in ways]
            name = short_label(spec)
            line = ax.plot(fractions, [0.0] + parts["changed"], "o-", label=f"{name}: bands {where}")[0]
            ax.plot(fractions, [0.0] + parts["unchanged"], "s:", color=line.get_color(), label=f"{name}: other bands")
            ax.plot(fractions, [0.0] + parts["all"], "^--", color=line.get_color(), alpha=0.6, label=f"{name}: episode")
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xlabel(f"fraction of the way to {short_label(first.toward)}'s gait ({first.where()})")
        ax.set_ylabel("return minus the policy's own")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("compare_policies: return by commanded speed")
    fig.tight_layout()
    try:
        save_png_atomically(fig, path)
    finally:
        plt.close(fig)


def format_by_speed(rows: dict[str, list[dict]]) -> str:
    """by_speed's rows as one table per policy."""
    lines = []
    for spec, bands in rows.items():
        lines.append(f"\n{spec}: return by commanded-speed band (means over the seeds)")
        lines.append(f"{'band [m/s]':<11}{'steps':>7}{'return':>9}{'std':>6}{'speed pen':>11}{'energy pen':>12}"
                     f"{'- first':>9}{'std':>6}")
        for r in bands:
            lines.append(f"{r['band'][0]:.1f}-{r['band'][1]:<7.1f}{r['policy_steps']:7.1f}{r['return']:9.2f}"
                         f"{r['return_std']:6.2f}{r['speed_penalty']:11.3f}{r['energy_penalty']:12.3f}"
                         f"{r['return_minus_first']:+9.2f}{r['return_minus_first_std']:6.2f}")
    return "\n".join(lines)


def summary(stats: list[EpisodeStats]) -> dict[str, float]:
    returns = np.array([s.episode_return for s in stats])
    return {"return_mean": float(returns.mean()), "return_std": float(returns.std(ddof=1)) if len(returns) > 1 else 0.0,
            "return_min": float(returns.min()), "return_max": float(returns.max()),
            "falls": int(sum(s.fell for s in stats)),
            "cost_of_transport_mean": float(np.mean([s.cost_of_transport for s in stats])),
            "speed_error_mean": float(np.mean([s.speed_error for s in stats]))}


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="compare_policies", description=__doc__.split("\n")[0])
    parser.add_argument("policies", nargs="+", metavar="POLICY",
                        help="learned | policy .npz | gait table .csv | scheduled | walk | slow_trot | rapid_trot "
                        "| fly_trot")
    parser.add_argument("--config", help="training config whose env and reward every policy is run on "
                                         "(default: the first policy file's own, else config/train_es.yaml)")
    parser.add_argument("--seeds", type=int, default=8, help="episodes per policy (default 8)")
    parser.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. first-seed + seeds - 1")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--lags", type=float, nargs="+", default=[], metavar="DEG",
                        help="also run each policy with these diagonal lags [deg] below --below")
    parser.add_argument("--below", type=float, default=1.25, help="commanded speed [m/s] under which --lags apply")
    parser.add_argument("--above", type=float, metavar="V",
                        help="apply --lags and --toward from this commanded speed [m/s] up instead of below --below")
    parser.add_argument("--timing", nargs="+", default=[], metavar="BEST_CSV",
                        help="sweep_gaits best.csv files: --lags variants take f and p_swing from them")
    parser.add_argument("--toward", metavar="POLICY", help="also run each policy's gait below --below moved "
                                                         "--fractions of the way to this policy's")
    parser.add_argument("--fractions", type=float, nargs="+", default=[], metavar="X",
                        help="fractions of the way to --toward's gait, each in [0, 1]")
    parser.add_argument("--by-speed", action="store_true",
                        help="also split each return by commanded-speed band, against the first policy's")
    parser.add_argument("--plot", type=Path, metavar="PNG", help="with --by-speed: draw it (and any --toward paths)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    try:
        if not 1 <= args.seeds <= 1000:
            raise ConfigError(f"--seeds must be in [1, 1000], got {args.seeds}")
        if not 1 <= args.workers <= 256:
            raise ConfigError(f"--workers must be in [1, 256], got {args.workers}")
        if args.first_seed < 0:
            raise ConfigError(f"--first-seed must be >= 0, got {args.first_seed}")
        if not 0.0 < args.below <= 5.0:
            raise ConfigError(f"--below must be in (0, 5] m/s, got {args.below}")
        if args.above is not None and not 0.0 <= args.above <= 5.0:
            raise ConfigError(f"--above must be in [0, 5] m/s, got {args.above}")
        if args.above is not None and not (args.lags or args.toward):
            raise ConfigError("--above applies to --lags and --toward variants: give one of them")
        for lag in args.lags:
            lag_family_offsets(lag)  # ConfigError naming the range
        if args.timing and not args.lags:
            raise ConfigError("--timing applies to --lags variants: give --lags too")
        if args.plot is not None and (not args.by_speed or args.plot.suffix != ".png"):
            raise ConfigError(f"--plot needs --by-speed and a .png path, got {args.plot}")
        if args.plot is not None and not args.plot.parent.is_dir():
            raise ConfigError(f"--plot: folder {args.plot.parent} does not exist")
        for name, values in (("POLICY", args.policies), ("--fractions", args.fractions), ("--lags", args.lags)):
            if len(set(values)) != len(values):
                raise ConfigError(f"{name}: each value once, got {values}")
        if bool(args.toward) != bool(args.fractions):
            raise ConfigError("--toward and --fractions go together: give both or neither")
        for fraction in args.fractions:
            require_range("--fractions", fraction, 0.0, 1.0)
        if args.toward:
            resolve_policy(args.toward)  # a bad one fails before any episode
        timings = {lag: load_timing(args.timing, lag) for lag in args.lags} if args.timing else {}
        configs = {spec: resolve_policy(spec)[1] for spec in args.policies}  # a bad one fails before any episode
        own = [c for spec, c in configs.items() if spec.endswith(".npz") or spec == "learned"]
        config = load_train_config(args.config) if args.config else (own[0] if own else load_train_config(None))
    except (ConfigError, OSError) as exc:
        print(f"compare_policies: {exc}", file=sys.stderr)
        return 2
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    variants = [Variant(spec, args.below, lag, timings.get(lag), above=args.above if lag is not None else None)
                for spec in args.policies for lag in (None, *args.lags)]
    variants += [Variant(spec, args.below, toward=args.toward, fraction=x, above=args.above) for spec in args.policies
                 for x in args.fractions]
    try:
        results = compare(variants, config, seeds, min(args.workers, len(seeds) * len(variants)))
    except ConfigError as exc:
        print(f"compare_policies: {exc}", file=sys.stderr)
        return 2
    rows = {spec: summary([stats for stats, _ in runs]) for spec, runs in results.items()}
    width = max(len(s) for s in rows)
    print(f"\n{'policy':<{width}}  return mean  std    min      max      falls  CoT    speed error^2")
    for spec, r in rows.items():
        print(f"{spec:<{width}}  {r['return_mean']:11.2f}  {r['return_std']:5.2f}  {r['return_min']:7.2f}  "
              f"{r['return_max']:7.2f}  {r['falls']:5d}  {r['cost_of_transport_mean']:.3f}  "
              f"{r['speed_error_mean']:.5f}")
    figures = {"seeds": seeds, "episode_steps": config.env.episode_steps, "profile": config.env.profile.kind,
               "policies": rows}
    if args.by_speed:
        figures["by_speed"] = by_speed(results)
        print(format_by_speed(figures["by_speed"]))
        if args.plot is not None:
            plot_by_speed(figures["by_speed"], variants, args.plot)
            print(f"wrote {args.plot}")
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
