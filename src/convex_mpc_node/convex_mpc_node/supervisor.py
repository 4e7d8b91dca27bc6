"""Mode logic around the locomotion controller: stand-up, walk, damping, e-stop, stale inputs.

Library core of the controller node (no ROS): the node only converts messages and calls this.
- Modes: STAND (joint PD to the nominal pose, ramped from wherever the legs are), WALK (the MPC
  controller), DAMPING (motors damped, the A1's safe state). Every start, and every return from
  DAMPING or a stale-input hold, goes through STAND for ``stand_time`` before the requested mode.
  STAND requested while walking is a controlled stop first (state "stopping_to_stand": the command
  ramps to zero at ``stop_deceleration``, STOP_SETTLE_TIME of trotting in place), then the stance.
- E-stop: latched DAMPING until cleared, whatever else arrives.
- Fall: a body tilted more than ``fall_tilt`` from upright (IMU) has fallen; the motors go to
  DAMPING, latched like the e-stop until it is cleared: the MPC pushing on from a fallen pose
  only flails the legs.
- Stale inputs: with no base velocity estimate for ``input_timeout`` the robot holds a safe
  stance (joint PD); when the estimate returns it stands up again and resumes. If the node has a
  backup estimate (its own estimator core, started from the last good estimate) a walking robot
  first comes to a controlled stop on it ("stopping": the command ramps to zero at
  ``stop_deceleration``, then STOP_SETTLE_TIME of trotting in place) before the safe stance:
  freezing the joints of a robot running at 1.5 m/s throws it over.
- Commands: /cmd_vel NaN/inf is rejected, values are clamped to the limits, the target is reached
  at ``max_acceleration``, and it falls back to zero after ``cmd_vel_timeout`` (0 = never).
- Gait: the last valid gait parameters; after ``gait_timeout`` without any, the hand-tuned gaits
  scheduled by speed take over (counted).
- Bad input never reaches a motor: a step whose observation is mis-sized or not finite (or whose
  time is not finite) commands damping for that step, state "invalid_input"; a command the
  controller computes that is not finite or has gains out of range is replaced by damping, state
  "invalid_command", and the robot stands up again before walking on. Both are counted, with the
  last reason kept in ``last_rejection``.
Times are seconds of the controller's clock (sim time under a sim bridge).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np
from a1_common.command import CommandError, CommandShaper, JointCommand, VelocityCommand
from a1_common.config import ConfigError, config_dir, load_node_parameters, require_choice, require_range, setting
from a1_common.robot import NUM_JOINTS, NUM_LEGS

from convex_mpc_node.controller import LocomotionController, Observation
from convex_mpc_node.gait import SPEED_SCHEDULE, GaitParams, gait_for_speed

STOOD_UP_JOINT_ERROR = 0.2  # [rad] largest joint error from the nominal pose to start walking
STOOD_UP_TILT = np.radians(10.0)  # [rad] largest body tilt to start walking
STOP_SETTLE_TIME = 0.5  # [s] of trotting in place at zero command before a stale-input safe stance
# Orientations are normalised; a norm outside this range is garbage, not noise.
MIN_QUATERNION_NORM, MAX_QUATERNION_NORM = 0.5, 2.0
_OBSERVATION_SHAPES = (("joint_position", (NUM_JOINTS,)), ("joint_velocity", (NUM_JOINTS,)), ("orientation", (4,)),
                       ("angular_velocity", (3,)), ("base_velocity", (3,)))


class Mode(enum.Enum):
    STAND = "stand"
    WALK = "walk"
    DAMPING = "damping"


@dataclass(frozen=True)
class SupervisorConfig:
    mode: str = setting("walk", "requested mode after stand-up: stand | walk | damping")
    stand_time: float = setting(1.0, "stand-up ramp to the nominal pose [s]")
    # [s] without a velocity estimate -> stop / safe stance; under the bridges' 50 ms command
    # watchdog, so the controller's own reaction comes before the bridge damps the motors
    input_timeout: float = setting(0.03, "no velocity estimate (/odom) for this long -> stop, safe stance [s]")
    gait_timeout: float = setting(0.5, "no /gait/params for this long -> hand-tuned gaits by speed [s]")
    cmd_vel_timeout: float = setting(2.0, "no /cmd_vel for this long -> target velocity 0 [s] (0: never)")
    max_acceleration: float = setting(1.0, "acceleration toward the commanded velocity [m/s^2, rad/s^2]")
    stop_deceleration: float = setting(2.0, "deceleration of a controlled stop on the backup estimate [m/s^2, rad/s^2]")
    max_forward_speed: float = setting(3.0, "/cmd_vel forward speed clamp [m/s]")
    max_lateral_speed: float = setting(1.0, "/cmd_vel lateral speed clamp [m/s]")
    max_yaw_rate: float = setting(2.0, "/cmd_vel yaw rate clamp [rad/s]")
    fall_tilt: float = setting(1.0, "body tilt beyond which the robot has fallen: damping until ~/clear_estop [rad]")

    def validated(self) -> SupervisorConfig:
        require_choice("mode", self.mode, [m.value for m in Mode])
        require_range("stand_time", self.stand_time, 0.0, 10.0)
        require_range("input_timeout", self.input_timeout, 0.0, 10.0, low_open=True)
        require_range("gait_timeout", self.gait_timeout, 0.0, 60.0, low_open=True)
        require_range("cmd_vel_timeout", self.cmd_vel_timeout, 0.0, 3600.0)
        require_range("max_acceleration", self.max_acceleration, 0.0, 20.0, low_open=True)
        require_range("stop_deceleration", self.stop_deceleration, 0.0, 20.0, low_open=True)
        require_range("max_forward_speed", self.max_forward_speed, 0.0, 5.0, low_open=True)
        require_range("max_lateral_speed", self.max_lateral_speed, 0.0, 3.0, low_open=True)
        require_range("max_yaw_rate", self.max_yaw_rate, 0.0, 6.0, low_open=True)
        require_range("fall_tilt", self.fall_tilt, 0.3, math.pi / 2)
        return self


def load_supervisor_config(path=None) -> SupervisorConfig:
    """SupervisorConfig from the controller's parameter file (default ``config/convex_mpc.yaml``),
    for a node that must act on the same command shaping as the controller (the gait policy)."""
    path = path or config_dir() / "convex_mpc.yaml"
    params = load_node_parameters(path, "convex_mpc")
    try:
        return SupervisorConfig(**{f.name: params[f.name] for f in fields(SupervisorConfig) if f.name in params}
                                ).validated()
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


@dataclass
class StepResult:
    command: JointCommand
    # "stand", "walk", "damping", "estop", "fallen", "stopping", "safe_stand" (stale estimate),
    # "stopping_to_stand" (mode stand requested while walking)
    state: str
    velocity_command: VelocityCommand


class ControllerSupervisor:
    def __init__(self, controller: LocomotionController, gaits: Mapping[str, GaitParams],
                 config: SupervisorConfig | None = None) -> None:
        """``gaits``: the hand-tuned gaits by name (config/gaits.yaml) taken by speed after gait_timeout."""
        self.controller = controller
        self.config = (config or SupervisorConfig()).validated()
        self.requested = Mode(self.config.mode)
        missing = sorted({name for _, name in SPEED_SCHEDULE} - set(gaits))
        if missing:  # taken by speed after gait_timeout: a missing one would fail mid-run
            raise ConfigError(f"hand-tuned gaits {missing} missing; the speed schedule needs "
                              f"{[name for _, name in SPEED_SCHEDULE]}")
        self.gaits = dict(gaits)
        self.estopped = False
        self.fallen = False  # latched like the e-stop (see the module docstring)
        self.falls = 0
        self.rejected_cmd_vel = 0
        self.rejected_gait_params = 0
        self.gait_fallbacks = 0
        self.safe_stand_steps = 0
        self.stopping_steps = 0  # steps of controlled stop on a backup velocity estimate
        self.rejected_observations = 0  # steps damped because the observation was unusable
        self.invalid_commands = 0  # controller outputs replaced by damping
        self.last_rejection = ""
        # vx, vy, yaw rate: requested (target) and after the acceleration limit (command)
        self._shaper = CommandShaper(self.config.max_acceleration, self.config.cmd_vel_timeout)
        self._gait: GaitParams | None = None
        self._gait_time = float("-inf")
        self._in_fallback_gait = False
        self._velocity_time = float("-inf")
        self._stand_start: tuple[float, np.ndarray] | None = None  # (time, pose) of the stand ramp
        self._walking = False
        self._stopped_since: float | None = None  # stopping: when the command reached zero
        self._stand_stop_settled_since: float | None = None  # the same for a stop to `mode stand`
        self._last_time: float | None = None

    # --- inputs --------------------------------------------------------------------------------
    def set_mode(self, mode: str) -> None:
        self.requested = Mode(require_choice("mode", mode, [m.value for m in Mode]))

    def estop(self) -> None:
        self.estopped = True

    def clear_estop(self) -> None:
        """Clear the e-stop and a fall: the robot stands up again before anything else."""
        if self.estopped or self.fallen:
            self.estopped = self.fallen = False
            self._stand_start = None

    def restart(self) -> None:
        """The robot's world started over (a simulation reset; its clock went back): stand up again,
        and wait for a new /cmd_vel, gait and estimate, since those of the old run are void. A fall is
        forgotten with the world it happened in; an e-stop stays latched."""
        self.fallen = self._walking = False
        self._stand_start = self._stopped_since = self._stand_stop_settled_since = self._last_time = None
        self._shaper.reset()
        self._gait_time = self._velocity_time = float("-inf")

    def on_cmd_vel(self, vx: float, vy: float, yaw_rate: float, now: float) -> bool:
        values = np.array([vx, vy, yaw_rate], dtype=float)
        if not np.all(np.isfinite(values)):
            self.rejected_cmd_vel += 1
            return False
        cfg = self.config
        limits = np.array([cfg.max_forward_speed, cfg.max_lateral_speed, cfg.max_yaw_rate])
        self._shaper.set_target(np.clip(values, -limits, limits), now)  # documented clamp
        return True

    def on_gait_params(self, params: GaitParams, now: float) -> bool:
        try:
            self._gait = params.validated()
        except ConfigError:
            self.rejected_gait_params += 1
            return False
        self._gait_time = now
        return True

    # --- the 500 Hz step -----------------------------------------------------------------------
    def step(self, now: float, obs: Observation, velocity_fresh: bool, backup_velocity: bool = False) -> StepResult:
        """Command for this step. ``velocity_fresh``: obs.base_velocity is a current estimate;
        ``backup_velocity``: it is not, but it is the node's backup estimate (see the module docstring).

        Never returns a command with NaN/inf or out-of-range gains (see the module docstring).
        """
        problem = "time is not finite" if not np.isfinite(now) else observation_problem(obs)
        if problem is not None:
            self.rejected_observations += 1
            self.last_rejection = f"observation: {problem}"
            return StepResult(JointCommand.damping(), "invalid_input", VelocityCommand(*self._shaper.command))
        obs = _normalised(obs)
        x, y = obs.orientation[0], obs.orientation[1]
        if not self.fallen and 1.0 - 2.0 * (x * x + y * y) < math.cos(self.config.fall_tilt):  # cos(tilt)
            self.fallen, self._walking, self._stand_start = True, False, None
            self.falls += 1
        if self.fallen:
            return StepResult(JointCommand.damping(), "fallen", VelocityCommand(*self._shaper.command))
        result = self._step(now, obs, velocity_fresh, backup_velocity)
        problem = command_problem(result.command)
        if problem is not None:
            self.invalid_commands += 1
            self.last_rejection = f"{result.state} command: {problem}"
            self._walking = False  # stand up again (joint PD) before the controller runs anew
            self._stand_start = None
            return StepResult(JointCommand.damping(), "invalid_command", result.velocity_command)
        return result

    def _step(self, now: float, obs: Observation, velocity_fresh: bool, backup_velocity: bool) -> StepResult:
        dt = 0.0 if self._last_time is None else max(now - self._last_time, 0.0)
        self._last_time = now
        if velocity_fresh:
            self._velocity_time = now
            self._stopped_since = None
        stale = now - self._velocity_time > self.config.input_timeout
        stopping = stale and backup_velocity and self._walking
        # `mode stand` while walking: a controlled stop like the one above, then the stance.
        stop_to_stand = self.requested == Mode.STAND and self._walking and not stale
        if not stop_to_stand:
            self._stand_stop_settled_since = None
        velocity_command = self._limited_command(now, dt, stopping or stop_to_stand)
        if self.estopped or self.requested == Mode.DAMPING:
            self._stand_start = None
            self._walking = False
            return StepResult(JointCommand.damping(), "estop" if self.estopped else "damping", velocity_command)
        if stopping:
            if self._stopped_since is None and not np.any(self._shaper.command):
                self._stopped_since = now
            if self._stopped_since is None or now - self._stopped_since < STOP_SETTLE_TIME:
                self.stopping_steps += 1
                return self._walk(now, dt, obs, velocity_command, "stopping")
        if stop_to_stand:
            if self._stand_stop_settled_since is None and not np.any(self._shaper.command):
                self._stand_stop_settled_since = now
            settled = self._stand_stop_settled_since
            if settled is None or now - settled < STOP_SETTLE_TIME:
                return self._walk(now, dt, obs, velocity_command, "stopping_to_stand")
            self._walking, self._stand_start, self._stand_stop_settled_since = False, None, None
        if stale:
            self.safe_stand_steps += 1
            self._walking = False
            return StepResult(self._stand(now, obs), "safe_stand", self._hold_command())
        if not self._walking and (self._stand_start is None or self.requested == Mode.STAND
                                  or now - self._stand_start[0] < self.config.stand_time
                                  or not self._stood_up(obs)):
            return StepResult(self._stand(now, obs), "stand", self._hold_command())
        if not self._walking:
            self.controller.reset()
            self._walking = True
        return self._walk(now, dt, obs, velocity_command, "walk")

    def _walk(self, now: float, elapsed: float, obs: Observation, command: VelocityCommand, state: str) -> StepResult:
        """One step of the locomotion controller on the current gait; ``elapsed`` [s] since the last
        step lets the controller's gait clock catch up with missed steps."""
        self.controller.set_gait(self._current_gait(now, command))
        return StepResult(self.controller.step(obs, command, elapsed=elapsed), state, command)

    def _stood_up(self, obs: Observation) -> bool:
        """Walking starts only from a real stance: joints near the nominal pose, body level."""
        robot = self.controller.robot
        joints_ok = np.max(np.abs(np.asarray(obs.joint_position) - robot.nominal_joint_angles)) < STOOD_UP_JOINT_ERROR
        x, y = obs.orientation[0], obs.orientation[1]
        level = 1 - 2 * (x * x + y * y) > np.cos(STOOD_UP_TILT)
        return bool(joints_ok and level)

    def _stand(self, now: float, obs: Observation) -> JointCommand:
        q = np.asarray(obs.joint_position, dtype=float)
        if self._stand_start is None:
            self._stand_start = (now, q.copy())
        t0, q0 = self._stand_start
        return JointCommand.stand_up(self.controller.robot, q0, now - t0, self.config.stand_time)

    def _hold_command(self) -> VelocityCommand:
        """Standing: the shaped command stays at zero, so walking starts from rest, not from a
        target the ramp reached while the robot stood."""
        self._shaper.hold()
        return VelocityCommand(0.0, 0.0, 0.0)

    def _limited_command(self, now: float, dt: float, stopping: bool = False) -> VelocityCommand:
        return VelocityCommand(*self._shaper.update(now, dt, self.config.stop_deceleration if stopping else None))

    def _current_gait(self, now: float, command: VelocityCommand) -> GaitParams:
        if self._gait is not None and now - self._gait_time <= self.config.gait_timeout:
            self._in_fallback_gait = False
            return self._gait
        if not self._in_fallback_gait:
            self.gait_fallbacks += 1
            self._in_fallback_gait = True
        return gait_for_speed(abs(command.vx), self.gaits)


