"""Gait-policy learning (issue 7): reward, action decoding, policy files, optimisers, configs, env."""

from __future__ import annotations

import json
import math
import pickle
import re

import numpy as np
import pytest
from a1_common.config import ConfigError
from a1_sim_bridge.sim import SimConfig
from convex_mpc_node.controller import load_controller_config
from convex_mpc_node.energy import motor_power
from convex_mpc_node.gait import load_hand_tuned_gaits
from gait_policy_node.env import GaitEnv, make_profile, step_reward
from gait_policy_node.es import Ars, CmaEs, restore
from gait_policy_node.eval_policy import in_stack_conditions
from gait_policy_node.gait_analysis import classify_gait, transition_speeds
from gait_policy_node.learned_policy import NetworkPolicy, decode_action, load_policy, save_policy
from gait_policy_node.policy import make_policy
from gait_policy_node.rollout_workers import run_episode
from gait_policy_node.sweep_gaits import compare_with_hand_tuned, lag_family_offsets, lag_name, sweep
from gait_policy_node.train_config import (
    ActionConfig,
    EnvConfig,
    ProfileConfig,
    RewardConfig,
    TrainConfig,
    TrainerConfig,
    load_train_config,
    train_config_from_mapping,
)
from gait_policy_node.train_es import main as train_es_main

from gait_policy_node import speed_profiles


# --- reward ---------------------------------------------------------------------------------
def test_reward_terms_on_hand_computed_cases():
    cfg = RewardConfig()  # c 3, w_v 1, w_e 0.37, m 15, g 9.8, floor 0.3 m/s
    r = step_reward(cfg, desired_speed=1.0, speed=0.9, power=147.0)
    assert r.speed_penalty == pytest.approx(0.01)  # ((1.0 - 0.9) / 1.0)^2
    assert r.energy_penalty == pytest.approx(0.37 * 147.0 / (15 * 9.8 * 1.0))  # = 0.37
    assert r.reward == pytest.approx(3 - 0.01 - 0.37)
    assert (r.relative_speed_error, r.cost_of_transport) == pytest.approx((0.1, 147.0 / (15 * 9.8)))
    low = step_reward(cfg, desired_speed=0.1, speed=0.2, power=44.1)  # both denominators floored at 0.3
    assert low.speed_penalty == pytest.approx((0.1 / 0.3) ** 2)
    assert low.energy_penalty == pytest.approx(0.37 * 44.1 / (15 * 9.8 * 0.3))
    backwards = step_reward(cfg, desired_speed=1.0, speed=-1.5, power=0.0)
    assert backwards.speed_penalty == pytest.approx(1.0)  # relative error 2.5 clipped to 1
    assert backwards.reward == pytest.approx(2.0)


def test_motor_power_has_no_regeneration():
    # tau w + alpha tau^2: 10 * -2 + 0.3 * 100 = 10 W; 10 * -5 + 30 = -20 -> 0 W.
    np.testing.assert_allclose(motor_power(np.array([10.0, 10.0]), np.array([-2.0, -5.0])), [10.0, 0.0])


# --- action decoding ------------------------------------------------------------------------
def test_decoded_gaits_stay_in_the_paper_ranges():
    cfg = ActionConfig()
    rng = np.random.default_rng(0)
    for a in np.concatenate([rng.uniform(-1, 1, (500, 8)), rng.choice([-1.0, 0.0, 1.0], (200, 8))]):
        g = decode_action(a, cfg).validated()  # validated() raises outside f in (0, 4], p in (0, 1)
        assert cfg.frequency_range[0] <= g.stepping_frequency <= cfg.frequency_range[1]
        assert cfg.swing_ratio_range[0] <= g.swing_ratio <= cfg.swing_ratio_range[1]
        assert g.phase_offsets[0] == 0.0 and all(0 <= t < 2 * math.pi for t in g.phase_offsets)
    lo = decode_action(-np.ones(8), cfg)
    hi = decode_action(np.ones(8), cfg)
    assert (lo.stepping_frequency, lo.swing_ratio) == pytest.approx((0.5, 0.05))
    assert (hi.stepping_frequency, hi.swing_ratio) == pytest.approx((4.0, 0.95))
    assert decode_action(np.full(8, 5.0), cfg).stepping_frequency == pytest.approx(4.0)  # clipped


