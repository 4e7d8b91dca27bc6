"""The controller walks the simulated A1: paper gaits at their speeds, acceleration, turning, standing.

In-process closed loop: sim core + Kalman estimator + controller, the controller running on the
estimated base velocity as on the robot. A fall is a tilt above 30 degrees or the base below 0.18 m.
Estimator accuracy limits (issue 5): forward-velocity RMS error <= 0.10 m/s at 1.0 m/s trot and
<= 0.15 m/s at 2.5 m/s fly trot, |bias| <= 0.05 m/s, drift while standing <= 0.02 m/s.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from a1_common.config import ConfigError, config_dir
from convex_mpc_node.controller import (
    MAX_CATCH_UP,
    ControllerConfig,
    Observation,
    VelocityCommand,
    load_controller_config,
)
from convex_mpc_node.gait import gait_for_speed, load_hand_tuned_gaits
from convex_mpc_node.swing import swing_curve
from gait_policy_node.rollout import ClosedLoop, run_closed_loop, run_with_late_commands

from gait_policy_node import speed_profiles

GAITS = load_hand_tuned_gaits()
CONFIG = config_dir()


def fixed(name: str):
    return lambda t, command: GAITS[name]


def test_swing_curve_passes_through_its_three_points():
    p0, air, land = np.array([-0.05, 0.1, -0.28]), np.array([0.0, 0.12, -0.18]), np.array([0.07, 0.13, -0.28])
    np.testing.assert_allclose(swing_curve(p0, air, land, 0.0), p0)
    np.testing.assert_allclose(swing_curve(p0, air, land, 0.5), air)
    np.testing.assert_allclose(swing_curve(p0, air, land, 1.0), land)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("gait", "speed"),
    [("walk", 0.5), ("slow_trot", 1.0), ("rapid_trot", 1.5), ("rapid_trot", 2.0), ("fly_trot", 2.5)],
)
def test_gait_tracks_speed_for_10_s(gait, speed):
    traj = run_closed_loop(fixed(gait), speed_profiles.ramp(speed), 10.0)
    assert not traj.fell, f"{gait} at {speed} m/s fell at t={traj.fall_time}"
    vx = traj.mean_velocity(5.0)[0]
    assert vx == pytest.approx(speed, rel=0.10), f"mean v_x over the last 5 s: {vx:.3f} m/s"
    rms, bias = traj.estimator_error(start=1.0)
    assert rms <= (0.15 if speed > 2.0 else 0.10) and abs(bias) <= 0.05, f"estimator rms {rms}, bias {bias}"


@pytest.mark.slow
def test_paper_acceleration_profile_with_speed_scheduled_gaits():
    traj = run_closed_loop(lambda t, c: gait_for_speed(c.vx, GAITS), speed_profiles.ramp(2.5, 1.0), 20.0)
    assert not traj.fell, f"fell at t={traj.fall_time}"
    rms, bias = traj.estimator_error(start=1.0)
    assert rms <= 0.15 and abs(bias) <= 0.05
    assert traj.mean_velocity(10.0)[0] == pytest.approx(2.5, rel=0.10)


@pytest.mark.slow
def test_trot_follows_yaw_rate_command():
    traj = run_closed_loop(fixed("slow_trot"), lambda t: VelocityCommand(yaw_rate=0.5), 10.0)
    assert not traj.fell
    assert np.mean(traj.yaw_rate[-2500:]) == pytest.approx(0.5, rel=0.2)


@pytest.mark.slow
def test_trot_follows_lateral_command():
    traj = run_closed_loop(fixed("slow_trot"), lambda t: VelocityCommand(vy=0.3), 10.0)
    assert not traj.fell
    assert traj.mean_velocity(5.0)[1] == pytest.approx(0.3, rel=0.2)


@pytest.mark.slow
def test_standing_still_does_not_drift():
    traj = run_closed_loop(fixed("slow_trot"), lambda t: VelocityCommand(), 10.0)
    assert not traj.fell
    drift = np.linalg.norm(traj.position[-1][:2] - traj.position[0][:2])
    assert drift < 0.05, f"drifted {drift:.3f} m in 10 s"
    estimated = np.asarray(traj.estimated_velocity)[:, :2]
    assert np.abs(estimated.mean(axis=0)).max() <= 0.02  # the estimate does not drift either


def test_hold_imu_feeds_the_held_imu_content_and_the_other_readings_live():
    """The in-process frozen IMU (benchmarks/imu_freeze_margin.py): while held, the estimator and the
    controller see the held orientation, rates and acceleration; joints stay live; released, all live."""
    loop = ClosedLoop(GAITS["slow_trot"])
    seen: list[Observation] = []
    step = loop.controller.step
    loop.controller.step = lambda obs, command, elapsed=None: seen.append(obs) or step(obs, command, elapsed)
    estimator_update = loop.estimator.update
    samples = []
    loop.estimator.update = lambda sample: samples.append(sample) or estimator_update(sample)
    try:
        loop.step(VelocityCommand(0.5))
        held = loop.readings
        loop.hold_imu(held)
        for _ in range(5):
            loop.step(VelocityCommand(0.5))
        loop.hold_imu(None)
        loop.step(VelocityCommand(0.5))
    finally:
        loop.sim.close()
    assert len(seen) == len(samples) == 7
    for obs, sample in zip(seen[1:6], samples[1:6], strict=True):
        assert np.array_equal(obs.orientation, held.imu_orientation)
        assert np.array_equal(obs.angular_velocity, held.imu_angular_velocity)
        assert np.array_equal(sample.imu_linear_acceleration, held.imu_linear_acceleration)
    assert not np.array_equal(seen[5].joint_position, held.joint_position)  # joints stayed live
    assert not np.array_equal(seen[6].orientation, held.imu_orientation)  # released: live again
    assert not np.array_equal(samples[6].imu_linear_acceleration, held.imu_linear_acceleration)


@pytest.mark.slow
def test_controller_alone_on_ground_truth_velocity():
    """The controller without the estimator (isolates control from estimation problems)."""
    traj = run_closed_loop(fixed("rapid_trot"), speed_profiles.ramp(1.5), 6.0, velocity_source="ground_truth")
    assert not traj.fell
    assert traj.mean_velocity(3.0)[0] == pytest.approx(1.5, rel=0.10)


def trot_to_1_5_mps(config) -> tuple[int, int, int]:
    """6 s of rapid trot ramped to 1.5 m/s with ``config``: asserts no fall and the speed within
    10 % over the last 3 s; returns the MPC solves adopted, the MPC fallbacks and the stopgap steps."""
    loop = ClosedLoop(GAITS["rapid_trot"], controller_config=config)
    solves, speeds = 0, []
    try:
        for k in range(3000):
            loop.step(VelocityCommand(vx=min(1.5, 0.002 * k)))
            solves += loop.controller.solved_this_step
            speeds.append(loop.forward_velocity())
            assert not loop.fallen, f"fell at {loop.sim.time:.2f} s"
    finally:
        loop.sim.close()
        loop.controller.close()
    assert np.mean(speeds[-1500:]) == pytest.approx(1.5, rel=0.10)
    return solves, loop.controller.mpc_fallbacks, loop.controller.stopgap_steps


@pytest.mark.slow
def test_mpc_every_third_step_still_trots_and_resolves_on_contact_changes():
    solves, _, stopgaps = trot_to_1_5_mps(dataclasses.replace(load_controller_config(), mpc_period_steps=3))
    # A third of the steps, plus a re-solve at each of the 4 Hz trot's 8 contact changes per second.
    assert 1000 <= solves <= 1000 + 8 * 6 + 10
    assert stopgaps == 0  # solved in the step: every plan is for the contacts of its step


def realtime_controller_config() -> ControllerConfig:
    """config/convex_mpc_realtime.yaml over convex_mpc.yaml: what realtime graphs run."""
    return load_controller_config(overlays=(CONFIG / "convex_mpc_realtime.yaml",))


@pytest.mark.slow
def test_realtime_controller_settings_walk_with_the_mpc_in_a_worker_process():
    """The realtime settings: the MPC solves asynchronously every 5 steps, the step uses the newest
    finished solve; it still tracks 1.5 m/s."""
    config = realtime_controller_config()
    assert config.mpc_async and config.mpc_period_steps == 5
    solves, fallbacks, stopgaps = trot_to_1_5_mps(config)
    assert fallbacks == 0
    # Solves finish in a worker: at most one per 5 steps plus the contact changes, and not none.
    assert 200 <= solves <= 600 + 8 * 6 + 10
    # Each of the 8 contact changes a second is bridged by static forces until its solve is back
    # (a step or a few), never for long: under 10 % of the 3000 steps.
    assert 8 * 6 // 2 <= stopgaps <= 300


@pytest.mark.slow
def test_realtime_force_weight_walks_through_20_ms_of_command_latency():
    """Realtime commands arrive late. With the realtime settings' MPC force weight and period (solved
    in the step here, so the run is deterministic) a 1.5 m/s trot stays up with every command 20 ms
    late for 3 s; with the lockstep file's force weight at the same period it falls, which shows
    the fault bites (benchmarks/delay_margin.py sweeps the margin)."""
    realtime = dataclasses.replace(realtime_controller_config(), mpc_async=False)
    lockstep_weight = dataclasses.replace(realtime, mpc=load_controller_config().mpc)
    assert realtime.mpc.force_weight > lockstep_weight.mpc.force_weight

    def fall_time(config):
        return run_with_late_commands(lambda t, c: gait_for_speed(c.vx, GAITS), speed_profiles.ramp(1.5), 6.0,
                                      controller_config=config, fault_at=3.0, latency=0.02)

    assert fall_time(realtime) is None
    assert fall_time(lockstep_weight) is not None


@pytest.mark.parametrize("mpc_async", [False, True])
def test_injected_qp_failures_last_that_many_control_steps(mpc_async):
    """``inject_qp_failures`` N: the next N steps each take a failed solve's fallback, whatever the
    MPC's period (5 here) or process; the step after, a real solve is due again."""
    config = dataclasses.replace(load_controller_config(), mpc_period_steps=5, mpc_async=mpc_async)
    loop = ClosedLoop(GAITS["rapid_trot"], controller_config=config)
    controller = loop.controller
    try:
        for _ in range(20):
            loop.step(VelocityCommand())
        assert controller.mpc_fallbacks == 0
        controller.inject_qp_failures(7)
        statuses = []
        for _ in range(7):
            loop.step(VelocityCommand())
            statuses.append((controller.solved_this_step, controller.last_solution.status))
        assert statuses == [(True, "injected failure")] * 7 and controller.mpc_fallbacks == 7
        for _ in range(200):  # a worker's solve takes a step or a few to come back (more on a busy machine)
            loop.step(VelocityCommand())
            if controller.last_solution.solved:
                break
        assert controller.last_solution.solved and controller.mpc_fallbacks == 7
        with pytest.raises(ConfigError, match=r"inject_qp_failures must be an integer in \[0, 1000000\]"):
            controller.inject_qp_failures(-1)
    finally:
        loop.sim.close()
        controller.close()


