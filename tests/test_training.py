"""train_es end to end (issue 7): tiny runs of the real command, kill and resume, Ctrl-C, backends.

Tiny means 4 policy steps per episode, population 4, 8 hidden units: the same code paths as a
full run, a few seconds each.
"""

from __future__ import annotations

import csv
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from a1_common.config import ConfigError
from gait_policy_node.learned_policy import TEMPORARY_MARK, load_policy, read_npz
from gait_policy_node.rollout_workers import ProcessEvaluator, RayEvaluator, RolloutTask, SerialEvaluator
from gait_policy_node.train_config import load_train_config
from gait_policy_node.train_es import Trainer

TINY = ["env.episode_steps=4", "trainer.population_size=4", "trainer.ars_directions=2", "policy.hidden_units=8",
        "trainer.eval_every=1", "trainer.checkpoint_every=1"]
CHEAP = ("--set", "env.episode_steps=1", "--set", "trainer.population_size=2")  # the kill-mid-write runs
COMPARED = ("iteration", "episodes", "policy_steps", "mean_return", "std_return", "max_return", "min_return",
            "falls", "step_size", "eval_return", "eval_speed_error", "eval_cost_of_transport", "eval_fell")


# train_es with np.savez patched so that the Nth write of one file's temporary file (see
# write_npz_atomically) stops halfway: half of the bytes written, flushed and fsynced, then SIGKILL
# from the process itself. Deterministic: no sleeps, no racing a kill against the writes.
# Arguments: file name, N, then train_es's own arguments.
KILL_MID_WRITE = """
import io, itertools, os, signal, sys
import numpy as np
from gait_policy_node.learned_policy import TEMPORARY_MARK
from gait_policy_node.train_es import main

name, nth = sys.argv[1], int(sys.argv[2])
writes, savez = itertools.count(1), np.savez

def savez_killed_midway(file, *args, **kwds):
    ours = os.path.basename(getattr(file, "name", "")).startswith(f".{name}{TEMPORARY_MARK}")
    if not ours or next(writes) < nth:
        return savez(file, *args, **kwds)
    whole = io.BytesIO()
    savez(whole, *args, **kwds)
    file.write(whole.getvalue()[: len(whole.getvalue()) // 2])
    file.flush()
    os.fsync(file.fileno())
    os.kill(os.getpid(), signal.SIGKILL)

np.savez = savez_killed_midway
sys.exit(main(sys.argv[3:]))
"""


def train_es(*args: str, **popen) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "gait_policy_node.train_es", *args]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **popen)


def tiny_args(run_dir: Path, *extra: str) -> list[str]:
    return [a for o in TINY for a in ("--set", o)] + ["--run-dir", str(run_dir), *extra]


def log_rows(run_dir: Path) -> list[dict]:
    with (run_dir / "log.csv").open() as fh:
        return [{k: row[k] for k in COMPARED} for row in csv.DictReader(fh)]


def checkpoint_iterations(run_dir: Path) -> int:
    try:
        return len(read_npz(run_dir / "checkpoint.npz", "checkpoint")["return_history"])
    except ConfigError:  # not written yet
        return 0


