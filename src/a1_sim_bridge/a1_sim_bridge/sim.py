"""PyBullet simulation of the Unitree A1 that exposes exactly what the real robot's sensors give.

Library core of the sim bridge: no ROS. The trainer and the tests drive it in-process; the sim
bridge node wraps it with topics.

Conventions:
- World frame: z up, gravity (0, 0, -9.81) m/s^2 (standard gravity; the reference used 9.8).
- Base frame: PyBullet's base frame, i.e. the trunk centre-of-mass frame (x forward, y left).
- Quaternions are (x, y, z, w), as in PyBullet and geometry_msgs.
- Joint order: FR, FL, RR, RL x (hip, thigh, calf).
"""

from __future__ import annotations

import collections
import dataclasses
import types
from dataclasses import dataclass, field

import numpy as np
import pybullet
import pybullet_data
from a1_common.command import JointCommand
from a1_common.config import ConfigError, require_choice, require_integer, require_range, setting
from a1_common.robot import NUM_LEGS, A1Constants, a1
from a1_interface.sensors import GroundTruth, SensorReadings
from pybullet_utils import bullet_client

from a1_sim_bridge.worlds import WORLD_NAMES, build_world

# The PyBullet calls of every step. BulletClient builds a fresh functools.partial on each attribute
# access (about 15 a step); A1Sim binds these to its connection once.
_STEP_CALLS = ("getJointStates", "setJointMotorControlArray", "stepSimulation", "getBaseVelocity",
               "getBasePositionAndOrientation", "getMatrixFromQuaternion", "getContactPoints")
FOOT_LINK_FRICTION = 1.0  # so that the ground's coefficient is the effective one
START_CLEARANCE = 0.32  # base COM height at which the robot is dropped, above the ground [m]


@dataclass
class SensorNoise:
    """Optional sensor imperfections (all zero by default). Standard deviations in SI units."""

    joint_position_noise: float = setting(0.0, "joint position noise, standard deviation [rad]")
    joint_velocity_noise: float = setting(0.0, "joint velocity noise, standard deviation [rad/s]")
    gyro_noise: float = setting(0.0, "gyroscope noise, standard deviation [rad/s]")
    gyro_bias: float = setting(0.0, "gyroscope bias, same on each axis [rad/s]")
    accel_noise: float = setting(0.0, "accelerometer noise, standard deviation [m/s^2]")
    accel_bias: float = setting(0.0, "accelerometer bias, same on each axis [m/s^2]")
    # Latencies [s], rounded to whole time steps: joint encoders, IMU, foot contact sensors.
    joint_latency: float = setting(0.0, "delay of joint readings, a multiple of time_step [s]")
    imu_latency: float = setting(0.0, "delay of IMU readings, a multiple of time_step [s]")
    contact_latency: float = setting(0.0, "delay of foot contact readings, a multiple of time_step [s]")


