"""A1Sim library core: standing, motor model, safety fallback, sensors, worlds, determinism."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from a1_common.command import CommandError, CommandWatchdog, DeadlineMonitor, JointCommand, MotorMode
from a1_common.config import ConfigError
from a1_common.robot import a1
from a1_sim_bridge.sim import A1Sim, SensorNoise, SimConfig
from a1_sim_bridge.worlds import WORLD_NAMES


@pytest.fixture(scope="module")
def sim():
    s = A1Sim()
    yield s
    s.close()


def run_hold(sim: A1Sim, seconds: float) -> list[float]:
    hold = JointCommand.hold(sim.robot)
    heights = []
    for _ in range(round(seconds / sim.config.time_step)):
        sim.step(hold)
        heights.append(sim.ground_truth().base_position[2])
    return heights


def test_stands_under_joint_pd_for_5_s(sim):
    sim.reset()
    settled = sim.ground_truth().base_position[2]
    assert 0.2 < settled < 0.32
    heights = np.array(run_hold(sim, 5.0))
    assert np.max(np.abs(heights - settled)) < 0.02
    assert sim.sensors().foot_contact.all()


def test_sensors_at_rest(sim):
    sim.reset()
    run_hold(sim, 0.5)
    r = sim.sensors()
    # The IMU measures specific force: +g along the body z axis when standing still.
    np.testing.assert_allclose(r.imu_linear_acceleration, [0, 0, sim.robot.gravity], atol=0.3)
    np.testing.assert_allclose(r.imu_angular_velocity, 0.0, atol=0.05)
    np.testing.assert_allclose(np.linalg.norm(r.imu_orientation), 1.0, atol=1e-9)
    # Feet carry the robot's weight.
    assert r.foot_force.sum() == pytest.approx(sim.robot.urdf_total_mass * sim.robot.gravity, rel=0.05)
    np.testing.assert_allclose(r.joint_position, sim.robot.nominal_joint_angles, atol=0.08)
    assert sim.time == pytest.approx(0.5)


def test_payload_adds_its_weight_to_the_feet():
    loaded = A1Sim(SimConfig(payload_mass=3.77))
    try:
        run_hold(loaded, 0.5)
        weight = (loaded.robot.urdf_total_mass + 3.77) * loaded.robot.gravity
        assert loaded.sensors().foot_force.sum() == pytest.approx(weight, rel=0.05)
        loaded.reset()  # the world is rebuilt: the payload must be there once, not twice
        run_hold(loaded, 0.5)
        assert loaded.sensors().foot_force.sum() == pytest.approx(weight, rel=0.05)
    finally:
        loaded.close()


def test_reported_torque_is_the_clipped_applied_torque(sim):
    sim.reset()
    cmd = JointCommand.hold(sim.robot)
    cmd.torque = np.full(12, 60.0)  # far beyond the 33.5 N m motor limit
    r = sim.step(cmd)
    assert np.all(np.abs(r.joint_torque) <= sim.robot.motor_torque_limit + 1e-12)
    np.testing.assert_allclose(r.joint_torque, sim.robot.motor_torque_limit)


def test_motor_model_formula():
    cmd = JointCommand(position=np.full(12, 1.0), velocity=np.full(12, 0.5), kp=np.full(12, 10.0),
                       kd=np.full(12, 2.0), torque=np.full(12, 0.25))
    q, dq = np.zeros(12), np.full(12, 1.5)
    tau = cmd.motor_torques(q, dq, torque_limit=33.5, damping_kd=2.0)
    np.testing.assert_allclose(tau, 10.0 * 1.0 + 2.0 * (0.5 - 1.5) + 0.25)
    damping = JointCommand.damping().motor_torques(q, dq, torque_limit=33.5, damping_kd=2.0)
    np.testing.assert_allclose(damping, -2.0 * 1.5)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("position", np.full(12, np.nan), "position"),
        ("torque", np.full(12, np.inf), "torque"),
        ("kp", np.ones(11), "kp must have 12"),
        ("kp", np.full(12, -1.0), "kp"),
        ("kd", np.full(12, 1e6), "kd"),
        ("mode", 7, "mode"),
    ],
)
def test_bad_commands_are_rejected_with_the_field(sim, field, value, match):
    cmd = dataclasses.replace(JointCommand.hold(sim.robot), **{field: value})
    with pytest.raises(CommandError, match=match):
        cmd.validated()
    before = sim.steps
    with pytest.raises(CommandError):
        sim.step(cmd)
    assert sim.steps == before  # nothing was applied


def test_watchdog_falls_back_to_damping_and_counts():
    wd = CommandWatchdog(timeout=0.05)
    robot_cmd = JointCommand(kp=np.full(12, 5.0))
    assert wd.active(0.0).mode == MotorMode.DAMPING  # nothing received yet
    assert wd.offer(robot_cmd, now=0.0)
    assert wd.active(0.049).mode == MotorMode.HYBRID
    assert wd.active(0.05).mode == MotorMode.DAMPING
    assert wd.timeouts == 1 and wd.in_fallback
    bad = JointCommand(kp=np.full(12, np.nan))
    assert not wd.offer(bad, now=0.06)
    assert wd.rejected == 1 and "kp" in wd.last_error
    assert wd.active(0.06).mode == MotorMode.DAMPING  # a bad command never revives the motors
    assert wd.offer(robot_cmd, now=0.07)
    assert wd.active(0.08).mode == MotorMode.HYBRID


def test_watchdog_timeout_is_the_same_number_of_steps_at_any_time():
    for start_step in (0, 50_000, 1_234_567):
        wd = CommandWatchdog(timeout=0.05)
        t0 = start_step * 0.002
        wd.offer(JointCommand(), now=t0)
        assert wd.active((start_step + 24) * 0.002).mode == MotorMode.HYBRID
        assert wd.active((start_step + 25) * 0.002).mode == MotorMode.DAMPING


def test_stand_up_moves_linearly_from_the_measured_pose_to_the_nominal_one():
    robot = a1()
    start = np.zeros(12)
    nominal = robot.nominal_joint_angles
    for elapsed, share in ((-1.0, 0.0), (0.0, 0.0), (0.5, 0.5), (1.0, 1.0), (7.0, 1.0)):
        command = JointCommand.stand_up(robot, start, elapsed, duration=1.0)
        np.testing.assert_allclose(command.position, share * nominal)
        np.testing.assert_array_equal(command.kp, robot.joint_kp)
    np.testing.assert_array_equal(JointCommand.stand_up(robot, start, 0.0, duration=0.0).position, nominal)


def test_deadline_monitor_counts_missed_periods_and_the_longest_gap_per_window():
    monitor = DeadlineMonitor(period=0.002)
    for accepted in (1, 2, 2, 2, 3, 4, 4):  # the watchdog's count at each period: 3 periods brought nothing
        monitor.count(accepted)
    for seconds in (0.001, 0.002, 0.003):
        monitor.latency(seconds)
    assert (monitor.periods, monitor.uncommanded) == (7, 3)
    window = monitor.window()
    assert window["longest_command_gap_ms"] == "6"  # two periods in a row without a new command
    assert window["commanded_steps_window"] == 3 and window["latency_median_ms"] == "2.000"
    monitor.count(5)
    assert monitor.window() == {"commanded_steps_window": 0, "latency_median_ms": "n/a",
                                "latency_p99_ms": "n/a", "longest_command_gap_ms": "2"}  # a new window
    assert monitor.uncommanded == 3  # totals are kept across windows
    monitor.count(6, late=True)  # a new command, but sent after the period's deadline: missed
    assert (monitor.uncommanded, monitor.window()["longest_command_gap_ms"]) == (4, "4")
    monitor.window()
    monitor.count(7)
    monitor.count(7)
    monitor.skipped(50)  # a realtime bridge 0.1 s behind skips what it cannot catch up with
    monitor.count(8)
    assert (monitor.periods, monitor.uncommanded) == (62, 55)
    assert monitor.window()["longest_command_gap_ms"] == "104"  # the run of 51 missed periods, and one
    with pytest.raises(ConfigError, match="period"):
        DeadlineMonitor(period=0.0)


def test_damping_lowers_the_robot_slowly(sim):
    """With damping only (no stiffness) the robot sinks, without violent torques."""
    sim.reset()
    z0 = sim.ground_truth().base_position[2]
    for _ in range(500):
        r = sim.step(JointCommand.damping())
        expected = np.clip(-sim.robot.damping_kd * r.joint_velocity, -33.5, 33.5)
        # Torque reported for the step is computed from the velocity before the step: bounded.
        assert np.all(np.abs(r.joint_torque) <= np.abs(expected).max() + 5.0)
    assert sim.ground_truth().base_position[2] < z0 - 0.03


@pytest.mark.parametrize("world", WORLD_NAMES)
def test_each_world_loads_and_robot_stands(world):
    with A1Sim(SimConfig(world=world, seed=3)) as sim:
        start = sim.ground_truth().base_position[2]
        run_hold(sim, 1.0)
        gt = sim.ground_truth()
        rot_z = 1 - 2 * (gt.base_orientation[0] ** 2 + gt.base_orientation[1] ** 2)  # body z . world z
        assert rot_z > 0.95, f"robot tipped over on {world}"
        assert abs(gt.base_position[2] - start) < 0.03
        assert sim.sensors().foot_contact.sum() >= 3


def test_step_world_has_a_step():
    with A1Sim(SimConfig(world="step", step_height=0.08, step_distance=0.6)) as sim:
        ray = sim._p.rayTest([0.8, 0.0, 1.0], [0.8, 0.0, -1.0])[0]
        assert ray[3][2] == pytest.approx(0.08, abs=1e-3)


def _trajectory(config: SimConfig, steps: int = 300) -> np.ndarray:
    rng = np.random.default_rng(11)
    with A1Sim(config) as sim:
        rows = []
        for _ in range(steps):
            cmd = JointCommand.hold(sim.robot, sim.robot.nominal_joint_angles + rng.normal(0, 0.1, 12))
            r = sim.step(cmd)
            rows.append(np.concatenate([r.joint_position, r.joint_velocity, r.imu_linear_acceleration,
                                        r.foot_force, sim.ground_truth().base_position]))
        return np.array(rows)


def test_lockstep_determinism_bit_identical():
    config = SimConfig(world="rough", seed=5, noise=SensorNoise(joint_position_noise=0.01, gyro_noise=0.01))
    a = _trajectory(config)
    b = _trajectory(config)
    assert np.array_equal(a, b)
    c = _trajectory(dataclasses.replace(config, seed=6))
    assert not np.array_equal(a, c)


def test_reset_reproduces_the_same_run(sim):
    sim.reset(world="flat", seed=0)
    first = run_hold(sim, 0.2)
    sim.reset()
    assert run_hold(sim, 0.2) == first


def test_per_sensor_latency_delays_readings():
    joint_steps, imu_steps = 5, 2
    noise = SensorNoise(joint_latency=joint_steps * 0.002, imu_latency=imu_steps * 0.002)
    with A1Sim(SimConfig(noise=noise)) as delayed, A1Sim() as direct:
        cmd = JointCommand.damping()  # the robot sags: every reading changes each step
        seen_delayed = [delayed.step(cmd) for _ in range(30)]
        seen_direct = [direct.step(cmd) for _ in range(30)]
        for k in range(joint_steps, 30):
            np.testing.assert_array_equal(seen_delayed[k].joint_position,
                                          seen_direct[k - joint_steps].joint_position)
            np.testing.assert_array_equal(seen_delayed[k].imu_angular_velocity,
                                          seen_direct[k - imu_steps].imu_angular_velocity)
            np.testing.assert_array_equal(seen_delayed[k].foot_force, seen_direct[k].foot_force)  # no latency
        assert not np.array_equal(seen_direct[10].joint_position, seen_direct[5].joint_position)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"world": "moon"}, "world must be one of"),
        ({"ground_friction": 0.0}, "ground_friction"),
        ({"time_step": 0.5}, "time_step"),
        ({"seed": -1}, "seed"),
        ({"noise": SensorNoise(gyro_noise=-1.0)}, "gyro_noise"),
        ({"noise": SensorNoise(imu_latency=0.003)}, "multiple of time_step"),
        ({"world": "slope", "slope_angle": -0.1}, "slope_angle"),
        ({"payload_mass": -1.0}, "payload_mass"),
    ],
)
def test_bad_sim_config_names_the_field(changes, match):
    with pytest.raises(ConfigError, match=match):
        dataclasses.replace(SimConfig(), **changes).validated()


def test_config_from_node_parameters_rejects_unknown_keys():
    with pytest.raises(ConfigError, match="worldd"):
        SimConfig.from_parameters({"worldd": "flat"})
    params = {"world": "soft", "gyro_bias": 0.01, "clock_mode": "x"}
    cfg = SimConfig.from_parameters(params, ignore=("clock_mode",))
    assert cfg.world == "soft" and cfg.noise.gyro_bias == 0.01
