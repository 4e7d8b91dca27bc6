"""Swing control: each swing foot along a curve from lift-off through a mid-air point to a Raibert
landing point, reached through the joints' PD (inverse kinematics).

Library core, no ROS; reset / update / get_action as the reference's swing-leg controller. The
landing point: under the hip (zero abduction, on the ground), moved by v T_stance / 2 + gain
(v - v_cmd) per axis (Raibert), clipped to ``raibert_clip``. Frames: the base frame (trunk COM),
positions [m], velocities [m/s], yaw rates [rad/s].
"""

from __future__ import annotations

import numpy as np
from a1_common.kinematics import foot_positions, inverse_kinematics
from a1_common.robot import LEG_SIGNS, NUM_LEGS, A1Constants

from convex_mpc_node.gait import PhaseIntegrator


def swing_curve(p0: np.ndarray, p_air: np.ndarray, p_land: np.ndarray, s: float | np.ndarray) -> np.ndarray:
    """Quadratic through lift-off (s=0), mid-air (s=0.5) and landing (s=1) points (paper app. A)."""
    return 2 * (s - 0.5) * (s - 1) * p0 - 4 * s * (s - 1) * p_air + 2 * s * (s - 0.5) * p_land


class SwingController:
    """Lift-off points, Raibert landing points and the swing legs' joint targets."""

    def __init__(self, robot: A1Constants, gait: PhaseIntegrator, *, body_height: float,
                 com_offset_z: float, swing_apex_height: float, raibert_feedback_gain: float,
                 raibert_clip: tuple[float, float]) -> None:
        self.robot = robot
        self.gait = gait
        # Geometry that depends on the configuration only, per leg, base frame [m]: the neutral
        # foothold (under the hip, zero abduction), the mid-air point above it, and the hip's
        # velocity per unit yaw rate (z x r) [m/rad].
        ground_z = -body_height + com_offset_z + robot.foot_radius  # toe centre on the ground
        neutral = robot.hip_offsets.copy()
        neutral[:, 1] += LEG_SIGNS * robot.hip_link_length
        neutral[:, 2] = ground_z
        self._neutral = neutral
        self._mid_air = neutral + np.array([0.0, 0.0, swing_apex_height])
        self._yaw_tangent = np.column_stack([-neutral[:, 1], neutral[:, 0]])
        self._gain = raibert_feedback_gain
        self._raibert_clip = np.asarray(raibert_clip)
        self.reset()

    def reset(self) -> None:
        self._was_swing = np.zeros(NUM_LEGS, dtype=bool)
        self._liftoff = foot_positions(self.robot, self.robot.nominal_joint_angles)

    def update(self, feet_base: np.ndarray) -> None:
        """Remember where each foot whose swing starts now (by the gait's desired contacts) lifts off."""
        desired_swing = ~self.gait.desired_contact
        starting = desired_swing & ~self._was_swing
        self._liftoff[starting] = feet_base[starting]
        self._was_swing = desired_swing

    def get_action(self, swing: np.ndarray, feet_base: np.ndarray, v_base: np.ndarray, yaw_rate: float,
                   v_cmd: np.ndarray, yaw_rate_cmd: float) -> np.ndarray:
        """Joint position targets (12,) [rad] with the ``swing`` legs' feet on their curves (the
        other legs' entries are the IK of their current feet); ``v_base`` base velocity, base frame
        [m/s]; ``yaw_rate`` the gyro's [rad/s]; ``v_cmd``, ``yaw_rate_cmd`` the command."""
        targets = feet_base.copy()
        tangent = self._yaw_tangent[swing]
        hip_velocity = v_base[:2] + yaw_rate * tangent
        desired = v_cmd + yaw_rate_cmd * tangent
        offset = hip_velocity * (0.5 * self.gait.stance_duration) + self._gain * (hip_velocity - desired)
        clip = self._raibert_clip
        landing = self._neutral[swing]  # a copy (boolean indexing)
        landing[:, :2] += np.minimum(np.maximum(offset, -clip), clip)
        progress = self.gait.normalised_phase()[swing][:, None]
        targets[swing] = swing_curve(self._liftoff[swing], self._mid_air[swing], landing, progress)
        return inverse_kinematics(self.robot, targets)
