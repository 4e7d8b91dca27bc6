"""The sim bridge node over real rclpy: commands in, sensor messages out, one per step in lockstep."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable

import numpy as np
import pytest
from a1_common.command import JointCommand
from a1_common.config import ConfigError
from a1_common.files import TEMPORARY_MARK
from a1_common.robot import a1
from a1_interface.contract import CONTROL_QOS
from a1_interface.conversions import motor_command_msg, ns_from_stamp, stamp_from_ns
from a1_sim_bridge.joint_hold_node import JointHoldNode
from a1_sim_bridge.node import SimBridgeNode
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from ros_helpers import spin_until
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_srvs.srv import SetBool

from a1_sim_bridge import flight_recorder
from gait_msgs.msg import FootContacts, MotorCommand

STEP_NS = 2_000_000


@pytest.fixture
def bridge_graph(rclpy_context):
    """A lockstep sim bridge, a joint_hold answering it, and a listener recording every topic."""
    overrides = [Parameter("clock_mode", value="lockstep"), Parameter("lockstep_timeout", value=0.2),
                 Parameter("settle_time", value=0.3)]
    bridge = SimBridgeNode(context=rclpy_context, parameter_overrides=overrides)
    hold = JointHoldNode(context=rclpy_context)
    listener = Node("listener", context=rclpy_context)
    seen = {"joints": [], "imu": [], "contacts": [], "clock": []}
    listener.create_subscription(JointState, "/joint_states", seen["joints"].append, CONTROL_QOS)
    listener.create_subscription(Imu, "/imu/data", seen["imu"].append, CONTROL_QOS)
    listener.create_subscription(FootContacts, "/foot_contacts", seen["contacts"].append, CONTROL_QOS)
    listener.create_subscription(Clock, "/clock", seen["clock"].append, CONTROL_QOS)
    executor = SingleThreadedExecutor(context=rclpy_context)
    for n in (bridge, hold, listener):
        executor.add_node(n)
    yield bridge, hold, listener, executor, seen
    executor.shutdown()
    bridge.shutdown()
    for n in (bridge, hold, listener):
        n.destroy_node()


@pytest.mark.ros
def test_lockstep_one_sensor_set_per_command(bridge_graph):
    bridge, _hold, _listener, executor, seen = bridge_graph
    assert spin_until(executor, lambda: len(seen["joints"]) >= 400, timeout_s=60.0)
    stamps = [ns_from_stamp(m.header.stamp) for m in seen["joints"]]
    # Once the graph is connected, every 2 ms step is published exactly once, in order.
    tail = np.diff(stamps[-300:])
    assert np.all(tail == STEP_NS), f"gaps or repeats in lockstep stamps: {set(tail.tolist())}"
    assert bridge.sim.steps >= 399
    assert bridge.watchdog.accepted >= 300 and bridge.watchdog.rejected == 0
    assert not bridge.watchdog.in_fallback
    assert bridge.deadlines.uncommanded <= bridge._lockstep_timeouts  # in lockstep only a timed-out step misses
    # The other sensor topics carry the same stamps, and the clock follows sim time once per
    # clock_period (10 ms by default: every 5th step). (Keep-last-1 queues may drop a message the
    # listener was too slow to take, so compare sets, not lists.)
    joint_stamps = set(stamps)
    for key in ("imu", "contacts"):
        other = {ns_from_stamp(m.header.stamp) for m in seen[key]}
        assert len(joint_stamps & other) >= 0.9 * len(joint_stamps), key
    clock_period_ns = round(bridge.get_parameter("clock_period").value * 1e9)
    assert clock_period_ns == 5 * STEP_NS
    # The first clock goes out at the first step that has a subscriber, wherever in its period
    # that falls; every later one at the first step of a period.
    clock = sorted({ns_from_stamp(m.clock) for m in seen["clock"]})[1:]
    assert all(t % clock_period_ns == 0 for t in clock), [t for t in clock if t % clock_period_ns]
    on_period = {t for t in joint_stamps if t % clock_period_ns == 0}
    assert len(on_period & set(clock)) >= 0.9 * len(on_period)
    msg = seen["joints"][-1]
    assert list(msg.name) == list(bridge.sim.robot.joint_names)
    assert len(msg.position) == len(msg.velocity) == len(msg.effort) == 12
    assert all(seen["contacts"][-1].contact)  # standing on four feet
    assert seen["imu"][-1].linear_acceleration.z == pytest.approx(9.81, abs=0.5)


@pytest.mark.ros
def test_bad_command_rejected_then_damping_after_timeout(bridge_graph):
    bridge, hold, listener, executor, seen = bridge_graph
    pub = listener.create_publisher(MotorCommand, "/motor_command", CONTROL_QOS)
    assert spin_until(executor, lambda: len(seen["joints"]) >= 50 and pub.get_subscription_count() > 0,
                      timeout_s=30.0)
    executor.remove_node(hold)  # the controller goes silent ...
    # Once a lockstep timeout has passed, none of its commands is still in flight (a late one
    # would replace ours in the depth-1 queue).
    assert spin_until(executor, lambda: bridge._lockstep_timeouts >= 1, timeout_s=10.0)
    bad = JointCommand.hold(bridge.sim.robot)
    bad.kp = np.full(12, np.nan)
    # ... except for a command with NaN gains, stamped for the step the bridge waits on. (Repeated
    # until it lands: a new writer may be matched by the reader after its first sample was sent.)
    steps_before = bridge.sim.steps
    bad_msg = motor_command_msg(bad, stamp_from_ns(steps_before * STEP_NS))

    def rejected() -> bool:
        if bridge.watchdog.rejected == 0:
            pub.publish(bad_msg)
        return bridge.watchdog.rejected >= 1

    assert spin_until(executor, rejected, timeout_s=10.0)
    assert "kp" in bridge.watchdog.last_error
    # Without valid commands the sim still advances (lockstep timeout) and falls back to damping
    # after command_timeout = 50 ms of sim time, i.e. 25 steps.
    assert spin_until(executor, lambda: bridge.sim.steps >= steps_before + 30, timeout_s=30.0)
    assert bridge.watchdog.in_fallback and bridge.watchdog.timeouts == 1
    assert bridge.deadlines.uncommanded >= 30  # each of those steps counts as a missed deadline


@pytest.mark.ros
def test_unknown_or_bad_parameters_are_config_errors(rclpy_context):
    with pytest.raises(ConfigError, match="wrold"):
        SimBridgeNode(context=rclpy_context, parameter_overrides=[Parameter("wrold", value="rough")])
    with pytest.raises(ConfigError, match="lockstep_timeout"):
        SimBridgeNode(context=rclpy_context, parameter_overrides=[Parameter("lockstep_timeout", value=-1.0)])
    with pytest.raises(ConfigError, match="command_timeout"):
        SimBridgeNode(context=rclpy_context, parameter_overrides=[Parameter("command_timeout", value=0.0)])
    with pytest.raises(ConfigError, match=r"clock_period must be a multiple of time_step"):
        SimBridgeNode(context=rclpy_context, parameter_overrides=[Parameter("clock_period", value=0.003)])


@contextlib.contextmanager
def bridge_and_commander(context, overrides: list[Parameter]):
    """A sim bridge and a node that publishes /motor_command, spun by one executor, torn down after:
    yields (bridge, listener node, /motor_command publisher, executor)."""
    bridge = SimBridgeNode(context=context, parameter_overrides=overrides)
    listener = Node("listener", context=context)
    commander = listener.create_publisher(MotorCommand, "/motor_command", CONTROL_QOS)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(bridge)
    executor.add_node(listener)
    try:
        yield bridge, listener, commander, executor
    finally:
        executor.shutdown()
        bridge.shutdown()
        bridge.destroy_node()
        listener.destroy_node()


@pytest.mark.ros
@pytest.mark.parametrize("clock_mode", ["lockstep", "realtime"])
def test_sim_holds_its_start_pose_until_the_first_command(rclpy_context, clock_mode):
    """Until a controller answers, the sim holds step 0 and offers its sensors again: lockstep runs
    stay reproducible, and a realtime robot does not fold into damping while its controller starts.
    The first command starts the sim."""
    overrides = [Parameter("clock_mode", value=clock_mode), Parameter("lockstep_timeout", value=0.05),
                 Parameter("settle_time", value=0.1)]
    with bridge_and_commander(rclpy_context, overrides) as (bridge, listener, commander, executor):
        joints = []
        listener.create_subscription(JointState, "/joint_states", joints.append, CONTROL_QOS)
        assert spin_until(executor, lambda: len(joints) >= 50, 20.0)
        assert bridge.sim.steps == 0
        assert {ns_from_stamp(m.header.stamp) for m in joints} == {0}
        start_height = float(bridge.sim.ground_truth().base_position[2])
        assert start_height > 0.2  # standing as spawned, not folded to the ground
        hold = JointCommand.hold(bridge.sim.robot, np.asarray(joints[-1].position))

        def commanded_five_steps() -> bool:  # answer the current step until the sim runs
            commander.publish(motor_command_msg(hold, stamp_from_ns(bridge.sim.steps * STEP_NS)))
            return bridge.sim.steps >= 5

        assert spin_until(executor, commanded_five_steps, 20.0)


@pytest.mark.ros
def test_flight_recorder_writes_the_seconds_before_a_fall(rclpy_context, tmp_path):
    """One command starts a realtime sim, then silence: the watchdog damps, the robot folds, and the
    recorder writes the window before the fall, with the command ageing and the damping in it."""
    overrides = [Parameter("clock_mode", value="realtime"), Parameter("settle_time", value=0.1),
                 Parameter("flight_recorder_dir", value=str(tmp_path)),
                 Parameter("flight_recorder_seconds", value=1.0)]
    with bridge_and_commander(rclpy_context, overrides) as (bridge, _, commander, executor):
        hold = JointCommand.hold(bridge.sim.robot)

        def started() -> bool:  # one command starts the sim; repeated until the bridge accepts one
            if bridge.watchdog.accepted == 0:
                commander.publish(motor_command_msg(hold, stamp_from_ns(0)))
            return bridge.sim.steps > 0

        assert spin_until(executor, started, 20.0)
        assert spin_until(executor, lambda: any(tmp_path.glob("fall_*.npz")), 20.0)
    (path,) = tmp_path.glob("fall_*.npz")
    data = flight_recorder.load(path)
    t = data["time_s"]
    # Every step from the start (the fall comes within the 1 s window), once each, 2 ms apart.
    assert t[0] == 0.0 and len(t) == round(t[-1] / 0.002) + 1 <= 500
    assert np.allclose(np.diff(t), 0.002)
    height = data["base_position_m"][:, 2]
    assert height[-1] < 0.18 <= height.max()
    assert data["damping"][-1] == 1 and data["damping"].sum() < len(t)  # it damped within the window
    assert not data["commanded_damping"].any()  # the watchdog's damping: nobody commanded it
    damped = np.flatnonzero(data["damping"])
    age = data["command_age_s"]
    # The watchdog's rule, seen from the robot: never damping while the command is younger than
    # command_timeout (0.05 s). Age counts from the stamp, the watchdog from the arrival, which this
    # test's executor may delay by some steps: the bound after the timeout is another test's.
    assert np.all(data["damping"][age <= 0.05] == 0) and age[damped[0]] > 0.05
    # Damped from then to the end, but for a command of this test's still queued in its executor when
    # the sim started: arriving within the timeout of its stamp it is accepted, and the damping
    # lifts until it too is old. Each accepted command can lift the damping once, no more.
    onsets = np.flatnonzero(np.diff(data["damping"]) == 1) + 1
    assert len(onsets) <= bridge.watchdog.accepted and np.all(data["damping"][onsets[-1]:] == 1), \
        (onsets, bridge.watchdog.accepted)
    assert not any(tmp_path.glob(f".*{TEMPORARY_MARK}*"))  # written atomically, the temporary file gone


@pytest.mark.ros
def test_commanded_damping_is_recorded_as_damped_not_as_a_fall(rclpy_context, tmp_path):
    """An e-stop or ``mode damping`` lays the robot down: the record is a damped_*.npz with the
    commanded damping in it, and no fall is logged (the watchdog's damping stays a fall, above)."""
    # Lockstep: every step waits for this test's command, so the watchdog never has to step in.
    overrides = [Parameter("clock_mode", value="lockstep"), Parameter("lockstep_timeout", value=1.0),
                 Parameter("settle_time", value=0.1), Parameter("flight_recorder_dir", value=str(tmp_path)),
                 Parameter("flight_recorder_seconds", value=2.0)]
    with bridge_and_commander(rclpy_context, overrides) as (bridge, _, commander, executor):
        hold, damping = JointCommand.hold(bridge.sim.robot), JointCommand.damping()

        def command() -> bool:  # hold for 0.2 s of sim time, then damping, fresh every step
            cmd = hold if bridge.sim.time < 0.2 else damping
            commander.publish(motor_command_msg(cmd, stamp_from_ns(bridge.sim.steps * STEP_NS)))
            return any(tmp_path.glob("*.npz"))

        assert spin_until(executor, command, 30.0)
    assert not any(tmp_path.glob("fall_*.npz"))
    (path,) = tmp_path.glob("damped_*.npz")
    data = flight_recorder.load(path)
    assert data["base_position_m"][-1, 2] < 0.18 and data["commanded_damping"][-1] == 1
    assert np.array_equal(data["commanded_damping"], data["damping"])  # the watchdog never stepped in


@pytest.mark.ros
def test_a_base_that_left_the_world_is_reported(rclpy_context):
    bridge = SimBridgeNode(context=rclpy_context, parameter_overrides=[Parameter("clock_mode", value="lockstep")])
    sent = []
    bridge.pub_diag.publish = sent.append
    try:
        bridge._publish_diagnostics()
        bridge.sim.base_position = (0.0, 0.0, -3.0)  # through the ground (no command yet: the sim holds)
        bridge._publish_diagnostics()
    finally:
        bridge.shutdown()
        bridge.destroy_node()
    standing, gone = (m.status[0] for m in sent)
    assert standing.level != DiagnosticStatus.ERROR
    assert gone.level == DiagnosticStatus.ERROR and "left the world: z = -3.0 m" in gone.message


def test_flight_recorder_ring_and_file_checks(tmp_path):
    recorder = flight_recorder.FlightRecorder(seconds=0.01, time_step=0.002)  # 5 rows
    row = {name: np.zeros(width) if width > 1 else 0.0 for name, width in flight_recorder.FIELDS.items()}
    row["base_orientation_xyzw"] = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(8):
        recorder.record(**{**row, "time_s": k * 0.002})
    window = recorder.window()
    assert np.allclose(window["time_s"], [0.006, 0.008, 0.010, 0.012, 0.014])  # the last 5, oldest first
    assert window["joint_torque_nm"].shape == (5, 12)
    path = recorder.save(tmp_path / "w.npz")
    assert np.allclose(flight_recorder.load(path)["time_s"], window["time_s"])
    del window["damping"]
    np.savez(tmp_path / "short.npz", **window)
    with pytest.raises(ConfigError, match="damping"):
        flight_recorder.load(tmp_path / "short.npz")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError):
        flight_recorder.load(tmp_path / "obj.npy")  # a pickle is never loaded
    with pytest.raises(ConfigError, match="flight_recorder_seconds"):
        flight_recorder.FlightRecorder(seconds=0.0, time_step=0.002)
    np.savez(tmp_path / "zero_quaternion.npz", **{**window, "damping": np.zeros(5),
                                                    "base_orientation_xyzw": np.zeros((5, 4))})
    with pytest.raises(ConfigError, match="base_orientation_xyzw"):
        flight_recorder.load(tmp_path / "zero_quaternion.npz")
    out = flight_recorder.plot(flight_recorder.load(path), tmp_path / "w.png")
    assert out.stat().st_size > 0


