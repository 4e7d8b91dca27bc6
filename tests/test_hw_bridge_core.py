"""Hardware bridge and virtual A1 cores without ROS: safe start, contact calibration, command
conversion both ways, the virtual robot's command-loss settings and packet loss, and the two
talking over real UDP sockets on loopback."""

from __future__ import annotations

import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest
from a1_common.command import JointCommand, MotorMode
from a1_common.config import ConfigError
from a1_common.robot import a1
from a1_hw_bridge.bridge import BridgeConfig, BridgeLogic, HardwareBridge, Phase
from a1_hw_bridge.contacts import FootContactCalibrator
from a1_hw_bridge.link import Pacer, RobotLink
from a1_hw_bridge.protocol import pack_low_cmd, pack_low_state, unpack_low_cmd, unpack_low_state
from a1_hw_bridge.robot_io import (
    joint_command_from_low_cmd,
    low_cmd_from_joint_command,
    low_state_from_readings,
    readings_from_low_state,
    rpy_from_quaternion,
)
from a1_hw_bridge.virtual_a1 import VirtualA1, VirtualA1Config, VirtualA1Server
from a1_interface.sensors import SensorReadings
from a1_sim_bridge.sim import SimConfig

from a1_hw_bridge import bridge as bridge_module
from a1_hw_bridge import protocol as wire

ROBOT = a1()
NOMINAL = ROBOT.nominal_joint_angles
LYING = np.tile([0.0, 1.2, -2.65], 4)  # legs folded, inside the joint limits
LIMITS = (ROBOT.joint_lower_limits, ROBOT.joint_upper_limits)


def state(q: np.ndarray, foot_force=(100, 110, 120, 130), tick: int = 0) -> wire.LowState:
    s = wire.LowState(tick=tick)
    s.q[:12] = q
    s.foot_force = np.array(foot_force)
    return s


def sent(logic: BridgeLogic, now: float) -> wire.LowCmd:
    return unpack_low_cmd(logic.motor_command(now))


def assert_damping(cmd: wire.LowCmd) -> None:
    assert np.all(cmd.mode[:12] == wire.SERVO_MODE) and np.all(cmd.mode[12:] == wire.IDLE_MODE)
    assert not cmd.kp.any() and not cmd.dq.any() and not cmd.tau.any()
    assert np.all(cmd.kd[:12] == ROBOT.damping_kd) and not cmd.kd[12:].any()


# --- safe start ----------------------------------------------------------------------------------------
def test_safe_start_damps_stands_up_calibrates_then_hands_over():
    logic = BridgeLogic(BridgeConfig(stand_up_time=1.0, stand_hold_time=0.5, command_timeout=0.04))
    assert logic.phase == Phase.CONNECTING
    assert_damping(sent(logic, 0.0))  # before any state: damping
    assert logic.on_state(state(LYING), 10.0) is None
    assert logic.phase == Phase.STANDING_UP
    # Interpolated PD targets from the measured pose to the nominal one, with the stand gains.
    for now, beta in ((10.0, 0.0), (10.25, 0.25), (10.5, 0.5), (11.0, 1.0), (11.3, 1.0)):
        cmd = sent(logic, now)
        assert np.allclose(cmd.q[:12], beta * NOMINAL + (1 - beta) * LYING, atol=1e-6), now
        assert np.array_equal(cmd.kp[:12], ROBOT.joint_kp) and np.array_equal(cmd.kd[:12], ROBOT.joint_kd)
    # Nothing published until the standing calibration is done; forces read during the hold only.
    assert logic.on_state(state(NOMINAL, (5, 5, 5, 5)), 10.9) is None
    assert logic.on_state(state(NOMINAL, (100, 110, 120, 130)), 11.0) is None
    assert logic.on_state(state(NOMINAL, (110, 120, 130, 140)), 11.25) is None
    readings = logic.on_state(state(NOMINAL, (120, 130, 140, 150)), 11.5)
    assert logic.phase == Phase.RUNNING and readings is not None
    assert np.allclose(logic.contacts.thresholds, 0.8 * np.array([110, 120, 130, 140]))
    assert readings.foot_contact.all() and readings.time == 11.5
    assert np.allclose(readings.joint_position, NOMINAL)
    # Until the controller's first command: hold the standing pose.
    cmd = sent(logic, 11.6)
    assert np.allclose(cmd.q[:12], NOMINAL, atol=1e-6) and np.array_equal(cmd.kp[:12], ROBOT.joint_kp)
    controller = JointCommand(position=NOMINAL + 0.1, kp=np.full(12, 37.5), kd=np.full(12, 1.25),
                              torque=np.linspace(-3, 3, 12))
    assert logic.watchdog.offer(controller, 11.6)
    cmd = sent(logic, 11.6 + 0.039)
    assert np.all(cmd.kp[:12] == 37.5) and np.all(cmd.kd[:12] == 1.25)
    assert np.allclose(cmd.tau[:12], controller.torque, atol=1 / 256)
    assert_damping(sent(logic, 11.6 + 0.04))  # the controller went silent for command_timeout