def test_zero_output_is_a_trot_with_the_prior_and_a_pronk_without():
    trot = decode_action(np.zeros(8), ActionConfig())
    np.testing.assert_allclose(trot.phase_offsets, (0, math.pi, math.pi, 0), atol=1e-12)
    pronk = decode_action(np.zeros(8), ActionConfig(offset_prior_weight=0.0))
    np.testing.assert_allclose(pronk.phase_offsets, (0, 0, 0, 0))


def test_timing_prior_is_the_zero_output_and_the_ranges_stay_reachable(tmp_path):
    walk = ActionConfig(offset_prior=(math.pi, 0.75 * math.pi, 1.75 * math.pi), timing_prior=(1.5, 0.3)).validated()
    zero = decode_action(np.zeros(8), walk)
    assert (zero.stepping_frequency, zero.swing_ratio) == pytest.approx((1.5, 0.3))
    assert classify_gait(zero.swing_ratio, np.array(zero.phase_offsets)) == "walk"
    lo, hi = decode_action(-np.ones(8), walk), decode_action(np.ones(8), walk)
    assert (lo.stepping_frequency, lo.swing_ratio) == pytest.approx((0.5, 0.05))
    assert (hi.stepping_frequency, hi.swing_ratio) == pytest.approx((4.0, 0.95))
    grid = [decode_action(np.full(8, a), walk) for a in np.linspace(-1, 1, 41)]
    assert np.all(np.diff([g.stepping_frequency for g in grid]) > 0)
    assert np.all(np.diff([g.swing_ratio for g in grid]) > 0)
    # Without it, a zero output is the ranges' midpoints, as before the prior existed.
    mid = decode_action(np.zeros(8), ActionConfig())
    assert (mid.stepping_frequency, mid.swing_ratio) == pytest.approx((2.25, 0.5))
    for bad, field in (((1.5,), "timing_prior must be"), ((4.5, 0.3), "timing_prior[0]"),
                       ((1.5, 0.95), "timing_prior[1]")):
        with pytest.raises(ConfigError, match=re.escape(field)):
            ActionConfig(timing_prior=bad).validated()
    # It is part of what gives a policy file its meaning: saved, loaded, and in the hash.
    config = train_config_from_mapping({"policy": {"action": {"timing_prior": [1.5, 0.3]}}})
    assert config.policy_hash() != TrainConfig().policy_hash()
    save_policy(tmp_path / "walk.npz", _random_policy(config), config)
    assert load_policy(tmp_path / "walk.npz")[1].policy.action.timing_prior == (1.5, 0.3)


def test_every_phase_offset_is_reachable_with_the_prior():
    cfg = ActionConfig()
    b, prior = cfg.offset_prior_weight, np.asarray(cfg.offset_prior)
    for theta in np.linspace(0, 2 * math.pi, 37)[:-1]:
        a = np.zeros(8)
        a[1:4] = 0.4 * np.sin(theta) - b * np.sin(prior)  # raw (sin, cos) vector points along theta
        a[4:7] = 0.4 * np.cos(theta) - b * np.cos(prior)
        assert np.all(np.abs(a) < 1)
        offsets = decode_action(a, cfg).phase_offsets[1:]
        np.testing.assert_allclose(np.angle(np.exp(1j * (np.array(offsets) - theta))), 0, atol=1e-9)