@pytest.mark.ros
@pytest.mark.parametrize("name, value", [("real_time_factor", 0.0), ("real_time_factor", 1.5),
                                         ("fall_height", -0.1), ("flight_recorder_seconds", -1.0)])
def test_realtime_factor_and_recorder_parameters_checked(rclpy_context, name, value):
    with pytest.raises(ConfigError, match=name):
        SimBridgeNode(context=rclpy_context, parameter_overrides=[Parameter(name, value=value),
                                                                  Parameter("flight_recorder_dir", value="/tmp")])


@pytest.mark.ros
@pytest.mark.parametrize("clock_mode", ["lockstep", "realtime"])
def test_stepped_by_the_executor_thread_one_sensor_set_per_step(rclpy_context, clock_mode):
    """own_thread=False (the composed control_chain): the executor's thread steps the sim through
    poll(). Lockstep: each step once its command is in, stamps once each and in order; realtime:
    poll never asks for a wait longer than a step (0.002 s / real_time_factor)."""
    overrides = [Parameter("clock_mode", value=clock_mode), Parameter("lockstep_timeout", value=0.2),
                 Parameter("settle_time", value=0.3), Parameter("real_time_factor", value=0.5)]
    bridge = SimBridgeNode(own_thread=False, context=rclpy_context, parameter_overrides=overrides)
    hold = JointHoldNode(context=rclpy_context)
    listener = Node("listener", context=rclpy_context)
    stamps: list[int] = []
    listener.create_subscription(JointState, "/joint_states", lambda m: stamps.append(ns_from_stamp(m.header.stamp)),
                                 CONTROL_QOS)
    executor = SingleThreadedExecutor(context=rclpy_context)
    for n in (bridge, hold):
        executor.add_node(n)
    listen = SingleThreadedExecutor(context=rclpy_context)  # its own: the step's callbacks never starve it
    listen.add_node(listener)
    waits = []
    try:
        for _ in range(20000):
            if len(stamps) >= 300:
                break
            waits.append(bridge.poll())
            executor.spin_once(timeout_sec=waits[-1])
            listen.spin_once(timeout_sec=0.0)
    finally:
        listen.shutdown()
        executor.shutdown()
        bridge.shutdown()
        for n in (bridge, hold, listener):
            n.destroy_node()
    assert len(stamps) >= 300 and bridge.watchdog.accepted >= 200
    if clock_mode == "lockstep":
        tail = np.diff(stamps[-200:])  # (a keep-last-1 listener may miss one: no repeats, in order)
        assert np.all(tail > 0) and np.all(tail % STEP_NS == 0), f"repeats in lockstep stamps: {set(tail.tolist())}"
        assert bridge.deadlines.uncommanded <= bridge._lockstep_timeouts  # a step waits for its command
        assert max(waits) <= 0.2 + 1e-9  # never past lockstep_timeout
    else:
        assert max(waits) <= 0.004 + 1e-9 and bridge.sim.steps >= 250


