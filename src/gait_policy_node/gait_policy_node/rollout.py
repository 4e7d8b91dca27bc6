"""In-process closed loop: the simulation core and the locomotion controller, without ROS transport.

The same classes the nodes wrap (A1Sim, LocomotionController) run here step by step at 500 Hz;
the gait comes from a schedule evaluated at 20 Hz, as the gait policy node would publish it. The
trainer, the evaluation tools, the tests and the benchmarks all run through ``run_closed_loop``,
or ``run_with_late_commands`` to measure what late commands do.
"""

from __future__ import annotations

import collections
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from a1_common.command import JointCommand, VelocityCommand
from a1_common.kinematics import heading_frame, quat_to_matrix
from a1_common.robot import FALL_HEIGHT
from a1_interface.sensors import SensorReadings
from a1_sim_bridge.sim import A1Sim, SimConfig
from convex_mpc_node.controller import ControllerConfig, LocomotionController, Observation, load_controller_config
from convex_mpc_node.energy import motor_power
from convex_mpc_node.gait import GaitParams
from state_estimator_node.estimator import EstimatorConfig, VelocityEstimator, load_estimator_config

from gait_policy_node.speed_profiles import SpeedProfile
from gait_policy_node.train_config import VELOCITY_SOURCES

POLICY_PERIOD = 0.05  # [s]: gait parameters change at 20 Hz
FALL_TILT = np.radians(30.0)  # a fall: body tilted more than this ...
_FALL_UP_Z = np.cos(FALL_TILT)  # ... i.e. the body z axis's world z below this

GaitSchedule = Callable[[float, VelocityCommand], GaitParams]


@dataclass
class Trajectory:
    """Per control step records of one closed-loop run (ground truth unless said otherwise)."""

    time: list[float] = field(default_factory=list)
    position: list[np.ndarray] = field(default_factory=list)  # world [m]
    velocity: list[np.ndarray] = field(default_factory=list)  # world [m/s], after the step
    # Estimator output the controller saw (world [m/s]), and the true velocity at that moment.
    estimated_velocity: list[np.ndarray] = field(default_factory=list)
    true_velocity: list[np.ndarray] = field(default_factory=list)
    yaw_rate: list[float] = field(default_factory=list)  # world z [rad/s]
    command: list[VelocityCommand] = field(default_factory=list)
    power: list[float] = field(default_factory=list)  # sum of motor powers [W]
    contacts: list[np.ndarray] = field(default_factory=list)
    fell: bool = False
    fall_time: float | None = None
    mpc_fallbacks: int = 0
    controller_time: list[float] = field(default_factory=list)  # [s] wall per controller step
    physics_time: list[float] = field(default_factory=list)  # [s] wall per sim step
    estimator_time: list[float] = field(default_factory=list)  # [s] wall per estimator update
    qp_build_time: list[float] = field(default_factory=list)  # [s] wall per MPC QP build
    qp_solve_time: list[float] = field(default_factory=list)  # [s] wall per OSQP update + solve

    def estimator_error(self, start: float, axis: int = 0) -> tuple[float, float]:
        """RMS and mean of (estimated - true) velocity along ``axis`` from ``start`` [m/s]."""
        t = np.asarray(self.time)
        err = (np.asarray(self.estimated_velocity) - np.asarray(self.true_velocity))[t >= start, axis]
        return float(np.sqrt(np.mean(err**2))), float(np.mean(err))

    def mean_velocity(self, start: float, end: float | None = None) -> np.ndarray:
        t = np.asarray(self.time)
        sel = (t >= start) & (t <= (end if end is not None else t[-1]))
        return np.mean(np.asarray(self.velocity)[sel], axis=0)


def tilted_or_low(position: np.ndarray, orientation: np.ndarray) -> bool:
    x, y = orientation[0], orientation[1]
    up_z = 1 - 2 * (x * x + y * y)  # world z of the body z axis
    return bool(up_z < _FALL_UP_Z or position[2] < FALL_HEIGHT)