@pytest.mark.parametrize(("q", "joint"), [
    (np.zeros(12), "FR_lower_joint"),  # an all-zero state: calf at 0 rad is impossible
    (np.where(np.arange(12) == 4, np.nan, LYING), "FL_upper_joint"),
    (np.where(np.arange(12) == 9, 1.1, LYING), "RL_hip_joint"),
])
def test_start_refused_when_the_joints_read_impossible_values(q, joint):
    logic = BridgeLogic(BridgeConfig())
    assert logic.on_state(state(q), 0.0) is None
    assert logic.phase == Phase.FAULT
    assert joint in logic.fault and "start refused" in logic.fault
    assert_damping(sent(logic, 5.0))
    assert logic.on_state(state(LYING), 10.0) is None and logic.phase == Phase.FAULT  # latched


# --- command conversion ----------------------------------------------------------------------------------
def test_joint_command_survives_the_wire_at_its_resolution():
    rng = np.random.default_rng(4)
    cmd = JointCommand(position=rng.uniform(-3, 3, 12), velocity=rng.uniform(-10, 10, 12), kp=rng.uniform(0, 200, 12),
                       kd=rng.uniform(0, 5, 12), torque=rng.uniform(-50, 50, 12)).validated()
    wire = pack_low_cmd(low_cmd_from_joint_command(cmd, ROBOT, NOMINAL), position_limits=LIMITS)
    back = joint_command_from_low_cmd(unpack_low_cmd(wire))
    assert np.allclose(back.position, np.clip(cmd.position, *LIMITS), atol=2e-7)
    assert np.allclose(back.velocity, cmd.velocity, atol=1e-5)
    assert np.all(np.abs(back.kp - cmd.kp) < 1 / 32) and np.all(np.abs(back.kd - cmd.kd) < 1 / 16)
    clipped = np.clip(cmd.torque, -33.5, 33.5)  # feed-forward clipped to the motor limit
    assert np.all(np.abs(back.torque - clipped) < 1 / 256) and np.abs(back.torque).max() <= 33.5


def test_damping_on_the_wire_damps_on_the_robot():
    measured = LYING + 0.01
    low = unpack_low_cmd(pack_low_cmd(low_cmd_from_joint_command(JointCommand.damping(), ROBOT, measured),
                                      position_limits=LIMITS))
    assert np.allclose(low.q[:12], measured, atol=1e-6)
    robot_side = joint_command_from_low_cmd(low)
    dq = np.linspace(-5, 5, 12)
    tau = robot_side.motor_torques(LYING, dq, 33.5, 0.0)
    assert np.allclose(tau, -ROBOT.damping_kd * dq)


def test_robot_side_sentinels_and_idle_mode():
    low = wire.LowCmd(mode=np.full(20, wire.SERVO_MODE), q=np.full(20, 0.5), dq=np.full(20, 1.0), kp=np.full(20, 10.0),
                 kd=np.full(20, 2.0), tau=np.full(20, 1.0))
    low.q[0] = wire.POS_STOP_F  # no position term on motor 0
    low.dq[1] = wire.VEL_STOP_F  # no velocity term on motor 1
    low.mode[2] = wire.IDLE_MODE  # motor 2 idle: no torque at all
    robot_side = joint_command_from_low_cmd(unpack_low_cmd(pack_low_cmd(low, position_limits=None)))
    q, dq = np.zeros(12), np.full(12, 0.5)
    tau = robot_side.motor_torques(q, dq, 33.5, 0.0)
    assert tau[0] == pytest.approx(1.0 + 2.0 * (1.0 - 0.5))
    assert tau[1] == pytest.approx(1.0 + 10.0 * 0.5)
    assert tau[2] == 0.0
    assert tau[3] == pytest.approx(1.0 + 10.0 * 0.5 + 2.0 * 0.5)


