"""Controller supervisor: stand-up, modes, e-stop latch, stale estimate, command shaping, gait fallback."""

from __future__ import annotations

import math

import numpy as np
import pytest
from a1_common.command import CommandShaper, MotorMode
from a1_common.config import ConfigError, config_dir, load_node_parameters
from a1_common.robot import a1
from convex_mpc_node.controller import LocomotionController, Observation, load_controller_config
from convex_mpc_node.gait import GaitParams, load_hand_tuned_gaits
from convex_mpc_node.supervisor import ControllerSupervisor, SupervisorConfig, load_supervisor_config

ROBOT = a1()
GAITS = load_hand_tuned_gaits()
DT = 0.002


def standing_obs(q=None) -> Observation:
    q = ROBOT.nominal_joint_angles.copy() if q is None else q
    return Observation(q, np.zeros(12), np.array([0, 0, 0, 1.0]), np.zeros(3), np.ones(4, bool), np.zeros(3))


def make(**config) -> ControllerSupervisor:
    controller = LocomotionController(GAITS["slow_trot"], load_controller_config())
    return ControllerSupervisor(controller, GAITS, SupervisorConfig(**config))


def run(sup: ControllerSupervisor, start: float, seconds: float, fresh: bool = True, obs=None, backup=False):
    result = None
    for k in range(round(seconds / DT)):
        result = sup.step(start + k * DT, obs or standing_obs(), velocity_fresh=fresh, backup_velocity=backup)
    return result


def test_stands_up_then_walks():
    sup = make(stand_time=0.5)
    crouched = ROBOT.nominal_joint_angles + np.tile([0.0, 0.5, -0.5], 4)
    first = sup.step(0.0, standing_obs(crouched), True)
    assert first.state == "stand"
    np.testing.assert_allclose(first.command.position, crouched)  # the ramp starts where the legs are
    assert run(sup, DT, 0.4).state == "stand"
    assert run(sup, 0.5, 0.1).state == "walk"


def test_walk_waits_until_actually_stood_up():
    sup = make(stand_time=0.1)
    lying = ROBOT.nominal_joint_angles + np.tile([0.0, 0.6, 0.6], 4)  # legs far from the stance
    assert run(sup, 0.0, 1.0, obs=standing_obs(lying)).state == "stand"


def test_estop_latches_damping_until_cleared():
    sup = make(stand_time=0.0)
    run(sup, 0.0, 0.1)
    sup.estop()
    result = run(sup, 0.1, 0.5)
    assert result.state == "estop" and result.command.mode == MotorMode.DAMPING
    sup.set_mode("walk")  # a mode change does not clear the e-stop
    assert run(sup, 0.6, 0.1).state == "estop"
    sup.clear_estop()
    assert run(sup, 0.7, 0.002).state == "stand"  # stands up again first


def test_a_fall_latches_damping_until_cleared():
    sup = make(stand_time=0.0, fall_tilt=1.0)
    assert run(sup, 0.0, 0.1).state == "walk"
    half = 0.5 * 1.05  # a 1.05 rad roll: over fall_tilt
    rolled = Observation(ROBOT.nominal_joint_angles.copy(), np.zeros(12),
                         np.array([math.sin(half), 0.0, 0.0, math.cos(half)]), np.zeros(3), np.zeros(4, bool),
                         np.zeros(3))
    result = run(sup, 0.1, 0.01, obs=rolled)
    assert result.state == "fallen" and result.command.mode == MotorMode.DAMPING and sup.falls == 1
    assert run(sup, 0.2, 0.1).state == "fallen"  # level again (righted by hand): still damped
    sup.clear_estop()
    assert run(sup, 0.3, 0.002).state == "stand" and sup.falls == 1


def test_a_walking_tilt_is_no_fall():
    sup = make(stand_time=0.0)
    half = 0.5 * 0.3  # 0.3 rad of pitch, more than walking ever reaches
    pitched = Observation(ROBOT.nominal_joint_angles.copy(), np.zeros(12),
                          np.array([0.0, math.sin(half), 0.0, math.cos(half)]), np.zeros(3), np.ones(4, bool),
                          np.zeros(3))
    assert run(sup, 0.0, 0.1, obs=pitched).state != "fallen"


def test_damping_mode_and_bad_mode_name():
    sup = make()
    sup.set_mode("damping")
    assert run(sup, 0.0, 0.01).command.mode == MotorMode.DAMPING
    with pytest.raises(ConfigError, match="mode must be one of"):
        sup.set_mode("sprint")