class ClosedLoop:
    """One simulated A1 with its estimator and controller, stepped together every 2 ms.

    ``velocity_source``: "estimator" (the Kalman filter on the sensors, as on the robot) or
    "ground_truth" (the simulator's, for isolating the controller). A fresh controller and
    estimator are built each time, so a loop never inherits solver warm starts or filter state
    from an earlier episode; ``sim`` may be an existing simulator (already reset) to reuse its
    PyBullet connection.
    """

    def __init__(self, gait: GaitParams, *, sim_config: SimConfig | None = None, sim: A1Sim | None = None,
                 controller_config: ControllerConfig | None = None,
                 estimator_config: EstimatorConfig | None = None, velocity_source: str = "estimator") -> None:
        if velocity_source not in VELOCITY_SOURCES:
            raise ValueError(f"velocity_source must be one of {VELOCITY_SOURCES}, got {velocity_source!r}")
        self.sim = sim if sim is not None else A1Sim(sim_config or SimConfig())
        # The offline tools' assembly point: config/'s files unless a config is given, as a node's parameters would be.
        self.controller = LocomotionController(gait, controller_config or load_controller_config())
        self.estimator = VelocityEstimator(estimator_config or load_estimator_config())
        self.use_estimate = velocity_source == "estimator"
        self.readings = self.sim.sensors()
        self.truth = self.sim.ground_truth()
        self.estimated_velocity = np.zeros(3)  # world [m/s], what the last estimator update gave
        self.step_times = (0.0, 0.0, 0.0)  # [s] wall: estimator, controller, physics of the last step
        self._estimated_at = self._simulated_at = 0.0  # perf_counter marks for step_times
        self._imu_held: SensorReadings | None = None  # hold_imu's readings, while the IMU is frozen

    def hold_imu(self, held: SensorReadings | None) -> None:
        """Fault injection, as fault_injection's freeze of /imu/data: until called with None the
        estimator and controller see ``held``'s IMU content (orientation, rates, acceleration), a
        sensor that stopped updating; the other readings stay live."""
        self._imu_held = held

    def step(self, command: VelocityCommand) -> None:
        """Estimate, control and simulate one control period; readings and truth are then current."""
        t0 = time.perf_counter()
        joint_command = self.control(command)
        t2 = time.perf_counter()
        self.actuate(joint_command)
        self.step_times = (self._estimated_at - t0, t2 - self._estimated_at, self._simulated_at - t2)

    def control(self, command: VelocityCommand, elapsed: float | None = None) -> JointCommand:
        """The estimator's update and the controller's joint command for the current readings
        (``elapsed``: sim time since the last control step, when steps were missed)."""
        r = self.readings
        if self._imu_held is not None:
            h = self._imu_held
            r = replace(r, imu_orientation=h.imu_orientation, imu_angular_velocity=h.imu_angular_velocity,
                        imu_linear_acceleration=h.imu_linear_acceleration)
        estimate = self.estimator.update(r)
        self._estimated_at = time.perf_counter()
        self.estimated_velocity = estimate.velocity_world
        velocity = estimate.velocity_world if self.use_estimate else self.truth.base_linear_velocity
        obs = Observation(r.joint_position, r.joint_velocity, r.imu_orientation, r.imu_angular_velocity,
                          r.foot_contact, velocity)
        return self.controller.step(obs, command, elapsed)

    def actuate(self, joint_command: JointCommand) -> None:
        """Simulate one control period with ``joint_command`` on the motors."""
        self.readings = self.sim.step(joint_command)
        self._simulated_at = time.perf_counter()
        self.truth = self.sim.ground_truth()

    @property
    def fallen(self) -> bool:
        return tilted_or_low(self.truth.base_position, self.truth.base_orientation)

    def forward_velocity(self) -> float:
        """True base velocity along the robot's heading (yaw-aligned x) [m/s]."""
        return float(heading_frame(self.truth.base_orientation).T[0] @ self.truth.base_linear_velocity)