@pytest.mark.ros
def test_realtime_step_in_the_executor_thread_takes_a_command_sent_before_its_deadline(rclpy_context):
    """Composed, the controller's work after its command (filter update, /odom) can end past the
    bridge's deadline before the executor has taken the command. The step then first lets the
    executor take what was sent (poll returns 0 without stepping) and applies it; a command sent
    after the deadline is applied too but still counts as a missed deadline."""
    overrides = [Parameter("clock_mode", value="realtime"), Parameter("real_time_factor", value=0.05)]
    bridge = SimBridgeNode(own_thread=False, context=rclpy_context, parameter_overrides=overrides)
    controller = Node("controller", context=rclpy_context)
    stamps: list[int] = []
    controller.create_subscription(JointState, "/joint_states", lambda m: stamps.append(ns_from_stamp(m.header.stamp)),
                                   CONTROL_QOS)
    pub = controller.create_publisher(MotorCommand, "/motor_command", CONTROL_QOS)
    hold = JointCommand.hold(a1())
    bridge_executor, controller_executor = (SingleThreadedExecutor(context=rclpy_context) for _ in range(2))
    bridge_executor.add_node(bridge)
    controller_executor.add_node(controller)

    def step_with_command(late: bool) -> tuple[int, int]:
        """One step whose command is sent (on time or late) but not taken when the step is due:
        (uncommanded periods added, sim steps added)."""
        assert spin_until(controller_executor, lambda: bool(stamps), timeout_s=10.0)
        stamp = stamps[-1]
        stamps.clear()
        if late:  # the deadline of the step that is to apply it passed before the command was sent
            bridge._published_at[stamp] = (bridge._published_at[stamp][0], time.time_ns() - 1)
        pub.publish(motor_command_msg(hold, stamp_from_ns(stamp)))
        before, steps = bridge.deadlines.uncommanded, bridge.sim.steps
        bridge._next_deadline = time.monotonic() - 1e-4  # due now, the command not taken yet
        assert bridge.poll() == 0.0 and bridge.sim.steps == steps  # first: take what was sent
        accepted = bridge.watchdog.accepted
        assert spin_until(bridge_executor, lambda: bridge.watchdog.accepted > accepted, timeout_s=10.0)
        bridge.poll()
        return bridge.deadlines.uncommanded - before, bridge.sim.steps - steps

    try:
        bridge.poll()  # the start pose's sensors
        assert step_with_command(late=False) == (0, 1)
        assert step_with_command(late=False) == (0, 1)
        assert step_with_command(late=True) == (1, 1)  # applied, and counted as a missed deadline
        assert bridge._applied_stamp_ns == bridge.sim.steps * bridge.dt_ns - STEP_NS
    finally:
        bridge_executor.shutdown()
        controller_executor.shutdown()
        bridge.shutdown()
        for n in (bridge, controller):
            n.destroy_node()