def test_gait_clock_catches_up_with_missed_steps():
    """A realtime controller that missed steps is told the sim time since its last one: the phase
    advances by that time (capped at MAX_CATCH_UP), not by one period per step it happened to run,
    so at 26 % missed steps a 2 Hz trot stays a 2 Hz trot in sim time instead of slowing to 1.5 Hz."""
    loop = ClosedLoop(GAITS["slow_trot"])  # 2 Hz: 4 pi rad/s
    controller = loop.controller
    try:
        r = loop.readings
        obs = Observation(r.joint_position, r.joint_velocity, r.imu_orientation, r.imu_angular_velocity,
                          r.foot_contact, np.zeros(3))
        rate = 2 * np.pi * GAITS["slow_trot"].stepping_frequency
        for elapsed, advance in [(None, 0.002), (0.002, 0.002), (0.006, 0.006), (0.0, 0.002), (5.0, MAX_CATCH_UP)]:
            before = controller.gait.phase_fr
            controller.step(obs, VelocityCommand(), elapsed=elapsed)
            assert (controller.gait.phase_fr - before) % (2 * np.pi) == pytest.approx(rate * advance), elapsed
    finally:
        loop.sim.close()
        controller.close()


def test_flat_ground_has_no_end_at_100_m():
    """plane.urdf is a 200 m box: a robot started 95 m out at 2.5 m/s used to run off its edge at
    x = 100 m and fall for good. Now the ground goes on (worlds.GroundTiles)."""
    from a1_sim_bridge.sim import A1Sim

    sim = A1Sim()
    loop = ClosedLoop(GAITS["fly_trot"], sim=sim)
    p = sim._p  # fast-forward: put the robot 95 m out, as 40 s of running would
    position, orientation = p.getBasePositionAndOrientation(sim._body)
    p.resetBasePositionAndOrientation(sim._body, [95.0, 0.0, position[2]], orientation)
    profile = speed_profiles.ramp(2.5)
    try:
        for _ in range(round(8.0 / 0.002)):
            loop.step(profile(sim.time))
            assert not loop.fallen, f"fell at x = {sim.ground_truth().base_position[0]:.1f} m"
        x, _, z = sim.ground_truth().base_position
        assert x > 105.0 and z > 0.2
    finally:
        sim.close()


def test_mpc_async_must_be_a_bool():
    with pytest.raises(ConfigError, match=r"mpc_async must be true or false, got 'yes'"):
        dataclasses.replace(load_controller_config(), mpc_async="yes").validated()


def test_mpc_period_steps_is_range_checked():
    with pytest.raises(ConfigError, match=r"mpc_period_steps must be an integer in \[1, 25\]"):
        dataclasses.replace(load_controller_config(), mpc_period_steps=0).validated()