def test_sensor_readings_survive_the_wire():
    angle = 0.3
    readings = SensorReadings(
        time=1.234, joint_position=LYING, joint_velocity=np.linspace(-2, 2, 12), joint_torque=np.linspace(-20, 20, 12),
        imu_orientation=np.array([np.sin(angle / 2), 0.0, 0.0, np.cos(angle / 2)]),
        imu_angular_velocity=np.array([0.1, -0.2, 0.3]), imu_linear_acceleration=np.array([0.5, 0.0, 9.7]),
        foot_contact=np.array([True, False, True, True]), foot_force=np.array([40.0, 0.0, 55.4, 1000.0]))
    low = unpack_low_state(pack_low_state(low_state_from_readings(readings, 1_234_000 + (1 << 32), np.full(12, 10),
                                                                  foot_force_gain=2.0, foot_force_offset=15.0)))
    assert low.tick == 1_234_000  # the robot's microsecond clock wraps at 2^32
    assert np.allclose(low.rpy, [angle, 0.0, 0.0], atol=1e-6)
    assert low.foot_force.tolist() == [95, 15, 126, 2015]  # offset + gain x N, rounded
    back = readings_from_low_state(low, 1.234, readings.foot_contact, readings.foot_force)
    assert np.allclose(back.imu_orientation, readings.imu_orientation, atol=1e-7)  # (x, y, z, w) again
    for name in ("joint_position", "joint_velocity", "imu_angular_velocity", "imu_linear_acceleration"):
        assert np.allclose(getattr(back, name), getattr(readings, name), atol=1e-6), name
    assert np.all(np.abs(back.joint_torque - readings.joint_torque) <= 1 / 512)


def test_rpy_convention():
    # yaw 0.5 then pitch 0.2 (intrinsic z-y-x): q = q_z * q_y
    cz, sz, cy, sy = np.cos(0.25), np.sin(0.25), np.cos(0.1), np.sin(0.1)
    quat = np.array([-sz * sy, cz * sy, sz * cy, cz * cy])
    assert np.allclose(rpy_from_quaternion(quat), [0.0, 0.2, 0.5], atol=1e-12)


# --- foot contacts -------------------------------------------------------------------------------------
def test_contact_calibration_from_standing_then_from_swings():
    c = FootContactCalibrator(standing_ratio=0.8, swing_margin=10.0, offset=15.0, scale=0.5)
    with pytest.raises(ValueError, match="no standing"):
        c.finish_standing()
    c.add_standing([115, 135, 155, 175])
    c.add_standing([125, 145, 165, 185])
    assert np.allclose(c.finish_standing(), [96, 112, 128, 144])
    assert c.contact([100, 100, 130, 150]).tolist() == [True, False, True, True]
    assert np.allclose(c.force([115, 15, 0, 215]), [50, 0, 0, 100])
    # FR swings twice (readings 20 and 22), then is scheduled into stance: threshold = 21 + 10.
    c.observe_schedule(np.array([False, True, True, True]), np.array([20, 300, 300, 300]))
    c.observe_schedule(np.array([False, True, True, True]), np.array([22, 300, 300, 300]))
    assert c.swing_calibrations == 0
    c.observe_schedule(np.array([True, True, True, True]), np.array([200, 300, 300, 300]))
    assert c.swing_calibrations == 1
    assert np.allclose(c.thresholds, [31, 112, 128, 144]) and c.unloaded[0] == 21
    assert c.contact([32, 0, 0, 0])[0] and not c.contact([30, 0, 0, 0])[0]
    assert c.force([41, 0, 0, 0])[0] == pytest.approx(10.0)


def test_standing_calibration_flags_feet_that_carried_nothing():
    c = FootContactCalibrator(offset=15.0, swing_margin=10.0)
    c.add_standing([200, 20, 200, 24])  # FL and RL read like feet in the air (robot hung up?)
    c.finish_standing()
    assert c.unloaded_legs == [1, 3]


