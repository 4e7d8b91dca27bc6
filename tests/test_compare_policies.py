"""compare_policies: the same seeds for every policy, and the figures are those of run_episode."""

from __future__ import annotations

import json

import numpy as np
import pytest
from a1_common.config import ConfigError
from convex_mpc_node.gait import GaitParams
from gait_policy_node.compare_policies import load_timing, main, with_lag
from gait_policy_node.env import GaitEnv
from gait_policy_node.learned_policy import NetworkPolicy, load_policy, save_policy
from gait_policy_node.rollout_workers import run_episode
from gait_policy_node.sweep_gaits import lag_family_offsets
from gait_policy_node.train_config import load_train_config

SHORT = ["env.episode_steps=6", "policy.hidden_units=8"]


@pytest.fixture
def two_policies(tmp_path):
    config = load_train_config(None, SHORT)
    rng = np.random.default_rng(3)
    size = NetworkPolicy.from_config(config).num_params
    paths = []
    for name in ("a", "b"):
        policy = NetworkPolicy.from_config(config, 0.3 * rng.standard_normal(size))
        save_policy(tmp_path / f"{name}.npz", policy, config)
        paths.append(tmp_path / f"{name}.npz")
    return config, paths


def test_every_policy_runs_the_same_seeds_and_the_figures_are_run_episodes(two_policies, capsys):
    config, (a, b) = two_policies
    assert main([str(a), str(b), "--seeds", "2", "--first-seed", "5", "--workers", "2"]) == 0
    out = capsys.readouterr().out
    figures = json.loads(out.strip().splitlines()[-1])
    assert figures["seeds"] == [5, 6] and figures["episode_steps"] == 6
    env = GaitEnv(config.env, config.reward)
    try:
        for path in (a, b):
            policy = load_policy(path)[0]
            returns = [run_episode(env, policy, seed)[0].episode_return for seed in (5, 6)]
            row = figures["policies"][str(path)]
            assert row["return_mean"] == pytest.approx(np.mean(returns), rel=1e-12)
            assert row["return_std"] == pytest.approx(np.std(returns, ddof=1), rel=1e-9, abs=1e-12)
            assert row["return_min"] == pytest.approx(min(returns), rel=1e-12)
    finally:
        env.close()
    assert figures["policies"][str(a)] != figures["policies"][str(b)]  # two policies, not one twice


def test_by_speed_splits_each_return_into_its_bands_against_the_first_policy(two_policies, capsys):
    _, (a, b) = two_policies
    assert main([str(a), str(b), "--seeds", "2", "--workers", "2", "--by-speed"]) == 0
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for spec, bands in figures["by_speed"].items():
        row = figures["policies"][spec]
        assert sum(r["return"] for r in bands) == pytest.approx(row["return_mean"], rel=1e-9)
        assert all(r["policy_steps"] > 0 and r["speed_penalty"] >= 0 and r["energy_penalty"] >= 0 for r in bands)
    assert all(r["return_minus_first"] == 0.0 for r in figures["by_speed"][str(a)])
    first = {tuple(r["band"]): r["return"] for r in figures["by_speed"][str(a)]}
    for r in figures["by_speed"][str(b)]:
        assert r["return_minus_first"] == pytest.approx(r["return"] - first[tuple(r["band"])], abs=1e-9)