def run_closed_loop(schedule: GaitSchedule, profile: SpeedProfile, duration: float, *,
                    sim_config: SimConfig | None = None,
                    controller_config: ControllerConfig | None = None,
                    velocity_source: str = "estimator",
                    estimator_config: EstimatorConfig | None = None) -> Trajectory:
    """Run ``duration`` seconds with the gait from ``schedule`` (re-evaluated at 20 Hz); stop at a fall."""
    loop = ClosedLoop(schedule(0.0, profile(0.0)), sim_config=sim_config, controller_config=controller_config,
                      estimator_config=estimator_config, velocity_source=velocity_source)
    try:
        dt = loop.sim.config.time_step
        steps_per_policy = round(POLICY_PERIOD / dt)
        traj = Trajectory()
        for k in range(round(duration / dt)):
            t = k * dt
            command = profile(t)
            if k % steps_per_policy == 0:
                loop.controller.set_gait(schedule(t, command))
            true_before = loop.truth.base_linear_velocity
            loop.step(command)
            r, truth = loop.readings, loop.truth
            traj.estimated_velocity.append(loop.estimated_velocity)
            traj.true_velocity.append(true_before)
            traj.time.append(truth.time)
            traj.position.append(truth.base_position)
            traj.velocity.append(truth.base_linear_velocity)
            omega_world = quat_to_matrix(truth.base_orientation) @ truth.base_angular_velocity_body
            traj.yaw_rate.append(float(omega_world[2]))
            traj.command.append(command)
            traj.power.append(float(motor_power(r.joint_torque, r.joint_velocity).sum()))
            traj.contacts.append(r.foot_contact)
            traj.estimator_time.append(loop.step_times[0])
            traj.controller_time.append(loop.step_times[1])
            traj.physics_time.append(loop.step_times[2])
            traj.qp_build_time.append(loop.controller.last_solution.build_time)
            traj.qp_solve_time.append(loop.controller.last_solution.solve_time)
            if loop.fallen:
                traj.fell, traj.fall_time = True, truth.time
                break
        traj.mpc_fallbacks = loop.controller.mpc_fallbacks
        return traj
    finally:
        loop.sim.close()


def run_with_late_commands(schedule: GaitSchedule, profile: SpeedProfile, duration: float, *,
                           controller_config: ControllerConfig | None = None, fault_at: float = 0.0,
                           latency: float = 0.0, stall: float = 0.0, stall_every: float = 0.5,
                           seed: int = 0) -> float | None:
    """Like ``run_closed_loop``, but from ``fault_at`` [s] on the commands reach the motors late, as
    on a loaded realtime computer; returns the sim time of a fall [s], or None if it stayed up.

    ``latency`` [s]: every command arrives that late (the motors hold the last one meanwhile).
    ``stall`` [s]: about every ``stall_every`` s (0.5x-1.5x, seeded) the controller misses that much
    time of steps (the motors hold its last command, the estimator sees nothing), then resumes with
    its gait clock caught up, as the node's supervisor does. Deterministic for a given seed.
    """
    loop = ClosedLoop(schedule(0.0, profile(0.0)), controller_config=controller_config)
    try:
        dt = loop.sim.config.time_step
        delay_steps, stall_steps = round(latency / dt), round(stall / dt)
        for name, value, steps in (("latency", latency, delay_steps), ("stall", stall, stall_steps)):
            if not 0.0 <= value <= 1.0 or abs(steps * dt - value) > 1e-9:
                raise ValueError(f"{name} must be a multiple of the {dt} s time step in [0, 1] s, got {value}")
        if delay_steps and stall_steps:
            raise ValueError("latency and stall are separate faults: set one of them")
        rng = np.random.default_rng(seed)
        next_stall = fault_at + stall_every * rng.uniform(0.0, 1.0)
        next_policy = 0.0
        in_flight: collections.deque[JointCommand] = collections.deque()
        applied = None
        last_control_step = None
        k = 0
        while k * dt < duration:
            t = k * dt
            command = profile(t)
            if t >= next_policy - 1e-9:  # by time: a stall must not skip the 20 Hz gait update
                loop.controller.set_gait(schedule(t, command))
                next_policy += POLICY_PERIOD
            held_steps = 1
            if stall_steps and t >= next_stall:
                next_stall = t + stall + stall_every * rng.uniform(0.5, 1.5)
                held_steps = stall_steps
            else:
                missed = last_control_step is not None and k - last_control_step > 1
                in_flight.append(loop.control(command, (k - last_control_step) * dt if missed else None))
                last_control_step = k
                if t < fault_at or len(in_flight) > delay_steps:
                    applied = in_flight.popleft()
            for _ in range(held_steps):
                loop.actuate(applied)
                k += 1
            if loop.fallen:
                return round(k * dt, 3)
        return None
    finally:
        loop.sim.close()
