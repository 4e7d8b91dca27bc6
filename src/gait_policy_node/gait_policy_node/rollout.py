"""In-process closed loop: the simulation core and the locomotion controller, without ROS transport.

The same classes the nodes wrap (A1Sim, LocomotionController) run here step by step at 500 Hz;
the gait comes from a schedule evaluated at 20 Hz, as the gait policy node would publish it. The
trainer, the evaluation tools, the tests and the benchmarks all run through ``run_closed_loop``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from a1_common.kinematics import quat_to_matrix
from a1_sim_bridge.sim import A1Sim, SensorReadings, SimConfig
from convex_mpc_node.controller import ControllerConfig, LocomotionController, Observation, VelocityCommand
from convex_mpc_node.energy import motor_power
from convex_mpc_node.gait import GaitParams
from state_estimator_node.estimator import EstimatorConfig, SensorSample, VelocityEstimator

POLICY_PERIOD = 0.05  # [s]: gait parameters change at 20 Hz
FALL_TILT = np.radians(30.0)  # a fall: body tilted more than this ...
FALL_HEIGHT = 0.18  # ... or base COM below this [m]

SpeedProfile = Callable[[float], VelocityCommand]
GaitSchedule = Callable[[float, VelocityCommand], GaitParams]


def ramp_profile(target: float, acceleration: float = 1.0) -> SpeedProfile:
    """Forward speed 0 -> target [m/s] at ``acceleration`` [m/s^2], then held."""
    return lambda t: VelocityCommand(vx=min(target, acceleration * t))


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


def sample_from_readings(r: SensorReadings) -> SensorSample:
    """The estimator's input from the simulator's sensor readings (same fields, same units)."""
    return SensorSample(r.time, r.joint_position, r.joint_velocity, r.imu_orientation, r.imu_angular_velocity,
                        r.imu_linear_acceleration, r.foot_contact, r.foot_force)


def tilted_or_low(position: np.ndarray, orientation: np.ndarray) -> bool:
    x, y = orientation[0], orientation[1]
    up_z = 1 - 2 * (x * x + y * y)  # world z of the body z axis
    return bool(up_z < np.cos(FALL_TILT) or position[2] < FALL_HEIGHT)


VELOCITY_SOURCES = ("estimator", "ground_truth")


def run_closed_loop(schedule: GaitSchedule, profile: SpeedProfile, duration: float, *,
                    sim_config: SimConfig | None = None,
                    controller_config: ControllerConfig | None = None,
                    velocity_source: str = "estimator",
                    estimator_config: EstimatorConfig | None = None) -> Trajectory:
    """Run ``duration`` seconds; stop early at a fall.

    ``velocity_source``: "estimator" (the Kalman filter on the sensors, as on the robot) or
    "ground_truth" (the simulator's, for isolating the controller).
    """
    if velocity_source not in VELOCITY_SOURCES:
        raise ValueError(f"velocity_source must be one of {VELOCITY_SOURCES}, got {velocity_source!r}")
    sim = A1Sim(sim_config or SimConfig())
    try:
        command = profile(0.0)
        controller = LocomotionController(schedule(0.0, command), controller_config)
        estimator = VelocityEstimator(estimator_config)
        dt = sim.config.time_step
        steps_per_policy = round(POLICY_PERIOD / dt)
        traj = Trajectory()
        for k in range(round(duration / dt)):
            t = k * dt
            command = profile(t)
            if k % steps_per_policy == 0:
                controller.set_gait(schedule(t, command))
            r = sim.sensors()
            truth = sim.ground_truth()
            t_est = time.perf_counter()
            estimate = estimator.update(sample_from_readings(r))
            traj.estimator_time.append(time.perf_counter() - t_est)
            use_estimate = velocity_source == "estimator"
            velocity = estimate.velocity_world if use_estimate else truth.base_linear_velocity
            traj.estimated_velocity.append(estimate.velocity_world)
            traj.true_velocity.append(truth.base_linear_velocity)
            obs = Observation(r.joint_position, r.joint_velocity, r.imu_orientation, r.imu_angular_velocity,
                              r.foot_contact, velocity)
            t0 = time.perf_counter()
            joint_command = controller.step(obs, command)
            t1 = time.perf_counter()
            r = sim.step(joint_command)
            t2 = time.perf_counter()
            truth = sim.ground_truth()
            traj.time.append(sim.time)
            traj.position.append(truth.base_position)
            traj.velocity.append(truth.base_linear_velocity)
            omega_world = quat_to_matrix(truth.base_orientation) @ truth.base_angular_velocity_body
            traj.yaw_rate.append(float(omega_world[2]))
            traj.command.append(command)
            traj.power.append(float(motor_power(r.joint_torque, r.joint_velocity).sum()))
            traj.contacts.append(r.foot_contact)
            traj.controller_time.append(t1 - t0)
            traj.physics_time.append(t2 - t1)
            traj.qp_build_time.append(controller.last_solution.build_time)
            traj.qp_solve_time.append(controller.last_solution.solve_time)
            if tilted_or_low(truth.base_position, truth.base_orientation):
                traj.fell, traj.fall_time = True, sim.time
                break
        traj.mpc_fallbacks = controller.mpc_fallbacks
        return traj
    finally:
        sim.close()
