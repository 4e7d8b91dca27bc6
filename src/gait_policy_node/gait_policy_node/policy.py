"""Gait policies: map the desired and measured base velocity to the paper's gait parameters.

The paper's policy observes [desired velocity, measured velocity] and outputs
[f, p_swing, theta_2, theta_3, theta_4] at 20 Hz: a learned policy file (learned_policy.py, made by
train_es), or the hand-tuned gaits: one fixed gait by name, the gaits scheduled by commanded
speed, or a gait table (a CSV of the gait against commanded speed, e.g. a published policy's).
Velocities are in the yaw-aligned frame [m/s]: desired (x, y), measured (x, y, z).
"""

from __future__ import annotations

import csv
import math
from typing import Protocol

import numpy as np
from a1_common.config import ConfigError, require_range
from convex_mpc_node.gait import MAX_FREQUENCY, GaitParams, gait_for_speed, load_hand_tuned_gaits

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


TABLE_COLUMNS = ("speed", "frequency", "swing_ratio", "fl_deg", "rr_deg", "rl_deg")
# Each column's allowed range (low, high, low open, high open): commanded speed [m/s], stepping
# frequency [Hz] and swing ratio (0 is no gait), phase offsets of FL, RR, RL from FR [deg] (any
# turn: the table's rows are joined along the shorter arc).
_TABLE_RANGES = {"speed": (0.0, 5.0, False, False), "frequency": (0.0, MAX_FREQUENCY, True, False),
                 "swing_ratio": (0.0, 1.0, True, True), "fl_deg": (-360.0, 360.0, False, False),
                 "rr_deg": (-360.0, 360.0, False, False), "rl_deg": (-360.0, 360.0, False, False)}


class GaitTable:
    """A gait against commanded forward speed, from a CSV of TABLE_COLUMNS (one row per speed,
    speeds increasing): f and p_swing linear between rows, each phase offset along the shorter arc
    between neighbouring rows, the end rows held beyond them. Why: a gait schedule someone
    published (the reference checkpoint's, docs/results/reference_gaits/) runs in every tool as is."""

    def __init__(self, path: str) -> None:
        self.path = path
        rows = _read_table(path)
        self.speeds, self.frequencies, self.swing_ratios = rows[:, 0], rows[:, 1], rows[:, 2]
        self.offsets = np.unwrap(np.radians(rows[:, 3:]), axis=0)  # [rad], (rows, 3)

    def gait(self, speed: float) -> GaitParams:
        """The gait at commanded speed |``speed``| [m/s]."""
        v = abs(float(speed))
        offsets = []
        for column in self.offsets.T:
            theta = float(np.interp(v, self.speeds, column)) % (2 * math.pi)
            offsets.append(0.0 if theta >= 2 * math.pi else theta)  # -1e-17 % 2pi is 2pi
        return GaitParams(float(np.interp(v, self.speeds, self.frequencies)),
                          float(np.interp(v, self.speeds, self.swing_ratios)), (0.0, *offsets))

    def __call__(self, desired_velocity: np.ndarray, measured_velocity: np.ndarray) -> GaitParams:
        return self.gait(float(np.hypot(desired_velocity[0], desired_velocity[1])))


def _read_table(path: str) -> np.ndarray:
    """The rows of a gait table CSV as numbers; ConfigError naming the file, line and column."""
    rows = []
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            reader = csv.DictReader(handle)
            missing = [c for c in TABLE_COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise ConfigError(f"gait table {path}: missing column(s) {missing}; needs {list(TABLE_COLUMNS)}")
            for row in reader:
                where = f"gait table {path}, line {reader.line_num}"
                values = []
                for column in TABLE_COLUMNS:
                    text = row[column] or ""  # a short row leaves its last columns None
                    try:
                        value: float | str = float(text)
                    except ValueError:
                        value = text  # require_range names it as not a number
                    low, high, low_open, high_open = _TABLE_RANGES[column]
                    try:
                        values.append(require_range(column, value, low, high, low_open=low_open, high_open=high_open))
                    except ConfigError as exc:
                        raise ConfigError(f"{where}: {exc}") from None
                rows.append(values)
    except OSError as exc:
        raise ConfigError(f"gait table {path}: {exc.strerror}") from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ConfigError(f"gait table {path}: not a CSV text file ({exc})") from None
    if not rows:
        raise ConfigError(f"gait table {path}: no rows")
    table = np.array(rows)
    if np.any(np.diff(table[:, 0]) <= 0):
        raise ConfigError(f"gait table {path}: speed must increase from row to row, got {table[:, 0].tolist()}")
    return table


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
    gait name from config/gaits.yaml | a gait table ``.csv`` (GaitTable)."""
    if spec.endswith(".csv"):
        return GaitTable(spec)
    gaits = load_hand_tuned_gaits()
    if spec == "scheduled":
        return SpeedScheduledGaits(gaits)
    if spec in gaits:
        return FixedGait(gaits[spec])
    if spec == SHIPPED_POLICY or spec.endswith(".npz"):
        return LearnedGait(spec)
    raise ConfigError(f"policy must be '{SHIPPED_POLICY}', 'scheduled', one of {sorted(gaits)}, a .npz policy "
                      f"file or a .csv gait table; got {spec!r}")
