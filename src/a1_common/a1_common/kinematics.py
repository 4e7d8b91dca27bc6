"""Analytic leg kinematics of the A1: foot position, 3x3 leg Jacobian and inverse kinematics.

Everything is in the base frame (trunk centre-of-mass frame: x forward, y left, z up), SI units.
Lives in a1_common because the controller (stance torques J^T f, swing IK), the estimator (leg
odometry) and a hardware bridge all need the same kinematics without a simulator.

Per leg, with joint angles (a, h, k) = (hip abduction, thigh, calf), thigh and calf lengths l1, l2
and the signed hip link length s = +-0.08505 m (+ for left legs):
  the knee folds the leg to an effective length L(k) = sqrt(l1^2 + l2^2 + 2 l1 l2 cos k) pointing
  at angle psi = h + k/2 from straight down in the leg's sagittal plane, so in the hip frame before
  abduction the foot is v = (-L sin psi, s, -L cos psi); abduction rotates v about x by a, and the
  hip offset moves it into the base frame.
"""

from __future__ import annotations

import math

import numpy as np

from a1_common.robot import LEG_SIGNS, NUM_LEGS, A1Constants


def _leg_params(robot: A1Constants) -> tuple[np.ndarray, float, float]:
    return LEG_SIGNS * robot.hip_link_length, robot.thigh_length, robot.calf_length


def foot_positions(robot: A1Constants, q: np.ndarray) -> np.ndarray:
    """Foot (toe centre) positions [m] in the base frame, shape (4, 3), for joint angles q (12,)."""
    return leg_kinematics(robot, q)[0]


def leg_kinematics(robot: A1Constants, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Foot positions (4, 3) [m] and leg Jacobians (4, 3, 3) [m/rad] in the base frame together:
    the controller and the estimator need both every 2 ms, and they share the trigonometry."""
    side, l1, l2 = _leg_params(robot)
    a, h, k = np.asarray(q, dtype=float).reshape(NUM_LEGS, 3).T
    length = np.sqrt(l1**2 + l2**2 + 2 * l1 * l2 * np.cos(k))
    dlength = -l1 * l2 * np.sin(k) / length  # dL/dk
    psi = h + 0.5 * k
    sp, cp, sa, ca = np.sin(psi), np.cos(psi), np.sin(a), np.cos(a)
    z0 = -length * cp
    feet = np.empty((NUM_LEGS, 3))
    feet[:, 0] = -length * sp
    feet[:, 1] = ca * side - sa * z0
    feet[:, 2] = sa * side + ca * z0
    feet += robot.hip_offsets
    jac = np.zeros((NUM_LEGS, 3, 3))
    # Column 0: abduction rotates the (y, z) part of v about x.
    jac[:, 1, 0] = -sa * side - ca * z0
    jac[:, 2, 0] = ca * side - sa * z0
    # Columns 1, 2: derivatives of v in the sagittal plane, then rotated by the abduction.
    for col, dx, dz in (
        (1, -length * cp, length * sp),  # d/dh: only psi changes
        (2, -dlength * sp - 0.5 * length * cp, -dlength * cp + 0.5 * length * sp),  # d/dk
    ):
        jac[:, 0, col] = dx
        jac[:, 1, col] = -sa * dz
        jac[:, 2, col] = ca * dz
    return feet, jac


def inverse_kinematics(robot: A1Constants, feet: np.ndarray) -> np.ndarray:
    """Joint angles (12,) that put the feet at ``feet`` (4, 3) [m], base frame.

    Knee-backward solution (calf angle negative, as the A1 stands) with the foot below the hip
    (|thigh + calf/2| < pi/2), the A1's working range. Unreachable targets are
    projected onto the workspace boundary (fully stretched or folded leg) rather than failing.
    """
    side, l1, l2 = _leg_params(robot)
    p = np.asarray(feet, dtype=float).reshape(NUM_LEGS, 3) - robot.hip_offsets
    x, y, z = p.T
    # The foot's distance from the hip fixes the knee: |p|^2 = s^2 + L^2.
    # np.minimum/np.maximum, not np.clip: on arrays this small np.clip costs several times more.
    length_sq = np.minimum(np.maximum(x**2 + y**2 + z**2 - side**2, (l1 - l2) ** 2), (l1 + l2) ** 2)
    cos_k = np.minimum(np.maximum((length_sq - l1**2 - l2**2) / (2 * l1 * l2), -1.0), 1.0)
    k = -np.arccos(cos_k)
    length = np.sqrt(np.maximum(length_sq, 1e-12))
    psi = np.arcsin(np.minimum(np.maximum(-x / length, -1.0), 1.0))
    h = psi - 0.5 * k
    # In the hip frame before abduction the foot is at (y, z) = (s, -L cos psi); abduction rotates it.
    z0 = -length * np.cos(psi)
    a = np.arctan2(z, y) - np.arctan2(z0, side)
    a = (a + np.pi) % (2 * np.pi) - np.pi
    return np.stack([a, h, k], axis=1).reshape(-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (base -> world) of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def heading_frame(orientation: np.ndarray) -> np.ndarray:
    """Rotation yaw-aligned frame -> world for a base orientation quaternion (x, y, z, w): the frame
    the gait policy sees velocities in (x forward along the heading, z up)."""
    rot = quat_to_matrix(orientation)
    yaw = np.arctan2(rot[1, 0], rot[0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_aligned_frame(rot: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, float, float]:
    """The yaw-aligned frame of a base orientation ``rot`` (base -> world): (yaw [rad], its rotation
    yaw-aligned -> world, the rotation base -> yaw-aligned, roll [rad], pitch [rad]). The frame the
    convex MPC plans in (world axes turned by the base yaw, z up)."""
    yaw = math.atan2(rot[1, 0], rot[0, 0])
    cy, sy = math.cos(yaw), math.sin(yaw)
    rot_yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    rot_rp = rot_yaw.T @ rot
    roll = math.atan2(rot_rp[2, 1], rot_rp[2, 2])
    pitch = -math.asin(min(max(rot_rp[2, 0], -1.0), 1.0))
    return yaw, rot_yaw, rot_rp, roll, pitch