def observation_problem(obs: Observation) -> str | None:
    """Why ``obs`` cannot drive the robot (wrong size, NaN/inf, no rotation), or None if usable."""
    arrays = [getattr(obs, name) for name, _ in _OBSERVATION_SHAPES]
    if (all(isinstance(a, np.ndarray) and a.dtype == float and a.shape == shape
            for a, (_, shape) in zip(arrays, _OBSERVATION_SHAPES, strict=True))
            and np.shape(obs.foot_contact) == (NUM_LEGS,)):
        # Fast path for the node's own float arrays (every 2 ms): one finiteness check, scalar norm.
        if np.isfinite(np.concatenate(arrays)).all():
            norm = math.sqrt(float(obs.orientation @ obs.orientation))
            if MIN_QUATERNION_NORM <= norm <= MAX_QUATERNION_NORM:
                return None
    for name, shape in _OBSERVATION_SHAPES:  # the slow path names what is wrong
        try:
            arr = np.asarray(getattr(obs, name), dtype=float)
        except (TypeError, ValueError, OverflowError):
            return f"{name} is not numeric"
        if arr.shape != shape:
            return f"{name} must have shape {shape}, got {arr.shape}"
        if not np.isfinite(arr).all():
            return f"{name} is not finite"
    if np.shape(obs.foot_contact) != (NUM_LEGS,):
        return f"foot_contact must have shape ({NUM_LEGS},), got {np.shape(obs.foot_contact)}"
    with np.errstate(over="ignore"):  # a huge quaternion overflows to inf: refused below
        norm = float(np.linalg.norm(np.asarray(obs.orientation, dtype=float)))
    if not MIN_QUATERNION_NORM <= norm <= MAX_QUATERNION_NORM:
        return f"orientation must be a unit quaternion, got norm {norm:.3g}"
    return None


def _normalised(obs: Observation) -> Observation:
    """``obs`` as float arrays with a unit orientation quaternion (an already checked observation)."""
    q = np.asarray(obs.orientation, dtype=float)
    return Observation(np.asarray(obs.joint_position, dtype=float), np.asarray(obs.joint_velocity, dtype=float),
                       q / np.linalg.norm(q), np.asarray(obs.angular_velocity, dtype=float),
                       np.asarray(obs.foot_contact, dtype=bool), np.asarray(obs.base_velocity, dtype=float))


def command_problem(command: JointCommand) -> str | None:
    """Why ``command`` must not reach the motors (JointCommand.validated's error), or None."""
    try:
        command.validated()
    except CommandError as exc:
        return str(exc)
    return None
