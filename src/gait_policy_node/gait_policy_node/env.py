"""The gait-policy MDP of the paper (section 4): 20 Hz gait parameters over the 500 Hz closed loop.

Library core, no ROS. One policy step = 0.05 s = 25 control steps of the very classes the nodes
run (A1Sim, VelocityEstimator, LocomotionController through rollout.ClosedLoop). The action is
GaitParams (f, p_swing, phase offsets); the policy module turns network outputs into it.
Observation (yaw-aligned frame, SI units): basic = [v_des_x, v_x, v_y, v_z] with v the velocity
the controller uses (Kalman estimate by default); extended appends roll, pitch [rad], gyro
[rad/s] (base frame), 12 joint angles [rad] and sin/cos of the 4 leg phases.
Deterministic for a given seed: the world is rebuilt and a fresh controller and estimator are
made on every reset.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from a1_common.command import VelocityCommand
from a1_common.kinematics import heading_frame, quat_to_matrix
from a1_sim_bridge.sim import A1Sim, SimConfig
from convex_mpc_node.controller import ControllerConfig
from convex_mpc_node.energy import motor_power
from convex_mpc_node.gait import GaitParams, load_hand_tuned_gaits
from state_estimator_node.estimator import EstimatorConfig, load_estimator_config

from gait_policy_node import speed_profiles
from gait_policy_node.rollout import POLICY_PERIOD, ClosedLoop
from gait_policy_node.speed_profiles import SpeedProfile
from gait_policy_node.train_config import OBSERVATION_SIZES, EnvConfig, ProfileConfig, RewardConfig


def make_profile(cfg: ProfileConfig, seed: int = 0) -> SpeedProfile:
    """Desired forward speed against time for an episode (``steps``: 0 before its first time);
    ``random`` draws its speeds from ``seed``."""
    if cfg.kind == "constant":
        return speed_profiles.constant(cfg.speed)
    if cfg.kind == "ramp":
        return speed_profiles.ramp(cfg.target_speed, cfg.acceleration)
    if cfg.kind == "steps":
        return speed_profiles.steps(cfg.steps)
    return speed_profiles.random_holds(cfg.random_range, cfg.random_hold, cfg.acceleration, seed)


@dataclass(frozen=True)
class RewardTerms:
    reward: float
    relative_speed_error: float  # |v_des - v| / max(v_des, min_speed), clipped
    cost_of_transport: float  # power / (m g max(v_des, min_speed))
    speed_penalty: float  # w_v * relative_speed_error^2
    energy_penalty: float  # w_e * cost_of_transport


def step_reward(cfg: RewardConfig, desired_speed: float, speed: float, power: float) -> RewardTerms:
    """The paper's reward for one policy step from its mean desired speed, mean speed [m/s] and
    mean total motor power [W] (already max(tau w + alpha tau^2, 0) per motor)."""
    denominator = max(abs(desired_speed), cfg.min_speed)
    relative = min(abs(desired_speed - speed) / denominator, cfg.max_relative_speed_error)
    cot = power / (cfg.mass * cfg.gravity * denominator)
    speed_penalty = cfg.speed_weight * relative**2
    energy_penalty = cfg.energy_weight * cot
    return RewardTerms(cfg.alive_bonus - speed_penalty - energy_penalty, relative, cot, speed_penalty, energy_penalty)


@dataclass
class StepInfo:
    desired_speed: float  # mean over the policy step [m/s]
    speed: float  # mean true forward speed [m/s]
    power: float  # mean total motor power [W]
    terms: RewardTerms
    fell: bool


@dataclass
class ControlRecord:
    """Per control step data of a recorded episode (evaluation, plots)."""

    time: list[float] = field(default_factory=list)
    desired_speed: list[float] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)  # true forward speed [m/s]
    estimated_speed: list[float] = field(default_factory=list)  # estimator's forward speed [m/s]
    power: list[float] = field(default_factory=list)  # [W]
    contacts: list[np.ndarray] = field(default_factory=list)
    frequency: list[float] = field(default_factory=list)
    swing_ratio: list[float] = field(default_factory=list)
    phase_offsets: list[tuple] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"time": np.asarray(self.time), "desired_speed": np.asarray(self.desired_speed),
                "speed": np.asarray(self.speed), "estimated_speed": np.asarray(self.estimated_speed),
                "power": np.asarray(self.power), "contacts": np.asarray(self.contacts, dtype=bool).reshape(-1, 4),
                "frequency": np.asarray(self.frequency), "swing_ratio": np.asarray(self.swing_ratio),
                "phase_offsets": np.asarray(self.phase_offsets, dtype=float).reshape(-1, 4)}


class GaitEnv:
    """reset(seed) -> observation; step(gait) -> (observation, reward, done, info)."""

    def __init__(self, env: EnvConfig | None = None, reward: RewardConfig | None = None, *,
                 controller_config: ControllerConfig | None = None,
                 estimator_config: EstimatorConfig | None = None) -> None:
        self.config = (env or EnvConfig()).validated()
        self.reward_config = (reward or RewardConfig()).validated()
        self.controller_config = controller_config or self.config.controller_config()
        self.estimator_config = estimator_config or load_estimator_config()
        self.sim = A1Sim(SimConfig(world=self.config.world, ground_friction=self.config.ground_friction,
                                   payload_mass=self.config.payload_mass))
        self._placeholder_gait = load_hand_tuned_gaits()["slow_trot"]
        self.loop: ClosedLoop | None = None
        self.record: ControlRecord | None = None
        self.steps_per_policy = round(POLICY_PERIOD / self.sim.config.time_step)

    @property
    def observation_size(self) -> int:
        return OBSERVATION_SIZES[self.config.observation]

    def reset(self, seed: int = 0, profile: SpeedProfile | None = None, record: bool = False) -> np.ndarray:
        """Start an episode; ``profile`` replaces the configured speed profile (evaluation tools)."""
        self.sim.reset(seed=seed)
        self.loop = ClosedLoop(self._placeholder_gait, sim=self.sim, controller_config=self.controller_config,
                               estimator_config=self.estimator_config, velocity_source=self.config.velocity_source)
        self.profile = profile or make_profile(self.config.profile, seed)
        self.policy_steps = 0
        self.record = ControlRecord() if record else None
        return self.observe()

    def observe(self) -> np.ndarray:
        loop = self.loop
        orientation = loop.readings.imu_orientation
        to_heading = heading_frame(orientation).T
        velocity = loop.estimated_velocity if loop.use_estimate else loop.truth.base_linear_velocity
        desired = self.profile(loop.sim.time).vx
        basic = np.concatenate([[desired], to_heading @ velocity])
        if self.config.observation == "basic":
            return basic
        r = loop.readings
        rot_rp = to_heading @ quat_to_matrix(orientation)
        roll = np.arctan2(rot_rp[2, 1], rot_rp[2, 2])
        pitch = -np.arcsin(np.clip(rot_rp[2, 0], -1.0, 1.0))
        phases = loop.controller.gait.phases
        return np.concatenate([basic, [roll, pitch], r.imu_angular_velocity, r.joint_position,
                               np.sin(phases), np.cos(phases)])

    def step(self, gait: GaitParams) -> tuple[np.ndarray, float, bool, StepInfo]:
        """Run one policy step (25 control steps) with ``gait``; stops early at a fall."""
        if self.loop is None:
            raise RuntimeError("GaitEnv.step before reset")
        loop = self.loop
        loop.controller.set_gait(gait)
        alpha = self.reward_config.joule_coefficient
        desired = speed = power = 0.0
        n = 0
        fell = False
        for _ in range(self.steps_per_policy):
            command = self.profile(loop.sim.time)
            loop.step(command)
            r = loop.readings
            p = float(motor_power(r.joint_torque, r.joint_velocity, alpha).sum())
            v = loop.forward_velocity()
            desired, speed, power, n = desired + command.vx, speed + v, power + p, n + 1
            if self.record is not None:
                self._record(command, v, p)
            if loop.fallen:
                fell = True
                break
        self.policy_steps += 1
        terms = step_reward(self.reward_config, desired / n, speed / n, power / n)
        done = fell or self.policy_steps >= self.config.episode_steps
        info = StepInfo(desired / n, speed / n, power / n, terms, fell)
        return self.observe(), terms.reward, done, info

    def _record(self, command: VelocityCommand, speed: float, power: float) -> None:
        loop, rec = self.loop, self.record
        params = loop.controller.gait.params
        to_heading = heading_frame(loop.truth.base_orientation).T
        rec.time.append(loop.sim.time)
        rec.desired_speed.append(command.vx)
        rec.speed.append(speed)
        rec.estimated_speed.append(float((to_heading @ loop.estimated_velocity)[0]))
        rec.power.append(power)
        rec.contacts.append(loop.readings.foot_contact.copy())
        rec.frequency.append(params.stepping_frequency)
        rec.swing_ratio.append(params.swing_ratio)
        rec.phase_offsets.append(params.phase_offsets)

    def close(self) -> None:
        self.sim.close()