# --- policy files ---------------------------------------------------------------------------
def _random_policy(config: TrainConfig, seed: int = 3) -> NetworkPolicy:
    policy = NetworkPolicy.from_config(config)
    policy.set_params(np.random.default_rng(seed).normal(0, 0.3, policy.num_params))
    return policy


@pytest.mark.parametrize("kind", ["mlp", "linear"])
def test_policy_file_round_trip(tmp_path, kind):
    config = train_config_from_mapping({"policy": {"kind": kind}})
    policy = _random_policy(config)
    assert policy.num_params == (256 * 5 + 8 * 257 if kind == "mlp" else 8 * 5)
    path = tmp_path / "p.npz"
    save_policy(path, policy, config, iteration=7)
    loaded, loaded_config = load_policy(path)
    assert loaded_config == config
    np.testing.assert_array_equal(loaded.params, policy.params)
    for obs in np.random.default_rng(1).uniform(-1, 3, (20, 4)):
        assert loaded(obs) == policy(obs)
    learned = make_policy(str(path))  # the gait policy node's loader
    assert learned(np.array([1.0, 0.0]), np.array([0.9, 0.05, 0.0])) == policy(np.array([1.0, 0.9, 0.05, 0.0]))


def _rewrite(path, **changes):
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.update(changes)
    for key in [k for k, v in changes.items() if v is None]:
        del arrays[key]
    np.savez(path, **arrays)


@pytest.mark.parametrize("damage", ["truncated", "pickled_object_array", "plain_pickle", "edited_config",
                                    "missing_key", "wrong_shape", "nan_weights", "not_a_file"])
def test_corrupt_or_pickled_policy_files_are_refused(tmp_path, damage):
    config = TrainConfig()
    path = tmp_path / "p.npz"
    save_policy(path, _random_policy(config), config)
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:1000])
    elif damage == "pickled_object_array":
        np.savez(path, params=np.array([{"evil": 1}], dtype=object))
    elif damage == "plain_pickle":
        path.write_bytes(pickle.dumps({"params": [0.0] * 10}))
    elif damage == "edited_config":
        edited = config.to_dict()
        edited["policy"]["hidden_units"] = 128
        _rewrite(path, config_json=np.array(json.dumps(edited)))
    elif damage == "missing_key":
        _rewrite(path, obs_std=None)
    elif damage == "wrong_shape":
        _rewrite(path, params=np.zeros(10))
    elif damage == "nan_weights":
        with np.load(path) as data:
            params = data["params"].copy()
        params[5] = np.nan
        _rewrite(path, params=params)
    else:
        path = tmp_path / "absent.npz"
    with pytest.raises(ConfigError, match="policy file"):
        load_policy(path)


# --- optimisers -----------------------------------------------------------------------------
@pytest.mark.parametrize("algorithm", ["cmaes", "ars"])
def test_restored_optimiser_asks_what_the_uninterrupted_one_asks(algorithm):
    cfg = TrainerConfig(algorithm=algorithm, population_size=6, ars_directions=3, seed=5)
    cls = CmaEs if algorithm == "cmaes" else Ars
    running = cls(20, cfg)
    history = []
    for it in range(4):
        candidates = running.ask()
        returns = np.array([-np.sum((x - 0.1 * it) ** 2) for x in candidates])
        running.tell(returns)
        history.append(returns)
    np.random.seed(123)  # the optimisers must not depend on numpy's global random state
    resumed = restore(20, cfg, np.array(history))
    np.testing.assert_array_equal(resumed.mean, running.mean)
    for a, b in zip(resumed.ask(), running.ask(), strict=True):
        np.testing.assert_array_equal(a, b)


def test_ars_moves_towards_higher_return():
    opt = Ars(5, TrainerConfig(algorithm="ars", ars_directions=8))
    target = np.array([0.5, -0.2, 0.1, 0.0, 0.3])
    for _ in range(60):
        opt.tell(np.array([-np.sum((x - target) ** 2) for x in opt.ask()]))
    assert np.linalg.norm(opt.mean - target) < 0.5 * np.linalg.norm(target)


