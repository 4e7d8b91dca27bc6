"""compare_runs: several train_es runs' learning curves on one plot, and a table of where each stands.

    compare_runs training/cmaes-scratch-wide training/cmaes-scratch-walkprior

Reads each run folder's ``log.csv`` (text; no pickles), prints one row per run (iterations, wall
time, rollout workers, best and last evaluation of the mean policy, step size, falls in the last
iteration) and plots the evaluation return against iterations and against wall time, one line per
run, into ``--out`` (default ``log/compare_runs/<time>/learning_curves.png``). Which of two runs
learns faster or plateaus higher is a question people answer better from the curves than from the
numbers. Returns compare only between runs scored alike: it says when the runs' env or reward
settings differ.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import yaml
from a1_common.config import ConfigError
from a1_common.files import new_timestamped_folder, save_png_atomically

# log.csv columns this tool reads (train_es.LOG_COLUMNS; "workers" is missing from older runs);
# the whole-number ones must be present on every row
NEEDED_COLUMNS = ("iteration", "wall_time_s", "falls", "step_size", "eval_return")
COUNT_COLUMNS = ("iteration", "falls")


@dataclass
class RunLog:
    name: str
    columns: dict[str, list[float]]

    @property
    def evaluated(self) -> list[tuple[float, float, float]]:
        """(iteration, wall time [s], evaluation return) of the iterations that evaluated the mean."""
        c = self.columns
        return [(i, t, e) for i, t, e in zip(c["iteration"], c["wall_time_s"], c["eval_return"], strict=True)
                if not math.isnan(e)]


def read_run_log(run_dir: Path, name: str | None = None) -> RunLog:
    """The run's log.csv as float columns (an empty cell is NaN), labelled ``name`` (default: the
    folder's name); ConfigError naming the file, line and column of what is wrong."""
    path = run_dir / "log.csv"
    if not path.is_file():
        raise ConfigError(f"{run_dir}: no log.csv (not a train_es run folder, or no iteration finished yet)")
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        rows = list(reader)
    if not header or not rows:
        raise ConfigError(f"{path}: no iterations logged yet")
    missing = [k for k in NEEDED_COLUMNS if k not in header]
    if missing:
        raise ConfigError(f"{path}: columns {missing} missing (not a train_es log)")
    columns: dict[str, list[float]] = {k: [] for k in header}
    for line, row in enumerate(rows, start=2):
        if len(row) != len(header):
            raise ConfigError(f"{path}, line {line}: {len(row)} fields, the header has {len(header)}")
        for key, text in zip(header, row, strict=True):
            try:
                value = float(text) if text else math.nan
            except ValueError:
                raise ConfigError(f"{path}, line {line}: {key} must be a number, got {text!r}") from None
            if key in COUNT_COLUMNS and not (math.isfinite(value) and value == int(value) and value >= 0):
                raise ConfigError(f"{path}, line {line}: {key} must be a whole number >= 0, got {text!r}")
            columns[key].append(value)
    return RunLog(name or run_dir.name, columns)


def run_labels(runs: list[Path]) -> list[str]:
    """Each run's label: its folder's name, or the path as given where two names collide."""
    names = [run.name for run in runs]
    return [name if names.count(name) == 1 else str(run) for name, run in zip(names, runs, strict=True)]


def summary_row(log: RunLog) -> dict[str, object]:
    """Where the run stands: its last iteration, wall time [h], workers, best and last evaluation."""
    c = log.columns
    evaluated = log.evaluated
    best = max(evaluated, key=lambda r: r[2]) if evaluated else (math.nan, math.nan, math.nan)
    workers = sorted({int(w) for w in c.get("workers", []) if math.isfinite(w)})
    return {"run": log.name, "iterations": int(c["iteration"][-1]), "wall_time_h": c["wall_time_s"][-1] / 3600.0,
            "workers": "/".join(map(str, workers)) or "?", "best_eval": best[2], "best_at": best[0],
            "last_eval": evaluated[-1][2] if evaluated else math.nan, "step_size": c["step_size"][-1],
            "falls_last": int(c["falls"][-1])}


