"""Configuration of gait-policy learning: the MDP, the policy, the trainer and the rollout workers.

One YAML file (default ``config/train_es.yaml``) with the sections ``env``, ``reward``, ``policy``,
``trainer`` and ``workers``; ``--set section.key=value`` overrides on the command line. Every value
is range-checked here, so a bad one fails before any rollout with its key and allowed range.
Defaults are the paper's (Yang et al. 2021, section 4 and appendix C).
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import yaml
from a1_common.config import (
    ConfigError,
    config_dir,
    dataclass_from_mapping,
    load_yaml_mapping,
    parse_yaml,
    require_integer,
    require_range,
)
from a1_sim_bridge.worlds import WORLD_NAMES  # names only: no simulator imported

if TYPE_CHECKING:
    from convex_mpc_node.controller import ControllerConfig

PROFILE_KINDS = ("ramp", "constant", "steps", "random")
# Observation name -> size: basic [v_des_x, v_x, v_y, v_z]; extended adds roll, pitch, gyro, 12 joint
# angles and sin/cos of the 4 leg phases (env.py builds them).
OBSERVATION_SIZES = {"basic": 4, "extended": 4 + 2 + 3 + 12 + 8}
OBSERVATIONS = tuple(OBSERVATION_SIZES)
VELOCITY_SOURCES = ("estimator", "ground_truth")
POLICY_KINDS = ("mlp", "linear")
ALGORITHMS = ("cmaes", "ars")
BACKENDS = ("process", "ray", "serial")


def _choice(name: str, value: str, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise ConfigError(f"{name} must be one of {list(allowed)}, got {value!r}")
    return value


def _interval(name: str, value: tuple, low: float, high: float) -> tuple[float, float]:
    if len(value) != 2:
        raise ConfigError(f"{name} must be [low, high], got {list(value)}")
    lo = require_range(f"{name}[0]", value[0], low, high)
    hi = require_range(f"{name}[1]", value[1], low, high)
    if lo >= hi:
        raise ConfigError(f"{name} must have low < high, got {list(value)}")
    return lo, hi


@dataclass(frozen=True)
class ProfileConfig:
    """Desired forward speed over an episode [m/s] (yaw-aligned x; no lateral or turning command)."""

    kind: str = "ramp"  # ramp | constant | steps | random
    target_speed: float = 2.5  # ramp: 0 -> target at `acceleration`, then held [m/s]
    acceleration: float = 1.0  # [m/s^2]
    speed: float = 1.0  # constant [m/s]
    steps: tuple = ((0.0, 0.5), (5.0, 1.5), (10.0, 2.5))  # steps: (start time [s], speed [m/s]); 0 before the first
    random_range: tuple = (0.0, 2.5)  # random: speeds drawn uniformly in this range [m/s] ...
    random_hold: float = 4.0  # ... each held this long [s], reached at `acceleration`

    def validated(self, where: str = "env.profile") -> ProfileConfig:
        _choice(f"{where}.kind", self.kind, PROFILE_KINDS)
        require_range(f"{where}.target_speed", self.target_speed, 0.0, 3.5)
        require_range(f"{where}.acceleration", self.acceleration, 0.0, 20.0, low_open=True)
        require_range(f"{where}.speed", self.speed, -1.0, 3.5)
        if not self.steps:
            raise ConfigError(f"{where}.steps must list at least one [time, speed] pair")
        last = -math.inf
        for i, pair in enumerate(self.steps):
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                raise ConfigError(f"{where}.steps[{i}] must be [time, speed], got {pair!r}")
            t = require_range(f"{where}.steps[{i}][0]", pair[0], 0.0, 3600.0)
            require_range(f"{where}.steps[{i}][1]", pair[1], -1.0, 3.5)
            if t <= last:
                raise ConfigError(f"{where}.steps times must increase, got {t} after {last}")
            last = t
        _interval(f"{where}.random_range", self.random_range, -1.0, 3.5)
        require_range(f"{where}.random_hold", self.random_hold, 0.1, 3600.0)
        return self


@dataclass(frozen=True)
class EnvConfig:
    """One episode: ``episode_steps`` policy steps of 0.05 s, each 25 control steps of 2 ms."""

    episode_steps: int = 400  # 20 s
    observation: str = "basic"  # basic: [v_des_x, v_x, v_y, v_z]; extended adds IMU, joints, phases
    velocity_source: str = "estimator"  # what the policy and the controller see: estimator | ground_truth
    world: str = "flat"
    ground_friction: float = 0.8
    payload_mass: float = 0.0  # [kg] on the simulated trunk (the reference simulates a 16.2 kg A1: 3.77)
    profile: ProfileConfig = field(default_factory=ProfileConfig)
    # Controller parameters by name over config/convex_mpc.yaml, for training in other conditions
    # than the deployed controller's (e.g. the reference's {mpc_friction_coefficient: 0.2}).
    controller: dict = field(default_factory=dict)

    def validated(self) -> EnvConfig:
        require_integer("env.episode_steps", self.episode_steps, 1, 100_000)
        _choice("env.observation", self.observation, OBSERVATIONS)
        _choice("env.velocity_source", self.velocity_source, VELOCITY_SOURCES)
        _choice("env.world", self.world, WORLD_NAMES)
        require_range("env.ground_friction", self.ground_friction, 0.0, 5.0, low_open=True)
        require_range("env.payload_mass", self.payload_mass, 0.0, 10.0)
        self.profile.validated()
        return self

    def controller_config(self) -> ControllerConfig:
        """The controller the episodes run: config/convex_mpc.yaml with ``controller`` over it. Checked
        here (train_es calls it before any rollout), not on every load: a policy file's training
        settings must not stop it loading in a node that never uses them."""
        from convex_mpc_node.controller import load_controller_config  # local: 0.3 s of imports

        try:
            return load_controller_config(overrides=self.controller)
        except ConfigError as exc:
            raise ConfigError(f"env.controller: {exc}") from None


@dataclass(frozen=True)
class RewardConfig:
    """r = c - w_v ((v_des - v) / v_des)^2 - w_e sum_i max(tau_i w_i + alpha tau_i^2, 0) / (m g v_des).

    Both denominators use max(v_des, min_speed); the relative speed error is clipped to
    ``max_relative_speed_error`` before squaring (the reference clips it at 1) so one slow step
    cannot dominate an episode.
    """

    alive_bonus: float = 3.0  # c
    speed_weight: float = 1.0  # w_v
    energy_weight: float = 0.37  # w_e
    joule_coefficient: float = 0.3  # alpha [W / (N m)^2]
    mass: float = 15.0  # m [kg], the paper's A1 (the simulated one is 12.458 kg)
    gravity: float = 9.8  # g [m/s^2], as in the paper
    min_speed: float = 0.3  # [m/s]
    max_relative_speed_error: float = 1.0

    def validated(self) -> RewardConfig:
        require_range("reward.alive_bonus", self.alive_bonus, 0.0, 100.0)
        require_range("reward.speed_weight", self.speed_weight, 0.0, 100.0)
        require_range("reward.energy_weight", self.energy_weight, 0.0, 100.0)
        require_range("reward.joule_coefficient", self.joule_coefficient, 0.0, 10.0)
        require_range("reward.mass", self.mass, 1.0, 200.0)
        require_range("reward.gravity", self.gravity, 1.0, 20.0)
        require_range("reward.min_speed", self.min_speed, 0.01, 5.0)
        require_range("reward.max_relative_speed_error", self.max_relative_speed_error, 0.01, 100.0)
        return self


@dataclass(frozen=True)
class ActionConfig:
    """How the network's 8 outputs a in (-1, 1) (after tanh) become the paper's gait parameters.

    f = affine(a0) over ``frequency_range`` [Hz]; p_swing = affine(a7) over ``swing_ratio_range``;
    theta_k = atan2(b sin(prior_k) + a_k, b cos(prior_k) + a_{k+3}) for FL, RR, RL, with b =
    ``offset_prior_weight``. b = 0 is the reference's decoding (zero output = pronk); the default
    b = 0.5 makes a zero output a trot while every offset stays reachable (|b| < 1).
    ``timing_prior`` (f, p_swing), when given, is what a zero output decodes to instead of the ranges'
    midpoints: a0 and a7 map linearly from -1 to the range's low end and from 0 to the prior, and
    from 0 to 1 on to the high end, so the whole range stays reachable (e.g. a walk's slow,
    short-swing timing as the CMA-ES starting mean). Not the paper's; empty by default.
    """

    frequency_range: tuple = (0.5, 4.0)  # [Hz], paper: f in (0, 4]
    swing_ratio_range: tuple = (0.05, 0.95)  # paper: p_swing in (0, 1)
    offset_prior: tuple = (math.pi, math.pi, 0.0)  # [rad] FL, RR, RL: the trot
    offset_prior_weight: float = 0.5
    timing_prior: tuple = ()  # (f [Hz], p_swing) of a zero output; empty: the ranges' midpoints

    def validated(self) -> ActionConfig:
        _interval("policy.action.frequency_range", self.frequency_range, 0.001, 4.0)
        _interval("policy.action.swing_ratio_range", self.swing_ratio_range, 0.001, 0.999)
        if len(self.offset_prior) != 3:
            raise ConfigError(f"policy.action.offset_prior must have 3 entries (FL, RR, RL), got {self.offset_prior}")
        for i, theta in enumerate(self.offset_prior):
            require_range(f"policy.action.offset_prior[{i}]", theta, 0.0, 2 * math.pi)
        require_range("policy.action.offset_prior_weight", self.offset_prior_weight, 0.0, 1.0, high_open=True)
        if self.timing_prior:
            if len(self.timing_prior) != 2:
                raise ConfigError("policy.action.timing_prior must be [] or [f, p_swing], "
                                  f"got {list(self.timing_prior)}")
            for i, (name, (lo, hi)) in enumerate((("frequency_range", self.frequency_range),
                                                   ("swing_ratio_range", self.swing_ratio_range))):
                require_range(f"policy.action.timing_prior[{i}] (inside {name})", self.timing_prior[i], lo, hi,
                              low_open=True, high_open=True)
        return self


@dataclass(frozen=True)
class PolicyConfig:
    kind: str = "mlp"  # mlp: one hidden tanh layer (paper); linear
    hidden_units: int = 256
    action: ActionConfig = field(default_factory=ActionConfig)

    def validated(self) -> PolicyConfig:
        _choice("policy.kind", self.kind, POLICY_KINDS)
        require_integer("policy.hidden_units", self.hidden_units, 1, 4096)
        self.action.validated()
        return self


@dataclass(frozen=True)
class TrainerConfig:
    algorithm: str = "cmaes"  # cmaes | ars
    seed: int = 1000
    iterations: int = 300
    population_size: int = 32  # CMA-ES
    sigma0: float = 0.03  # CMA-ES initial step size (mean 0)
    ars_directions: int = 16  # ARS: 2 rollouts per direction
    ars_sigma: float = 0.03
    ars_step_size: float = 0.02
    checkpoint_every: int = 5  # iterations
    eval_every: int = 5  # iterations between rollouts of the current mean policy (0: never)

    def validated(self) -> TrainerConfig:
        _choice("trainer.algorithm", self.algorithm, ALGORITHMS)
        require_integer("trainer.seed", self.seed, 0, 2**31 - 1)
        require_integer("trainer.iterations", self.iterations, 1, 1_000_000)
        require_integer("trainer.population_size", self.population_size, 2, 10_000)
        require_range("trainer.sigma0", self.sigma0, 0.0, 10.0, low_open=True)
        require_integer("trainer.ars_directions", self.ars_directions, 1, 10_000)
        require_range("trainer.ars_sigma", self.ars_sigma, 0.0, 10.0, low_open=True)
        require_range("trainer.ars_step_size", self.ars_step_size, 0.0, 10.0, low_open=True)
        require_integer("trainer.checkpoint_every", self.checkpoint_every, 1, 1_000_000)
        require_integer("trainer.eval_every", self.eval_every, 0, 1_000_000)
        return self


@dataclass(frozen=True)
class WorkerConfig:
    backend: str = "process"  # process (local pool) | ray | serial (in this process)
    count: int = 0  # rollout workers; 0 = all cores (os.cpu_count())
    address: str = ""  # ray: cluster address ("auto", "ray://host:10001"); empty = start a local instance

    def validated(self) -> WorkerConfig:
        _choice("workers.backend", self.backend, BACKENDS)
        require_integer("workers.count", self.count, 0, 4096)
        return self

    def resolved_count(self) -> int:
        return self.count or os.cpu_count() or 1


@dataclass(frozen=True)
class TrainConfig:
    env: EnvConfig = field(default_factory=EnvConfig)
    reward: RewardConfig = field(default_factory=RewardConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    trainer: TrainerConfig = field(default_factory=TrainerConfig)
    workers: WorkerConfig = field(default_factory=WorkerConfig)

    def validated(self) -> TrainConfig:
        for section in (self.env, self.reward, self.policy, self.trainer, self.workers):
            section.validated()
        return self

    def to_dict(self) -> dict:
        return json.loads(json.dumps(dataclasses.asdict(self)))  # tuples -> lists

    def policy_hash(self) -> str:
        """Hash of what gives a policy file its meaning (observation, action decoding, network)."""
        key = {"observation": self.env.observation, "policy": dataclasses.asdict(self.policy)}
        if not self.policy.action.timing_prior:  # the decoding before timing_prior existed: same hash
            del key["policy"]["action"]["timing_prior"]
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def parse_override(text: str) -> tuple[list[str], object]:
    """``section.key=value`` (value parsed as YAML: numbers, lists, strings) -> (path, value)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like section.key=value")
    key, _, raw = text.partition("=")
    path = [p for p in key.strip().split(".") if p]
    if not path:
        raise ConfigError(f"override {text!r} has no key")
    try:
        value = parse_yaml(raw)
    except yaml.YAMLError as exc:
        raise ConfigError(f"override {key}: value {raw!r} is not valid YAML: {exc}") from None
    return path, value


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """A copy of the nested mapping ``data`` with each ``section.key=value`` set."""
    data = copy.deepcopy(data)  # (not a JSON round trip: YAML dates or sets must reach the checks)
    for text in overrides:
        path, value = parse_override(text)
        node = data
        for part in path[:-1]:
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"override {text!r}: {part} is not a section")
            node = child
        node[path[-1]] = value
    return data


def train_config_from_mapping(data: dict, where: str = "") -> TrainConfig:
    try:
        return dataclass_from_mapping(TrainConfig, data, where).validated()
    except TypeError as exc:  # e.g. a section given as a scalar
        raise ConfigError(f"{where or 'config'}: {exc}") from None


def load_train_config(path: str | os.PathLike | None = None, overrides: list[str] | None = None) -> TrainConfig:
    """The training config from YAML (default ``config/train_es.yaml``) with overrides applied."""
    path = path or config_dir() / "train_es.yaml"
    data = load_yaml_mapping(path)
    data = apply_overrides(data, overrides or [])
    try:
        return train_config_from_mapping(data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