# --- configuration --------------------------------------------------------------------------
def test_shipped_training_config_is_the_paper_default():
    config = load_train_config()
    assert config == TrainConfig()
    assert (config.reward.alive_bonus, config.reward.speed_weight, config.reward.energy_weight) == (3.0, 1.0, 0.37)
    assert (config.reward.joule_coefficient, config.reward.mass) == (0.3, 15.0)
    assert (config.trainer.sigma0, config.trainer.population_size) == (0.03, 32)
    assert (config.trainer.ars_directions, config.trainer.ars_sigma, config.trainer.ars_step_size) == (16, 0.03, 0.02)
    assert (config.env.episode_steps, config.policy.hidden_units) == (400, 256)


@pytest.mark.parametrize(("override", "message"), [
    ("trainer.sigma0=-1", r"trainer.sigma0 must be in \(0.0, 10.0\]"),
    ("trainer.population_size=1", r"trainer.population_size must be an integer in \[2, 10000\]"),
    ("env.observation=pixels", r"env.observation must be one of \['basic', 'extended'\]"),
    ("reward.energy_weigth=0.3", r"reward: unknown keys \['energy_weigth'\]"),
    ("env.profile.target_speed=9", r"env.profile.target_speed must be in \[0.0, 3.5\]"),
    ("policy.action.frequency_range=[3, 1]", r"policy.action.frequency_range must have low < high"),
    ("workers.backend=mpi", r"workers.backend must be one of"),
    ("trainer.iterations=many", r"trainer.iterations must be a number"),
    ("trainer", r"must look like section.key=value"),
])
def test_bad_training_config_names_the_key(override, message):
    with pytest.raises(ConfigError, match=message):
        load_train_config(overrides=[override])


@pytest.mark.parametrize(("controller", "message"), [
    ("{mpc_friction: 0.2}", r"env.controller: .*unknown controller parameter 'mpc_friction'"),
    ("{mpc_friction_coefficient: 7}", r"env.controller: .*friction_coefficient must be in"),
    ("{max_forward_speed: 9, mode: stand}", r"\['max_forward_speed', 'mode'\] are the controller node's"),
])
def test_bad_env_controller_stops_train_es_before_any_rollout(controller, message, tmp_path, capsys):
    assert train_es_main(["--set", f"env.controller={controller}", "--run-dir", str(tmp_path / "run")]) == 2
    assert re.search(message, capsys.readouterr().err)
    assert not (tmp_path / "run").exists()
    # a policy file's training settings do not stop it loading: only running episodes checks them
    assert load_train_config(overrides=[f"env.controller={controller}"]).env.controller


def test_env_controller_overrides_reach_the_episodes_controller():
    """Training in the reference's conditions (its MPC assumes friction 0.2) must not need a copy of
    config/convex_mpc.yaml: the run's config says it, and the rollout workers rebuild it from that."""
    config = load_train_config(overrides=["env.controller={mpc_friction_coefficient: 0.2, mpc_mass: 13.0}"])
    assert train_config_from_mapping(config.to_dict()) == config  # what a spawned worker gets
    e = GaitEnv(config.env, config.reward)
    try:
        assert (e.controller_config.mpc.friction_coefficient, e.controller_config.mpc.mass) == (0.2, 13.0)
        # everything else is the controller's parameter file
        assert e.controller_config.body_height == load_controller_config().body_height
    finally:
        e.close()
    assert TrainConfig().env.controller_config().mpc.friction_coefficient == \
        load_controller_config().mpc.friction_coefficient