@pytest.mark.ros
def test_realtime_periods_skipped_after_a_stall_count_as_missed_deadlines(rclpy_context):
    """Composed, a stall of the whole process stalls the simulation too: the steps it does not
    catch up with (over 0.1 s behind) are deadlines the robot passed without a command."""
    overrides = [Parameter("clock_mode", value="realtime")]
    bridge = SimBridgeNode(own_thread=False, context=rclpy_context, parameter_overrides=overrides)
    try:
        bridge.poll()  # the start pose's sensors
        bridge.take_command(serialize_message(motor_command_msg(JointCommand.hold(a1()), stamp_from_ns(0))))
        bridge._next_deadline = time.monotonic()
        bridge.poll()  # the first commanded step
        periods, missed, steps = bridge.deadlines.periods, bridge.deadlines.uncommanded, bridge.sim.steps
        assert steps == 1
        due = bridge._next_deadline = time.monotonic() - 0.5  # the process was stopped for half a second
        assert bridge.poll() == 0.0 and bridge.sim.steps == steps  # first: let the executor take a command
        bridge.poll()
        behind = time.monotonic() - due
        assert bridge.sim.steps == steps + 1  # one step, not 250 to catch up
        skipped = bridge.deadlines.periods - periods - 1
        assert 0.5 / bridge._period - 2 <= skipped <= behind / bridge._period
        assert bridge.deadlines.uncommanded - missed == skipped + 1  # no command came for any of them
        assert abs(bridge._next_deadline - time.monotonic()) < 0.05  # on schedule again from now
    finally:
        bridge.shutdown()
        bridge.destroy_node()