# --- configuration ---------------------------------------------------------------------------------------
@pytest.mark.parametrize(("cls", "changes", "match"), [
    (BridgeConfig, {"clock_mode": "fast"}, r"clock_mode must be one of \['realtime', 'lockstep'\], got 'fast'"),
    (BridgeConfig, {"robot_port": 70000}, r"robot_port must be an integer in \[1, 65535\], got 70000"),
    (BridgeConfig, {"command_timeout": 0.0}, r"command_timeout must be in \(0.0, 1.0\], got 0.0"),
    (BridgeConfig, {"stand_up_time": 0.0}, r"stand_up_time must be in \[0.1, 10.0\]"),
    (BridgeConfig, {"foot_force_scale": -1.0}, r"foot_force_scale must be in \(0.0, 100.0\]"),
    (VirtualA1Config, {"on_command_loss": "explode"}, r"on_command_loss must be one of \['hold', 'damping', "),
    (VirtualA1Config, {"packet_loss": 1.0}, r"packet_loss must be in \[0.0, 1.0\), got 1.0"),
    (VirtualA1Config, {"port": -1}, r"port must be an integer in \[0, 65535\], got -1"),
])
def test_bad_settings_are_named_with_their_range(cls, changes, match):
    with pytest.raises(ConfigError, match=match):
        cls(**changes).validated()


# --- virtual A1 ----------------------------------------------------------------------------------------
def command_packet(cmd: JointCommand, kd_override: float | None = None) -> bytes:
    low = low_cmd_from_joint_command(cmd, ROBOT, NOMINAL)
    if kd_override is not None:
        low.kd[:12] = kd_override
    return pack_low_cmd(low, position_limits=LIMITS)


@pytest.fixture(scope="module")
def shared_sim_config() -> SimConfig:
    return SimConfig(settle_time=0.2)


@pytest.mark.parametrize("behaviour", ["hold", "damping", "zero_torque"])
def test_virtual_a1_command_loss_setting(behaviour, shared_sim_config):
    robot = VirtualA1(VirtualA1Config(port=0, on_command_loss=behaviour, command_loss_timeout=0.02), shared_sim_config)
    try:
        assert robot.active_command().mode == MotorMode.DAMPING  # before any command: damping (L2+B)
        hold = JointCommand(position=NOMINAL, kp=np.full(12, 40.0), kd=np.full(12, 1.0))
        assert robot.receive(command_packet(hold))
        for _ in range(9):  # 18 ms of robot time: still the command
            assert np.all(robot.active_command().kp == 40.0)
            robot.tick()
        robot.tick()  # 20 ms: the timeout
        active = robot.active_command()
        expected = {"hold": hold, "damping": JointCommand.damping(), "zero_torque": JointCommand()}[behaviour]
        assert active.mode == expected.mode and np.array_equal(active.kp, expected.kp)
        assert np.array_equal(active.kd, expected.kd) and np.array_equal(active.torque, expected.torque)
        assert robot.counters.command_loss_fallbacks == 1
        assert robot.receive(command_packet(hold)) and np.all(robot.active_command().kp == 40.0)  # recovers
    finally:
        robot.close()


def test_virtual_a1_drops_bad_datagrams_and_refuses_gains_its_motors_cannot_model(shared_sim_config):
    robot = VirtualA1(VirtualA1Config(port=0), shared_sim_config)
    try:
        good = command_packet(JointCommand.hold(ROBOT))
        corrupt = bytearray(good)
        corrupt[100] ^= 0x10
        assert not robot.receive(bytes(corrupt)) and not robot.receive(good[:600])
        assert not robot.receive(pack_low_cmd(wire.LowCmd(header=wire.Header(level_flag=0)), position_limits=None))
        assert not robot.receive(command_packet(JointCommand.hold(ROBOT), kd_override=500.0))  # wire ok, kd > 100
        assert robot.counters.commands_refused == 1 and "kd" in robot.last_error
        assert (robot.stats.bad_crc, robot.stats.wrong_size, robot.stats.bad_level) == (1, 1, 1)
        assert robot.active_command().mode == MotorMode.DAMPING  # none of them took effect
        assert robot.receive(good)
        first = unpack_low_state(robot.tick())
        second = unpack_low_state(robot.tick())
        assert (first.tick, second.tick) == (2000, 4000)  # the robot's clock [us], 2 ms per tick
        assert np.all(second.mode[:12] == wire.SERVO_MODE)
    finally:
        robot.close()


