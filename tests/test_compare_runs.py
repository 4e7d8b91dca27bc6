"""compare_runs: the table and plot of several train_es runs, and its errors on bad folders (plain pytest)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from a1_common.config import ConfigError
from gait_policy_node.compare_runs import comparability_note, main, read_run_log, summary_row

HEADER = "iteration,wall_time_s,episodes,policy_steps,mean_return,std_return,max_return,min_return,falls,step_size," \
         "eval_return,eval_speed_error,eval_cost_of_transport,eval_fell,workers\n"


def make_run(folder: Path, evals: list[str], profile: str = "steps") -> Path:
    folder.mkdir(parents=True)
    rows = [f"{i},{100.0 * i},33,1000,900,10,1000,800,{10 - i},0.1,{e},0.01,0.8,0,2\n" for i, e in enumerate(evals, 1)]
    (folder / "log.csv").write_text(HEADER + "".join(rows))
    (folder / "config.yaml").write_text(yaml.safe_dump({"env": {"profile": {"kind": profile}}, "reward": {"c": 3}}))
    return folder


def test_summary_takes_the_best_evaluation_and_skips_iterations_without_one(tmp_path):
    log = read_run_log(make_run(tmp_path / "a", ["1000", "", "1050.5", "1040"]))
    row = summary_row(log)
    assert (row["iterations"], row["best_eval"], row["best_at"], row["last_eval"]) == (4, 1050.5, 3, 1040.0)
    assert row["workers"] == "2" and row["falls_last"] == 6 and row["wall_time_h"] == pytest.approx(400 / 3600)


def test_runs_scored_differently_are_flagged(tmp_path):
    a = make_run(tmp_path / "a", ["1000"])
    b = make_run(tmp_path / "b", ["1010"])
    c = make_run(tmp_path / "c", ["900"], profile="ramp")
    assert comparability_note([a, b]) is None
    note = comparability_note([a, b, c])
    assert note is not None and "a, b; c" in note


def test_main_writes_the_plot_and_refuses_bad_folders_by_name(tmp_path, capsys):
    a = make_run(tmp_path / "a", ["1000", "1020"])
    out = tmp_path / "curves.png"
    assert main([str(a), "--out", str(out)]) == 0
    assert out.stat().st_size > 1000 and "1020.00" in capsys.readouterr().out
    assert main([str(tmp_path / "missing")]) == 2
    assert "no log.csv" in capsys.readouterr().err
    bad = make_run(tmp_path / "bad", ["1000", "lots"])
    with pytest.raises(ConfigError, match=r"line 3: eval_return must be a number, got 'lots'"):
        read_run_log(bad)