@pytest.mark.ros
def test_a_command_handed_over_in_process_steps_lockstep_at_once_and_its_wire_copy_is_dropped(rclpy_context):
    """Composed (a1_bringup.control_chain), the controller hands its command to the bridge as it
    sends it: a lockstep step is due at once, with no wait for the executor, and the copy that
    then comes over the wire is neither a second command nor a late one."""
    overrides = [Parameter("clock_mode", value="lockstep"), Parameter("lockstep_timeout", value=5.0)]
    bridge = SimBridgeNode(own_thread=False, context=rclpy_context, parameter_overrides=overrides)
    hold = JointCommand.hold(a1())
    try:
        bridge.poll()  # the start pose's sensors, stamped 0
        raw = serialize_message(motor_command_msg(hold, stamp_from_ns(0)))
        bridge.take_command(raw)
        assert bridge.watchdog.accepted == 1
        assert bridge.poll() == 0.0 and bridge.sim.steps == 1  # stepped with it, no executor in between
        bridge._on_command(raw, {"source_timestamp": time.time_ns()})  # its wire copy, after the step
        assert (bridge.watchdog.accepted, bridge._late_commands) == (1, 0)
        bridge._on_command(serialize_message(motor_command_msg(hold, stamp_from_ns(STEP_NS))),
                           {"source_timestamp": time.time_ns()})  # the next step's command
        assert bridge.watchdog.accepted == 2 and bridge.poll() == 0.0 and bridge.sim.steps == 2
        stale = serialize_message(motor_command_msg(hold, stamp_from_ns(0)))  # for a step long gone
        bridge.take_command(stale)
        bridge._on_command(stale, {"source_timestamp": time.time_ns()})  # its wire copy: not counted again
        assert (bridge.watchdog.accepted, bridge._late_commands) == (2, 1)
    finally:
        bridge.shutdown()
        bridge.destroy_node()


