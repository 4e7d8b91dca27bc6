"""fit_policy: a policy network refitted to act as compare_policies' low-speed lag variant of it, or as a gait table.

    fit_policy POLICY --lag DEG [--below V] [--timing BEST.csv ...] --out NEW.npz [--samples N] [--seed S]
    fit_policy POLICY --table GAITS.csv --out NEW.npz [--samples N] [--seed S]

Why: CMA-ES moves a policy in small steps from where it stands. To ask whether it keeps a gait it
has not found itself (a four-beat walk at low speed), a run has to start from a policy that walks.
This keeps POLICY's hidden layer and solves its output layer by least squares (on the tanh's
inverse) so that the network acts like ``compare_policies --lags DEG --below V --timing ...``: below
V commanded, the lag family's phase offsets (and the sweep's f and p_swing with ``--timing``);
above, its own action. Observations are drawn around the diagonal the episodes visit (measured
speed near the command). The result is an ordinary policy file with POLICY's training config:
``compare_policies`` evaluates it, ``train_es --init-from NEW.npz`` starts a run there. Prints how
closely the fit acts like its target, and ends with one JSON line of those figures.

``--table`` fits the whole policy to a gait schedule by commanded speed instead: a CSV with the
columns ``speed`` [m/s], ``frequency`` [Hz], ``swing_ratio``, ``fl_deg``, ``rr_deg``, ``rl_deg``
(phase offsets of FL, RR and RL from FR [deg]), one row per speed, speeds increasing; between rows
the gait is interpolated (offsets along the shorter arc), beyond them held. So a published gait
schedule (the reference checkpoint's, docs/results/reference_gaits/) becomes a network that a
training run can start from (``eval_policy`` and ``compare_policies`` run the CSV itself too:
policy.GaitTable).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable

import numpy as np
from a1_common.config import ConfigError
from convex_mpc_node.gait import GaitParams

from gait_policy_node.compare_policies import load_timing, with_lag
from gait_policy_node.gait_analysis import shortest_arc
from gait_policy_node.learned_policy import ACTION_SIZE, NetworkPolicy, encode_action, load_policy, save_policy
from gait_policy_node.policy import TABLE_COLUMNS, GaitTable
from gait_policy_node.train_config import ProfileConfig

RIDGE = 1e-4  # output-layer least squares regulariser (hidden features are O(1))
MAX_TARGET = 0.98  # targets clipped into the tanh's range before its inverse
DEFAULT_BELOW = 1.25  # [m/s] --lag's switch speed when --below is not given


def sample_observations(count: int, top_speed: float, seed: int) -> np.ndarray:
    """``count`` basic observations [v_des_x, v_x, v_y, v_z] [m/s]: commands uniform in [0, top_speed],
    measured speed within about 0.15 m/s of the command, small lateral and vertical speeds."""
    rng = np.random.default_rng(seed)
    v_des = rng.uniform(0.0, top_speed, count)
    return np.column_stack([v_des, v_des + rng.normal(0.0, 0.15, count), rng.normal(0.0, 0.05, count),
                            rng.normal(0.0, 0.05, count)])


def profile_top_speed(profile: ProfileConfig) -> float:
    """The largest forward speed [m/s] the profile of this kind commands (its fields for other kinds are unused)."""
    return abs(float({"ramp": profile.target_speed, "constant": profile.speed,
                      "steps": max((abs(v) for _, v in profile.steps), default=0.0),
                      "random": max(abs(v) for v in profile.random_range)}[profile.kind]))


def fit_output_layer(policy: NetworkPolicy, observations: np.ndarray, targets: np.ndarray) -> NetworkPolicy:
    """A copy of ``policy`` (mlp) whose output layer maps its hidden features of ``observations`` to
    ``targets`` (network outputs in (-1, 1), one row per observation) in the least-squares sense."""
    if policy.kind != "mlp":
        raise ConfigError(f"fit_policy refits an mlp policy's output layer; this one is {policy.kind}")
    (w1, b1), _ = policy._layers
    hidden = np.tanh((observations - policy.obs_mean) / policy.obs_std @ w1.T + b1)
    features = np.column_stack([hidden, np.ones(len(hidden))])
    z = np.arctanh(np.clip(targets, -MAX_TARGET, MAX_TARGET))
    gram = features.T @ features + RIDGE * len(features) * np.eye(features.shape[1])
    solution = np.linalg.solve(gram, features.T @ z)  # (hidden + 1) x 8
    h = policy.hidden_units
    params = policy.params.copy()
    start = h * policy.obs_size + h
    params[start:start + ACTION_SIZE * h] = solution[:h].T.reshape(-1)
    params[start + ACTION_SIZE * h:] = solution[h]
    return NetworkPolicy(policy.kind, policy.observation, h, policy.action, params, policy.obs_mean, policy.obs_std)


def lag_targets(policy: NetworkPolicy, observations: np.ndarray, lag_deg: float, below: float,
                timing=None) -> np.ndarray:
    """Network outputs that decode to the lag variant's gait for each observation (its own above ``below``)."""
    variant = with_lag(policy, lag_deg, below, timing)
    rows = []
    for obs in observations:
        own = policy.raw_action(obs)
        rows.append(own if abs(obs[0]) >= below else encode_action(variant(obs), policy.action, own, MAX_TARGET))
    return np.array(rows)


def table_targets(policy: NetworkPolicy, observations: np.ndarray, table: GaitTable) -> np.ndarray:
    """Network outputs that decode to ``table``'s gait at each observation's commanded speed."""
    return np.array([encode_action(table.gait(obs[0]), policy.action, policy.raw_action(obs), MAX_TARGET)
                     for obs in observations])