def test_virtual_a1_packet_loss_is_seeded_and_at_the_set_rate(shared_sim_config):
    def run(seed: int) -> tuple[list[int], int]:
        robot = VirtualA1(VirtualA1Config(port=0, packet_loss=0.2, loss_seed=seed), shared_sim_config)
        packet = command_packet(JointCommand.hold(ROBOT))
        try:
            lost_states = [i for i in range(600) if (robot.receive(packet), robot.tick())[1] is None]
            return lost_states, robot.counters.commands_lost
        finally:
            robot.close()

    lost_a, commands_lost_a = run(5)
    lost_b, commands_lost_b = run(5)
    assert lost_a == lost_b and commands_lost_a == commands_lost_b  # same seed, same losses
    assert 80 < len(lost_a) < 160 and 80 < commands_lost_a < 160  # 20 % of 600 each way
    assert run(6)[0] != lost_a


def test_virtual_a1_realtime_streams_states_at_500_hz_then_damps(shared_sim_config):
    robot = VirtualA1(VirtualA1Config(port=0, clock_mode="realtime", command_loss_timeout=0.1), shared_sim_config)
    server = VirtualA1Server(robot)
    thread = threading.Thread(target=server.serve, daemon=True)
    thread.start()
    link = RobotLink(*server.address, "127.0.0.1", 0)
    try:
        assert link.receive(0.1) is None  # no state before the robot heard from a client
        assert link.send(command_packet(JointCommand.hold(ROBOT)))
        ticks, modes = [], []
        # 200 states are 0.4 s of the robot's clock, past its 0.1 s command-loss timeout; the wall
        # time they take is the machine's (the rate is benchmarks/graph_realtime.py's to measure).
        deadline = time.monotonic() + 10.0
        while len(ticks) < 200 and time.monotonic() < deadline:  # one command only: the robot streams on its own
            for datagram in link._drain():
                s = unpack_low_state(datagram)
                ticks.append(s.tick)
                modes.append(int(s.mode[0]))
            time.sleep(0.005)
        steps = np.diff(ticks)
        assert len(ticks) >= 200, f"only {len(ticks)} states in 10 s"
        assert np.all(steps == 2000), "states skipped or repeated"
        assert modes[0] == wire.SERVO_MODE and modes[-1] == wire.IDLE_MODE  # damped after 100 ms without commands
        assert robot.counters.command_loss_fallbacks == 1
    finally:
        link.close()
        server.stop()
        thread.join(timeout=2)
        robot.close()


def test_realtime_sends_count_a_command_over_a_period_late_as_missed(monkeypatch):
    """A command that comes more than one control period after the state it answers was published
    still goes out, but its send counts as a missed deadline, as the sim bridge counts one sent after
    its step's deadline; one in time does not."""
    bridge = HardwareBridge(BridgeConfig(robot_ip="127.0.0.1", local_ip="127.0.0.1", local_port=0),
                            publish=lambda readings, stamp_ns: None, clock_ns=time.time_ns)
    now = 1000.0  # [s] the bridge's monotonic clock, held still: a loaded machine must not make it late
    monkeypatch.setattr(bridge_module, "time", SimpleNamespace(monotonic=lambda: now))
    try:
        bridge.logic.phase = Phase.RUNNING
        bridge._published_at.update({2_000_000: now, 4_000_000: now - 0.010})  # 10 ms: five periods ago
        hold = JointCommand.hold(ROBOT)
        for stamp_ns, missed in ((2_000_000, 0), (4_000_000, 1)):
            assert bridge.offer_command(hold, stamp_ns) == "accepted"
            before = bridge.deadlines.uncommanded
            with bridge._lock:
                bridge._count_send()
            assert bridge.deadlines.uncommanded - before == missed
        with bridge._lock:
            bridge._count_send()  # nothing new since: missed
        assert bridge.deadlines.uncommanded == 2
    finally:
        bridge.link.close()


