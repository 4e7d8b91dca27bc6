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
from a1_common.command import JointCommand
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
from a1_common.kinematics import foot_positions, inverse_kinematics, leg_kinematics, quat_to_matrix
from a1_common.robot import LEG_SIGNS, NUM_LEGS, A1Constants, a1

from convex_mpc_node.gait import LEG_SWING, GaitParams, PhaseIntegrator
from convex_mpc_node.mpc import ConvexMpc, MpcCommand, MpcConfig, MpcSolution, MpcState
from convex_mpc_node.mpc_worker import MpcWorkerProcess

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


def load_controller_config(path=None, ignore: frozenset[str] = frozenset()) -> ControllerConfig:
    """ControllerConfig from the node's parameter file (default ``config/convex_mpc.yaml``).

    Keys in ``ignore`` belong to the node, not the controller core (default: the supervisor's and
    the node's own, which live in the same file).
    """
    path = path or config_dir() / "convex_mpc.yaml"
    params = load_node_parameters(path, "convex_mpc")
    skip = ignore or NODE_ONLY_PARAMETERS
    return controller_config_from_parameters({k: v for k, v in params.items() if k not in skip}, str(path))


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


@dataclass
class VelocityCommand:
    """Desired base velocity in the yaw-aligned frame (forward, left) [m/s] and yaw rate [rad/s]."""

    vx: float = 0.0
    vy: float = 0.0
    yaw_rate: float = 0.0


def swing_curve(p0: np.ndarray, p_air: np.ndarray, p_land: np.ndarray, s: float | np.ndarray) -> np.ndarray:
    """Quadratic through lift-off (s=0), mid-air (s=0.5) and landing (s=1) points (paper app. A)."""
    return 2 * (s - 0.5) * (s - 1) * p0 - 4 * s * (s - 1) * p_air + 2 * s * (s - 0.5) * p_land


