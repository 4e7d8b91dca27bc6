"""Gait parameters and the phase integrator of the paper (Yang et al. 2021, section 3.2).

One phase per leg in [0, 2pi): phi_1 (FR) advances by 2 pi f dt every control step, the other legs
follow at fixed offsets phi_i = phi_1 + theta_i. A leg swings while phi < 2 pi p_swing and stands
afterwards; each cycle starts with lift-off. Leg order: FR, FL, RR, RL.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np
from a1_common.config import ConfigError, config_dir, load_yaml_mapping, require_range
from a1_common.robot import NUM_LEGS

TWO_PI = 2.0 * math.pi
MAX_FREQUENCY = 4.0  # [Hz], paper: f in (0, 4]
# Measured-state thresholds on the normalised phase within swing / stance (reference values):
# contact after this much of the swing is an early touchdown; no contact after this much of
# the stance is a lost contact (earlier, the foot is just landing).
EARLY_CONTACT_SWING_FRACTION = 0.5
LOST_CONTACT_STANCE_FRACTION = 0.1


class LegState(enum.IntEnum):
    """Same values as the LEG_* constants of gait_msgs/GaitState."""

    SWING = 0
    STANCE = 1
    EARLY_CONTACT = 2
    LOST_CONTACT = 3


# As plain ints for the 2 ms path: comparing an array with an enum member costs several times more.
LEG_SWING, LEG_STANCE, LEG_EARLY_CONTACT, LEG_LOST_CONTACT = (int(s) for s in LegState)


@dataclass(frozen=True)
class GaitParams:
    """f [Hz] in (0, 4], p_swing in (0, 1), phase offsets [rad] of FR, FL, RR, RL in [0, 2pi), FR = 0."""

    stepping_frequency: float
    swing_ratio: float
    phase_offsets: tuple[float, float, float, float]

    def validated(self) -> GaitParams:
        f = require_range("stepping_frequency", self.stepping_frequency, 0.0, MAX_FREQUENCY, low_open=True)
        p = require_range("swing_ratio", self.swing_ratio, 0.0, 1.0, low_open=True, high_open=True)
        try:
            offsets = tuple(float(v) for v in np.asarray(self.phase_offsets, dtype=float).reshape(-1))
        except (TypeError, ValueError, OverflowError):
            raise ConfigError(f"phase_offsets must be {NUM_LEGS} numbers in [0, 2pi) (FR, FL, RR, RL), "
                              f"got {self.phase_offsets!r}") from None
        if len(offsets) != NUM_LEGS:
            raise ConfigError(
                f"phase_offsets must have {NUM_LEGS} entries (FR, FL, RR, RL), got {len(offsets)}")
        for leg, theta in enumerate(offsets):
            require_range(f"phase_offsets[{leg}]", theta, 0.0, TWO_PI, high_open=True)
        if offsets[0] != 0.0:
            raise ConfigError(f"phase_offsets[0] (FR, the reference leg) must be 0, got {offsets[0]}")
        return GaitParams(f, p, offsets)  # type: ignore[arg-type]


def load_hand_tuned_gaits(path=None) -> dict[str, GaitParams]:
    """The paper's hand-tuned gaits (Table 1) from ``config/gaits.yaml``, validated."""
    path = path or config_dir() / "gaits.yaml"
    data = load_yaml_mapping(path)
    gaits = {}
    keys = {"stepping_frequency", "swing_ratio", "phase_offsets"}
    for name, entry in data.items():
        if not isinstance(entry, dict) or set(entry) != keys:
            raise ConfigError(f"{path}: gait '{name}' needs exactly the keys {sorted(keys)}")
        try:
            gaits[name] = GaitParams(**entry).validated()
        except ConfigError as exc:
            raise ConfigError(f"{path}: gait '{name}': {exc}") from None
    missing = sorted({name for _, name in SPEED_SCHEDULE} - set(gaits))
    if missing:  # the controller falls back to these by speed: a missing one would fail mid-run
        raise ConfigError(f"{path}: missing gaits {missing}; the speed schedule needs "
                          f"{[name for _, name in SPEED_SCHEDULE]}")
    return gaits


# Speed schedule of the hand-tuned gaits [m/s]: (upper speed, gait name), first match wins.
SPEED_SCHEDULE = ((0.8, "walk"), (1.3, "slow_trot"), (2.0, "rapid_trot"), (float("inf"), "fly_trot"))


