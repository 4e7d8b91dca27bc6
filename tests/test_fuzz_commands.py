"""Property tests (hypothesis) of the message handlers' cores: what /motor_command, /cmd_vel,
/gait/params and the sensor topics turn into, whatever they carry.

The invariant everywhere: no NaN, inf or out-of-range gain reaches a motor. A bad joint command is
rejected naming its field; a bad /cmd_vel is rejected (NaN/inf) or clamped to the speed limits; bad
gait parameters are rejected; an unusable observation makes the controller damp for that step.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from a1_common.command import MAX_FEEDFORWARD_TORQUE, MAX_KD, MAX_KP, CommandWatchdog, JointCommand, MotorMode
from a1_common.config import ConfigError
from a1_common.robot import a1
from a1_interface.conversions import motor_command_msg, stamp_from_ns
from a1_interface.sensors import SensorReadings
from convex_mpc_node.controller import LocomotionController, Observation, load_controller_config
from convex_mpc_node.gait import TWO_PI, GaitParams, load_hand_tuned_gaits
from convex_mpc_node.supervisor import ControllerSupervisor, SupervisorConfig
from hypothesis import example, given
from hypothesis import strategies as st
from rclpy.serialization import serialize_message

from a1_interface import wire
from gait_msgs.msg import MotorCommand


def decoded_command(msg: MotorCommand) -> JointCommand:
    """The command a bridge applies for ``msg``: decoded from its bytes, as the bridges do."""
    return wire.decode_motor_command(serialize_message(msg))[0]

ROBOT = a1()
GAITS = load_hand_tuned_gaits()
DT = 0.002
FIELDS = ("position", "velocity", "kp", "kd", "torque")

any_float = st.floats(width=64)  # NaN, +-inf, subnormals, +-1.8e308 included
hostile_float = st.one_of(any_float, st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, -0.0]))


def arrays(size=None, elements=hostile_float):
    size = st.integers(0, 14) if size is None else size
    return size.flatmap(lambda n: st.lists(elements, min_size=n, max_size=n))


def assert_safe(command: JointCommand) -> None:
    """What the motors may get: damping, or 12 finite values per field with gains in range."""
    valid = command.validated()  # raises CommandError otherwise
    if valid.mode == MotorMode.HYBRID:
        assert np.all(valid.kp <= MAX_KP) and np.all(valid.kd <= MAX_KD)
        assert np.all(np.abs(valid.torque) <= MAX_FEEDFORWARD_TORQUE)


# --- /motor_command (sim bridge; the hardware bridge uses the same JointCommand check) --------------
@given(mode=st.sampled_from([0, 0, 1]) | st.integers(-3, 300), values=st.fixed_dictionaries({f: st.one_of(
    arrays(st.sampled_from([12, 12, 12, 0, 11, 13])), st.lists(st.floats(0, 120), min_size=12, max_size=12))
    for f in FIELDS}))
@example(mode=0, values={f: [0.0] * 12 for f in FIELDS})
@example(mode=0, values={**{f: [0.0] * 12 for f in FIELDS}, "kp": [math.nan] * 12})
@example(mode=1, values={f: [math.inf] * 12 for f in FIELDS})  # damping ignores the arrays
def test_motor_command_message_is_validated_before_the_motors(fuzz_cases, mode, values):
    msg = MotorCommand()
    msg.mode = mode if 0 <= mode <= 255 else 0
    for name, v in values.items():
        setattr(msg, name, v)
    command = decoded_command(msg)
    command.mode = mode  # also modes a uint8 cannot hold (a bridge may be fed from elsewhere)
    watchdog = CommandWatchdog(0.05)
    accepted = watchdog.offer(command, now=0.0)
    fuzz_cases["/motor_command -> JointCommand"]["accepted" if accepted else "rejected"] += 1
    if not accepted:
        assert watchdog.rejected == 1
        assert watchdog.last_error.split("[")[0].split(" ")[0] in ("mode", *FIELDS)
        assert watchdog.active(0.001).mode == MotorMode.DAMPING  # nothing else to apply
        return
    active = watchdog.active(0.001)
    assert_safe(active)
    # Applied at any finite joint state, the torque stays finite and within the motor limit.
    q, dq = np.full(12, 1e6), np.full(12, -1e6)
    tau = active.motor_torques(q, dq, ROBOT.motor_torque_limit, ROBOT.damping_kd)
    assert np.all(np.isfinite(tau)) and np.all(np.abs(tau) <= ROBOT.motor_torque_limit)


@given(events=st.lists(st.tuples(st.booleans(), st.floats(0, 0.1)), min_size=1, max_size=20))
def test_watchdog_only_ever_hands_out_valid_commands_or_damping(fuzz_cases, events):
    """Valid and NaN commands interleaved at random times: the active one is always safe, and stale
    ones fall back to damping exactly ``timeout`` after the last valid one."""
    watchdog = CommandWatchdog(0.05)
    now, last_valid = 0.0, -math.inf
    for valid, dt in events:
        now += dt
        command = JointCommand.hold(ROBOT)
        if not valid:
            command.torque = np.full(12, math.nan)
        if watchdog.offer(command, now):
            last_valid = now
        fuzz_cases["watchdog sequences"]["steps"] += 1
        active = watchdog.active(now + 0.01)
        assert_safe(active)
        assert (active.mode == MotorMode.DAMPING) == (now + 0.01 - last_valid >= 0.05 - 1e-9)


def test_motor_command_round_trip_keeps_a_valid_command():
    command = JointCommand.hold(ROBOT)
    back = decoded_command(motor_command_msg(command, stamp_from_ns(2_000_000)))
    np.testing.assert_array_equal(back.validated().position, command.position)


# --- /cmd_vel and /gait/params into the controller's supervisor --------------------------------------
def standing_obs(**changes) -> Observation:
    obs = Observation(ROBOT.nominal_joint_angles.copy(), np.zeros(12), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3),
                      np.ones(4, bool), np.zeros(3))
    for k, v in changes.items():
        setattr(obs, k, v)
    return obs


@pytest.fixture(scope="module")
def controller():
    return LocomotionController(GAITS["slow_trot"], load_controller_config())


@given(vx=hostile_float, vy=hostile_float, yaw=hostile_float)
@example(vx=math.nan, vy=0.0, yaw=0.0)
@example(vx=1e308, vy=-1e308, yaw=math.inf)
@example(vx=-50.0, vy=0.0, yaw=0.0)
def test_cmd_vel_is_rejected_if_not_finite_else_clamped(controller, fuzz_cases, vx, vy, yaw):
    cfg = SupervisorConfig(max_acceleration=20.0)
    sup = ControllerSupervisor(controller, GAITS, cfg)
    accepted = sup.on_cmd_vel(vx, vy, yaw, now=0.0)
    finite = all(math.isfinite(v) for v in (vx, vy, yaw))
    fuzz_cases["/cmd_vel -> supervisor"]["accepted (clamped)" if accepted else "rejected"] += 1
    assert accepted == finite and sup.rejected_cmd_vel == (0 if finite else 1)
    limits = np.array([cfg.max_forward_speed, cfg.max_lateral_speed, cfg.max_yaw_rate])
    for k in range(60):  # in damping mode the command shaping runs without the controller
        sup.set_mode("damping")
        result = sup.step(k * 0.01, standing_obs(), velocity_fresh=True)
    v = np.array([result.velocity_command.vx, result.velocity_command.vy, result.velocity_command.yaw_rate])
    assert np.all(np.isfinite(v)) and np.all(np.abs(v) <= limits + 1e-12)
    if finite:  # the documented clamp, reached at max_acceleration
        np.testing.assert_allclose(v, np.clip([vx, vy, yaw], -limits, limits), atol=1e-9)
    else:
        np.testing.assert_array_equal(v, 0.0)


@given(f=hostile_float | st.floats(0, 5), p=hostile_float | st.floats(0, 1),
       offsets=arrays(st.sampled_from([4, 4, 4, 3, 5, 0]), st.floats(0, 7))
       | st.lists(st.floats(0, TWO_PI, exclude_max=True), min_size=3, max_size=3).map(lambda t: [0.0, *t])
       | arrays(st.sampled_from([4, 4, 4, 3, 5, 0])))
@example(f=2.0, p=0.5, offsets=[0.0, math.pi, math.pi, 0.0])
@example(f=2.0, p=0.5, offsets=[0.0, math.pi, TWO_PI, 0.0])  # 2 pi is outside [0, 2 pi)
@example(f=4.0000001, p=0.5, offsets=[0.0, 0.0, 0.0, 0.0])
def test_gait_params_are_accepted_only_inside_the_paper_ranges(controller, fuzz_cases, f, p, offsets):
    sup = ControllerSupervisor(controller, GAITS)
    params = GaitParams(f, p, tuple(offsets))
    try:
        params.validated()
        valid = True
    except ConfigError as exc:
        valid = False
        assert exc.args[0].split(" ")[0].split("[")[0] in ("stepping_frequency", "swing_ratio", "phase_offsets")
    accepted = sup.on_gait_params(params, now=0.0)
    fuzz_cases["/gait/params -> supervisor"]["accepted" if accepted else "rejected"] += 1
    assert accepted == valid
    in_range = (0 < f <= 4 and 0 < p < 1 and len(offsets) == 4 and offsets[0] == 0
                and all(0 <= t < TWO_PI for t in offsets))
    assert accepted == in_range


# --- observations (the controller's sensor inputs) -----------------------------------------------------
def hostile_obs():
    def field(shape_size, elements=hostile_float):
        return st.one_of(st.just(None), arrays(st.sampled_from([shape_size, shape_size, 0, shape_size + 1]), elements))

    return st.fixed_dictionaries({}, optional={
        "joint_position": field(12), "joint_velocity": field(12), "orientation": field(4),
        "angular_velocity": field(3), "base_velocity": field(3),
        "foot_contact": st.lists(st.booleans(), min_size=0, max_size=5)})


@given(steps=st.lists(st.tuples(st.just({}) | hostile_obs(), st.booleans()), min_size=1, max_size=8),
       mode=st.sampled_from(["walk", "stand"]))
@example(steps=[({"joint_position": [math.nan] * 12}, True)], mode="walk")
@example(steps=[({}, True), ({"joint_velocity": [1e300] * 12, "base_velocity": [1e300] * 3}, True)], mode="walk")
@example(steps=[({"orientation": [0.0, 0.0, 0.0, 0.0]}, True)], mode="stand")
@example(steps=[({"joint_position": [0.0] * 5}, False)], mode="stand")
def test_no_observation_makes_the_supervisor_command_nan(controller, fuzz_cases, steps, mode):
    """Stood-up robot, then steps with hostile observations: every command is safe; unusable ones damp."""
    sup = ControllerSupervisor(controller, GAITS, SupervisorConfig(mode=mode, stand_time=0.0))
    t = 0.0
    assert_safe(sup.step(t, standing_obs(), velocity_fresh=True).command)
    invalid = 0
    for changes, fresh in steps:
        t += DT
        obs = standing_obs(**{k: (np.asarray(v) if v is not None else None) for k, v in changes.items()})
        result = sup.step(t, obs, velocity_fresh=fresh)
        fuzz_cases["observation -> supervisor step"][result.state] += 1
        assert_safe(result.command)
        assert (result.state == "invalid_input") == unusable(changes)
        if result.state == "invalid_input":
            invalid += 1
            assert result.command.mode == MotorMode.DAMPING and sup.last_rejection.startswith("observation")
    assert sup.rejected_observations == invalid


def unusable(changes: dict) -> bool:
    """The observation contract, stated independently of the supervisor's code."""
    sizes = {"joint_position": 12, "joint_velocity": 12, "orientation": 4, "angular_velocity": 3, "base_velocity": 3}
    for name, size in sizes.items():
        if name in changes:
            v = changes[name]
            if v is None or len(v) != size or not all(math.isfinite(x) for x in v):
                return True
    if "foot_contact" in changes and len(changes["foot_contact"]) != 4:
        return True
    q = changes.get("orientation")
    return q is not None and not 0.5 <= math.sqrt(sum(x * x for x in q)) <= 2.0  # overflow: inf