@pytest.mark.ros
def test_sensors_handed_over_in_process_let_lockstep_run_on_poll_alone(rclpy_context):
    """Composed with its controller (a1_bringup.control_chain), the bridge hands each step's three
    sensor messages, the bytes it publishes, to a sink as it publishes them: a controller answering
    there commands every step within poll, with no executor at all (the whole step in one call)."""
    overrides = [Parameter("clock_mode", value="lockstep"), Parameter("lockstep_timeout", value=5.0)]
    bridge = SimBridgeNode(own_thread=False, context=rclpy_context, parameter_overrides=overrides)
    hold = JointCommand.hold(a1())
    handed: list[tuple[bytes, bytes, bytes]] = []

    def controller(imu: bytes, contacts: bytes, joints: bytes) -> None:
        handed.append((imu, contacts, joints))
        stamp = ns_from_stamp(deserialize_message(joints, JointState).header.stamp)
        bridge.take_command(serialize_message(motor_command_msg(hold, stamp_from_ns(stamp))))

    bridge.sensor_sinks.append(controller)
    try:
        for _ in range(20):
            assert bridge.poll() == 0.0
        assert bridge.sim.steps == 19 and bridge.watchdog.accepted == 20  # (the first poll: the start pose)
        assert bridge.deadlines.uncommanded == 0 and bridge._lockstep_timeouts == 0
        stamps = [ns_from_stamp(deserialize_message(m, t).header.stamp)
                  for imu, contacts, joints in handed for m, t in ((imu, Imu), (contacts, FootContacts),
                                                                   (joints, JointState))]
        assert stamps == [step * STEP_NS for step in range(20) for _ in range(3)]
    finally:
        bridge.shutdown()
        bridge.destroy_node()


