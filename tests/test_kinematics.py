"""Analytic A1 kinematics against PyBullet's own forward kinematics and Jacobian."""

from __future__ import annotations

import numpy as np
import pybullet
import pybullet_data
import pytest
from a1_common.kinematics import foot_positions, inverse_kinematics, leg_kinematics
from a1_common.robot import a1
from pybullet_utils import bullet_client


@pytest.fixture(scope="module")
def bullet_a1():
    """A1 floating base at the origin, identity orientation: world frame = base frame + COM offset."""
    p = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
    p.setAdditionalSearchPath(pybullet_data.getDataPath())
    body = p.loadURDF("a1/a1.urdf", [0, 0, 1.0], [0, 0, 0, 1])
    names = {p.getJointInfo(body, i)[1].decode(): i for i in range(p.getNumJoints(body))}
    links = {p.getJointInfo(body, i)[12].decode(): i for i in range(p.getNumJoints(body))}
    robot = a1()
    joints = [names[n] for n in robot.joint_names]
    feet = [links[n] for n in robot.foot_link_names]
    movable = [i for i in range(p.getNumJoints(body)) if p.getJointInfo(body, i)[2] != p.JOINT_FIXED]
    yield p, body, joints, feet, movable
    p.disconnect()


def random_poses(n: int, seed: int = 0) -> np.ndarray:
    robot = a1()
    rng = np.random.default_rng(seed)
    # Stay inside the joint limits, and in the knee range the A1 actually uses.
    low = np.maximum(robot.joint_lower_limits, np.tile([-0.8, -0.5, -2.6], 4))
    high = np.minimum(robot.joint_upper_limits, np.tile([0.8, 2.0, -0.95], 4))
    return rng.uniform(low, high, size=(n, 12))


def bullet_feet_and_jacobians(bullet_a1, q):
    p, body, joints, feet, movable = bullet_a1
    for jid, angle in zip(joints, q, strict=True):
        p.resetJointState(body, jid, angle, 0.0)
    com, orn = p.getBasePositionAndOrientation(body)
    assert np.allclose(orn, [0, 0, 0, 1])
    positions = np.array([p.getLinkState(body, f, computeForwardKinematics=True)[4] for f in feet]) - com
    q_all = [p.getJointState(body, j)[0] for j in movable]
    zeros = [0.0] * len(movable)
    jacs = []
    for leg, f in enumerate(feet):
        lin, _ = p.calculateJacobian(body, f, [0, 0, 0], q_all, zeros, zeros)
        lin = np.array(lin)[:, 6:]  # drop the floating-base columns
        cols = [movable.index(j) for j in joints[3 * leg:3 * leg + 3]]
        jacs.append(lin[:, cols])
    return positions, np.array(jacs)


def test_forward_kinematics_and_jacobian_match_pybullet(bullet_a1):
    robot = a1()
    for q in random_poses(50):
        ref_pos, ref_jac = bullet_feet_and_jacobians(bullet_a1, q)
        np.testing.assert_allclose(foot_positions(robot, q), ref_pos, atol=2e-4)
        np.testing.assert_allclose(leg_kinematics(robot, q)[1], ref_jac, atol=2e-4)


def test_nominal_stance_feet():
    robot = a1()
    feet = foot_positions(robot, robot.nominal_joint_angles)
    assert np.all(feet[:, 2] < -0.2)  # below the hips
    np.testing.assert_allclose(np.abs(feet[:, 1]), 0.134, atol=0.01)


def test_jacobian_matches_finite_differences():
    robot = a1()
    q = random_poses(1, seed=4)[0]
    eps = 1e-6
    jac = leg_kinematics(robot, q)[1]
    for j in range(12):
        dq = np.zeros(12)
        dq[j] = eps
        diff = (foot_positions(robot, q + dq) - foot_positions(robot, q - dq)) / (2 * eps)
        leg = j // 3
        np.testing.assert_allclose(diff[leg], jac[leg][:, j % 3], atol=1e-6)


def test_inverse_kinematics_round_trip():
    robot = a1()
    poses = random_poses(400, seed=1)
    legs = poses.reshape(-1, 4, 3)
    # IK returns the branch with the foot below the hip (|thigh + calf/2| < pi/2), where the A1 walks.
    below_hip = np.all(np.abs(legs[:, :, 1] + 0.5 * legs[:, :, 2]) < np.pi / 2 - 0.05, axis=1)
    assert below_hip.sum() > 100
    for q in poses[below_hip]:
        feet = foot_positions(robot, q)
        np.testing.assert_allclose(inverse_kinematics(robot, feet), q, atol=1e-7)


def test_unreachable_target_is_projected_not_nan():
    robot = a1()
    feet = foot_positions(robot, robot.nominal_joint_angles)
    feet[0, 2] = -2.0  # far below reach
    q = inverse_kinematics(robot, feet)
    assert np.all(np.isfinite(q))
    assert q[2] == pytest.approx(0.0, abs=1e-6)  # fully stretched knee
