"""Kalman-filter velocity estimator: synthetic motions, gating, bad input, gaps, closed-loop accuracy."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from a1_common.config import ConfigError
from a1_common.kinematics import leg_kinematics
from a1_common.robot import a1
from a1_interface.sensors import SensorReadings
from state_estimator_node.estimator import (
    EstimatorConfig,
    VelocityEstimator,
    load_estimator_config,
)

DT = 0.002
ROBOT = a1()
Q_NOMINAL = ROBOT.nominal_joint_angles.copy()


def joint_velocity_for(base_velocity: np.ndarray, q: np.ndarray = Q_NOMINAL) -> np.ndarray:
    """Joint rates that keep every foot's ground contact point still while the base moves at v.

    Solves (J + [r e_z]x M) dq = -v per leg (level base, no rotation), where M maps the leg's joint
    rates to the foot's angular velocity: the rolling-sphere foot model the estimator uses.
    """
    jac = leg_kinematics(ROBOT, q)[1]
    r_up = np.array([0.0, 0.0, ROBOT.foot_radius])
    skew = np.array([[0, -r_up[2], r_up[1]], [r_up[2], 0, -r_up[0]], [-r_up[1], r_up[0], 0]])
    dq = np.zeros(12)
    for leg in range(4):
        a = q[3 * leg]
        m = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), np.cos(a)], [0.0, np.sin(a), np.sin(a)]])
        dq[3 * leg:3 * leg + 3] = np.linalg.solve(jac[leg] + skew @ m, -base_velocity)
    return dq


def sample(t: float, velocity, accel=(0.0, 0.0, 0.0), contact=(True,) * 4, **changes) -> SensorReadings:
    dq = joint_velocity_for(np.asarray(velocity, float))
    base = SensorReadings(
        time=t, joint_position=Q_NOMINAL.copy(), joint_velocity=dq,
        joint_torque=np.zeros(12), imu_orientation=np.array([0.0, 0.0, 0.0, 1.0]), imu_angular_velocity=np.zeros(3),
        imu_linear_acceleration=np.asarray(accel, float) + np.array([0.0, 0.0, ROBOT.gravity]),
        foot_contact=np.array(contact, dtype=bool), foot_force=np.full(4, 30.0))
    return dataclasses.replace(base, **changes)


def test_constant_velocity_is_recovered():
    est = VelocityEstimator(load_estimator_config())
    v = np.array([1.2, -0.3, 0.0])
    for k in range(500):
        out = est.update(sample(k * DT, v))
    np.testing.assert_allclose(out.velocity_world, v, atol=1e-3)
    np.testing.assert_allclose(out.velocity_body, v, atol=1e-3)
    assert out.feet_used == 4 and not out.stale and not out.diverging
    assert out.height == pytest.approx(0.26, abs=0.03)


def test_constant_acceleration_is_tracked_without_lag():
    est = VelocityEstimator(load_estimator_config())
    a = np.array([1.0, 0.0, 0.0])
    for k in range(1000):
        t = k * DT
        out = est.update(sample(t, a * t, accel=a))
    assert out.velocity_world[0] == pytest.approx(a[0] * t, abs=0.01)


def test_swing_feet_are_not_used():
    est = VelocityEstimator(load_estimator_config())
    for k in range(200):
        est.update(sample(k * DT, np.zeros(3)))
    # Two feet swing fast (their joint rates say the base moves at 3 m/s) but are not in contact.
    wild = joint_velocity_for(np.array([3.0, 0.0, 0.0]))
    calm = joint_velocity_for(np.zeros(3))
    dq = np.where(np.repeat([True, False, False, True], 3), calm, wild)
    for k in range(200, 400):
        out = est.update(sample(k * DT, np.zeros(3), contact=(True, False, False, True), joint_velocity=dq))
    assert out.feet_used == 2
    np.testing.assert_allclose(out.velocity_world, 0.0, atol=1e-3)


def test_imu_alone_integrates_between_contacts():
    est = VelocityEstimator(load_estimator_config())
    a = np.array([0.5, 0.0, 0.0])
    for k in range(100):  # flight phase: no foot on the ground, only the IMU
        out = est.update(sample(k * DT, np.zeros(3), accel=a, contact=(False,) * 4))
    assert out.feet_used == 0
    assert out.velocity_world[0] == pytest.approx(0.5 * 99 * DT, rel=1e-6)


@pytest.mark.parametrize("field", ["joint_velocity", "imu_linear_acceleration", "imu_orientation", "foot_force"])
def test_nan_samples_are_rejected_and_counted(field):
    est = VelocityEstimator(load_estimator_config())
    for k in range(100):
        good = est.update(sample(k * DT, np.array([0.5, 0, 0])))
    shape = np.asarray(getattr(sample(0, np.zeros(3)), field)).shape
    out = est.update(sample(100 * DT, np.array([0.5, 0, 0]), **{field: np.full(shape, np.nan)}))
    assert est.rejected_samples == 1
    np.testing.assert_array_equal(out.velocity_world, good.velocity_world)
    assert np.all(np.isfinite(out.velocity_world))


def test_gap_grows_covariance_without_extrapolating():
    config = load_estimator_config()
    est = VelocityEstimator(config)
    for k in range(200):
        before = est.update(sample(k * DT, np.array([0.5, 0, 0]), accel=(0.0, 0.0, 0.0)))
    assert not est.estimate(before.time + 0.01).stale
    assert est.estimate(before.time + 1.0).stale  # nothing for a second: flagged
    # The next sample comes 1 s later, with an IMU reading of 2 m/s^2 and no feet on the ground.
    out = est.update(sample(before.time + 1.0, np.zeros(3), accel=(2.0, 0, 0), contact=(False,) * 4))
    np.testing.assert_allclose(out.velocity_world, before.velocity_world)  # not integrated over the gap
    grown = np.diag(out.covariance_world) - np.diag(before.covariance_world)
    np.testing.assert_allclose(grown, np.asarray(config.process_noise) * 1.0, rtol=1e-6)


def test_reset_and_time_going_backwards():
    est = VelocityEstimator(load_estimator_config())
    for k in range(100):
        est.update(sample(k * DT, np.array([1.0, 0, 0])))
    out = est.update(sample(0.0, np.zeros(3), contact=(False,) * 4))  # source restarted
    np.testing.assert_allclose(out.velocity_world, 0.0)
    est.reset(velocity=np.array([0.2, 0.0, 0.0]))
    assert est.estimate(0.0).velocity_world[0] == 0.2


def test_config_errors_name_the_field(tmp_path):
    with pytest.raises(ConfigError, match="measurement_noise"):
        EstimatorConfig(measurement_noise=(0.1, -1.0, 0.1)).validated()
    bad = tmp_path / "state_estimator.yaml"
    bad.write_text("state_estimator:\n  ros__parameters:\n    proces_noise: [1, 1, 1]\n")
    with pytest.raises(ConfigError, match="proces_noise"):
        load_estimator_config(bad)