@pytest.mark.ros
def test_realtime_a_command_handed_over_after_the_next_deadline_counts_as_missed(rclpy_context):
    """Handed over within the poll that published its sensors, a command's deadline is not settled
    yet: it is judged when that poll ends. A controller that answers 3 ms after the sensors (the
    step is 2 ms) misses nearly every deadline; one that answers at once misses few."""
    overrides = [Parameter("clock_mode", value="realtime")]
    bridge = SimBridgeNode(own_thread=False, context=rclpy_context, parameter_overrides=overrides)
    hold = JointCommand.hold(a1())
    answer_after = [0.0]  # [s]

    def controller(imu: bytes, contacts: bytes, joints: bytes) -> None:
        time.sleep(answer_after[0])
        stamp = ns_from_stamp(deserialize_message(joints, JointState).header.stamp)
        bridge.take_command(serialize_message(motor_command_msg(hold, stamp_from_ns(stamp))))

    def missed_fraction(steps: int) -> float:
        missed, periods = bridge.deadlines.uncommanded, bridge.deadlines.periods
        while bridge.deadlines.periods < periods + steps:
            time.sleep(bridge.poll())
        return (bridge.deadlines.uncommanded - missed) / (bridge.deadlines.periods - periods)

    bridge.sensor_sinks.append(controller)
    try:
        assert missed_fraction(100) < 0.5
        answer_after[0] = 0.003
        assert missed_fraction(50) > 0.9
    finally:
        bridge.shutdown()
        bridge.destroy_node()