def _require_within_action(table: GaitTable, policy: NetworkPolicy) -> None:
    """ConfigError if the table asks for a frequency or swing ratio the policy's outputs cannot
    decode to (they would be clipped: the fit would not act like the table)."""
    for name, values, (low, high) in (("frequency", table.frequencies, policy.action.frequency_range),
                                      ("swing_ratio", table.swing_ratios, policy.action.swing_ratio_range)):
        if values.min() < low or values.max() > high:
            raise ConfigError(f"--table {table.path}: {name} must be within the policy's range [{low:g}, {high:g}], "
                              f"got {values.min():g}-{values.max():g}")


def _offset_error_deg(a: GaitParams, b: GaitParams) -> float:
    return float(np.degrees(np.max(np.abs(shortest_arc(b.phase_offsets, a.phase_offsets)))))


def fit_report(fitted: NetworkPolicy, target: Callable[[np.ndarray], GaitParams], observations: np.ndarray,
               below: float | None) -> dict[str, float]:
    """Worst differences of the fitted policy's gait from the target's, below and above the switch
    speed ``below`` and away from it (within 0.15 m/s of it the fit blends the two by construction);
    with no switch (a gait table), at all speeds."""
    rows = {"below": [], "above": []} if below is not None else {"all": []}
    for obs in observations:
        if below is not None and abs(abs(obs[0]) - below) < 0.15:
            continue
        got, want = fitted(obs), target(obs)
        rows["all" if below is None else "below" if abs(obs[0]) < below else "above"].append(
            (abs(got.stepping_frequency - want.stepping_frequency), abs(got.swing_ratio - want.swing_ratio),
             _offset_error_deg(got, want)))
    report = {}
    for side, values in rows.items():
        worst = np.max(values, axis=0) if values else np.zeros(3)
        report.update({f"{side}_max_frequency_error_hz": float(worst[0]),
                       f"{side}_max_swing_ratio_error": float(worst[1]),
                       f"{side}_max_offset_error_deg": float(worst[2])})
    return report


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="fit_policy", description=__doc__.split("\n")[0])
    parser.add_argument("policy", metavar="POLICY", help="policy .npz (an mlp) or 'learned'")
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--lag", type=float, help="diagonal lag [deg] below --below (lag family)")
    target.add_argument("--table", metavar="GAITS_CSV",
                        help="a gait schedule by commanded speed (columns: " + ", ".join(TABLE_COLUMNS) + ")")
    parser.add_argument("--below", type=float, default=None,
                        help=f"commanded speed [m/s] under which the lag applies (default {DEFAULT_BELOW:g}; "
                             "--lag only)")
    parser.add_argument("--timing", nargs="+", default=[], metavar="BEST_CSV",
                        help="sweep_gaits best.csv files: f and p_swing below --below from them")
    parser.add_argument("--out", required=True, help="the new policy file (.npz)")
    parser.add_argument("--samples", type=int, default=20000, help="observations fitted (default 20000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the observation draw")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    try:
        if args.lag is not None and not -180.0 <= args.lag <= 180.0:
            raise ConfigError(f"--lag must be in [-180, 180] deg, got {args.lag}")
        if args.seed < 0:
            raise ConfigError(f"--seed must be >= 0, got {args.seed}")
        if args.table is not None and (args.timing or args.below is not None):
            raise ConfigError("--timing and --below apply to --lag only (a --table gives the gait at every speed)")
        if args.below is None:
            args.below = DEFAULT_BELOW
        if not 0.0 < args.below <= 5.0:
            raise ConfigError(f"--below must be in (0, 5] m/s, got {args.below}")
        if not 100 <= args.samples <= 1_000_000:
            raise ConfigError(f"--samples must be in [100, 1000000], got {args.samples}")
        if not args.out.endswith(".npz"):
            raise ConfigError(f"--out must end in .npz, got {args.out}")
        table = GaitTable(args.table) if args.table is not None else None
        timing = load_timing(args.timing, args.lag) if args.timing else None
        policy, config = load_policy(args.policy)
        if config.env.observation != "basic":
            raise ConfigError(f"fit_policy draws basic observations; this policy's is {config.env.observation}")
        top = profile_top_speed(config.env.profile) + 0.3
        observations = sample_observations(args.samples, top, args.seed)
        if table is not None:
            _require_within_action(table, policy)
            switch, target = None, (lambda obs: table.gait(obs[0]))
            targets = table_targets(policy, observations, table)
        else:
            switch, target = args.below, with_lag(policy, args.lag, args.below, timing)
            targets = lag_targets(policy, observations, args.lag, args.below, timing)
        fitted = fit_output_layer(policy, observations, targets)
        report = fit_report(fitted, target, sample_observations(2000, top, args.seed + 1), switch)
        save_policy(args.out, fitted, config)
    except (ConfigError, OSError) as exc:
        print(f"fit_policy: {exc}", file=sys.stderr)
        return 2
    if table is not None:
        print(f"fit_policy: wrote {args.out}: the gait table {args.table}; worst differences from it on 2000 "
              "other observations:")
        figures = {"out": args.out, "table": args.table}
    else:
        print(f"fit_policy: wrote {args.out}: lag {args.lag:+g} deg below {args.below:g} m/s"
              f"{' with the swept timing' if timing else ''}; worst differences from the target on 2000 other "
              "observations (more than 0.15 m/s from the switch):")
        figures = {"out": args.out, "lag_deg": args.lag, "below_mps": args.below}
    for side in ("below", "above") if table is None else ("all",):
        print(f"  {side:5s}: f {report[f'{side}_max_frequency_error_hz']:.3f} Hz, "
              f"p_swing {report[f'{side}_max_swing_ratio_error']:.3f}, "
              f"offsets {report[f'{side}_max_offset_error_deg']:.1f} deg")
    print(json.dumps({**figures, **report}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