def wait_for(condition, timeout: float, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert proc.poll() is None, f"train_es ended early:\n{proc.stdout.read()}"
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def test_two_iterations_end_to_end(tmp_path):
    run = tmp_path / "run"
    proc = train_es(*tiny_args(run, "--iterations", "2", "--backend", "process", "--workers", "2"))
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out
    assert "train_es: cmaes" in out and "done: 2 iterations" in out
    for name in ("config.yaml", "log.csv", "learning_curve.png", "checkpoint.npz", "policy.npz", "best_policy.npz"):
        assert (run / name).stat().st_size > 0, name
    rows = log_rows(run)
    assert [r["iteration"] for r in rows] == ["1", "2"] and all(r["episodes"] == "5" for r in rows)
    policy, config = load_policy(run / "policy.npz")
    assert config == load_train_config(run / "config.yaml") and policy.num_params == 8 * 5 + 8 * 9
    assert np.any(policy.params != 0)  # the mean moved


def test_resume_after_kill_continues_exactly(tmp_path):
    straight, killed = tmp_path / "straight", tmp_path / "killed"
    proc = train_es(*tiny_args(straight, "--iterations", "4", "--backend", "serial"))
    assert proc.wait(timeout=300) == 0
    proc = train_es(*tiny_args(killed, "--iterations", "4", "--backend", "serial"))
    wait_for(lambda: checkpoint_iterations(killed) >= 2, 300, proc)
    proc.kill()  # SIGKILL: no chance to save anything more
    proc.wait()
    stopped_at = checkpoint_iterations(killed)
    assert 2 <= stopped_at < 4
    resumed = train_es("--resume", str(killed), "--iterations", "4")
    out, _ = resumed.communicate(timeout=300)
    assert resumed.returncode == 0 and f"resuming at iteration {stopped_at}" in out, out
    assert log_rows(killed) == log_rows(straight)
    a, _ = load_policy(killed / "policy.npz")
    b, _ = load_policy(straight / "policy.npz")
    np.testing.assert_array_equal(a.params, b.params)


@pytest.fixture(scope="module")
def cheap_straight_run(tmp_path_factory) -> Path:
    """An uninterrupted 2-iteration run of CHEAP, shared by the kill-mid-write cases."""
    run = tmp_path_factory.mktemp("straight") / "run"
    proc = train_es(*tiny_args(run, *CHEAP, "--iterations", "2", "--backend", "serial"))
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0, out
    return run


@pytest.mark.parametrize(("name", "nth", "good"), [("checkpoint.npz", 2, 1), ("policy.npz", 2, 2)],
                         ids=["checkpoint", "last-policy"])
def test_kill_during_a_checkpoint_write_resumes_from_the_last_good_one(tmp_path, cheap_straight_run, name, nth,
                                                                        good):
    """kill -9 halfway through writing a checkpoint's files: the previous checkpoint stays readable, and
    --resume continues from it to the same log and policy as the uninterrupted run (issue 9).

    "last-policy" dies after the final checkpoint.npz but before policy.npz: nothing is left to train,
    yet --resume must still bring policy.npz and log.csv up to the checkpoint.
    """
    run = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", KILL_MID_WRITE, name, str(nth),
                           *tiny_args(run, *CHEAP, "--iterations", "2", "--backend", "serial")],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stdout
    leftover = list(run.glob(f".{name}{TEMPORARY_MARK}*"))
    assert len(leftover) == 1 and 0 < leftover[0].stat().st_size  # died inside the write
    with pytest.raises(ConfigError):
        read_npz(leftover[0])
    assert checkpoint_iterations(run) == good  # the last good checkpoint, read without pickle
    load_policy(run / "policy.npz")  # whole, if perhaps one checkpoint behind
    resumed = train_es("--resume", str(run), "--iterations", "2")
    out, _ = resumed.communicate(timeout=300)
    assert resumed.returncode == 0 and f"resuming at iteration {good}" in out, out
    assert not [p.name for p in run.iterdir() if ".tmp" in p.name]  # the half-written file is gone
    assert log_rows(run) == log_rows(cheap_straight_run)
    for policy_file in ("policy.npz", "best_policy.npz"):
        a, _ = load_policy(run / policy_file)
        b, _ = load_policy(cheap_straight_run / policy_file)
        np.testing.assert_array_equal(a.params, b.params)
    assert int(read_npz(run / "policy.npz")["iteration"]) == 2


def test_ctrl_c_saves_a_checkpoint_and_says_how_to_resume(tmp_path):
    run = tmp_path / "run"
    proc = train_es(*tiny_args(run, "--iterations", "1000", "--backend", "process", "--workers", "2",
                               "--set", "trainer.checkpoint_every=1000"))
    wait_for(lambda: (run / "best_policy.npz").exists(), 300, proc)  # written during iteration 1
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, out
    assert "continue with: train_es --resume" in out
    assert checkpoint_iterations(run) >= 1 and len(log_rows(run)) == checkpoint_iterations(run)


def test_resume_refuses_to_change_what_is_learned(tmp_path):
    run = tmp_path / "run"
    assert train_es(*tiny_args(run, "--iterations", "1", "--backend", "serial")).wait(timeout=300) == 0
    proc = train_es("--resume", str(run), "--set", "reward.energy_weight=0.1")
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "--resume can only change" in out
    proc = train_es(*tiny_args(run, "--iterations", "1"))
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "already holds a run" in out
    proc = train_es("--set", "trainer.sigma0=0")
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "trainer.sigma0 must be in (0.0, 10.0]" in out


def test_ars_trains_in_process(tmp_path):
    config = load_train_config(overrides=[*TINY, "trainer.algorithm=ars", "workers.backend=serial"])
    trainer = Trainer(config, tmp_path)
    trainer.run(2)
    assert trainer.iteration == 2 and len(trainer.return_history[0]) == 4  # 2 directions x (+, -)
    assert np.any(trainer.optimizer.mean != 0)