def test_stand_requested_while_walking_stops_under_control_then_stands():
    sup = make(stand_time=0.1, max_acceleration=10.0, stop_deceleration=2.0, cmd_vel_timeout=0.0)
    sup.on_cmd_vel(1.0, 0.0, 0.0, now=0.0)
    assert run(sup, 0.0, 0.5).velocity_command.vx == pytest.approx(1.0)
    sup.set_mode("stand")  # `ros2 param set /convex_mpc mode stand` while walking at 1 m/s
    stopping = run(sup, 0.5, 0.25)
    assert stopping.state == "stopping_to_stand" and stopping.velocity_command.vx == pytest.approx(0.5, abs=0.01)
    assert np.any(stopping.command.torque)  # still walking (MPC stance forces), not a frozen stance
    # Zero 0.5 s after the request, then STOP_SETTLE_TIME of trotting in place, then the stance.
    assert run(sup, 0.75, 0.7).state == "stopping_to_stand"
    stood = run(sup, 1.45, 0.1)
    assert stood.state == "stand" and not np.any(stood.command.torque) and np.all(stood.command.kp > 0)
    assert run(sup, 1.55, 1.0).state == "stand"  # and stays standing, the command notwithstanding
    sup.set_mode("walk")
    assert run(sup, 2.55, 0.01).state == "walk"


def test_restart_after_a_sim_reset_stands_up_and_waits_for_a_new_command():
    sup = make(stand_time=0.1, fall_tilt=1.0, cmd_vel_timeout=0.0)
    sup.on_cmd_vel(1.0, 0.0, 0.0, now=0.0)
    assert run(sup, 0.0, 1.5).state == "walk"
    sup.fallen = True  # the old world's fall is forgotten with it
    sup.restart()  # the sim's clock went back to 0
    first = run(sup, 0.0, 0.002)
    assert first.state == "stand" and first.velocity_command.vx == 0.0
    assert run(sup, 0.002, 0.3).velocity_command.vx == 0.0  # the old run's 1 m/s is void
    sup.on_cmd_vel(1.0, 0.0, 0.0, now=0.3)
    walking = run(sup, 0.3, 0.2)
    assert walking.state == "walk" and walking.velocity_command.vx > 0.0
    sup.estop()
    sup.restart()
    assert run(sup, 0.5, 0.01).state == "estop"  # an e-stop outlives a reset


def test_stale_estimate_holds_a_safe_stance_and_recovers():
    sup = make(stand_time=0.1, input_timeout=0.05)
    assert run(sup, 0.0, 0.3).state == "walk"
    stale = run(sup, 0.3, 0.2, fresh=False)
    assert stale.state == "safe_stand" and stale.command.mode == MotorMode.HYBRID
    assert np.all(stale.command.kp > 0)  # joint PD: a stance, not a collapse
    assert sup.safe_stand_steps > 0
    assert run(sup, 0.5, 0.05).state == "walk"


def test_stale_estimate_with_a_backup_stops_under_control_then_holds_a_safe_stance():
    sup = make(stand_time=0.1, input_timeout=0.05, max_acceleration=10.0, stop_deceleration=2.0,
               cmd_vel_timeout=0.0)
    sup.on_cmd_vel(1.5, 0.0, 0.0, now=0.0)
    assert run(sup, 0.0, 0.5).velocity_command.vx == pytest.approx(1.5)
    # /odom stops at t = 0.5: walking goes on for input_timeout, then the stop at 2 m/s^2 ...
    stopping = run(sup, 0.5, 0.5, fresh=False, backup=True)
    assert stopping.state == "stopping" and stopping.velocity_command.vx == pytest.approx(1.5 - 2.0 * 0.45, abs=0.01)
    assert np.any(stopping.command.torque)  # still the MPC's stance forces, not a joint hold
    # ... reaches zero 0.75 s after it began, trots in place STOP_SETTLE_TIME, then the safe stance.
    assert run(sup, 1.0, 0.7, fresh=False, backup=True).state == "stopping"
    held = run(sup, 1.7, 0.15, fresh=False, backup=True)
    assert held.state == "safe_stand" and not np.any(held.command.torque)
    assert sup.stopping_steps > 0
    # /odom back: stands up, then walks again, starting from a zero command (not from 1.5 m/s).
    back = [sup.step(1.85 + k * DT, standing_obs(), velocity_fresh=True) for k in range(100)]
    first_walk = next(r for r in back if r.state == "walk")
    assert first_walk.velocity_command.vx <= 10.0 * DT + 1e-9
    # Without a walking robot there is nothing to stop: straight to the safe stance.
    idle = make(stand_time=0.1, input_timeout=0.05)
    assert run(idle, 0.0, 0.2, fresh=False, backup=True).state == "safe_stand"