class LocomotionController:
    """Turns a velocity command and the robot's state into joint commands, every 2 ms."""

    def __init__(self, gait: GaitParams, config: ControllerConfig | None = None,
                 robot: A1Constants | None = None) -> None:
        self.robot = robot or a1()
        self.config = (config or load_controller_config()).validated()
        self.gait = PhaseIntegrator(gait)
        self.mpc = ConvexMpc(self.config.mpc)
        # Swing geometry that depends on the configuration only, per leg, base frame [m]: the
        # neutral foothold (under the hip, zero abduction), the mid-air point above it, and the
        # hip's velocity per unit yaw rate (z x r) [m/rad].
        cfg = self.config
        ground_z = -cfg.body_height + cfg.com_offset[2] + self.robot.foot_radius  # toe centre on the ground
        neutral = self.robot.hip_offsets.copy()
        neutral[:, 1] += LEG_SIGNS * self.robot.hip_link_length
        neutral[:, 2] = ground_z
        self._neutral = neutral
        self._mid_air = neutral + np.array([0.0, 0.0, cfg.swing_apex_height])
        self._yaw_tangent = np.column_stack([-neutral[:, 1], neutral[:, 0]])
        self._raibert_clip = np.asarray(cfg.raibert_clip)
        self.mpc_fallbacks = 0
        self.qp_failure_steps = 0  # fault injection: the MPC fails for this many more steps
        self._worker = MpcWorkerProcess(self.config.mpc) if self.config.mpc_async else None
        self.reset()

    def close(self) -> None:
        """Stop the MPC worker process, if any (it also exits on its own when this process dies)."""
        if self._worker is not None:
            self._worker.close()
            self._worker = None

    def inject_qp_failures(self, steps: int) -> None:
        """Fault injection: the MPC fails for the next ``steps`` control steps (each step takes a
        solver failure's fallback, whatever ``mpc_period_steps`` and ``mpc_async`` are)."""
        self.qp_failure_steps = require_integer("inject_qp_failures", steps, 0, 1_000_000)

    def reset(self) -> None:
        if self._worker is not None:
            self._worker.wait()  # a solve still running belongs to the state before the reset
        self.gait.reset()
        self.last_solution: MpcSolution | None = None
        self.solved_this_step = False  # False: the last step reused the previous MPC forces
        self._steps_since_solve = 0
        self._solved_contacts = np.zeros(NUM_LEGS, dtype=bool)  # of the newest problem handed to a solver
        self._plan_contacts = np.zeros(NUM_LEGS, dtype=bool)  # ... and of last_solution
        self.stopgap_steps = 0  # steps that applied static forces while a solve for new contacts ran
        self.plan_delay_steps = 0  # control steps from handing the adopted solve to a solver to adopting it
        self._position_error = np.zeros(2)  # yaw-aligned frame [m]
        self._yaw_target: float | None = None
        self._was_swing = np.zeros(NUM_LEGS, dtype=bool)
        self._liftoff = foot_positions(self.robot, self.robot.nominal_joint_angles)

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
        q_measured = np.asarray(obs.joint_position, dtype=float)
        q = q_measured + cfg.latency_compensation * np.asarray(obs.joint_velocity, dtype=float)
        rot = quat_to_matrix(np.asarray(obs.orientation, dtype=float))  # base -> world
        yaw = math.atan2(rot[1, 0], rot[0, 0])
        cy, sy = math.cos(yaw), math.sin(yaw)
        rot_yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        rot_rp = rot_yaw.T @ rot  # base -> yaw-aligned frame
        roll = math.atan2(rot_rp[2, 1], rot_rp[2, 2])
        pitch = -math.asin(min(max(rot_rp[2, 0], -1.0), 1.0))

        feet_base, jac = leg_kinematics(robot, q)
        feet_yaw = (rot_rp @ (feet_base - np.asarray(cfg.com_offset)).T).T
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
        # np.minimum/np.maximum, not np.clip: on arrays this small np.clip costs several times more.
        self._position_error = np.minimum(np.maximum(self._position_error + (v_cmd - v_yaw[:2]) * dt,
                                                     -cfg.max_position_error), cfg.max_position_error)
        if self._yaw_target is None:
            self._yaw_target = yaw
        yaw_error = (self._yaw_target - yaw + np.pi) % (2 * np.pi) - np.pi
        yaw_error = min(max(float(yaw_error), -cfg.max_yaw_error), cfg.max_yaw_error)
        self._yaw_target = yaw + yaw_error + command.yaw_rate * dt

        mpc_cfg = cfg.mpc
        plan = self.gait.contact_schedule(mpc_cfg.horizon, mpc_cfg.step, leg_states=states)
        self.solved_this_step = False
        worker = self._worker
        finished = worker.poll() if worker is not None else None
        if finished is not None:
            self._adopt(finished, self._solved_contacts, self._steps_since_solve + 1)  # submitted that long ago
        due = (self.last_solution is None or self._steps_since_solve + 1 >= cfg.mpc_period_steps
               or not np.array_equal(plan[0], self._solved_contacts))
        if self.qp_failure_steps > 0:  # fault injection: this step's solve "fails"
            self.qp_failure_steps -= 1
            self._adopt(self.mpc.fallback(plan[0], "injected failure"), plan[0], 0)
            self._steps_since_solve = cfg.mpc_period_steps  # a real solve is due right after
            self._solved_contacts = plan[0].copy()
        elif due and not (worker is not None and worker.pending):
            problem = (MpcState(roll, pitch, height, w_yaw, v_yaw, feet_yaw),
                       MpcCommand(v_cmd, command.yaw_rate, cfg.body_height, self._position_error, yaw_error), plan)
            if worker is not None and self.last_solution is not None:  # the first solve: in this process
                worker.submit(*problem)
            else:
                self._adopt(self.mpc.solve(*problem), plan[0], 0)
            self._steps_since_solve = 0
            self._solved_contacts = plan[0].copy()
        else:
            self._steps_since_solve += 1
        forces = self.last_solution.forces  # yaw-aligned frame [N]
        if not np.array_equal(self._plan_contacts, stance):
            # Only while a worker solves for a new contact set (a touchdown or a lift-off): the plan
            # in hand gives a foot that just landed no force, so the weight shared by the feet in
            # contact bridges those few ms instead of letting the body drop.
            forces = self.mpc.static_forces(stance)
            self.stopgap_steps += 1

        out = JointCommand()
        # Stance: the foot pushes on the ground with -f; torques = J^T (that force in the base frame),
        # as rows: (J^T f)^T = f^T J, all legs at once.
        foot_force_base = -forces @ rot_rp
        torques = np.matmul(foot_force_base[:, None, :], jac)[:, 0, :]
        torques[~stance] = 0.0
        out.torque = torques.reshape(-1)

        swing = ~stance
        desired_swing = ~self.gait.desired_contact
        starting = desired_swing & ~self._was_swing
        self._liftoff[starting] = feet_base[starting]
        self._was_swing = desired_swing
        if swing.any():
            targets = feet_base.copy()
            v_base = rot.T @ np.asarray(obs.base_velocity, dtype=float)
            targets[swing] = self._swing_targets(swing, v_base, float(obs.angular_velocity[2]), v_cmd,
                                                 command.yaw_rate)
            joints = np.repeat(swing, 3)
            out.position[joints] = inverse_kinematics(robot, targets)[joints]
            out.kp[joints] = robot.joint_kp[joints]
            out.kd[joints] = robot.joint_kd[joints]
        out.torque = np.minimum(np.maximum(out.torque, -robot.motor_torque_limit), robot.motor_torque_limit)
        self.gait.step(cfg.control_period)
        if not np.isfinite(out.position.sum() + out.torque.sum()):  # a NaN/inf anywhere spoils the sum
            self.mpc_fallbacks += 1
            return JointCommand.hold(robot, q_measured if np.all(np.isfinite(q_measured)) else None)
        return out

    def _adopt(self, solution: MpcSolution, contacts: np.ndarray, delay_steps: int) -> None:
        self.last_solution = solution
        self._plan_contacts = contacts.copy()
        self.plan_delay_steps = delay_steps
        self.mpc_fallbacks += solution.fallback
        self.solved_this_step = True

    def _swing_targets(self, legs: np.ndarray, v_base: np.ndarray, yaw_rate: float, v_cmd: np.ndarray,
                       yaw_rate_cmd: float) -> np.ndarray:
        """Foot targets (n, 3), base frame, of the ``legs`` (mask) along the lift-off -> mid-air ->
        Raibert landing curve; ``v_cmd`` [m/s] and ``yaw_rate_cmd`` [rad/s] are the command."""
        cfg = self.config
        tangent = self._yaw_tangent[legs]
        hip_velocity = v_base[:2] + yaw_rate * tangent
        desired = v_cmd + yaw_rate_cmd * tangent
        offset = hip_velocity * (0.5 * self.gait.stance_duration) + cfg.raibert_feedback_gain * (hip_velocity - desired)
        clip = self._raibert_clip
        landing = self._neutral[legs]  # a copy (boolean indexing)
        landing[:, :2] += np.minimum(np.maximum(offset, -clip), clip)
        progress = self.gait.normalised_phase()[legs][:, None]
        return swing_curve(self._liftoff[legs], self._mid_air[legs], landing, progress)