def gait_for_speed(speed: float, gaits: dict[str, GaitParams],
                   schedule: tuple[tuple[float, str], ...] = SPEED_SCHEDULE) -> GaitParams:
    """The hand-tuned gait for a forward speed: walk below 0.8 m/s, trots to 2.0, fly trot above."""
    for upper, name in schedule:
        if abs(speed) < upper:
            return gaits[name]
    return gaits[schedule[-1][1]]


class PhaseIntegrator:
    """Advances the leg phases at the control rate and turns them into a contact schedule."""

    def __init__(self, params: GaitParams) -> None:
        self.params: GaitParams | None = None  # the validated copy of the last parameters set
        self._set_from: GaitParams | None = None  # what set_params was last given
        self.phase_fr = 0.0  # phi_1 [rad], in [0, 2pi)
        self.set_params(params)

    def reset(self) -> None:
        """All legs restart at the beginning of their cycle (FR lifts off first)."""
        self.phase_fr = 0.0

    @property
    def phase_fr(self) -> float:
        return self._phase_fr

    @phase_fr.setter
    def phase_fr(self, value: float) -> None:
        self._phase_fr = value
        self._views: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def set_params(self, params: GaitParams) -> None:
        """New gait parameters; phi_1 continues from where it is, without a jump."""
        if params is self._set_from:
            return  # set again every 2 ms by the supervisor: validated already (GaitParams is frozen)
        self.params = params.validated()
        self._set_from = params
        self._offsets = np.asarray(self.params.phase_offsets, dtype=float)
        self._views = None

    def step(self, dt: float) -> None:
        """Advance by ``dt`` seconds: phi_1 <- phi_1 + 2 pi f dt (mod 2 pi)."""
        self.phase_fr = (self.phase_fr + TWO_PI * self.params.stepping_frequency * dt) % TWO_PI

    def _phase_views(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(phases, desired contact, normalised phase), computed once per phase and gait: a control
        step reads them several times. Read-only, so no caller can spoil them for the others."""
        if self._views is None:
            phi = (self.phase_fr + self._offsets) % TWO_PI
            cut = self.swing_threshold
            views = (phi, phi >= cut, np.where(phi < cut, phi / cut, (phi - cut) / (TWO_PI - cut)))
            for view in views:
                view.flags.writeable = False
            self._views = views
        return self._views

    @property
    def phases(self) -> np.ndarray:
        """phi_i = phi_1 + theta_i of each leg [rad], in [0, 2pi)."""
        return self._phase_views()[0]

    @property
    def swing_threshold(self) -> float:
        return TWO_PI * self.params.swing_ratio

    @property
    def desired_contact(self) -> np.ndarray:
        """True for legs the schedule wants in stance now."""
        return self._phase_views()[1]

    def normalised_phase(self) -> np.ndarray:
        """Progress in [0, 1) through the current swing or stance of each leg."""
        return self._phase_views()[2]

    @property
    def stance_duration(self) -> float:
        """T_stance = (1 - p_swing) / f [s]."""
        return (1.0 - self.params.swing_ratio) / self.params.stepping_frequency

    @property
    def swing_duration(self) -> float:
        return self.params.swing_ratio / self.params.stepping_frequency

    def leg_states(self, foot_contact: np.ndarray) -> np.ndarray:
        """Measured leg states: the schedule, overridden by early touchdown and lost contact."""
        desired = self.desired_contact
        progress = self.normalised_phase()
        contact = np.asarray(foot_contact, dtype=bool)
        states = np.where(desired, LEG_STANCE, LEG_SWING)
        states[desired & ~contact & (progress > LOST_CONTACT_STANCE_FRACTION)] = LEG_LOST_CONTACT
        states[~desired & contact & (progress > EARLY_CONTACT_SWING_FRACTION)] = LEG_EARLY_CONTACT
        return states

    def contact_schedule(self, horizon: int, step: float, foot_contact: np.ndarray | None = None,
                         leg_states: np.ndarray | None = None) -> np.ndarray:
        """Planned contact (horizon, 4) at t = k * step, k = 0..horizon-1, at the current f.

        Row 0 is replaced by the measured states when ``foot_contact`` (or the ``leg_states``
        already computed from it) is given: a leg in STANCE, EARLY_CONTACT or LOST_CONTACT counts
        as in contact for the current step.
        """
        k = np.arange(horizon)[:, None]
        future = (self.phases[None, :] + TWO_PI * self.params.stepping_frequency * step * k) % TWO_PI
        plan = future >= self.swing_threshold
        if leg_states is None and foot_contact is not None:
            leg_states = self.leg_states(foot_contact)
        if leg_states is not None and horizon > 0:
            plan[0] = leg_states != LEG_SWING
        return plan
