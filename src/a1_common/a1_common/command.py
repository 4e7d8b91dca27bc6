"""The commands passed down the stack, free of ROS: the body velocity command (what /cmd_vel
carries to the controller; CommandShaper: the command as the controller tracks it) and the
low-level joint command (the A1's hardware contract).

The joint command mirrors ``gait_msgs/MotorCommand`` and what the A1's low-level interface accepts per motor:
in HYBRID mode each joint applies ``tau = kp (q* - q) + kd (dq* - dq) + tau_ff`` [N m], clipped to
the motor limit; in DAMPING mode every joint applies ``tau = -kd_damping * dq``, the robot's safe
state. Joint order: FR, FL, RR, RL x (hip, thigh, calf).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from a1_common.config import require_range
from a1_common.robot import NUM_JOINTS, A1Constants

# Gains above these are rejected: far beyond what the A1's motors can track (its SDK scales
# kp and kd into 16-bit fields with these ceilings in mind).
MAX_KP = 1000.0  # [N m / rad]
MAX_KD = 100.0  # [N m s / rad]
# Feed-forward torques beyond this are certainly a bug upstream, not a clip candidate.
MAX_FEEDFORWARD_TORQUE = 100.0  # [N m]


@dataclass
class VelocityCommand:
    """Desired base velocity in the yaw-aligned frame (forward, left) [m/s] and yaw rate [rad/s]."""

    vx: float = 0.0
    vy: float = 0.0
    yaw_rate: float = 0.0


class CommandShaper:
    """The velocity command a controller tracks, from the latest requested one (/cmd_vel): that
    target, zero once it is older than ``timeout`` [s] (0: never), approached at ``acceleration``
    [m/s^2, rad/s^2] per axis (vx, vy, yaw rate).

    The controller's supervisor drives the robot with it; the gait policy node observes the same
    shaped command, because the policy was trained on commands that change at most at the paper's
    1 m/s^2: a step in /cmd_vel must not ask it for the gait of a speed the robot is not at yet.
    """

    def __init__(self, acceleration: float, timeout: float) -> None:
        self.acceleration = require_range("acceleration", acceleration, 0.0, 20.0, low_open=True)
        self.timeout = require_range("timeout", timeout, 0.0, 3600.0)
        self.reset()

    def reset(self) -> None:
        """No target and a command at rest (a new run)."""
        self.target = np.zeros(3)
        self.command = np.zeros(3)
        self.target_time = float("-inf")

    def set_target(self, target: np.ndarray, now: float) -> None:
        """The requested (vx, vy, yaw rate), received at ``now`` [s]."""
        self.target = np.asarray(target, dtype=float)
        self.target_time = now

    def update(self, now: float, dt: float, stop_rate: float | None = None) -> np.ndarray:
        """The command after ``dt`` [s] more toward the target, or toward zero at ``stop_rate``
        (a controlled stop) when that is given."""
        target = self.target
        if stop_rate is not None or (self.timeout > 0 and now - self.target_time > self.timeout):
            target = np.zeros(3)
        step = (self.acceleration if stop_rate is None else stop_rate) * dt
        # np.minimum/np.maximum: np.clip costs several times more on a 3-vector, every 2 ms.
        self.command = self.command + np.minimum(np.maximum(target - self.command, -step), step)
        return self.command

    def hold(self) -> None:
        """The command back to rest (the robot stands), so walking starts from rest, not from a
        target the ramp reached meanwhile."""
        self.command = np.zeros(3)


class CommandError(ValueError):
    """A joint command that must not reach the motors (the message names the field)."""


class MotorMode(enum.IntEnum):
    HYBRID = 0
    DAMPING = 1


def _zeros() -> np.ndarray:
    return np.zeros(NUM_JOINTS)


_MODE_VALUES = tuple(int(m) for m in MotorMode)
# Bounds of position, velocity, kp, kd, torque, concatenated (JointCommand.validated's fast path).
# Position and velocity only need to be finite: +-float max, which inf and NaN fail.
_FINITE = np.finfo(float).max
_LOWER = np.concatenate([np.full(2 * NUM_JOINTS, -_FINITE), np.zeros(2 * NUM_JOINTS),
                         np.full(NUM_JOINTS, -MAX_FEEDFORWARD_TORQUE)])
_UPPER = np.concatenate([np.full(2 * NUM_JOINTS, _FINITE), np.full(NUM_JOINTS, MAX_KP),
                         np.full(NUM_JOINTS, MAX_KD), np.full(NUM_JOINTS, MAX_FEEDFORWARD_TORQUE)])


@dataclass
class JointCommand:
    """One command for all 12 joints. Arrays have shape (12,), units rad, rad/s, N m."""

    mode: MotorMode = MotorMode.HYBRID
    position: np.ndarray = field(default_factory=_zeros)
    velocity: np.ndarray = field(default_factory=_zeros)
    kp: np.ndarray = field(default_factory=_zeros)
    kd: np.ndarray = field(default_factory=_zeros)
    torque: np.ndarray = field(default_factory=_zeros)

    @classmethod
    def damping(cls) -> JointCommand:
        return cls(mode=MotorMode.DAMPING)

    @classmethod
    def hold(cls, robot: A1Constants, position: np.ndarray | None = None) -> JointCommand:
        """Joint PD hold of ``position`` (default: the nominal standing pose)."""
        q = robot.nominal_joint_angles if position is None else position
        return cls(position=np.array(q, dtype=float), kp=robot.joint_kp.copy(), kd=robot.joint_kd.copy())

    @classmethod
    def stand_up(cls, robot: A1Constants, start: np.ndarray, elapsed: float, duration: float) -> JointCommand:
        """The safe stand-up every standing node does (as the A1's own): joint PD hold of a target
        moving linearly from the measured ``start`` pose [rad] to the nominal one over ``duration``
        [s] (0: at once), ``elapsed`` [s] after it began."""
        beta = 1.0 if duration <= 0 else min(max(elapsed / duration, 0.0), 1.0)
        return cls.hold(robot, beta * robot.nominal_joint_angles + (1.0 - beta) * np.asarray(start, dtype=float))

    def validated(self) -> JointCommand:
        """Return a float64 copy, or raise CommandError naming the first bad field."""
        fields = (self.position, self.velocity, self.kp, self.kd, self.torque)
        if (isinstance(self.mode, int) and self.mode in _MODE_VALUES
                and all(np.shape(a) == (NUM_JOINTS,) for a in fields)):
            # Fast path, every 2 ms on the controller and the bridge: all checks in one comparison.
            try:
                values = np.concatenate(fields, dtype=float)
            except (TypeError, ValueError):
                values = None
            if values is not None and np.all((values >= _LOWER) & (values <= _UPPER)):  # NaN fails too
                n = NUM_JOINTS
                return JointCommand(MotorMode(int(self.mode)), values[:n], values[n:2 * n], values[2 * n:3 * n],
                                    values[3 * n:4 * n], values[4 * n:])
        try:
            mode = MotorMode(int(self.mode))
        except (ValueError, TypeError):
            raise CommandError(
                f"mode must be one of {[m.value for m in MotorMode]}, got {self.mode!r}"
            ) from None
        arrays = {}
        for name in ("position", "velocity", "kp", "kd", "torque"):
            try:
                arr = np.array(getattr(self, name), dtype=float).reshape(-1)
            except (TypeError, ValueError):
                raise CommandError(f"{name} must be {NUM_JOINTS} numbers") from None
            if arr.shape != (NUM_JOINTS,):
                raise CommandError(f"{name} must have {NUM_JOINTS} entries, got {arr.size}")
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise CommandError(f"{name}[{bad[0]}] is not finite ({arr[bad[0]]})")
            arrays[name] = arr
        for name, low, high in (("kp", 0.0, MAX_KP), ("kd", 0.0, MAX_KD),
                                ("torque", -MAX_FEEDFORWARD_TORQUE, MAX_FEEDFORWARD_TORQUE)):
            arr = arrays[name]
            bad = np.flatnonzero((arr < low) | (arr > high))
            if bad.size:
                raise CommandError(f"{name}[{bad[0]}] = {arr[bad[0]]} outside [{low}, {high}]")
        return JointCommand(mode=mode, **arrays)

    def motor_torques(self, q: np.ndarray, dq: np.ndarray, torque_limit: float,
                      damping_kd: float) -> np.ndarray:
        """Torque [N m] each motor applies at joint state (q, dq), after the +-limit clip."""
        if self.mode == MotorMode.DAMPING:
            tau = -damping_kd * dq
        else:
            tau = self.kp * (self.position - q) + self.kd * (self.velocity - dq) + self.torque
        return np.clip(tau, -torque_limit, torque_limit)


class CommandWatchdog:
    """Gate between incoming commands and the motors, with the real A1's safety behaviour.

    Invalid commands are rejected (counted, with the reason kept) and never applied; once the last
    valid command is ``timeout`` seconds old the motors go to damping. Times are in seconds of
    whichever clock drives the motors (sim time in simulation, wall time on hardware).
    """

    def __init__(self, timeout: float) -> None:
        self.timeout = require_range("command_timeout", timeout, 0.0, 10.0, low_open=True)  # [s]
        self.accepted = 0
        self.accepted_since_reset = 0
        self.rejected = 0
        self.timeouts = 0  # times the motors fell back to damping for lack of commands
        self.last_error = ""
        self._command: JointCommand | None = None
        self._received_at = float("-inf")
        self._in_fallback = True

    def offer(self, command: JointCommand, now: float) -> bool:
        """Accept ``command`` received at ``now`` if valid; return whether it was accepted."""
        valid = self.check(command)
        if valid is not None:
            self.accept(valid, now)
        return valid is not None

    def check(self, command: JointCommand) -> JointCommand | None:
        """The validated command, or None after counting the rejection and keeping its reason."""
        try:
            return command.validated()
        except CommandError as exc:
            self.rejected += 1
            self.last_error = str(exc)
            return None

    def accept(self, valid: JointCommand, now: float) -> None:
        """Make an already validated command the one in force from ``now``."""
        self._command = valid
        self.accepted += 1
        self.accepted_since_reset += 1
        self._received_at = now

    def active(self, now: float) -> JointCommand:
        """The command to apply at ``now``: the latest valid one, or damping if it is stale."""
        # Damped from the moment the command is ``timeout`` old (a 50 ms timeout at 2 ms steps
        # damps the 25th step after it); the tolerance keeps that exact at any absolute time.
        stale = self._command is None or now - self._received_at >= self.timeout - 1e-9
        if stale and not self._in_fallback:
            self.timeouts += 1
        self._in_fallback = stale
        return JointCommand.damping() if stale else self._command

    def clear_command(self) -> None:
        """Forget the command in force (after a reset); counters are kept for diagnostics."""
        self._command = None
        self._received_at = float("-inf")
        self._in_fallback = True
        self.accepted_since_reset = 0

    @property
    def in_fallback(self) -> bool:
        return self._in_fallback

    @property
    def received_at(self) -> float:
        """When the command in force was accepted [s, the motors' clock]; -inf if there is none."""
        return self._received_at


class DeadlineMonitor:
    """What the robot sees of its controller, counted by a bridge once per control period (the sim
    bridge's steps, the hardware bridge's sends): periods with no new command since the one before
    or with one that came too late (a missed deadline), the longest run of them, and the
    sensor-to-command latency. One class, so that both bridges count alike and report the same
    figures."""

    def __init__(self, period: float) -> None:
        self.period = require_range("period", period, 0.0, 1.0, low_open=True)  # [s]
        self.periods = 0
        self.uncommanded = 0  # periods with nothing new to apply: missed deadlines
        self._accepted_before = 0
        self._run = 0  # uncommanded periods in a row, now
        self._longest_run = 0  # ... the longest in this window
        self._latencies: list[float] = []  # [s] in this window

    def count(self, accepted: int, late: bool = False) -> None:
        """One period, with ``accepted`` the watchdog's count of commands accepted so far; ``late``:
        the new command came too late for this period by the bridge's rule (the sim bridge: sent
        after the step's deadline; the hardware bridge: over a period after its state), which is
        still a missed deadline."""
        fresh = accepted != self._accepted_before and not late
        self._accepted_before = accepted
        self.periods += 1
        self.uncommanded += not fresh
        self._run = 0 if fresh else self._run + 1
        self._longest_run = max(self._longest_run, self._run)

    def skipped(self, periods: int) -> None:
        """``periods`` the bridge did not run at all (a realtime sim bridge that fell over 0.1 s
        behind starts again from now instead of catching up): each a missed deadline, continuing
        the current run of them."""
        self.periods += periods
        self.uncommanded += periods
        self._run += periods
        self._longest_run = max(self._longest_run, self._run)

    def latency(self, seconds: float) -> None:
        """Wall time from publishing a period's sensors to receiving the command that answers them."""
        self._latencies.append(seconds)

    def window(self) -> dict[str, str | int]:
        """The window's figures for /diagnostics, and a new window: commands answered, latency median
        and p99 [ms], longest time between two periods with a new command (one period: none missed) [ms]."""
        latencies, self._latencies = self._latencies, []
        longest, self._longest_run = self._longest_run, 0
        return {"commanded_steps_window": len(latencies),
                "latency_median_ms": f"{np.median(latencies) * 1e3:.3f}" if latencies else "n/a",
                "latency_p99_ms": f"{np.percentile(latencies, 99) * 1e3:.3f}" if latencies else "n/a",
                "longest_command_gap_ms": f"{(longest + 1) * self.period * 1e3:.0f}"}