def test_bridge_stands_a_dropped_virtual_a1_up_over_udp_in_lockstep():
    """The two cores over real sockets: damping, stand-up, calibration, hand-over to a 'controller'."""
    robot = VirtualA1(VirtualA1Config(port=0, clock_mode="lockstep", foot_force_offset=15.0),
                      SimConfig(settle_time=0.0))  # dropped from 0.32 m with no settling: it has to be stood up
    server = VirtualA1Server(robot)
    thread = threading.Thread(target=server.serve, daemon=True)
    published: list[tuple[int, SensorReadings]] = []
    bridge: HardwareBridge | None = None

    def controller(readings: SensorReadings, stamp_ns: int) -> None:
        published.append((stamp_ns, readings))
        assert bridge.offer_command(JointCommand.hold(ROBOT), stamp_ns) == "accepted"

    config = BridgeConfig(robot_ip="127.0.0.1", robot_port=server.address[1], local_ip="127.0.0.1", local_port=0,
                          clock_mode="lockstep", stand_up_time=0.5, stand_hold_time=0.2)
    bridge = HardwareBridge(config, publish=controller, clock_ns=time.time_ns)
    thread.start()
    bridge.start()
    try:
        deadline = time.monotonic() + 60
        while len(published) < 100 and time.monotonic() < deadline and bridge.failure is None:
            time.sleep(0.05)
    finally:
        bridge.stop()
        server.stop()
        thread.join(timeout=2)
    try:
        assert bridge.failure is None and len(published) >= 100
        stamps = np.array([s for s, _ in published])
        assert np.all(np.diff(stamps) == 2_000_000)  # the robot's tick, 2 ms per command
        assert stamps[0] * 1e-9 >= 0.7  # nothing before stand-up + hold
        assert robot.sim.ground_truth().base_position[2] > 0.24  # stood up
        last = published[-1][1]
        assert last.foot_contact.all() and np.allclose(last.joint_position, NOMINAL, atol=0.1)
        # Standing calibration: 0.8 x (offset + body weight share per foot [N]) in raw units.
        weight = ROBOT.urdf_total_mass * ROBOT.gravity
        assert 0.8 * 15 < bridge.logic.contacts.thresholds.min()
        assert bridge.logic.contacts.thresholds.sum() == pytest.approx(0.8 * (4 * 15 + weight), rel=0.1)
        assert bridge.link.stats.dropped == 0 and bridge.counters.late_commands == 0
    finally:
        robot.close()


def test_a_dead_link_thread_damps_the_motors_and_reports():
    robot = VirtualA1(VirtualA1Config(port=0, clock_mode="lockstep"), SimConfig(settle_time=0.2))
    server = VirtualA1Server(robot)
    thread = threading.Thread(target=server.serve, daemon=True)
    failures: list[Exception] = []

    def broken_publish(readings: SensorReadings, stamp_ns: int) -> None:
        raise RuntimeError("publisher gone")

    config = BridgeConfig(robot_ip="127.0.0.1", robot_port=server.address[1], local_ip="127.0.0.1", local_port=0,
                          clock_mode="lockstep", stand_up_time=0.1, stand_hold_time=0.01)
    bridge = HardwareBridge(config, publish=broken_publish, clock_ns=time.time_ns, on_failure=failures.append)
    thread.start()
    bridge.start()
    try:
        deadline = time.monotonic() + 30
        while not failures and time.monotonic() < deadline:
            time.sleep(0.02)
        assert failures and isinstance(bridge.failure, RuntimeError) and failures[0] is bridge.failure
        deadline = time.monotonic() + 5
        while robot.stats.accepted < bridge.link.stats.sent and time.monotonic() < deadline:
            time.sleep(0.01)  # let the virtual robot take the last datagrams
        active = robot.active_command()
        assert not active.kp.any() and np.all(active.kd == ROBOT.damping_kd)  # the stand-up hold is gone
    finally:
        bridge.stop()
        server.stop()
        thread.join(timeout=2)
        robot.close()


def test_pacer_keeps_time_catches_up_a_little_and_reports_what_it_skips():
    pacer = Pacer(0.002)
    pacer.deadline = time.monotonic() + 1.0
    assert pacer.advance() == 0 and pacer.overruns == 0  # ahead: the next deadline, nothing skipped
    pacer.deadline = time.monotonic() - 0.05
    assert pacer.advance() == 0 and pacer.overruns == 1  # 50 ms behind: catch up, send by send
    due = pacer.deadline = time.monotonic() - 0.5  # a stalled process: start again from now
    skipped = pacer.advance()
    behind = time.monotonic() - due
    assert 0.5 / 0.002 - 2 <= skipped <= behind / 0.002 and pacer.overruns == 2
    assert pacer.remaining() <= 0.0 and abs(pacer.remaining()) < 0.05
