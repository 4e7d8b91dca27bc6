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
    rows = [f"{i},{100.0 * i},33,1000,900,10,1000,800,{10 - i},0.1,{e},0.01,0.8,0,2\n"
            for i, e in enumerate(evals, 1)]
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
    with pytest.raises(SystemExit):
        main([str(a), "--out", str(tmp_path / "curves.pdf")])  # PNG only
    assert "--out must name a .png file" in capsys.readouterr().err


@pytest.mark.parametrize(("edit", "message"), [
    (lambda text: text.replace(",1050,", ",lots,"), r"line 3: eval_return must be a number, got 'lots'"),
    (lambda text: text.replace("\n2,", "\n,"), r"line 3: iteration must be a whole number >= 0, got ''"),
    (lambda text: text.replace("\n2,", "\ninf,"), r"line 3: iteration must be a whole number >= 0, got 'inf'"),
    (lambda text: text.rstrip("\n") + ",9\n", r"line 3: 16 fields, the header has 15"),
    (lambda text: text.rstrip("\n").rsplit(",", 1)[0] + "\n", r"line 3: 14 fields, the header has 15"),
])
def test_a_damaged_log_is_refused_naming_line_and_column(tmp_path, edit, message):
    run = make_run(tmp_path / "run", ["1000", "1050"])
    (run / "log.csv").write_text(edit((run / "log.csv").read_text()))
    with pytest.raises(ConfigError, match=message):
        read_run_log(run)


def test_runs_of_one_name_are_told_apart_and_missing_configs_said(tmp_path, capsys):
    a = make_run(tmp_path / "x" / "run", ["1000"])
    b = make_run(tmp_path / "y" / "run", ["1010"])
    (b / "config.yaml").unlink()
    assert main([str(a), str(b), "--out", str(tmp_path / "c.png")]) == 0
    out = capsys.readouterr().out
    assert str(a) in out and str(b) in out and f"no config.yaml in {b}" in out
    (a / "config.yaml").write_text("env: [unclosed")
    assert main([str(a), str(b), "--out", str(tmp_path / "c.png")]) == 2
    assert "not valid YAML" in capsys.readouterr().err
