"""Kalman-filter estimate of the base linear velocity from the IMU and leg kinematics.

The torso velocity cannot be measured on the A1 (paper section 3.1), so it is estimated, from only
what the robot gives: joint states, IMU (orientation, gyro, specific force) and foot contacts.

- State: base (trunk COM) linear velocity in the world frame [m/s]; F = I.
- Predict: u = (R a_imu - g e_z) dt, the IMU's specific force rotated to the world with gravity
  removed. Process noise grows with the elapsed time, so a gap in the data grows the covariance;
  over a gap longer than ``max_gap`` the acceleration is *not* integrated (no extrapolation).
- Update, one per foot in contact: leg odometry v = -R (J(q) dq + omega x p_foot), the velocity the
  base must have for that foot to stay still. Swing feet give no update; a foot that touched down
  less than ``touchdown_window`` ago, or carries less than ``low_force`` newtons (about to lift
  off), is trusted ``soft_contact_scale`` times less.
Built on filterpy.kalman.KalmanFilter. Noise values come from config/state_estimator.yaml.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from a1_common.config import ConfigError, config_dir, load_node_parameters, require_range, setting
from a1_common.kinematics import leg_kinematics, quat_to_matrix
from a1_common.robot import NUM_JOINTS, NUM_LEGS, A1Constants, a1
from a1_interface.sensors import SensorReadings
from filterpy.kalman import KalmanFilter

# Readings beyond these are sensor faults, not motion (the A1's joints turn < 30 rad/s, its IMU
# saturates far below these): [rad], [rad/s], [rad/s], [m/s^2], [N].
MAX_JOINT_ANGLE, MAX_JOINT_SPEED, MAX_GYRO, MAX_ACCELERATION, MAX_FOOT_FORCE = 10.0, 100.0, 100.0, 1e4, 1e5
# Shapes and magnitude limits of a sample's arrays, in VelocityEstimator._valid's order.
_SAMPLE_SHAPES = ((NUM_JOINTS,), (NUM_JOINTS,), (3,), (3,), (NUM_LEGS,), (4,))
_SAMPLE_LIMITS = np.concatenate([np.full(NUM_JOINTS, MAX_JOINT_ANGLE), np.full(NUM_JOINTS, MAX_JOINT_SPEED),
                                 np.full(3, MAX_GYRO), np.full(3, MAX_ACCELERATION), np.full(NUM_LEGS, MAX_FOOT_FORCE),
                                 np.full(4, 2.0)])


@dataclass(frozen=True)
class EstimatorConfig:
    # Per-axis process noise density: variance added per second of prediction [(m/s)^2 / s].
    process_noise: tuple[float, float, float] = setting(
        (7.1e-3, 7.9e-3, 4.4e-2), "process noise density per axis x, y, z [(m/s)^2 per s]")
    # Per-axis leg-odometry measurement noise [(m/s)^2] (reference values).
    measurement_noise: tuple[float, float, float] = setting(
        (0.010112, 0.004458, 0.020532), "leg-odometry measurement noise per axis x, y, z [(m/s)^2]")
    initial_covariance: float = setting(0.1, "initial velocity covariance per axis [(m/s)^2]")
    touchdown_window: float = setting(0.02, "feet that touched down less than this ago are trusted less [s]")
    low_force: float = setting(10.0, "feet carrying less than this are trusted less [N]")
    soft_contact_scale: float = setting(10.0, "measurement-noise multiplier for the feet trusted less")
    max_gap: float = setting(0.02, "longer gaps between samples are not integrated [s]")
    stale_timeout: float = setting(0.05, "no valid sample for this long -> estimate flagged stale [s]")
    max_covariance: float = setting(1.0, "covariance trace above this -> estimate flagged diverging [(m/s)^2]")
    max_speed: float = setting(10.0, "estimated speed above this -> flagged diverging [m/s]")
    gravity: float = setting(9.81, "gravity removed from the accelerometer reading [m/s^2]")

    def validated(self) -> EstimatorConfig:
        for name in ("process_noise", "measurement_noise"):
            try:
                values = np.asarray(getattr(self, name), dtype=float)
            except (TypeError, ValueError, OverflowError):
                values = np.full(0, np.nan)
            if values.shape != (3,) or not np.all(np.isfinite(values)) or np.any(values <= 0):
                raise ConfigError(f"{name} must be 3 positive numbers, got {getattr(self, name)!r}")
        require_range("initial_covariance", self.initial_covariance, 0.0, 100.0, low_open=True)
        require_range("touchdown_window", self.touchdown_window, 0.0, 1.0)
        require_range("low_force", self.low_force, 0.0, 1000.0)
        require_range("soft_contact_scale", self.soft_contact_scale, 1.0, 1e6)
        require_range("max_gap", self.max_gap, 0.0, 1.0, low_open=True)
        require_range("stale_timeout", self.stale_timeout, 0.0, 10.0, low_open=True)
        require_range("max_covariance", self.max_covariance, 0.0, 1e6, low_open=True)
        require_range("max_speed", self.max_speed, 0.0, 100.0, low_open=True)
        require_range("gravity", self.gravity, 0.0, 20.0, low_open=True)
        return self


def load_estimator_config(path=None) -> EstimatorConfig:
    """EstimatorConfig from the node's parameter file (default ``config/state_estimator.yaml``)."""
    path = path or config_dir() / "state_estimator.yaml"
    params = load_node_parameters(path, "state_estimator")
    fields = {f.name for f in dataclasses.fields(EstimatorConfig)}
    unknown = sorted(set(params) - fields)
    if unknown:
        raise ConfigError(f"{path}: unknown estimator parameters {unknown}; allowed: {sorted(fields)}")
    args = {k: tuple(v) if isinstance(v, list) else v for k, v in params.items()}
    try:
        return EstimatorConfig(**args).validated()
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


