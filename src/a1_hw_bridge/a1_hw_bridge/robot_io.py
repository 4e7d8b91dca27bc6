"""The A1's wire records <-> the stack's data classes (JointCommand, SensorReadings). No ROS.

Both directions, because the hardware bridge (client) and the virtual A1 (robot) meet on the
wire: bridge JointCommand -> LowCmd -> virtual A1 JointCommand -> A1Sim -> SensorReadings ->
LowState -> bridge SensorReadings. Joint order is the same on both sides (FR, FL, RR, RL x hip,
thigh, calf = motor slots 0..11). Quaternions: (w, x, y, z) on the wire, (x, y, z, w) in the stack.
"""

from __future__ import annotations

import numpy as np
from a1_common.command import JointCommand, MotorMode
from a1_common.kinematics import quat_to_matrix
from a1_common.robot import NUM_JOINTS, A1Constants
from a1_interface.sensors import SensorReadings

from a1_hw_bridge.protocol import NUM_ROBOT_MOTORS, SERVO_MODE, LowCmd, LowState

# Thresholds at which the robot treats q / dq as the SDK's "no position / velocity term" sentinels
# (PosStopF = 2.146e9, VelStopF = 16000). The firmware's exact test is undocumented: an assumption.
POSITION_SENTINEL = 1.0e9  # [rad]
VELOCITY_SENTINEL = 1.6e4  # [rad/s]
IMU_TEMPERATURE = 40  # [deg C] reported by the virtual A1
MOTOR_TEMPERATURE = 35  # [deg C]

assert NUM_JOINTS == NUM_ROBOT_MOTORS


def low_cmd_from_joint_command(cmd: JointCommand, robot: A1Constants, measured_q: np.ndarray) -> LowCmd:
    """Servo-mode command for motors 0..11 (slots 12..19 stay zero, mode idle, as the reference sent).

    HYBRID: the command's per-joint targets and gains, feed-forward torque clipped to the motor
    limit. DAMPING: tau = -damping_kd * dq as a servo command (Kp = 0 at the measured position,
    dq* = 0, Kd = damping_kd), so the motors damp whatever the firmware does with idle mode.
    The caller validates ``cmd`` first (a1_common.command.CommandWatchdog).
    """
    low = LowCmd()
    n = NUM_ROBOT_MOTORS
    low.mode[:n] = SERVO_MODE
    if cmd.mode == MotorMode.DAMPING:
        low.q[:n] = measured_q
        low.kd[:n] = robot.damping_kd
        return low
    low.q[:n] = cmd.position
    low.dq[:n] = cmd.velocity
    low.kp[:n] = cmd.kp
    low.kd[:n] = cmd.kd
    low.tau[:n] = np.clip(cmd.torque, -robot.motor_torque_limit, robot.motor_torque_limit)
    return low


def joint_command_from_low_cmd(low: LowCmd) -> JointCommand:
    """What the motors of slots 0..11 do with a received command (robot side, unvalidated).

    Servo mode applies tau = tau_ff + Kp (q* - q) + Kd (dq* - dq), where a sentinel q* (dq*)
    switches the position (velocity) term off; any other mode is idle: no torque.
    """
    n = NUM_ROBOT_MOTORS
    servo = np.asarray(low.mode[:n]) == SERVO_MODE
    q, dq = np.asarray(low.q[:n], dtype=float), np.asarray(low.dq[:n], dtype=float)
    use_q = servo & (np.abs(q) < POSITION_SENTINEL)
    use_dq = servo & (np.abs(dq) < VELOCITY_SENTINEL)
    return JointCommand(
        mode=MotorMode.HYBRID, position=np.where(use_q, q, 0.0), velocity=np.where(use_dq, dq, 0.0),
        kp=np.where(use_q, low.kp[:n], 0.0), kd=np.where(use_dq, low.kd[:n], 0.0),
        torque=np.where(servo, low.tau[:n], 0.0))


def rpy_from_quaternion(quat_xyzw: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw [rad] (intrinsic z-y-x, REP-103) of a unit quaternion (x, y, z, w)."""
    r = quat_to_matrix(np.asarray(quat_xyzw, dtype=float))
    return np.array([np.arctan2(r[2, 1], r[2, 2]), np.arcsin(np.clip(-r[2, 0], -1.0, 1.0)),
                     np.arctan2(r[1, 0], r[0, 0])])


def low_state_from_readings(r: SensorReadings, tick_us: int, modes: np.ndarray, foot_force_gain: float,
                            foot_force_offset: float) -> LowState:
    """The state datagram content the virtual A1 reports for sensor readings ``r``.

    Foot force in raw units = offset + gain x normal force [N] (an invented sensor model: the
    real sensor's unit is undocumented); tick = robot time [us] modulo 2^32.
    """
    state = LowState()
    x, y, z, w = r.imu_orientation
    state.quaternion = np.array([w, x, y, z])
    state.gyroscope = np.asarray(r.imu_angular_velocity, dtype=float)
    state.accelerometer = np.asarray(r.imu_linear_acceleration, dtype=float)
    state.rpy = rpy_from_quaternion(r.imu_orientation)
    state.imu_temperature = IMU_TEMPERATURE
    n = NUM_ROBOT_MOTORS
    state.mode[:n] = modes
    state.q[:n] = state.q_raw[:n] = r.joint_position
    state.dq[:n] = state.dq_raw[:n] = r.joint_velocity
    state.tau_est[:n] = r.joint_torque
    state.temperature[:n] = MOTOR_TEMPERATURE
    state.foot_force = np.clip(np.round(foot_force_offset + foot_force_gain * np.asarray(r.foot_force)),
                               -32768, 32767).astype(int)
    state.tick = int(tick_us) % (1 << 32)
    return state


def readings_from_low_state(state: LowState, time: float, contact: np.ndarray, force: np.ndarray) -> SensorReadings:
    """SensorReadings of a received state; ``contact`` and ``force`` [N] come from the foot calibration."""
    n = NUM_ROBOT_MOTORS
    w, x, y, z = state.quaternion
    return SensorReadings(
        time=time, joint_position=state.q[:n].copy(), joint_velocity=state.dq[:n].copy(),
        joint_torque=state.tau_est[:n].copy(), imu_orientation=np.array([x, y, z, w]),
        imu_angular_velocity=state.gyroscope.copy(), imu_linear_acceleration=state.accelerometer.copy(),
        foot_contact=np.asarray(contact, dtype=bool), foot_force=np.asarray(force, dtype=float))
