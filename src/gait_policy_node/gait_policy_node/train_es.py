"""train_es: train the gait policy with CMA-ES or ARS, offline, on the in-process closed loop.

    train_es [--config config/train_es.yaml] [--set section.key=value ...] [--algorithm cmaes|ars]
             [--backend process|ray|serial] [--workers N] [--address ADDR] [--iterations N]
             [--run-dir DIR]
    train_es --resume DIR [--iterations N] [--backend ...] [--workers N]
    train_es --init-from POLICY.npz ...   (a new run whose search starts at that policy)

A run folder (default ``runs/<algorithm>-<time>/``) holds: ``config.yaml`` (the resolved config),
``log.csv`` (one row per iteration), ``learning_curve.png``, ``checkpoint.npz`` (optimiser state
as its return history, written atomically every ``trainer.checkpoint_every`` iterations and on
Ctrl-C), ``policy.npz`` (the current mean policy) and ``best_policy.npz`` (the mean policy with
the best evaluation return so far). ``--resume`` replays the checkpoint and continues exactly where
the run stopped; iterations after the last checkpoint are redone identically. It first removes the
temporary files of a session killed mid-write and rewrites policy.npz, log.csv and the curve from
the checkpoint (a kill between checkpoint.npz and them leaves them one checkpoint behind).

``--init-from`` starts a new run's search at a trained policy instead of at zero (the paper): a
second stage on another speed profile or reward, say. The file is copied into the run folder as
``initial_policy.npz`` (resume reads it from there), and must have this run's network, observation
and action decoding (its config hash).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import signal
import sys
import time
from pathlib import Path

import numpy as np
import yaml
from a1_common.config import ConfigError
from a1_common.files import new_timestamped_folder, save_png_atomically
from tqdm import tqdm

from gait_policy_node.es import Optimizer, make_optimizer, restore
from gait_policy_node.learned_policy import (
    NetworkPolicy,
    load_policy,
    policy_file,
    read_npz,
    remove_stale_temporaries,
    save_policy,
    write_npz_atomically,
)
from gait_policy_node.rollout_workers import EpisodeStats, Evaluator, RolloutTask, make_evaluator
from gait_policy_node.train_config import TrainConfig, load_train_config

LOG_COLUMNS = ("iteration", "wall_time_s", "episodes", "policy_steps", "mean_return", "std_return", "max_return",
               "min_return", "falls", "step_size", "eval_return", "eval_speed_error", "eval_cost_of_transport",
               "eval_fell", "workers")
EVAL_SEED = 0
INITIAL_POLICY = "initial_policy.npz"  # a warm-started run's starting point, in its folder
# What --resume may change: how and how long to run, not what is learned.
RESUMABLE_OVERRIDES = ("workers.", "trainer.iterations", "trainer.checkpoint_every", "trainer.eval_every")


def episode_seed(trainer_seed: int, iteration: int, candidate: int) -> int:
    return int(np.random.SeedSequence([trainer_seed, iteration, candidate]).generate_state(1)[0])


class Trainer:
    """The ask / evaluate / tell loop with logging and checkpoints in ``run_dir``."""

    def __init__(self, config: TrainConfig, run_dir: Path, evaluator: Evaluator | None = None) -> None:
        self.config = config
        self.run_dir = run_dir
        self.policy = NetworkPolicy.from_config(config)
        self.evaluator = evaluator
        self.rows: list[list[float]] = []
        self.return_history: list[np.ndarray] = []
        self.best_eval = -np.inf
        self.elapsed = 0.0  # wall time of earlier sessions of this run [s]
        remove_stale_temporaries(run_dir)  # a session killed mid-write left it; it can never complete
        self.x0 = self._initial_params()
        checkpoint = run_dir / "checkpoint.npz"
        if checkpoint.exists():
            self._load_checkpoint(checkpoint)
        else:
            self.optimizer: Optimizer = make_optimizer(self.policy.num_params, config.trainer, self.x0)

    @property
    def iteration(self) -> int:
        return len(self.return_history)

    def _initial_params(self) -> np.ndarray | None:
        """The warm start's parameters (``INITIAL_POLICY`` in the run folder), None for the paper's zeros."""
        path = self.run_dir / INITIAL_POLICY
        return _check_initial_policy(path, self.config) if path.exists() else None

    def _load_checkpoint(self, path: Path) -> None:
        data = read_npz(path, "checkpoint")
        stored = str(data["config_hash"]) if "config_hash" in data else ""
        if stored != self.config.policy_hash() or str(data.get("algorithm", "")) != self.config.trainer.algorithm:
            raise ConfigError(f"{path} was written with another policy or algorithm config; "
                              "resume with the run's own config.yaml")
        history = np.asarray(data["return_history"], dtype=float)
        self.optimizer = restore(self.policy.num_params, self.config.trainer, history, self.x0)
        self.return_history = list(history)
        rows = np.asarray(data["log"], dtype=float)
        missing = len(LOG_COLUMNS) - rows.shape[1] if rows.ndim == 2 else 0  # runs from before "workers"
        self.rows = np.pad(rows, ((0, 0), (0, max(missing, 0))), constant_values=np.nan).tolist()
        self.best_eval = float(data["best_eval_return"])
        self.elapsed = float(data["wall_time_s"])

    def save_checkpoint(self) -> None:
        """Checkpoint, then the policy file, CSV log and learning curve; each file replaced atomically."""
        history = np.array(self.return_history, dtype=float).reshape(len(self.return_history), -1)
        write_npz_atomically(self.run_dir / "checkpoint.npz", {
            "algorithm": np.array(self.config.trainer.algorithm), "config_hash": np.array(self.config.policy_hash()),
            "return_history": history, "log": np.array(self.rows, dtype=float).reshape(len(self.rows), -1),
            "best_eval_return": np.array(self.best_eval), "wall_time_s": np.array(self._wall_time()),
            "mean": self.optimizer.mean})
        self._write_outputs()

    def _write_outputs(self) -> None:
        """policy.npz, log.csv and the learning curve as of the current iteration (what a checkpoint holds)."""
        self.policy.set_params(self.optimizer.mean)
        save_policy(self.run_dir / "policy.npz", self.policy, self.config, self.iteration)
        self._write_log()
        plot_learning_curve(self.rows, self.run_dir / "learning_curve.png", self.config.trainer.algorithm)

    def _workers(self) -> int:
        """Rollout processes of this session (a resumed run may use another machine)."""
        w = self.config.workers
        return 1 if w.backend == "serial" else w.resolved_count()

    def _wall_time(self) -> float:
        return self.elapsed + (time.monotonic() - self._session_start)

    def _write_log(self) -> None:
        buf = io.StringIO()
        writer = csv.writer(buf)
        writer.writerow(LOG_COLUMNS)
        for row in self.rows:
            writer.writerow([int(v) if k in ("iteration", "episodes", "policy_steps", "falls") and np.isfinite(v) else
                             ("" if np.isnan(v) else f"{v:.6g}") for k, v in zip(LOG_COLUMNS, row, strict=True)])
        tmp = self.run_dir / ".log.csv.tmp"
        tmp.write_text(buf.getvalue())
        tmp.replace(self.run_dir / "log.csv")

    def run(self, iterations: int | None = None) -> None:
        """Train until ``iterations`` in total (default: the config's); Ctrl-C saves, then re-raises."""
        cfg = self.config.trainer
        total = iterations or cfg.iterations
        self._session_start = time.monotonic()
        if self.iteration:  # resumed: a kill -9 between checkpoint.npz and these may have left them behind it
            self._write_outputs()
        if self.evaluator is None:
            self.evaluator = make_evaluator(self.config)
        bar = tqdm(total=total, initial=self.iteration, desc=f"train_es {cfg.algorithm}", unit="it",
                   dynamic_ncols=True, file=sys.stdout)
        try:
            while self.iteration < total:
                self._iterate(bar)
                if self.iteration % cfg.checkpoint_every == 0 or self.iteration == total:
                    self.save_checkpoint()
        except KeyboardInterrupt:
            bar.close()
            self.save_checkpoint()
            print(f"\ninterrupted: checkpoint at iteration {self.iteration} saved in {self.run_dir}; "
                  f"continue with: train_es --resume {self.run_dir}", flush=True)
            raise
        finally:
            bar.close()
            self.evaluator.close()

    def _iterate(self, bar: tqdm) -> None:
        cfg = self.config.trainer
        it = self.iteration
        candidates = self.optimizer.ask()
        tasks = [RolloutTask(x, episode_seed(cfg.seed, it, j)) for j, x in enumerate(candidates)]
        evaluate_mean = cfg.eval_every > 0 and it % cfg.eval_every == 0
        if evaluate_mean:
            tasks.append(RolloutTask(self.optimizer.mean, EVAL_SEED))
        results: list[EpisodeStats] = self.evaluator.evaluate(tasks)
        train, ev = results[: len(candidates)], (results[-1] if evaluate_mean else None)
        returns = np.array([r.episode_return for r in train])
        self.optimizer.tell(returns)
        self.return_history.append(returns)
        if ev is not None and ev.episode_return > self.best_eval:
            self.best_eval = ev.episode_return
            self.policy.set_params(tasks[-1].params)
            save_policy(self.run_dir / "best_policy.npz", self.policy, self.config, it)
        nan = float("nan")
        self.rows.append([it + 1, self._wall_time(), len(results), sum(r.policy_steps for r in results),
                          returns.mean(), returns.std(), returns.max(), returns.min(), sum(r.fell for r in train),
                          self.optimizer.step_size, ev.episode_return if ev else nan, ev.speed_error if ev else nan,
                          ev.cost_of_transport if ev else nan, float(ev.fell) if ev else nan, self._workers()])
        postfix = {"best": f"{returns.max():.1f}", "mean": f"{returns.mean():.1f}"}
        if ev is not None:
            postfix["eval"] = f"{ev.episode_return:.1f}"
        bar.set_postfix(postfix)
        bar.update(1)


def plot_learning_curve(rows: list[list[float]], path: Path, algorithm: str) -> None:
    """Return against iterations and against wall time [h], with the rollout workers of each session."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not rows:
        return
    data = np.array(rows, dtype=float)
    col = {k: i for i, k in enumerate(LOG_COLUMNS)}
    ev = ~np.isnan(data[:, col["eval_return"]])
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    workers = sorted({int(w) for w in data[:, col["workers"]] if np.isfinite(w)})
    for ax, x, label in ((axes[0], data[:, col["iteration"]], "iteration"),
                         (axes[1], data[:, col["wall_time_s"]] / 3600.0,
                          "wall time [h]" + (f" ({'/'.join(map(str, workers))} rollout workers)" if workers else ""))):
        ax.fill_between(x, data[:, col["min_return"]], data[:, col["max_return"]], alpha=0.2,
                        label="population min-max")
        ax.plot(x, data[:, col["mean_return"]], label="population mean")
        if ev.any():
            ax.plot(x[ev], data[ev, col["eval_return"]], ".-", label="mean policy (evaluation)")
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("episode return")
    axes[1].legend(loc="lower right")
    fig.suptitle(f"{algorithm}: learning curve")
    fig.tight_layout()
    try:
        save_png_atomically(fig, path)
    finally:
        plt.close(fig)


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="train_es", description=__doc__.split("\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", help="training config YAML (default: config/train_es.yaml)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override one config value (repeatable), e.g. --set trainer.population_size=16")
    parser.add_argument("--algorithm", choices=("cmaes", "ars"))
    parser.add_argument("--backend", choices=("process", "ray", "serial"))
    parser.add_argument("--workers", type=int, help="rollout workers (default: all cores)")
    parser.add_argument("--address", help="ray cluster address (with --backend ray)")
    parser.add_argument("--iterations", type=int, help="train until this many iterations in total")
    parser.add_argument("--seed", type=int)
    parser.add_argument("--run-dir", type=Path, help="run folder (default: runs/<algorithm>-<time>)")
    parser.add_argument("--resume", type=Path, metavar="RUN_DIR", help="continue the run in this folder")
    parser.add_argument("--init-from", type=Path, metavar="POLICY",
                        help="a new run's search starts at this policy file (default: zeros, as the paper)")
    return parser.parse_args(argv)


def _shorthand_overrides(args: argparse.Namespace) -> list[str]:
    pairs = (("trainer.algorithm", args.algorithm), ("workers.backend", args.backend),
             ("workers.count", args.workers), ("workers.address", args.address),
             ("trainer.iterations", args.iterations), ("trainer.seed", args.seed))
    return [f"{key}={json.dumps(value)}" for key, value in pairs if value is not None]


def prepare_run(args: argparse.Namespace) -> tuple[TrainConfig, Path]:
    """The config and run folder for a new run or a resumed one (config.yaml written for new runs)."""
    overrides = args.overrides + _shorthand_overrides(args)
    if args.resume is not None:
        run_dir = args.resume
        if not (run_dir / "config.yaml").exists():
            raise ConfigError(f"--resume {run_dir}: no config.yaml there (not a train_es run folder)")
        if args.config or args.run_dir or args.init_from:
            raise ConfigError("--resume takes the run's own config.yaml and start; drop --config, --run-dir "
                              "and --init-from")
        bad = [o for o in overrides if not o.startswith(RESUMABLE_OVERRIDES)]
        if bad:
            raise ConfigError(f"--resume can only change {list(RESUMABLE_OVERRIDES)}, not {bad}")
        config = load_train_config(run_dir / "config.yaml", overrides)
        config.env.controller_config()  # env.controller: a bad one fails here, not in a worker
        return config, run_dir
    config = load_train_config(args.config, overrides)
    config.env.controller_config()
    run_dir = args.run_dir
    if run_dir is not None and (run_dir / "checkpoint.npz").exists():
        raise ConfigError(f"{run_dir} already holds a run; continue it with --resume {run_dir}")
    if args.init_from is not None:  # checked before the run folder exists
        if not policy_file(args.init_from).is_file():
            raise ConfigError(f"--init-from {args.init_from}: no such file")
        _check_initial_policy(args.init_from, config)
    if run_dir is None:
        run_dir = new_timestamped_folder(Path("runs"), config.trainer.algorithm)
    run_dir.mkdir(parents=True, exist_ok=True)
    if args.init_from is not None:
        tmp = run_dir / f".{INITIAL_POLICY}.tmp"
        tmp.write_bytes(policy_file(args.init_from).read_bytes())
        tmp.replace(run_dir / INITIAL_POLICY)
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))
    return config, run_dir


def _check_initial_policy(path: str | Path, config: TrainConfig) -> np.ndarray:
    """The parameters of the policy file a run starts from; ConfigError unless its network,
    observation, action decoding and observation scaling are this run's."""
    policy, policy_config = load_policy(path)
    if policy_config.policy_hash() != config.policy_hash():
        raise ConfigError(f"{path}: its network, observation or action decoding differs from this run's "
                          f"(config hash {policy_config.policy_hash()}, run {config.policy_hash()})")
    fresh = NetworkPolicy.from_config(config)
    if not (np.array_equal(policy.obs_mean, fresh.obs_mean) and np.array_equal(policy.obs_std, fresh.obs_std)):
        raise ConfigError(f"{path}: its observation scaling differs from what train_es starts a policy with")
    return policy.params.copy()


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    try:
        config, run_dir = prepare_run(args)
        trainer = Trainer(config, run_dir)
    except ConfigError as exc:
        print(f"train_es: {exc}", file=sys.stderr)
        return 2
    w = config.workers
    print(f"train_es: {config.trainer.algorithm}, {trainer.policy.num_params} parameters, "
          f"population {trainer.optimizer.population_size}, {config.env.episode_steps} policy steps per episode, "
          f"backend {w.backend} ({w.resolved_count() if w.backend != 'serial' else 1} workers); run folder {run_dir}"
          + (f"; resuming at iteration {trainer.iteration}" if trainer.iteration else ""), flush=True)
    # `kill` saves a checkpoint like Ctrl-C; so does SIGINT even when started with it ignored (as a
    # non-interactive shell starts `cmd &`: without this, `kill -INT` did nothing there).
    signal.signal(signal.SIGTERM, _raise_interrupt)
    signal.signal(signal.SIGINT, _raise_interrupt)
    try:
        trainer.run()
    except KeyboardInterrupt:
        return 130
    print(f"done: {trainer.iteration} iterations; policy {run_dir / 'policy.npz'}, log {run_dir / 'log.csv'}, "
          f"curve {run_dir / 'learning_curve.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