@pytest.mark.ros
def test_realtime_never_applies_an_older_steps_command_over_a_newer_one(rclpy_context):
    """Realtime takes the newest command whatever its step, but one answering an older step than
    the command in force (a copy delivered late) is stale: the newer one stays."""
    overrides = [Parameter("clock_mode", value="realtime"), Parameter("real_time_factor", value=0.05)]
    bridge = SimBridgeNode(own_thread=False, context=rclpy_context, parameter_overrides=overrides)
    hold = JointCommand.hold(a1())
    try:
        bridge.poll()  # the start pose's sensors
        bridge._on_command(serialize_message(motor_command_msg(hold, stamp_from_ns(STEP_NS))),
                           {"source_timestamp": time.time_ns()})
        bridge._on_command(serialize_message(motor_command_msg(hold, stamp_from_ns(0))),
                           {"source_timestamp": time.time_ns()})
        assert (bridge._pending_stamp_ns, bridge.watchdog.accepted, bridge._late_commands) == (STEP_NS, 1, 1)
    finally:
        bridge.shutdown()
        bridge.destroy_node()


@pytest.mark.ros
def test_start_paused_holds_t0_until_pause_false(rclpy_context):
    """``start_paused`` (the demo's): commands answered, yet no step until ~/pause false; then it runs."""
    overrides = [Parameter("clock_mode", value="lockstep"), Parameter("lockstep_timeout", value=0.05),
                 Parameter("settle_time", value=0.1), Parameter("start_paused", value=True)]
    with bridge_and_commander(rclpy_context, overrides) as (bridge, listener, commander, executor):
        hold = JointCommand.hold(bridge.sim.robot)
        pause = listener.create_client(SetBool, "/sim_bridge/pause")

        def commanded(steps: int) -> Callable[[], bool]:
            def done() -> bool:  # answer the current step, as a controller would
                commander.publish(motor_command_msg(hold, stamp_from_ns(bridge.sim.steps * STEP_NS)))
                return bridge.sim.steps >= steps
            return done

        assert not spin_until(executor, commanded(1), 1.0), "stepped while started paused"
        assert bridge.watchdog.accepted > 0  # the commands arrived; the pause held the sim
        future = pause.call_async(SetBool.Request(data=False))
        assert spin_until(executor, future.done, 10.0) and future.result().message == "running from 0.000000 s"
        assert spin_until(executor, commanded(25), 20.0)