@dataclass
class SimConfig:
    """Simulation settings; ``validated()`` raises ConfigError naming a bad field and its range."""

    world: str = setting("flat", "simulated world: flat | step | rough | soft | slope")
    seed: int = setting(0, "terrain and sensor-noise seed")
    gui: bool = setting(False, "open the PyBullet GUI window (needs a display)")
    time_step: float = setting(0.002, "physics step, one sensor sample per step [s] (0.002: 500 Hz)")
    solver_iterations: int = setting(30, "PyBullet constraint solver iterations per step")
    ground_friction: float = setting(0.8, "effective foot-ground Coulomb friction coefficient")
    step_height: float = setting(0.08, "'step' world: height of the step [m]")
    step_distance: float = setting(1.0, "'step' world: distance of the step edge ahead of the robot [m]")
    rough_amplitude: float = setting(0.04, "'rough' world: largest terrain height [m]")
    slope_angle: float = setting(0.1, "'slope' world: incline, uphill along +x [rad]")
    settle_time: float = setting(1.0, "on reset: joint PD hold that settles the robot [s]")
    payload_mass: float = setting(0.0, "mass added to the trunk at its centre of mass [kg] (the reference "
                                       "simulates a 16.2 kg A1: 3.77)")
    noise: SensorNoise = field(default_factory=SensorNoise)

    def validated(self) -> SimConfig:
        require_choice("world", self.world, WORLD_NAMES)
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {self.seed!r}")
        require_range("time_step", self.time_step, 1e-4, 0.01)
        require_integer("solver_iterations", self.solver_iterations, 1, 1000)
        require_range("ground_friction", self.ground_friction, 0.0, 5.0, low_open=True)
        require_range("step_height", self.step_height, 0.0, 0.3, low_open=True)
        require_range("step_distance", self.step_distance, 0.5, 50.0)
        require_range("rough_amplitude", self.rough_amplitude, 0.0, 0.2, low_open=True)
        require_range("slope_angle", self.slope_angle, 0.0, 0.5, low_open=True)  # uphill ramp
        require_range("settle_time", self.settle_time, 0.0, 10.0)
        require_range("payload_mass", self.payload_mass, 0.0, 10.0)
        for f in dataclasses.fields(self.noise):
            value = getattr(self.noise, f.name)
            high = 1.0 if f.name.endswith("_latency") else 10.0
            require_range(f.name, value, 0.0, high)
            steps = value / self.time_step
            if f.name.endswith("_latency") and abs(steps - round(steps)) > 1e-6:
                raise ConfigError(
                    f"{f.name} must be a multiple of time_step ({self.time_step} s), got {value}")
        return self

    @classmethod
    def from_parameters(cls, params: dict, ignore: tuple[str, ...] = ()) -> SimConfig:
        """Build from a flat parameter mapping (a node's ``ros__parameters``).

        Keys in ``ignore`` belong to the node, not the simulation; any other unknown key is an error.
        """
        sim_keys = {f.name for f in dataclasses.fields(cls)} - {"noise"}
        noise_keys = {f.name for f in dataclasses.fields(SensorNoise)}
        unknown = sorted(set(params) - sim_keys - noise_keys - set(ignore))
        if unknown:
            raise ConfigError(
                f"unknown simulation parameters {unknown}; allowed: {sorted(sim_keys | noise_keys)}")
        noise = SensorNoise(**{k: params[k] for k in noise_keys if k in params})
        return cls(noise=noise, **{k: params[k] for k in sim_keys if k in params}).validated()