def test_a_blend_moves_the_low_speed_gait_toward_the_other_policys_along_the_shorter_arc(two_policies, capsys,
                                                                                          tmp_path):
    from gait_policy_node.compare_policies import blend, with_blend

    _, (a, b) = two_policies
    a_gait, b_gait = GaitParams(1.0, 0.2, (0.0, 0.1, 3.0, 6.2)), GaitParams(3.0, 0.6, (0.0, 6.1, 3.2, 0.2))
    half = blend(a_gait, b_gait, 0.5)
    assert half.stepping_frequency == pytest.approx(2.0) and half.swing_ratio == pytest.approx(0.4)
    # FL and RL go the short way across 0 / 2 pi (0.28 rad apart, not 6.0), and stay in [0, 2 pi).
    assert np.allclose(half.phase_offsets, (0.0, 2 * np.pi - (np.pi - 3.1), 3.1, 6.2 + (np.pi - 3.0) - 2 * np.pi))
    assert blend(a_gait, b_gait, 0.0) == GaitParams(1.0, 0.2, pytest.approx(a_gait.phase_offsets))
    pa, pb = load_policy(a)[0], load_policy(b)[0]
    slow, fast = np.array([0.5, 0.4, 0.0, 0.0]), np.array([1.5, 1.4, 0.0, 0.0])
    whole_way = with_blend(pa, pb, 1.0, below=1.0)
    assert whole_way(slow).stepping_frequency == pytest.approx(pb(slow).stepping_frequency)
    assert whole_way(fast) == pa(fast)
    plot = tmp_path / "by_speed.png"
    assert main([str(a), "--seeds", "1", "--workers", "1", "--toward", str(b), "--fractions", "0", "1",
                 "--below", "5", "--by-speed", "--plot", str(plot)]) == 0
    rows = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["policies"]
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert rows[f"{a} -> {b} x0 below 5 m/s"]["return_mean"] == pytest.approx(rows[str(a)]["return_mean"], rel=1e-12)
    assert main([str(a), "--fractions", "0.5", "0.5", "--toward", str(b)]) == 2
    assert "--fractions: each value once" in capsys.readouterr().err
    assert main([str(a), str(a)]) == 2
    assert "POLICY: each value once" in capsys.readouterr().err
    assert main([str(a), "--by-speed", "--plot", str(tmp_path / "missing" / "p.png")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main([str(a), "--plot", str(plot)]) == 2
    assert "--plot needs --by-speed" in capsys.readouterr().err
    assert main([str(a), "--toward", str(b)]) == 2
    assert "--toward and --fractions go together" in capsys.readouterr().err
    assert main([str(a), "--toward", str(b), "--fractions", "1.5"]) == 2
    assert "--fractions must be in [0.0, 1.0], got 1.5" in capsys.readouterr().err


def test_every_commanded_speed_of_a_profile_has_its_band():
    from gait_policy_node.compare_policies import band_of
    from gait_policy_node.gait_analysis import SPEED_BANDS

    assert band_of(0.0) == 0 and band_of(0.5) == 1 and band_of(2.49) == 4
    assert band_of(SPEED_BANDS[-1][1]) == len(SPEED_BANDS) - 1  # the top speed a profile may reach
    assert band_of(SPEED_BANDS[-1][1] + 0.01) is None


def test_bad_arguments_name_what_is_wrong(two_policies, capsys, tmp_path):
    _, (a, _) = two_policies
    assert main([str(a), "--seeds", "0"]) == 2
    assert "--seeds must be in [1, 1000], got 0" in capsys.readouterr().err
    assert main([str(a), str(tmp_path / "missing.npz")]) == 2
    assert "missing.npz" in capsys.readouterr().err
    assert main([str(a), "canter"]) == 2
    assert "canter" in capsys.readouterr().err


def test_a_low_speed_lag_replaces_only_the_offsets_and_only_below_the_speed(two_policies, capsys):
    _, (a, _) = two_policies
    policy = load_policy(a)[0]
    walking = with_lag(policy, -45.0, below=1.0)
    slow, fast = np.array([0.5, 0.4, 0.0, 0.0]), np.array([1.5, 1.4, 0.0, 0.0])
    own = policy(slow)
    assert walking(slow) == GaitParams(own.stepping_frequency, own.swing_ratio, lag_family_offsets(-45.0))
    assert walking(fast) == policy(fast)
    assert main([str(a), "--seeds", "1", "--workers", "1", "--lags", "-45", "--below", "1.0"]) == 0
    rows = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["policies"]
    assert set(rows) == {str(a), f"{a} @ lag -45 below 1 m/s"}
    assert main([str(a), "--lags", "200"]) == 2
    assert "--lags must be in [-180, 180] deg, got 200" in capsys.readouterr().err
    assert main([str(a), "--lags", "-45", "--below", "0"]) == 2
    assert "--below must be in (0, 5] m/s, got 0.0" in capsys.readouterr().err


def test_above_moves_the_change_to_the_top_speeds(two_policies, capsys, tmp_path):
    """--above: the lag (or blend) applies from that commanded speed up, and nowhere below it."""
    from gait_policy_node.compare_policies import with_blend

    _, (a, b) = two_policies
    pa, pb = load_policy(a)[0], load_policy(b)[0]
    slow, fast = np.array([0.5, 0.4, 0.0, 0.0]), np.array([1.5, 1.4, 0.0, 0.0])
    trotting_top = with_lag(pa, 0.0, below=1.25, above=1.0)
    assert trotting_top(slow) == pa(slow)
    assert trotting_top(fast) == GaitParams(pa(fast).stepping_frequency, pa(fast).swing_ratio, lag_family_offsets(0.0))
    toward_top = with_blend(pa, pb, 1.0, below=1.25, above=1.0)
    assert toward_top(slow) == pa(slow)
    assert toward_top(fast).stepping_frequency == pytest.approx(pb(fast).stepping_frequency)
    plot = tmp_path / "top.png"
    assert main([str(a), "--seeds", "1", "--workers", "1", "--lags", "0", "--toward", str(b), "--fractions", "1",
                 "--above", "0", "--by-speed", "--plot", str(plot)]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(out["policies"]) == {str(a), f"{a} @ lag +0 from 0 m/s", f"{a} -> {b} x1 from 0 m/s"}
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # From 0 m/s the whole way is the other policy's gait: the same return as the other policy's.
    assert main([str(b), "--seeds", "1", "--workers", "1"]) == 0
    other = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["policies"][str(b)]
    assert out["policies"][f"{a} -> {b} x1 from 0 m/s"]["return_mean"] == pytest.approx(other["return_mean"], rel=1e-9)
    assert main([str(a), "--above", "1.0"]) == 2
    assert "--above applies to --lags and --toward" in capsys.readouterr().err
    assert main([str(a), "--lags", "0", "--above", "-1"]) == 2
    assert "--above must be in [0, 5] m/s, got -1.0" in capsys.readouterr().err


def test_swept_timing_sets_f_and_p_swing_from_the_sweeps_best_rows(two_policies, capsys, tmp_path):
    _, (a, _) = two_policies
    header = "name,target_speed,frequency,swing_ratio,speed,speed_error,power,cost_of_transport,reward,fell\n"
    slow, fast = tmp_path / "slow.csv", tmp_path / "fast.csv"
    slow.write_text(header + "lag-30,0.5,1.5,0.3,0.5,0,1,1,1,False\nlag+0,0.5,1.0,0.2,0.5,0,1,1,1,False\n")
    fast.write_text(header + "lag-30,1,2.5,0.4,1,0,1,1,1,False\n")
    timing = load_timing([str(slow), str(fast)], -30.0)
    assert timing == ((0.5, 1.0), (1.5, 2.5), (0.3, 0.4))
    policy = load_policy(a)[0]
    walking = with_lag(policy, -30.0, below=1.25, timing=timing)
    assert walking(np.array([0.75, 0.7, 0.0, 0.0])) == GaitParams(2.0, pytest.approx(0.35), lag_family_offsets(-30.0))
    assert walking(np.array([0.2, 0.2, 0.0, 0.0])).stepping_frequency == 1.5  # held below the swept speeds
    assert walking(np.array([1.5, 1.4, 0.0, 0.0])) == policy(np.array([1.5, 1.4, 0.0, 0.0]))
    assert main([str(a), "--seeds", "1", "--workers", "1", "--lags", "-30", "--timing", str(slow), str(fast)]) == 0
    rows = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["policies"]
    assert set(rows) == {str(a), f"{a} @ lag -30 swept timing below 1.25 m/s"}
    assert main([str(a), "--lags", "-45", "--timing", str(slow)]) == 2
    assert "--timing: no row named lag-45" in capsys.readouterr().err
    fast.write_text(header + "lag-30,1,7.5,0.4,1,0,1,1,1,False\n")
    assert main([str(a), "--lags", "-30", "--timing", str(fast)]) == 2
    assert "row lag-30: stepping_frequency must be in (0.0, 4.0], got 7.5" in capsys.readouterr().err
    assert main([str(a), "--timing", str(slow)]) == 2
    assert "give --lags too" in capsys.readouterr().err


def test_fit_policy_acts_as_the_lag_variant_away_from_the_switch_and_loads_as_a_policy(two_policies, tmp_path, capsys):
    from gait_policy_node.fit_policy import main as fit_main

    _, (a, _) = two_policies
    out = tmp_path / "walking.npz"
    assert fit_main([str(a), "--lag", "-30", "--below", "1.0", "--out", str(out), "--samples", "4000"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    fitted, target = load_policy(out)[0], with_lag(load_policy(a)[0], -30.0, below=1.0)
    slow = np.array([0.4, 0.45, 0.0, 0.0])
    got, want = fitted(slow), target(slow)
    assert np.allclose(np.cos(np.subtract(got.phase_offsets, want.phase_offsets)), 1.0, atol=1 - np.cos(np.radians(10)))
    fast = np.array([1.8, 1.75, 0.0, 0.0])
    assert fitted(fast).stepping_frequency == pytest.approx(target(fast).stepping_frequency, abs=0.3)
    assert all(np.isfinite(v) for v in report.values() if isinstance(v, float))
    assert fit_main([str(a), "--lag", "-30", "--out", str(tmp_path / "x.txt")]) == 2
    assert "--out must end in .npz" in capsys.readouterr().err


def test_a_gait_table_interpolates_along_the_shorter_arc_and_a_fitted_policy_acts_as_it(two_policies, tmp_path,
                                                                                         capsys):
    from gait_policy_node.fit_policy import main as fit_main
    from gait_policy_node.gait_analysis import shortest_arc
    from gait_policy_node.policy import GaitTable, make_policy

    _, (a, _) = two_policies
    table_path = tmp_path / "gaits.csv"
    # A walk-like gait at 0.2 m/s to a flying trot at 2.0 m/s. RL goes 330 -> 30 deg: the shorter
    # arc passes 0 (a plain interpolation of the numbers would pass 180); RR goes 270 -> -180.
    table_path.write_text("speed,frequency,swing_ratio,fl_deg,rr_deg,rl_deg\n"
                          "0.2,1.5,0.2,180,270,330\n2.0,3.0,0.6,180,-180,30\n")
    table = GaitTable(str(table_path))
    for speed, weight in ((1.1, 0.5), (0.65, 0.25)):
        gait = table.gait(speed)
        assert gait.stepping_frequency == pytest.approx(1.5 + 1.5 * weight)
        assert gait.swing_ratio == pytest.approx(0.2 + 0.4 * weight)
        want = np.radians([180.0, 270.0 - 90.0 * weight, 330.0 + 60.0 * weight])
        assert np.abs(shortest_arc(np.array(gait.phase_offsets[1:]), want)) == pytest.approx(np.zeros(3), abs=1e-9)
    assert table.gait(-3.0) == table.gait(2.0) and table.gait(0.0) == table.gait(0.2)  # held beyond the rows
    assert make_policy(str(table_path))(np.array([0.0, 1.1]), np.zeros(3)) == table.gait(1.1)  # |desired velocity|

    out = tmp_path / "scheduled.npz"
    assert fit_main([str(a), "--table", str(table_path), "--out", str(out), "--samples", "4000"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    fitted = load_policy(out)[0]
    for speed in (0.3, 0.65, 1.1, 1.9):
        got, want = fitted(np.array([speed, speed, 0.0, 0.0])), table.gait(speed)
        assert got.stepping_frequency == pytest.approx(want.stepping_frequency, abs=0.2)
        assert got.swing_ratio == pytest.approx(want.swing_ratio, abs=0.05)
        assert np.degrees(np.abs(shortest_arc(np.array(got.phase_offsets), np.array(want.phase_offsets)))).max() < 15
    assert report["all_max_offset_error_deg"] < 30  # over 2000 draws, with this test's 8 hidden units


@pytest.mark.parametrize(("rows", "message"), [
    ("1.0,2,0.5,180,180,0\n0.5,2,1.5,0,0,0\n", "line 3: swing_ratio must be in (0.0, 1.0), got 1.5"),
    ("1.0,2,0.5,180,180,0\n0.5,2,0.5,0,0,0\n", "speed must increase"),
    ("1.0,fast,0.5,180,180,0\n", "line 2: frequency must be a number"),
    ("1.0,2,0.5,180\n", "line 2: rr_deg must be a number"),
    ("", "no rows"),
])
def test_a_bad_gait_table_names_its_line_and_field(two_policies, tmp_path, capsys, rows, message):
    from gait_policy_node.fit_policy import main as fit_main

    _, (a, _) = two_policies
    table_path = tmp_path / "gaits.csv"
    table_path.write_text("speed,frequency,swing_ratio,fl_deg,rr_deg,rl_deg\n" + rows)
    assert fit_main([str(a), "--table", str(table_path), "--out", str(tmp_path / "x.npz")]) == 2
    assert message in capsys.readouterr().err


def test_fit_policy_refuses_what_a_table_cannot_use(two_policies, tmp_path, capsys):
    from gait_policy_node.fit_policy import main as fit_main

    _, (a, _) = two_policies
    table_path = tmp_path / "gaits.csv"
    table_path.write_text("speed,frequency,swing_ratio\n1.0,2,0.5\n")
    assert fit_main([str(a), "--table", str(table_path), "--out", str(tmp_path / "x.npz")]) == 2
    assert "missing column(s) ['fl_deg', 'rr_deg', 'rl_deg']" in capsys.readouterr().err
    table_path.write_text("speed,frequency,swing_ratio,fl_deg,rr_deg,rl_deg\n1.0,0.2,0.5,180,180,0\n")
    assert fit_main([str(a), "--table", str(table_path), "--out", str(tmp_path / "x.npz")]) == 2
    assert "frequency must be within the policy's range [0.5, 4]" in capsys.readouterr().err
    assert fit_main([str(a), "--table", str(tmp_path / "none.csv"), "--out", str(tmp_path / "x.npz")]) == 2
    assert "No such file" in capsys.readouterr().err
    assert fit_main([str(a), "--table", str(table_path), "--below", "1.0", "--out", str(tmp_path / "x.npz")]) == 2
    assert "apply to --lag only" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # one target or the other
        fit_main([str(a), "--table", str(table_path), "--lag", "-30", "--out", str(tmp_path / "x.npz")])


@pytest.mark.parametrize("saturated", [False, True])
@pytest.mark.parametrize("timing_prior", [(), (1.5, 0.3)])
def test_encode_action_is_decode_actions_inverse_within_its_limit(saturated, timing_prior):
    from gait_policy_node.learned_policy import decode_action, encode_action
    from gait_policy_node.train_config import ActionConfig

    cfg = ActionConfig(timing_prior=timing_prior).validated()
    rng = np.random.default_rng(1)
    for _ in range(200):
        like = rng.choice([-0.999, 0.999], 8) if saturated else rng.uniform(-0.5, 0.5, 8)
        gait = GaitParams(rng.uniform(0.6, 3.9), rng.uniform(0.1, 0.9), lag_family_offsets(rng.uniform(-180, 180)))
        a = encode_action(gait, cfg, like, limit=0.98)
        assert np.all(np.abs(a) <= 0.98)
        back = decode_action(a, cfg)
        assert back.stepping_frequency == pytest.approx(gait.stepping_frequency)
        assert back.swing_ratio == pytest.approx(gait.swing_ratio)
        assert np.allclose(np.cos(np.subtract(back.phase_offsets, gait.phase_offsets)), 1.0)


def test_a_policy_file_replaced_during_a_comparison_is_an_error_not_a_silent_mix(two_policies, tmp_path):
    """A training run replaces best_policy.npz between iterations: the variants of one comparison
    must not run different policies without saying so."""
    from gait_policy_node.compare_policies import Variant, _episode, policy_files

    _, (a, b) = two_policies
    path = tmp_path / "best_policy.npz"
    path.write_bytes(a.read_bytes())
    files = policy_files([Variant(str(path)), Variant(str(path), lag=0.0)])
    assert list(files) == [str(path)]
    path.write_bytes(b.read_bytes())
    with pytest.raises(ConfigError, match="changed while compare_policies ran"):
        _episode(Variant(str(path), lag=0.0), {}, 0, files)
