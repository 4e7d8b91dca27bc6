"""Foot contact from the A1's raw foot-force sensors, calibrated the way the reference did. No ROS.

The sensor reports an uncalibrated int16 per foot (leg order FR, FL, RR, RL) whose zero and gain
differ between feet and drift. The reference implementation thresholds it per leg:
- at stand-up: threshold = ``standing_ratio`` (0.8) x the mean reading while standing still;
- while walking: readings are collected while the gait schedule says a leg swings; when that leg
  is scheduled into stance, its threshold becomes mean(swing readings) + ``swing_margin`` (10 raw
  units) -- the unloaded reading plus a margin, so the threshold follows the sensor's drift.
The published normal force [N] is (raw - unloaded reading) x ``scale``, floored at 0; the unloaded
reading starts at ``offset`` and is then the latest swing mean.
"""

from __future__ import annotations

import numpy as np
from a1_common.robot import NUM_LEGS


class FootContactCalibrator:
    """Per-leg thresholds and unloaded readings, in raw sensor units."""

    def __init__(self, standing_ratio: float = 0.8, swing_margin: float = 10.0, offset: float = 0.0,
                 scale: float = 1.0) -> None:
        self.standing_ratio = standing_ratio
        self.swing_margin = swing_margin
        self.scale = scale  # [N per raw unit]
        self.unloaded = np.full(NUM_LEGS, float(offset))  # raw reading of a foot in the air
        self.thresholds = self.unloaded + swing_margin  # until a calibration has run
        self.swing_calibrations = 0
        self.unloaded_legs: list[int] = []  # legs that carried no load during the standing calibration
        self._standing: list[np.ndarray] = []
        self._swing: list[list[float]] = [[] for _ in range(NUM_LEGS)]

    def add_standing(self, raw: np.ndarray) -> None:
        """One reading of all four feet while the robot stands still on them."""
        self._standing.append(np.asarray(raw, dtype=float))

    def finish_standing(self) -> np.ndarray:
        """Set thresholds = ratio x mean standing reading; return them. Needs at least one reading."""
        if not self._standing:
            raise ValueError("no standing foot-force readings to calibrate from")
        mean = np.mean(self._standing, axis=0)
        self.thresholds = self.standing_ratio * mean
        # A foot that read no more than unloaded + margin was not carrying the robot (hung up?).
        self.unloaded_legs = [int(i) for i in np.flatnonzero(mean <= self.unloaded + self.swing_margin)]
        self._standing.clear()
        return self.thresholds.copy()

    def observe_schedule(self, desired_contact: np.ndarray, raw: np.ndarray) -> None:
        """The gait schedule's desired contact and the raw readings of one and the same step."""
        for leg in range(NUM_LEGS):
            if not desired_contact[leg]:
                self._swing[leg].append(float(raw[leg]))
            elif self._swing[leg]:  # scheduled swing -> stance: recalibrate from this swing
                mean = float(np.mean(self._swing[leg]))
                self.unloaded[leg] = mean
                self.thresholds[leg] = mean + self.swing_margin
                self._swing[leg].clear()
                self.swing_calibrations += 1

    def contact(self, raw: np.ndarray) -> np.ndarray:
        """(4,) bool: reading above the leg's threshold."""
        return np.asarray(raw, dtype=float) > self.thresholds

    def force(self, raw: np.ndarray) -> np.ndarray:
        """(4,) normal force estimate [N], >= 0."""
        return np.maximum(np.asarray(raw, dtype=float) - self.unloaded, 0.0) * self.scale