def test_cmd_vel_validation_clamp_and_acceleration_limit():
    sup = make(stand_time=0.0, max_acceleration=1.0, max_forward_speed=3.0, cmd_vel_timeout=0.0)
    assert not sup.on_cmd_vel(math.nan, 0.0, 0.0, now=0.0)
    assert sup.rejected_cmd_vel == 1
    assert sup.on_cmd_vel(10.0, 0.0, 0.0, now=0.0)  # clamped to 3 m/s
    result = run(sup, 0.0, 0.5)
    assert result.velocity_command.vx == pytest.approx(0.5, abs=0.01)  # 1 m/s^2 for 0.5 s
    result = run(sup, 0.5, 3.0)
    assert result.velocity_command.vx == pytest.approx(3.0)


def test_cmd_vel_timeout_brings_the_target_to_zero():
    sup = make(stand_time=0.0, cmd_vel_timeout=0.5, max_acceleration=10.0)
    sup.on_cmd_vel(1.0, 0.0, 0.0, now=0.0)
    assert run(sup, 0.0, 0.4).velocity_command.vx == pytest.approx(1.0)
    assert run(sup, 0.4, 0.4).velocity_command.vx == pytest.approx(0.0)


def test_gait_params_rejected_or_timed_out_fall_back_to_hand_tuned():
    sup = make(stand_time=0.0, gait_timeout=0.2)
    assert not sup.on_gait_params(GaitParams(9.0, 0.5, (0, math.pi, math.pi, 0)), now=0.0)
    assert sup.rejected_gait_params == 1
    custom = GaitParams(3.0, 0.4, (0.0, math.pi, math.pi, 0.0))
    assert sup.on_gait_params(custom, now=0.0)
    run(sup, 0.0, 0.1)
    assert sup.controller.gait.params == custom
    run(sup, 0.1, 0.3)  # no new parameters for longer than gait_timeout
    assert sup.gait_fallbacks == 1
    assert sup.controller.gait.params == GAITS["walk"]  # commanded 0 m/s -> walk


def test_supervisor_config_errors():
    with pytest.raises(ConfigError, match="input_timeout"):
        SupervisorConfig(input_timeout=0.0).validated()
    with pytest.raises(ConfigError, match="fall_tilt"):
        SupervisorConfig(fall_tilt=2.0).validated()


def test_hand_tuned_gaits_missing_from_the_speed_schedule_are_refused_at_construction():
    controller = LocomotionController(GAITS["slow_trot"], load_controller_config())
    partial = {k: v for k, v in GAITS.items() if k != "fly_trot"}
    with pytest.raises(ConfigError, match=r"hand-tuned gaits \['fly_trot'\] missing"):
        ControllerSupervisor(controller, partial)


def test_command_shaper_ramps_to_the_target_times_out_to_zero_and_stops_at_its_rate():
    shaper = CommandShaper(acceleration=1.0, timeout=2.0)
    shaper.set_target(np.array([1.5, 0.0, 0.0]), now=0.0)
    speeds = [shaper.update(now=0.1 * k, dt=0.1)[0] for k in range(1, 21)]
    assert speeds[0] == pytest.approx(0.1) and speeds[9] == pytest.approx(1.0) and speeds[-1] == 1.5
    shaper.update(now=2.1, dt=0.1)  # /cmd_vel older than the timeout: the target is zero
    assert shaper.command[0] == pytest.approx(1.4)
    assert shaper.update(now=2.2, dt=0.1, stop_rate=2.0)[0] == pytest.approx(1.2)  # a controlled stop
    shaper.hold()
    assert not np.any(shaper.command)
    with pytest.raises(ConfigError, match="acceleration"):
        CommandShaper(acceleration=0.0, timeout=1.0)


def test_load_supervisor_config_reads_the_controller_file_and_names_a_bad_value(tmp_path):
    """The gait policy node shapes /cmd_vel with these values, so a bad one must stop it with the reason."""
    file = load_node_parameters(config_dir() / "convex_mpc.yaml", "convex_mpc")
    loaded = load_supervisor_config()
    assert (loaded.max_acceleration, loaded.cmd_vel_timeout) == (file["max_acceleration"], file["cmd_vel_timeout"])
    bad = tmp_path / "convex_mpc.yaml"
    bad.write_text("/**/convex_mpc:\n  ros__parameters:\n    max_acceleration: -1.0\n")
    with pytest.raises(ConfigError, match=r"convex_mpc.yaml: max_acceleration"):
        load_supervisor_config(bad)