class A1Sim:
    """One PyBullet world with one A1; ``reset`` then ``step(command)`` every ``time_step``.

    Deterministic: a fresh world is built on every reset, so the same config, seed and command
    sequence give bit-identical trajectories.
    """

    def __init__(self, config: SimConfig | None = None, robot: A1Constants | None = None) -> None:
        self.config = (config or SimConfig()).validated()
        self.robot = robot or a1()
        mode = pybullet.GUI if self.config.gui else pybullet.DIRECT
        self._p = bullet_client.BulletClient(connection_mode=mode)
        self._p.setAdditionalSearchPath(pybullet_data.getDataPath())
        self._calls = types.SimpleNamespace(**{name: getattr(self._p, name) for name in _STEP_CALLS})
        self.steps = 0
        self.reset()

    @property
    def time(self) -> float:
        """Time since reset [s], from the integer step count (no accumulated rounding)."""
        return self.steps * self.config.time_step

    # --- construction ---------------------------------------------------------------------
    def reset(self, world: str | None = None, seed: int | None = None) -> SensorReadings:
        """Rebuild the world, drop the robot in the nominal pose and let it settle under joint PD."""
        changes = {k: v for k, v in (("world", world), ("seed", seed)) if v is not None}
        if changes:
            self.config = dataclasses.replace(self.config, **changes).validated()
        cfg = self.config
        p = self._p
        p.resetSimulation()
        p.configureDebugVisualizer(p.COV_ENABLE_RENDERING, 0)
        p.setGravity(0.0, 0.0, -self.robot.gravity)
        p.setPhysicsEngineParameter(fixedTimeStep=cfg.time_step, numSolverIterations=cfg.solver_iterations,
                                    numSubSteps=0, deterministicOverlappingPairs=1)
        terrain_rng = np.random.default_rng([cfg.seed, 0])
        self._noise_rng = np.random.default_rng([cfg.seed, 1])
        _, ground_z, self._ground = build_world(
            p, cfg.world, ground_friction=cfg.ground_friction, rng=terrain_rng, step_height=cfg.step_height,
            step_distance=cfg.step_distance, rough_amplitude=cfg.rough_amplitude, slope_angle=cfg.slope_angle)
        self._body = p.loadURDF("a1/a1.urdf", [0.0, 0.0, ground_z + START_CLEARANCE], [0, 0, 0, 1])
        self._index_joints()
        # Disable the default velocity motors so that only our torques act.
        p.setJointMotorControlArray(self._body, self._joint_ids, p.VELOCITY_CONTROL,
                                    forces=[0.0] * len(self._joint_ids))
        for foot in self._foot_ids:
            p.changeDynamics(self._body, foot, lateralFriction=FOOT_LINK_FRICTION)
        if cfg.payload_mass > 0.0:  # Bullet scales the trunk's inertia with its mass (same box)
            trunk_mass = p.getDynamicsInfo(self._body, -1)[0]
            p.changeDynamics(self._body, -1, mass=trunk_mass + cfg.payload_mass)
        for jid, q in zip(self._joint_ids, self.robot.nominal_joint_angles, strict=True):
            p.resetJointState(self._body, jid, q, 0.0)
        p.configureDebugVisualizer(p.COV_ENABLE_RENDERING, 1)
        self._applied_torque = np.zeros(len(self._joint_ids))
        self._prev_velocity = np.zeros(3)
        hold = JointCommand.hold(self.robot)
        for _ in range(round(cfg.settle_time / cfg.time_step)):
            self._physics_step(hold)
        self.steps = 0
        self._prev_velocity = np.array(p.getBaseVelocity(self._body)[0])
        noise = cfg.noise
        self._latency_steps = {name: round(getattr(noise, name + "_latency") / cfg.time_step)
                               for name in ("joint", "imu", "contact")}
        self._history = collections.deque(maxlen=max(self._latency_steps.values()) + 1)
        self._history.append(self._measure(np.zeros(3)))
        return self.sensors()

    def _index_joints(self) -> None:
        by_name = {}
        for i in range(self._p.getNumJoints(self._body)):
            info = self._p.getJointInfo(self._body, i)
            by_name[info[1].decode()] = i
            by_name[info[12].decode()] = i  # link name -> index of its parent joint = link index
        try:
            self._joint_ids = [by_name[n] for n in self.robot.joint_names]
            self._foot_ids = [by_name[n] for n in self.robot.foot_link_names]
        except KeyError as exc:
            raise ConfigError(f"a1/a1.urdf has no joint or link named {exc.args[0]!r}") from None
        self._foot_slot = {link: leg for leg, link in enumerate(self._foot_ids)}

    # --- stepping -------------------------------------------------------------------------
    def step(self, command: JointCommand) -> SensorReadings:
        """Apply ``command`` through the motor model for one time step; return the sensors.

        The command is validated first (CommandError names a bad field); nothing invalid is applied.
        """
        accel_world = self._physics_step(command.validated())
        self.steps += 1
        self._history.append(self._measure(accel_world))
        return self.sensors()

    def _physics_step(self, command: JointCommand) -> np.ndarray:
        p = self._calls
        states = p.getJointStates(self._body, self._joint_ids)
        q = np.array([s[0] for s in states])
        dq = np.array([s[1] for s in states])
        tau = command.motor_torques(q, dq, self.robot.motor_torque_limit, self.robot.damping_kd)
        p.setJointMotorControlArray(self._body, self._joint_ids, pybullet.TORQUE_CONTROL, forces=tau.tolist())
        p.stepSimulation()
        self._applied_torque = tau
        velocity = np.array(p.getBaseVelocity(self._body)[0])
        accel = (velocity - self._prev_velocity) / self.config.time_step
        self._prev_velocity = velocity
        return accel

    # --- sensing --------------------------------------------------------------------------
    def _measure(self, accel_world: np.ndarray) -> SensorReadings:
        p = self._calls
        noise = self.config.noise
        rng = self._noise_rng
        states = p.getJointStates(self._body, self._joint_ids)
        q = np.array([s[0] for s in states])
        dq = np.array([s[1] for s in states])
        position, orientation = p.getBasePositionAndOrientation(self._body)
        self.base_position = position  # world [m], for checks that need no full ground truth
        self._ground.follow(position[0], position[1])  # ground without end (worlds.GroundTiles)
        _, omega_world = p.getBaseVelocity(self._body)
        rot = np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)  # base -> world
        gyro = rot.T @ np.array(omega_world)
        specific_force = rot.T @ (accel_world + np.array([0.0, 0.0, self.robot.gravity]))
        if noise.joint_position_noise:
            q = q + rng.normal(0.0, noise.joint_position_noise, q.shape)
        if noise.joint_velocity_noise:
            dq = dq + rng.normal(0.0, noise.joint_velocity_noise, dq.shape)
        if noise.gyro_noise or noise.gyro_bias:
            gyro = gyro + noise.gyro_bias + rng.normal(0.0, noise.gyro_noise, 3)
        if noise.accel_noise or noise.accel_bias:
            specific_force = specific_force + noise.accel_bias + rng.normal(0.0, noise.accel_noise, 3)
        contact = np.zeros(NUM_LEGS, dtype=bool)
        force = np.zeros(NUM_LEGS)
        for point in p.getContactPoints(bodyA=self._body):
            leg = self._foot_slot.get(point[3])
            if leg is not None and point[2] != self._body:
                contact[leg] = True
                force[leg] += point[9]
        return SensorReadings(
            time=self.time, joint_position=q, joint_velocity=dq, joint_torque=self._applied_torque.copy(),
            imu_orientation=np.array(orientation), imu_angular_velocity=gyro,
            imu_linear_acceleration=specific_force, foot_contact=contact, foot_force=force)

    def sensors(self) -> SensorReadings:
        """The readings of the current step as the controller sees them, each sensor delayed by
        its latency (until the history fills after a reset, the oldest reading stands in)."""
        history = self._history

        def delayed(kind: str) -> SensorReadings:
            return history[max(len(history) - 1 - self._latency_steps[kind], 0)]

        now, joints, imu, contacts = history[-1], delayed("joint"), delayed("imu"), delayed("contact")
        if joints is imu is contacts is now:
            return now
        return dataclasses.replace(
            now, joint_position=joints.joint_position, joint_velocity=joints.joint_velocity,
            joint_torque=joints.joint_torque, imu_orientation=imu.imu_orientation,
            imu_angular_velocity=imu.imu_angular_velocity,
            imu_linear_acceleration=imu.imu_linear_acceleration,
            foot_contact=contacts.foot_contact, foot_force=contacts.foot_force)

    def ground_truth(self) -> GroundTruth:
        p = self._calls
        position, orientation = p.getBasePositionAndOrientation(self._body)
        v_world, omega_world = p.getBaseVelocity(self._body)
        rot = np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)
        return GroundTruth(
            time=self.time, base_position=np.array(position), base_orientation=np.array(orientation),
            base_linear_velocity=np.array(v_world), base_linear_velocity_body=rot.T @ np.array(v_world),
            base_angular_velocity_body=rot.T @ np.array(omega_world))

    def close(self) -> None:
        """Disconnect from PyBullet (idempotent)."""
        if self._p is not None:
            self._p.disconnect()
            self._p = None
            self._calls = None  # bound to the closed connection's id, which PyBullet reuses

    def __enter__(self) -> A1Sim:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
