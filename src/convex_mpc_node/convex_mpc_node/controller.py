"""The 500 Hz locomotion controller: phase integrator + convex MPC stance + Raibert swing control.

Library core, no ROS. Inputs are what a robot gives (joint states, IMU orientation and gyro, foot
contacts) plus the base linear velocity through one argument, so ground truth or the Kalman
estimate can feed it unchanged. Output is a JointCommand for the motors.

Frames: world z up; base frame = trunk COM frame; the MPC works in the yaw-aligned frame (world
axes rotated by the current yaw, see mpc.py). Quaternions (x, y, z, w).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from a1_common.command import JointCommand, VelocityCommand
from a1_common.config import (
    ConfigError,
    config_dir,
    load_node_parameters,
    parameter_defaults,
    parameter_descriptions,
    recording_constraints,
    require_integer,
    require_numbers,
    require_range,
    setting,
)
from a1_common.kinematics import leg_kinematics, quat_to_matrix, yaw_aligned_frame
from a1_common.robot import A1Constants, a1

from convex_mpc_node.gait import LEG_SWING, GaitParams, PhaseIntegrator
from convex_mpc_node.mpc import MpcCommand, MpcConfig, MpcState
from convex_mpc_node.stance import DriftCorrection, StanceController
from convex_mpc_node.swing import SwingController

# [s] the most the gait clock catches up in one step: a longer gap (a stall past the bridges'
# 50 ms watchdog, which has damped the motors meanwhile) is not walked through in one jump.
MAX_CATCH_UP = 0.1


@dataclass(frozen=True)
class ControllerConfig:
    control_period: float = setting(0.002, "control step period [s] (0.002: 500 Hz)")
    body_height: float = setting(0.26, "desired COM height above the ground [m]")
    swing_apex_height: float = setting(0.10, "mid-swing foot height above the landing height [m]")
    # Raibert landing offset = v T_stance / 2 + gain (v - v_cmd), clipped per axis [m].
    raibert_feedback_gain: float = setting(0.03, "Raibert landing offset per unit of velocity error [s]")
    raibert_clip: tuple[float, float] = setting((0.15, 0.10), "largest Raibert landing offset along x, y [m]")
    # Whole-robot COM relative to the trunk COM (base frame) [m], measured on the pybullet_data A1:
    # the MPC's lever arms are taken from the true COM.
    com_offset: tuple[float, float, float] = setting(
        (-0.0186, -0.0014, -0.0196), "whole-robot COM relative to the trunk COM, base frame x, y, z [m]")
    # Drift correction: the integrated command-minus-velocity error is clamped to this [m], [rad].
    max_position_error: float = setting(0.05, "clamp of the integrated command-minus-velocity drift correction [m]")
    max_yaw_error: float = setting(0.1, "clamp of the integrated yaw drift correction [rad]")
    # Solve the MPC every this many control steps (1: every step, as the paper); in between, and
    # never across a change of the measured contact set, the last forces are reused. Larger values
    # trade force-plan freshness for CPU, for realtime graphs on small computers.
    mpc_period_steps: int = setting(1, "solve the MPC every N control steps (1: every step, as the paper)")
    # Solve the MPC in a worker process (mpc_worker.py: its own GIL, below the step's priority):
    # the control step never waits for a solve and uses the newest finished one, a few ms old. For
    # realtime graphs on small computers; off in lockstep and training, where results must not
    # depend on timing.
    mpc_async: bool = setting(False, "solve the MPC in a worker process, never waited for (realtime graphs)")
    # Joint positions are predicted this far ahead (q + dq * t) before use [s]: the command acts
    # on a later state than the sensors saw (transport, compute, actuation). Measured in the
    # fault scenarios: without it 20 ms of joint-state latency makes the robot fall; 0.01 s
    # tolerates 0 to 20 ms. 0: the paper's controller.
    latency_compensation: float = setting(
        0.01, "joint positions predicted this far ahead, q + dq t [s] (0: the paper's controller)")
    mpc: MpcConfig = field(default_factory=MpcConfig)

    def validated(self) -> ControllerConfig:
        """Every field in its range (ConfigError naming it), so a bad parameter never starts a
        controller that computes NaN."""
        require_range("control_period", self.control_period, 0.0, 0.02, low_open=True)
        require_range("body_height", self.body_height, 0.1, 0.5)
        require_range("swing_apex_height", self.swing_apex_height, 0.0, 0.3, low_open=True)
        require_range("raibert_feedback_gain", self.raibert_feedback_gain, 0.0, 1.0)
        require_numbers("raibert_clip", self.raibert_clip, 2, 0.0, 0.5)
        require_numbers("com_offset", self.com_offset, 3, -0.2, 0.2)
        require_range("max_position_error", self.max_position_error, 0.0, 1.0)
        require_range("max_yaw_error", self.max_yaw_error, 0.0, math.pi)
        require_integer("mpc_period_steps", self.mpc_period_steps, 1, 25)
        if not isinstance(self.mpc_async, bool):
            raise ConfigError(f"mpc_async must be true or false, got {self.mpc_async!r}")
        require_range("latency_compensation", self.latency_compensation, 0.0, 0.05)
        return self


def controller_parameter_defaults() -> dict:
    """ControllerConfig as flat parameters (``mpc_<field>`` for MpcConfig fields), lists for tuples."""
    defaults = ControllerConfig()
    return {**parameter_defaults(defaults), **parameter_defaults(defaults.mpc, prefix="mpc_")}


def controller_parameter_descriptions() -> dict:
    """The descriptions of :func:`controller_parameter_defaults`, by parameter name."""
    defaults = ControllerConfig()
    return {**parameter_descriptions(defaults), **parameter_descriptions(defaults.mpc, prefix="mpc_")}


def controller_config_from_parameters(params: dict, source: str = "parameters") -> ControllerConfig:
    """ControllerConfig from flat parameters; unknown keys and bad values name the key."""
    mpc_fields = {f.name for f in dataclasses.fields(MpcConfig)}
    top_fields = {f.name for f in dataclasses.fields(ControllerConfig)} - {"mpc"}
    mpc_args, top_args = {}, {}
    for key, value in params.items():
        value = tuple(value) if isinstance(value, list) else value
        if key.startswith("mpc_") and key[4:] in mpc_fields:
            mpc_args[key[4:]] = value
        elif key in top_fields:
            top_args[key] = value
        else:
            allowed = sorted(top_fields | {"mpc_" + f for f in mpc_fields})
            raise ConfigError(f"{source}: unknown controller parameter '{key}'; allowed: {allowed}")
    try:
        with recording_constraints(prefix="mpc_"):  # the validator names fields, the node mpc_<field>
            mpc = MpcConfig(**mpc_args).validated()
    except ValueError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    try:
        return ControllerConfig(mpc=mpc, **top_args).validated()
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None


def load_controller_config(path=None, ignore: frozenset[str] = frozenset(), overlays: tuple = (),
                           overrides: dict | None = None) -> ControllerConfig:
    """ControllerConfig from the node's parameter file (default ``config/convex_mpc.yaml``), then
    each of ``overlays`` over it (as a second ``--params-file`` would: e.g. the realtime overlay),
    then ``overrides``, parameters by name (a training config's ``env.controller``).

    Keys in ``ignore`` belong to the node, not the controller core (default: the supervisor's and
    the node's own, which live in the same file).
    """
    paths = [path or config_dir() / "convex_mpc.yaml", *overlays]
    params = {}
    for each in paths:
        params.update(load_node_parameters(each, "convex_mpc"))
    skip = ignore or NODE_ONLY_PARAMETERS
    node_only = sorted(set(overrides or {}) & skip)
    if node_only:  # the file may hold them (the node reads it too); an override means the core
        raise ConfigError(f"overrides: {node_only} are the controller node's parameters, not the "
                          "controller's")
    params.update(overrides or {})
    source = " + ".join([str(p) for p in paths] + (["overrides"] if overrides else []))
    return controller_config_from_parameters({k: v for k, v in params.items() if k not in skip}, source)


# Keys of config/convex_mpc.yaml that configure the supervisor and the node, not the controller core.
NODE_ONLY_PARAMETERS = frozenset({
    "mode", "stand_time", "input_timeout", "gait_timeout", "cmd_vel_timeout", "max_acceleration", "stop_deceleration",
    "max_forward_speed", "max_lateral_speed", "max_yaw_rate", "fall_tilt", "cmd_vel_stamped", "mass_for_cot",
    "embedded_estimator", "estimate_after_command", "estimator_failover", "odom_every_steps", "inject_qp_failures",
})


@dataclass
class Observation:
    """What the controller reads each step."""

    joint_position: np.ndarray  # (12,) [rad]
    joint_velocity: np.ndarray  # (12,) [rad/s]
    orientation: np.ndarray  # (4,) base orientation (x, y, z, w)
    angular_velocity: np.ndarray  # (3,) base frame [rad/s] (gyro)
    foot_contact: np.ndarray  # (4,) bool
    base_velocity: np.ndarray  # (3,) world frame [m/s], ground truth or estimate


class LocomotionController:
    """Turns a velocity command and the robot's state into joint commands, every 2 ms: the phase
    integrator (gait.py) says which legs stand and swing, StanceController (stance.py) gives the
    stance legs' torques from the convex MPC, SwingController (swing.py) the swing legs' joint
    targets; this class reads the state once per step in the frames they use and composes them."""

    def __init__(self, gait: GaitParams, config: ControllerConfig, robot: A1Constants | None = None) -> None:
        self.robot = robot or a1()
        self.config = config.validated()
        cfg = self.config
        self.gait = PhaseIntegrator(gait)
        self.stance = StanceController(cfg.mpc, cfg.mpc_period_steps, cfg.mpc_async)
        self.mpc = self.stance.mpc
        self.swing = SwingController(self.robot, self.gait, body_height=cfg.body_height,
                                     com_offset_z=cfg.com_offset[2], swing_apex_height=cfg.swing_apex_height,
                                     raibert_feedback_gain=cfg.raibert_feedback_gain, raibert_clip=cfg.raibert_clip)
        self.drift = DriftCorrection(cfg.max_position_error, cfg.max_yaw_error)
        self._com_offset = np.asarray(cfg.com_offset)  # once, not every 2 ms
        self.nan_commands = 0  # steps whose command had a NaN/inf: the joints were held instead
        self.reset()

    # What the node and the tests read of the stance controller.
    mpc_fallbacks = property(lambda self: self.stance.fallbacks + self.nan_commands)
    last_solution = property(lambda self: self.stance.last_solution)
    solved_this_step = property(lambda self: self.stance.solved_this_step)
    stopgap_steps = property(lambda self: self.stance.stopgap_steps)
    plan_delay_steps = property(lambda self: self.stance.plan_delay_steps)

    def close(self) -> None:
        """Stop the MPC worker process, if any (it also exits on its own when this process dies)."""
        self.stance.close()

    def inject_qp_failures(self, steps: int) -> None:
        """Fault injection: the MPC fails for the next ``steps`` control steps (each step takes a
        solver failure's fallback, whatever ``mpc_period_steps`` and ``mpc_async`` are)."""
        self.stance.inject_failures(steps)

    def reset(self) -> None:
        self.stance.reset()
        self.gait.reset()
        self.drift.reset()
        self.swing.reset()

    def set_gait(self, params: GaitParams) -> None:
        self.gait.set_params(params)

    def step(self, obs: Observation, command: VelocityCommand, elapsed: float | None = None) -> JointCommand:
        """One control step: compute the joint command for ``obs``, then advance the phases by one
        control period.

        ``elapsed``: sim time since the previous step [s], from the sensor stamps. More than one
        period means steps were missed (a realtime controller late for its 2 ms): the gait clock
        first catches up, so the phases, the MPC's contact plan and the swing timing stay in time
        with the world rather than lagging by every missed step.
        """
        cfg = self.config
        robot = self.robot
        dt = cfg.control_period
        if elapsed is not None and elapsed > dt:
            catch_up = min(elapsed, MAX_CATCH_UP) - dt
            self.gait.step(catch_up)
            dt += catch_up
        # The state, once, in the frames the parts use.
        q_measured = np.asarray(obs.joint_position, dtype=float)
        q = q_measured + cfg.latency_compensation * np.asarray(obs.joint_velocity, dtype=float)
        rot = quat_to_matrix(np.asarray(obs.orientation, dtype=float))  # base -> world
        yaw, rot_yaw, rot_rp, roll, pitch = yaw_aligned_frame(rot)
        feet_base, jac = leg_kinematics(robot, q)
        feet_yaw = (rot_rp @ (feet_base - self._com_offset).T).T
        contact = np.asarray(obs.foot_contact, dtype=bool)
        states = self.gait.leg_states(contact)
        stance = states != LEG_SWING
        touching = stance & contact
        # COM height above the ground under the feet in contact (toe centre + toe radius).
        n_touching = int(np.count_nonzero(touching))
        height = (robot.foot_radius - float(feet_yaw[touching, 2].sum()) / n_touching if n_touching
                  else cfg.body_height)
        v_yaw = rot_yaw.T @ np.asarray(obs.base_velocity, dtype=float)
        w_yaw = rot_rp @ np.asarray(obs.angular_velocity, dtype=float)
        v_cmd = np.array([command.vx, command.vy])

        # Stance: the MPC's forces for the contact plan, as torques.
        self.drift.update(v_cmd, v_yaw, yaw, command.yaw_rate, dt)
        plan = self.gait.contact_schedule(cfg.mpc.horizon, cfg.mpc.step, leg_states=states)
        self.stance.update(MpcState(roll, pitch, height, w_yaw, v_yaw, feet_yaw),
                           MpcCommand(v_cmd, command.yaw_rate, cfg.body_height, self.drift.position_error,
                                      self.drift.yaw_error), plan, stance)
        out = JointCommand()
        out.torque = self.stance.get_action(rot_rp, jac, stance).reshape(-1)

        # Swing: the swing legs' feet along their curves, through the joints' PD.
        swing = ~stance
        self.swing.update(feet_base)
        if swing.any():
            v_base = rot.T @ np.asarray(obs.base_velocity, dtype=float)
            positions = self.swing.get_action(swing, feet_base, v_base, float(obs.angular_velocity[2]), v_cmd,
                                              command.yaw_rate)
            joints = np.repeat(swing, 3)
            out.position[joints] = positions[joints]
            out.kp[joints] = robot.joint_kp[joints]
            out.kd[joints] = robot.joint_kd[joints]
        out.torque = np.minimum(np.maximum(out.torque, -robot.motor_torque_limit), robot.motor_torque_limit)
        self.gait.step(cfg.control_period)
        if not np.isfinite(out.position.sum() + out.torque.sum()):  # a NaN/inf anywhere spoils the sum
            self.nan_commands += 1
            return JointCommand.hold(robot, q_measured if np.all(np.isfinite(q_measured)) else None)
        return out
