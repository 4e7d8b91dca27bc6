"""Gait policies: map the desired and measured base velocity to the paper's gait parameters.

The paper's policy observes [desired velocity, measured velocity] and outputs
[f, p_swing, theta_2, theta_3, theta_4] at 20 Hz: a learned policy file (learned_policy.py, made by
train_es), or the hand-tuned gaits: one fixed gait by name, or the gaits scheduled by commanded
speed. Velocities are in the yaw-aligned frame [m/s]: desired (x, y), measured (x, y, z).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from a1_common.config import ConfigError
from convex_mpc_node.gait import GaitParams, gait_for_speed, load_hand_tuned_gaits

from gait_policy_node.learned_policy import SHIPPED_POLICY, load_policy


class GaitPolicy(Protocol):
    def __call__(self, desired_velocity: np.ndarray, measured_velocity: np.ndarray) -> GaitParams: ...


class FixedGait:
    """Always the same hand-tuned gait."""

    def __init__(self, params: GaitParams) -> None:
        self.params = params.validated()

    def __call__(self, desired_velocity: np.ndarray, measured_velocity: np.ndarray) -> GaitParams:
        return self.params


class SpeedScheduledGaits:
    """The hand-tuned gaits chosen by commanded forward speed (walk, slow/rapid trot, fly trot)."""

    def __init__(self, gaits: dict[str, GaitParams]) -> None:
        self.gaits = gaits

    def __call__(self, desired_velocity: np.ndarray, measured_velocity: np.ndarray) -> GaitParams:
        return gait_for_speed(float(np.hypot(desired_velocity[0], desired_velocity[1])), self.gaits)


class LearnedGait:
    """A policy file from train_es (or the shipped one), on the paper's observation [v_des_x, v_x, v_y, v_z]."""

    def __init__(self, path: str) -> None:
        self.network, _ = load_policy(path)
        if self.network.observation != "basic":
            raise ConfigError(f"policy '{path}' uses the {self.network.observation!r} observation; the gait "
                              "policy node provides only 'basic' (desired and measured velocity)")

    def __call__(self, desired_velocity: np.ndarray, measured_velocity: np.ndarray) -> GaitParams:
        obs = np.array([desired_velocity[0], *np.asarray(measured_velocity, dtype=float)[:3]])
        return self.network(obs)


def make_policy(spec: str) -> GaitPolicy:
    """``learned`` (the shipped trained policy) | a learned policy file | ``scheduled`` | a hand-tuned
    gait name from config/gaits.yaml."""
    gaits = load_hand_tuned_gaits()
    if spec == "scheduled":
        return SpeedScheduledGaits(gaits)
    if spec in gaits:
        return FixedGait(gaits[spec])
    if spec == SHIPPED_POLICY or spec.endswith(".npz"):
        return LearnedGait(spec)
    raise ConfigError(f"policy must be '{SHIPPED_POLICY}', 'scheduled', one of {sorted(gaits)}, or a .npz policy "
                      f"file; got {spec!r}")