@given(time=hostile_float)
def test_a_non_finite_clock_damps_instead_of_computing(controller, time):
    sup = ControllerSupervisor(controller, GAITS, SupervisorConfig(stand_time=0.0))
    result = sup.step(time, standing_obs(), velocity_fresh=True)
    assert_safe(result.command)
    assert (result.state == "invalid_input") == (not math.isfinite(time))


class _NanController(LocomotionController):
    """A controller whose output has gone bad (e.g. a solver returning NaN forces)."""

    def step(self, obs, command, elapsed=None):
        out = super().step(obs, command, elapsed)
        out.torque = np.full(12, math.nan)
        return out


def test_a_nan_controller_output_is_replaced_by_damping_then_the_robot_stands_again():
    sup = ControllerSupervisor(_NanController(GAITS["slow_trot"], load_controller_config()), GAITS,
                          SupervisorConfig(stand_time=0.0))
    states = []
    for k in range(4):
        result = sup.step(k * DT, standing_obs(), velocity_fresh=True)
        assert_safe(result.command)
        states.append(result.state)
        if result.state == "invalid_command":
            assert result.command.mode == MotorMode.DAMPING and "torque" in sup.last_rejection
    # Each start goes through STAND (joint PD, no controller); the bad walk step is damped, and the
    # robot stands up again before the controller gets another go.
    assert states == ["stand", "invalid_command", "stand", "invalid_command"]
    assert sup.invalid_commands == 2