def test_log_records_the_workers_and_resumes_a_run_logged_without_them(tmp_path):
    config = load_train_config(overrides=[*TINY, "workers.backend=serial"])
    Trainer(config, tmp_path).run(1)
    # A run folder from before the workers column: its checkpoint's log has one column fewer.
    data = read_npz(tmp_path / "checkpoint.npz", "checkpoint")
    np.savez(tmp_path / "checkpoint.npz", **{**data, "log": data["log"][:, :-1]})
    Trainer(config, tmp_path).run(2)
    with (tmp_path / "log.csv").open() as fh:
        assert [row["workers"] for row in csv.DictReader(fh)] == ["", "1"]  # unknown, then this session's


def test_init_from_starts_the_search_at_that_policy_and_resumes_from_it(tmp_path):
    first = tmp_path / "first"
    assert train_es(*tiny_args(first, "--iterations", "1", "--backend", "serial")).wait(timeout=300) == 0
    start = load_policy(first / "policy.npz")[0].params
    assert np.any(start != 0)
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    for run, iterations in ((straight, "2"), (resumed, "1")):
        proc = train_es(*tiny_args(run, "--iterations", iterations, "--backend", "serial",
                                   "--init-from", str(first / "policy.npz")))
        out, _ = proc.communicate(timeout=300)
        assert proc.returncode == 0, out
        assert (run / "initial_policy.npz").read_bytes() == (first / "policy.npz").read_bytes()
    config = load_train_config(resumed / "config.yaml")
    assert np.array_equal(Trainer(config, tmp_path / "no_initial_policy").optimizer.mean, np.zeros(start.size))
    (tmp_path / "warm").mkdir()
    (tmp_path / "warm" / "initial_policy.npz").write_bytes((first / "policy.npz").read_bytes())
    assert np.array_equal(Trainer(config, tmp_path / "warm").optimizer.mean, start)  # the search starts there
    assert train_es("--resume", str(resumed), "--iterations", "2").wait(timeout=300) == 0
    assert log_rows(resumed) == log_rows(straight)  # resume replays from the same start


def test_init_from_refuses_another_network_before_making_the_run_folder(tmp_path):
    first = tmp_path / "first"
    assert train_es(*tiny_args(first, "--iterations", "1", "--backend", "serial")).wait(timeout=300) == 0
    run = tmp_path / "wider"
    proc = train_es(*tiny_args(run, "--iterations", "1", "--set", "policy.hidden_units=16",
                               "--init-from", str(first / "policy.npz")))
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 2 and "network, observation or action decoding differs" in out and not run.exists()
    proc = train_es(*tiny_args(run, "--iterations", "1", "--init-from", str(tmp_path / "none.npz")))
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 2 and "--init-from" in out and "no such file" in out and not run.exists()
    proc = train_es("--resume", str(first), "--init-from", str(first / "policy.npz"))
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 2 and "drop --config, --run-dir and --init-from" in out


@pytest.mark.slow
def test_backends_agree_for_the_same_seed():
    pytest.importorskip("ray")
    config = load_train_config(overrides=[*TINY, "workers.count=2"])
    rng = np.random.default_rng(0)
    params = [rng.normal(0, 0.5, 8 * 5 + 8 * 9) for _ in range(3)]
    tasks = [RolloutTask(params[i], seed) for i, seed in ((0, 0), (1, 1), (2, 2), (0, 0))]
    serial = SerialEvaluator(config)
    try:
        expected = [r.episode_return for r in serial.evaluate(tasks)]
    finally:
        serial.close()
    assert expected[0] == expected[3] and len(set(expected[:3])) == 3
    pool = ProcessEvaluator(config, 2)
    try:
        assert [r.episode_return for r in pool.evaluate(tasks)] == expected
    finally:
        pool.close()
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        on_ray = RayEvaluator(config, 2)
        assert [r.episode_return for r in on_ray.evaluate(tasks)] == expected
        on_ray.close()
    finally:
        ray.shutdown()


def test_default_output_folders_started_in_the_same_second_are_distinct(tmp_path, monkeypatch):
    # eval_policy, sweep_gaits and train_es name their default folder by the second they start in;
    # two started together (e.g. one per core) must not write into one folder.
    from a1_common import files

    monkeypatch.setattr(files.time, "strftime", lambda fmt: "20261204-170000")
    first = files.new_timestamped_folder(tmp_path / "eval", "policy")
    second = files.new_timestamped_folder(tmp_path / "eval", "policy")
    plain = files.new_timestamped_folder(tmp_path / "sweep")
    assert first.name == "policy-20261204-170000" and second.name == "policy-20261204-170000-2"
    assert plain.name == "20261204-170000"
    assert all(p.is_dir() and not any(p.iterdir()) for p in (first, second, plain))