@dataclass
class Estimate:
    time: float  # [s]
    velocity_world: np.ndarray  # (3,) [m/s]
    covariance_world: np.ndarray  # (3, 3) [(m/s)^2]
    orientation: np.ndarray  # (4,) (x, y, z, w), from the IMU
    height: float | None  # base COM above the ground under the stance feet [m]; None if no contact
    stale: bool
    diverging: bool
    feet_used: int  # feet that updated the filter this sample

    # The body-frame views are computed when read: a 500 Hz controller needs only the world velocity.
    @property
    def velocity_body(self) -> np.ndarray:
        """(3,) [m/s], base frame."""
        return quat_to_matrix(self.orientation).T @ self.velocity_world

    @property
    def covariance_body(self) -> np.ndarray:
        """(3, 3) [(m/s)^2], base frame."""
        rot = quat_to_matrix(self.orientation)
        return rot.T @ self.covariance_world @ rot


def _skew(w: np.ndarray) -> np.ndarray:
    """The matrix S with S @ p = w x p."""
    wx, wy, wz = w.tolist()
    return np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])


# Row vectors w times this are w x e_z = (w_y, -w_x, 0).
_CROSS_EZ = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])


class VelocityEstimator:
    """Feed ``update`` every sensor sample (500 Hz); read the returned Estimate."""

    def __init__(self, config: EstimatorConfig, robot: A1Constants | None = None) -> None:
        self.config = config.validated()
        self.robot = robot or a1()
        self.rejected_samples = 0
        cfg = self.config
        self._process_noise = np.diag(cfg.process_noise)  # per second of prediction
        self._gravity = np.array([0.0, 0.0, cfg.gravity])
        self._measurement_noise = np.asarray(cfg.measurement_noise, dtype=float)
        self.reset()

    def reset(self, velocity: np.ndarray | None = None) -> None:
        """Start over at ``velocity`` (default: at rest) with the initial covariance."""
        kf = KalmanFilter(dim_x=3, dim_z=3, dim_u=3)
        kf.F = np.eye(3)
        kf.B = np.eye(3)
        kf.H = np.eye(3)
        kf.x = np.zeros(3) if velocity is None else np.asarray(velocity, dtype=float).copy()
        kf.P = np.eye(3) * self.config.initial_covariance
        self._kf = kf
        self._last_time: float | None = None
        self._contact_since = np.full(NUM_LEGS, -np.inf)  # touchdown time of each foot
        self._was_contact = np.zeros(NUM_LEGS, dtype=bool)
        self._orientation = np.array([0.0, 0.0, 0.0, 1.0])
        self._height: float | None = None
        self._feet_used = 0

    def update(self, sample: SensorReadings) -> Estimate:
        """Predict with the IMU, correct with the stance legs; bad samples are rejected and counted.
        ``sample.joint_torque`` is not read (a JointState without efforts is fine)."""
        if not self._valid(sample):
            self.rejected_samples += 1
            return self.estimate(sample.time if np.isfinite(sample.time) else (self._last_time or 0.0))
        cfg = self.config
        kf = self._kf
        quaternion = np.asarray(sample.imu_orientation, dtype=float)
        rot = quat_to_matrix(quaternion / math.sqrt(quaternion @ quaternion))
        dt = 0.0 if self._last_time is None else sample.time - self._last_time
        if dt < 0:  # time went backwards: the source restarted
            self.reset()
            dt = 0.0
        accel_world = rot @ np.asarray(sample.imu_linear_acceleration, dtype=float) - self._gravity  # [m/s^2]
        u = accel_world * dt if dt <= cfg.max_gap else np.zeros(3)  # no extrapolation over gaps
        kf.predict(u=u, Q=self._process_noise * dt)
        self._last_time = sample.time

        contact = np.asarray(sample.foot_contact, dtype=bool)
        touchdown = contact & ~self._was_contact
        self._contact_since[touchdown] = sample.time
        self._was_contact = contact
        q = np.asarray(sample.joint_position, dtype=float)
        dq = np.asarray(sample.joint_velocity, dtype=float)
        omega = np.asarray(sample.imu_angular_velocity, dtype=float)
        feet, jac = leg_kinematics(self.robot, q)
        legs = np.flatnonzero(contact)
        used = len(legs)
        if used:
            dq_legs = dq.reshape(4, 3)[legs]
            # Foot-centre velocity relative to the base, base frame, all stance legs at once.
            foot_velocity = np.matmul(jac[legs], dq_legs[:, :, None])[:, :, 0] + feet[legs] @ _skew(omega).T
            # The foot is a sphere rolling on the ground: its centre (what the kinematics give) moves
            # at omega_foot x (r e_z) while the contact point stays still (about 7% of the speed
            # when walking). omega_foot = omega + abduction rate e_x + (thigh + calf rate) e_y'.
            abduction = q[3 * legs]
            pitch_rate = dq_legs[:, 1] + dq_legs[:, 2]
            omega_foot = np.empty((used, 3))
            omega_foot[:, 0] = dq_legs[:, 0]
            omega_foot[:, 1] = pitch_rate * np.cos(abduction)
            omega_foot[:, 2] = pitch_rate * np.sin(abduction)
            omega_foot += omega
            rolling = self.robot.foot_radius * (omega_foot @ rot.T @ _CROSS_EZ)  # (rot w) x e_z, world frame
            measurements = rolling - foot_velocity @ rot.T
            # Each stance foot measures the velocity directly (H = I) with noise R_foot = scale * R.
            # Stacked, the update equals one update with the inverse-variance weighted mean of the
            # feet and R / sum(1 / scale) (information form), for a 3x3 update's cost.
            inverse_scale = np.ones(used)
            inverse_scale[sample.time - self._contact_since[legs] < cfg.touchdown_window] /= cfg.soft_contact_scale
            inverse_scale[np.asarray(sample.foot_force)[legs] < cfg.low_force] /= cfg.soft_contact_scale
            total = inverse_scale.sum()
            kf.update(inverse_scale @ measurements / total, R=np.diag(self._measurement_noise / total))
        self._feet_used = used
        self._orientation = quaternion
        if used:
            self._height = float(self.robot.foot_radius - (feet[legs] @ rot[2]).sum() / used)
        return self.estimate(sample.time)

    def estimate(self, now: float) -> Estimate:
        """The current estimate as seen at ``now`` (flags stale if no valid sample recently)."""
        cfg = self.config
        kf = self._kf
        v = kf.x.reshape(3).copy()
        cov = np.array(kf.P)
        stale = self._last_time is None or now - self._last_time > cfg.stale_timeout
        speed_squared = float(v @ v)  # a NaN compares False: flagged as diverging too
        diverging = not (np.trace(cov) <= cfg.max_covariance and speed_squared <= cfg.max_speed**2)
        return Estimate(time=now, velocity_world=v, covariance_world=cov, orientation=self._orientation.copy(),
                        height=self._height, stale=stale, diverging=diverging, feet_used=self._feet_used)

    @staticmethod
    def _valid(sample: SensorReadings) -> bool:
        """Right sizes, finite, and physically possible readings only: a unit quaternion (loosely)
        and magnitudes far beyond the A1's (so the filter's arithmetic cannot overflow into NaN).
        One comparison over all numbers: at 500 Hz the per-array checks cost more than the filter."""
        arrays = (sample.joint_position, sample.joint_velocity, sample.imu_angular_velocity,
                  sample.imu_linear_acceleration, sample.foot_force, sample.imu_orientation)
        if (tuple(np.shape(a) for a in arrays) != _SAMPLE_SHAPES or np.shape(sample.foot_contact) != (NUM_LEGS,)
                or not np.isfinite(sample.time)):
            return False
        values = np.concatenate(arrays, dtype=float)
        if not np.all(np.abs(values) < _SAMPLE_LIMITS):  # NaN compares False: refused too
            return False
        return bool(0.25 < values[-4:] @ values[-4:] < 4.0)  # |q| in (0.5, 2)