# --- the estimator's sensor samples ---------------------------------------------------------------------
def _sample(time: float, **changes):
    fields = dict(time=time, joint_position=ROBOT.nominal_joint_angles.copy(), joint_velocity=np.zeros(12),
                  joint_torque=np.zeros(12), imu_orientation=np.array([0.0, 0.0, 0.0, 1.0]),
                  imu_angular_velocity=np.zeros(3), imu_linear_acceleration=np.array([0.0, 0.0, 9.81]),
                  foot_contact=np.ones(4, bool), foot_force=np.full(4, 30.0))
    fields.update({k: np.asarray(v) for k, v in changes.items()})
    return SensorReadings(**fields)


@given(changes=st.fixed_dictionaries({}, optional={
    "joint_position": arrays(st.sampled_from([12, 12, 3])), "joint_velocity": arrays(st.sampled_from([12, 12, 0])),
    "imu_orientation": arrays(st.sampled_from([4, 4, 4, 3])),
    "imu_angular_velocity": arrays(st.sampled_from([3, 3, 2])),
    "imu_linear_acceleration": arrays(st.sampled_from([3, 3, 4])), "foot_force": arrays(st.sampled_from([4, 4, 1]))}))
@example(changes={"imu_orientation": [0.0, 0.0, 0.0, 0.0]})
def test_estimator_rejects_unusable_samples_and_stays_finite(fuzz_cases, changes):
    """NaN/inf, wrong sizes and zero quaternions: rejected and counted; the estimate stays finite."""
    from state_estimator_node import estimator as module

    est = module.VelocityEstimator(module.load_estimator_config())
    est.update(_sample(0.0))
    rejected = est.rejected_samples
    reference = _sample(0.0)
    limits = {"joint_position": module.MAX_JOINT_ANGLE, "joint_velocity": module.MAX_JOINT_SPEED,
              "imu_angular_velocity": module.MAX_GYRO, "imu_linear_acceleration": module.MAX_ACCELERATION,
              "foot_force": module.MAX_FOOT_FORCE}
    with np.errstate(all="ignore"):
        unusable = {k: v for k, v in changes.items()  # wrong size, NaN/inf, not a unit quaternion, beyond a sensor
                    if len(v) != len(getattr(reference, k)) or not np.all(np.isfinite(v))
                    or (k == "imu_orientation" and not 0.5 < np.linalg.norm(v) < 2.0)
                    or (k in limits and np.max(np.abs(v)) >= limits[k])}
    after = est.update(_sample(DT, **unusable))
    fuzz_cases["sensor sample -> estimator"]["rejected" if est.rejected_samples > rejected else "accepted"] += 1
    assert est.rejected_samples == rejected + bool(unusable)
    assert np.all(np.isfinite(after.velocity_body)) and np.all(np.isfinite(after.covariance_body))
    assert np.all(np.isfinite(est.update(_sample(2 * DT)).velocity_body))


@given(orientation=arrays(st.just(4), st.floats(-1e300, 1e300)))
@example(orientation=[1e200, 1e200, 0.0, 0.0])
def test_estimator_output_stays_finite_for_any_finite_quaternion(orientation):
    from state_estimator_node.estimator import VelocityEstimator, load_estimator_config

    est = VelocityEstimator(load_estimator_config())
    est.update(_sample(0.0))
    with np.errstate(all="ignore"):
        out = est.update(_sample(DT, imu_orientation=orientation))
    assert np.all(np.isfinite(out.velocity_body))