def format_table(rows: list[dict[str, object]]) -> str:
    """summary_row's rows as a fixed-width table, one line per run."""
    width = max([len("run")] + [len(str(r["run"])) for r in rows])
    lines = [f"{'run':{width}s} {'iter':>5s} {'wall h':>7s} {'workers':>7s} {'best eval':>10s} {'at':>4s} "
             f"{'last eval':>10s} {'sigma':>7s} {'falls':>5s}"]
    for r in rows:
        lines.append(f"{r['run']:{width}s} {r['iterations']:5d} {r['wall_time_h']:7.2f} {r['workers']:>7s} "
                     f"{r['best_eval']:10.2f} {r['best_at']:4.0f} {r['last_eval']:10.2f} {r['step_size']:7.4f} "
                     f"{r['falls_last']:5d}")
    return "\n".join(lines)


def reward_settings(run_dir: Path) -> dict | None:
    """The run's env and reward sections (config.yaml, read with yaml.safe_load): runs whose returns
    can be compared have the same; None when the folder has no config.yaml."""
    path = run_dir / "config.yaml"
    if not path.is_file():
        return None
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: not a train_es config (a mapping with env and reward sections)")
    return {k: data.get(k) for k in ("env", "reward")}


def comparability_note(runs: list[Path], labels: list[str] | None = None) -> str | None:
    """A warning when the runs were scored by different episodes or rewards (their returns then do
    not compare), naming the groups that share one and the runs whose settings are unknown; None
    when all share one."""
    labels = labels or [run.name for run in runs]
    groups: list[tuple[dict, list[str]]] = []
    unknown: list[str] = []
    for run, label in zip(runs, labels, strict=True):
        settings = reward_settings(run)
        if settings is None:
            unknown.append(label)
            continue
        for key, names in groups:
            if key == settings:
                names.append(label)
                break
        else:
            groups.append((settings, [label]))
    notes = []
    if len(groups) > 1:
        listed = "; ".join(", ".join(names) for _, names in groups)
        notes.append(f"note: these runs differ in their env or reward settings (config.yaml), so only returns "
                     f"within a group compare: {listed}")
    if unknown:
        notes.append(f"note: no config.yaml in {', '.join(unknown)}: whether their returns compare is unknown")
    return "\n".join(notes) or None


def plot_runs(logs: list[RunLog], path: Path) -> None:
    """Evaluation return of the mean policy against iterations and wall time [h], one line per run,
    into the PNG file ``path`` (replaced atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    for log in logs:
        evaluated = log.evaluated
        if not evaluated:
            continue
        iterations, wall, returns = zip(*evaluated, strict=True)
        axes[0].plot(iterations, returns, ".-", label=log.name)
        axes[1].plot([t / 3600.0 for t in wall], returns, ".-", label=log.name)
    axes[0].set_xlabel("iteration")
    axes[1].set_xlabel("wall time [h] (each run on its own rollout workers: see the table)")
    axes[0].set_ylabel("evaluation return of the mean policy")
    for ax in axes:
        ax.grid(alpha=0.3)
    if any(log.evaluated for log in logs):
        axes[1].legend(loc="lower right")
    fig.suptitle("train_es runs compared")
    fig.tight_layout()
    try:
        save_png_atomically(fig, path)
    finally:
        plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="train_es run folders")
    parser.add_argument("--out", type=Path, help="plot file (default log/compare_runs/<time>/learning_curves.png)")
    args = parser.parse_args(argv)
    if args.out is not None and (args.out.suffix.lower() != ".png" or args.out.is_dir()):
        parser.error(f"--out must name a .png file, got {args.out}")
    labels = run_labels(args.runs)
    try:
        logs = [read_run_log(run, label) for run, label in zip(args.runs, labels, strict=True)]
        note = comparability_note(args.runs, labels)
    except ConfigError as exc:
        print(f"compare_runs: {exc}", file=sys.stderr)
        return 2
    print(format_table([summary_row(log) for log in logs]))
    if note:
        print(note)
    out = args.out or new_timestamped_folder(Path("log") / "compare_runs") / "learning_curves.png"
    plot_runs(logs, out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