def test_eval_policy_runs_a_policy_trained_elsewhere_in_the_stacks_conditions():
    trained = load_train_config(overrides=["env.ground_friction=0.25", "env.controller={mpc_friction_coefficient: 0.2}",
                                           "env.profile.acceleration=0.5", "env.payload_mass=3.77"])
    stack = in_stack_conditions(trained)
    assert (stack.env.ground_friction, stack.env.payload_mass, stack.env.controller) == \
        (SimConfig().ground_friction, SimConfig().payload_mass, {})
    assert stack.env.controller_config() == load_controller_config()
    assert stack.env.profile == trained.env.profile and stack.policy == trained.policy  # nothing else changes


def test_malformed_yaml_is_a_config_error(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("env: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_train_config(bad)


def test_speed_profiles():
    ramp = make_profile(ProfileConfig())
    assert [ramp(t).vx for t in (0.0, 1.0, 2.5, 10.0)] == pytest.approx([0.0, 1.0, 2.5, 2.5])
    steps = make_profile(ProfileConfig(kind="steps", steps=((0.0, 0.5), (2.0, 1.5))))
    assert [steps(t).vx for t in (0.0, 1.99, 2.0, 9.0)] == [0.5, 0.5, 1.5, 1.5]
    cfg = ProfileConfig(kind="random", random_range=(0.5, 2.0), random_hold=2.0, acceleration=1.0)
    a, b, c = make_profile(cfg, 1), make_profile(cfg, 1), make_profile(cfg, 2)
    times = np.arange(0, 20, 0.05)
    speeds = np.array([a(t).vx for t in times])
    assert np.array_equal(speeds, [b(t).vx for t in times]) and not np.array_equal(speeds, [c(t).vx for t in times])
    assert np.all(np.abs(np.diff(speeds)) <= 0.05 + 1e-9)  # never faster than the acceleration
    assert speeds.max() <= 2.0


def test_speed_profiles_beyond_what_episodes_use_as_the_velocity_command_node_asks():
    backwards = speed_profiles.ramp(-1.0, acceleration=0.5)
    assert [backwards(t).vx for t in (0.0, 1.0, 4.0)] == [0.0, -0.5, -1.0]
    late = speed_profiles.steps([(1.0, 0.5), (2.0, -0.3)])
    assert [late(t).vx for t in (0.0, 0.99, 1.0, 5.0)] == [0.0, 0.0, 0.5, -0.3]  # nothing before the first step
    turning = speed_profiles.constant(0.5, 0.1, -0.4)(3.0)
    assert (turning.vx, turning.vy, turning.yaw_rate) == (0.5, 0.1, -0.4)


# --- gait classes ---------------------------------------------------------------------------
def test_gait_classes_of_the_hand_tuned_and_textbook_gaits():
    gaits = load_hand_tuned_gaits()
    assert classify_gait(gaits["walk"].swing_ratio, gaits["walk"].phase_offsets) == "walk"
    assert classify_gait(gaits["slow_trot"].swing_ratio, gaits["slow_trot"].phase_offsets) == "trot"
    assert classify_gait(gaits["fly_trot"].swing_ratio, gaits["fly_trot"].phase_offsets) == "fly trot"
    pi = math.pi
    assert classify_gait(0.4, (0, pi, 0, pi)) == "pace"
    assert classify_gait(0.4, (0, 0, pi, pi)) == "bound"
    assert classify_gait(0.4, (0, 0.1, 6.2, 0.05)) == "pronk"
    assert classify_gait(0.4, (0, pi, 0.1, 2.0)) == "other"  # FR and RR in phase, not a two-beat gait
    walk_offsets = gaits["walk"].phase_offsets
    assert classify_gait(0.5, walk_offsets) == "walk"
    assert classify_gait(0.61, walk_offsets) == "4-beat run"  # four beats, but under two feet down on average
    # The reference checkpoint's offsets at 0.5 and 2.5 m/s (reference facts, section 7.3).
    assert classify_gait(0.197, (0, 2.948, -2.312 % (2 * pi), 0.475)) == "walk"
    assert classify_gait(0.622, (0, 3.109, -2.942 % (2 * pi), 0.080)) == "fly trot"


def test_transition_speeds_from_a_gait_schedule():
    gaits = load_hand_tuned_gaits()
    speeds = np.repeat(np.arange(0, 2.5, 0.05), 25)  # one policy step per 0.05 m/s
    names = ["walk" if v < 0.8 else "slow_trot" if v < 2.0 else "fly_trot" for v in speeds]
    data = {"desired_speed": speeds, "swing_ratio": np.array([gaits[n].swing_ratio for n in names]),
            "phase_offsets": np.array([gaits[n].phase_offsets for n in names])}
    found = transition_speeds(data)
    assert [(a, b) for _, a, b in found] == [("walk", "trot"), ("trot", "fly trot")]
    assert [s for s, _, _ in found] == pytest.approx([0.8, 2.0])


def test_policy_is_compared_with_the_cheapest_hand_tuned_gait_that_tracks():
    def run(name, speed, cot, error, fell=False, f=2.0):
        return {"name": name, "target_speed": speed, "cost_of_transport": cot, "speed_error": error,
                "fell": fell, "frequency": f}

    best = [run("walk", 0.5, 1.0, 0.02), run("slow_trot", 0.5, 1.1, 0.01), run("pi", 0.5, 1.05, 0.03),
            # the cheapest hand-tuned run at 1.0 m/s lags by 10 %: the rival is the one that tracks
            run("walk", 1.0, 0.5, 0.10), run("slow_trot", 1.0, 0.8, 0.02, f=3.0), run("pi", 1.0, 0.7, 0.01),
            run("fly_trot", 2.5, 0.6, 0.01), run("pi", 2.5, 0.5, 0.08),  # cheaper but not tracking
            run("walk", 2.0, 0.9, 0.0, fell=True), run("pi", 2.0, 0.9, 0.01)]  # no rival tracks
    rows = {r["target_speed"]: r for r in compare_with_hand_tuned(best, ["walk", "slow_trot", "fly_trot"], ["pi"])}
    assert [(s, r["best_gait"], r["wins"]) for s, r in sorted(rows.items())] == [
        (0.5, "walk", False), (1.0, "slow_trot", True), (2.0, "", True), (2.5, "fly_trot", False)]
    assert rows[1.0]["best_frequency"] == 3.0 and rows[1.0]["best_cost_of_transport"] == 0.8


# --- environment ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def env():
    e = GaitEnv(EnvConfig(episode_steps=8), RewardConfig())
    yield e
    e.close()


def test_env_is_deterministic_and_independent_of_earlier_episodes(env):
    policy = _random_policy(TrainConfig(), seed=4)
    first, _ = run_episode(env, policy, seed=3)
    run_episode(env, NetworkPolicy.from_config(TrainConfig()), seed=9)  # something else in between
    again, _ = run_episode(env, policy, seed=3)
    assert first.episode_return == again.episode_return and first.policy_steps == again.policy_steps == 8
    obs = env.reset(0)
    assert obs.shape == (4,) and obs[0] == 0.0  # desired speed at t = 0 of the ramp
    _, reward, done, info = env.step(load_hand_tuned_gaits()["slow_trot"])
    assert not done and 0 < reward <= 3.0 and info.power > 0


def test_env_ends_the_episode_at_a_fall():
    env = GaitEnv(EnvConfig(episode_steps=200, profile=ProfileConfig(kind="constant", speed=2.5)))
    try:
        env.reset(0)
        clumsy = decode_action(np.array([-1, 0, 0, 0, 0, 0, 0, 1.0]), ActionConfig(offset_prior_weight=0.0))
        steps, done, info = 0, False, None
        while not done:
            _, _, done, info = env.step(clumsy)  # 0.5 Hz pronk with 95 % swing, asked for 2.5 m/s
            steps += 1
    finally:
        env.close()
    assert info.fell and steps < 200


def test_extended_observation_has_imu_joints_and_phases():
    env = GaitEnv(EnvConfig(episode_steps=2, observation="extended"))
    try:
        obs = env.reset(0)
        assert obs.shape == (env.observation_size,) == (29,)
        np.testing.assert_allclose(obs[9:21], np.tile([0.0, 0.9, -1.8], 4), atol=0.15)  # standing pose
        np.testing.assert_allclose(np.hypot(obs[21:25], obs[25:29]), 1.0)  # sin, cos of each leg's phase
    finally:
        env.close()


def test_sweep_runs_each_gait_at_each_swing_ratio_of_the_grid_and_refuses_one_out_of_range():
    config = load_train_config()
    rows = sweep(config, ["walk"], [0.5], [2.0], [], hold=3.0, workers=1, swing_ratios=[0.25, 0.4])
    assert sorted(r["swing_ratio"] for r in rows) == [0.25, 0.4]
    assert all(r["name"] == "walk" and r["frequency"] == 2.0 and not r["fell"] for r in rows)
    assert rows[0]["power"] != rows[1]["power"]  # the swing ratio reached the controller
    with pytest.raises(ConfigError, match=r"--swing-ratios: .*swing_ratio"):
        sweep(config, ["walk"], [0.5], [2.0], [], hold=3.0, workers=1, swing_ratios=[1.5])


def test_lag_family_runs_from_the_trot_to_both_walks_and_refuses_what_it_cannot_run():
    deg = np.degrees
    assert np.allclose(deg(lag_family_offsets(0)), (0, 180, 180, 0))  # trot
    assert np.allclose(deg(lag_family_offsets(90)), deg(load_hand_tuned_gaits()["walk"].phase_offsets))
    assert np.allclose(deg(lag_family_offsets(-90)), (0, 180, 90, 270))
    assert classify_gait(0.3, lag_family_offsets(30)) == "walk" and classify_gait(0.3, lag_family_offsets(10)) == "trot"
    config = load_train_config()
    rows = sweep(config, [], [0.5], [1.5], [], hold=3.0, workers=1, swing_ratios=[0.3], lags=[-45, 45])
    assert sorted(r["name"] for r in rows) == ["lag+45", "lag-45"] and not any(r["fell"] for r in rows)
    assert rows[0]["power"] != rows[1]["power"]  # the offsets reached the controller
    with pytest.raises(ConfigError, match="--lags needs --swing-ratios"):
        sweep(config, [], [0.5], [1.5], [], hold=3.0, workers=1, lags=[30])
    with pytest.raises(ConfigError, match=r"--lags must be in \[-180, 180\]"):
        lag_family_offsets(200)


def test_lag_pair_splits_one_diagonal_and_keeps_the_other_a_trots():
    deg = np.degrees
    assert np.allclose(deg(lag_family_offsets(-30, "FR-RL")), (0, 180, 180, 330))  # RL lags FR by 30 deg
    assert np.allclose(deg(lag_family_offsets(-30, "FL-RR")), (0, 180, 150, 0))
    assert np.allclose(lag_family_offsets(0, "FR-RL"), lag_family_offsets(0))  # lag 0: the trot, whichever pair
    assert lag_name(-30, "FR-RL") == "FR-RL-30" and lag_name(-30) == "lag-30"
    with pytest.raises(ConfigError, match="--lag-pair must be one of both, FR-RL, FL-RR"):
        lag_family_offsets(10, "FR-FL")
    with pytest.raises(ConfigError, match="--lag-pair FR-RL needs --lags"):
        sweep(load_train_config(), [], [0.5], [1.5], [], hold=3.0, workers=1, swing_ratios=[0.3], lag_pair="FR-RL")


def test_config_train_es_yaml_holds_the_dataclasses_own_defaults():
    """The training defaults live once, in train_config's dataclasses; config/train_es.yaml lists
    them for editing and must not say otherwise (a second source that drifts)."""
    assert load_train_config(None) == TrainConfig()
