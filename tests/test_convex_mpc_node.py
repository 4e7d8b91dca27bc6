"""The convex_mpc node's step triggering (convex_mpc_node.step_trigger), without ROS and in the node:
one command per sensor step whatever arrives late, twice or not at all, and the estimator failover
(backup estimate only after a first /odom)."""

from __future__ import annotations

import numpy as np
import pytest
from a1_sim_bridge.sim import A1Sim, SimConfig
from convex_mpc_node.node import ConvexMpcNode
from convex_mpc_node.step_trigger import StepTrigger
from nav_msgs.msg import Odometry
from state_estimator_node.estimator import EstimatorConfig
from state_estimator_node.frontend import OdometryFrontend

from a1_interface import conversions as cv
from a1_interface import wire

STEP_NS = 2_000_000


@pytest.fixture(scope="module")
def readings():
    sim = A1Sim(SimConfig())
    try:
        yield sim.sensors(), list(sim.robot.joint_names)
    finally:
        sim.close()


@pytest.fixture
def node(rclpy_context):
    n = ConvexMpcNode(context=rclpy_context)
    n.sent = []  # stamps of the motor commands it published
    n.pub_command.publish = lambda msg: n.sent.append(wire.decode_motor_command(msg)[1])
    yield n
    n.destroy_node()


def sensors(node: ConvexMpcNode, readings, k: int) -> None:
    r, names = readings
    stamp = cv.stamp_from_ns(k * STEP_NS)
    node.trigger.on_imu(cv.imu_msg(r, stamp))
    node.trigger.on_contacts(cv.foot_contacts_msg(r, stamp))
    node._on_joints(cv.joint_state_msg(r, stamp, names))


def odom(node: ConvexMpcNode, k: int, vx: float = 0.0) -> None:
    msg = Odometry()
    msg.header.stamp = cv.stamp_from_ns(k * STEP_NS)
    msg.pose.pose.orientation.w = 1.0
    msg.twist.twist.linear.x = vx
    node._on_odom(msg)


def test_the_trigger_alone_steps_once_per_step_goes_stale_answers_a_repeat_and_restarts(readings):
    """No rclpy: messages in, callbacks out."""
    r, names = readings
    calls = []
    trigger = StepTrigger(input_timeout=0.03, frontend=None, backup=None, estimate_after_command=False,
                          control=lambda stamp, s, v, b: calls.append(("control", stamp, v is None)),
                          republish=lambda: calls.append(("again",)), on_estimate=lambda s, e: None,
                          on_restart=lambda: calls.append(("restart",)), log=lambda *a: None)

    def step(k: int, with_odom: bool) -> None:
        stamp = cv.stamp_from_ns(k * STEP_NS)
        trigger.on_imu(cv.imu_msg(r, stamp))
        trigger.on_contacts(cv.foot_contacts_msg(r, stamp))
        trigger.on_joints(cv.joint_state_msg(r, stamp, names))
        if with_odom:
            trigger.on_odom(k * STEP_NS, np.zeros(3))

    for k in range(3):
        step(k, with_odom=True)
    assert calls == [("control", k * STEP_NS, False) for k in range(3)]
    trigger.on_joints(cv.joint_state_msg(r, cv.stamp_from_ns(2 * STEP_NS), names))  # step 2 again
    assert calls[-1] == ("again",)
    calls.clear()
    for k in range(3, 80):  # no /odom: from input_timeout on, the sensors alone, with no velocity
        step(k, with_odom=False)
    first = calls[0][1]  # the first step over input_timeout after the last /odom (step 2)
    assert (first - 2 * STEP_NS) * 1e-9 > 0.03 >= (first - 3 * STEP_NS) * 1e-9 and all(c[2] for c in calls)
    assert [c[1] for c in calls] == list(range(first, 80 * STEP_NS, STEP_NS))
    calls.clear()
    step(0, with_odom=True)  # time jumped back by 158 ms: a simulation reset
    assert calls == [("restart",), ("control", 0, False)]


@pytest.mark.ros
def test_one_command_per_step_with_odom_late_or_twice(node, readings):
    for k in range(20):
        sensors(node, readings, k)
        odom(node, k)
        odom(node, k)  # duplicated
    assert node.sent == [k * STEP_NS for k in range(20)]
    # /odom stops: after input_timeout (30 ms = 15 steps) the sensors alone trigger each step.
    for k in range(20, 60):
        sensors(node, readings, k)
    assert node.sent[-1] == 59 * STEP_NS and len(node.sent) == len(set(node.sent))
    assert node.trigger.on_backup
    # /odom for a step the sensors already triggered commands nothing more, but says the estimator
    # is back: the next step waits for its /odom again and the backup stands down.
    sensors(node, readings, 60)
    odom(node, 60)
    assert node.sent.count(60 * STEP_NS) == 1 and node.trigger.on_backup
    sensors(node, readings, 61)
    assert node.sent[-1] == 60 * STEP_NS  # waiting for /odom of step 61
    odom(node, 61)
    assert node.sent[-1] == 61 * STEP_NS and not node.trigger.on_backup


@pytest.mark.ros
def test_sensors_in_any_order_trigger_a_stale_step_once(node, readings):
    r, names = readings
    for k in range(100, 105):  # past input_timeout: at start-up the estimator gets 30 ms to answer
        stamp = cv.stamp_from_ns(k * STEP_NS)
        node._on_joints(cv.joint_state_msg(r, stamp, names))  # joints first this time
        node.trigger.on_imu(cv.imu_msg(r, stamp))
        node.trigger.on_contacts(cv.foot_contacts_msg(r, stamp))
        node.trigger.on_contacts(cv.foot_contacts_msg(r, stamp))  # and one twice
    assert node.sent == [k * STEP_NS for k in range(100, 105)]
    assert not node.trigger.on_backup  # no /odom yet: nothing to start a backup estimate from


@pytest.mark.ros
def test_a_step_offered_again_gets_the_same_command_without_a_second_control_step(node, readings):
    # A lockstep bridge offers step k again while its command has not arrived (lost before the DDS
    # match): without an answer both would wait for good.
    for k in range(3):
        sensors(node, readings, k)
        odom(node, k)
    sent = []
    node.pub_command.publish = sent.append
    steps = node._steps
    sensors(node, readings, 2)
    assert [wire.decode_motor_command(m)[1] for m in sent] == [2 * STEP_NS] and node._steps == steps
    assert sent[0] is node._last_command


@pytest.mark.ros
def test_sim_reset_starts_the_step_count_over(node, readings):
    for k in range(100, 110):
        sensors(node, readings, k)
        odom(node, k)
    for k in range(3):  # the sim bridge was reset: time starts at 0 again
        sensors(node, readings, k)
        odom(node, k)
    assert node.sent[-3:] == [0, STEP_NS, 2 * STEP_NS]
    assert np.all(np.diff(node.sent[:10]) == STEP_NS)


@pytest.mark.ros
def test_sim_reset_after_seconds_is_controlled_from_its_first_step_standing(node, readings):
    """A reset after more steps than the sensor buffers hold (they used to keep the old run's stamps
    and evict the new run's): the first steps of the new run are answered, standing up."""
    for k in range(2000, 2100):  # 4 s into a run
        sensors(node, readings, k)
        odom(node, k)
    for k in range(3):
        sensors(node, readings, k)
        odom(node, k)
    assert node.sent[-3:] == [0, STEP_NS, 2 * STEP_NS]
    assert node._state == "stand"
    # And the estimator's odometry starts over at the origin, where the reset put the robot.
    r, names = readings

    def step(k: int) -> tuple:
        stamp = cv.stamp_from_ns(k * STEP_NS)
        return cv.joint_state_msg(r, stamp, names), cv.imu_msg(r, stamp), cv.foot_contacts_msg(r, stamp)

    front = OdometryFrontend(EstimatorConfig())
    front.update(*step(2000))
    front.update(*step(2001))
    front.position = np.array([5.0, 1.0])  # dead-reckoned 5 m out
    front.update(*step(0))
    np.testing.assert_array_equal(front.position, 0.0)


@pytest.mark.ros
def test_estimate_after_command_controls_on_the_previous_estimate_then_updates(rclpy_context, readings):
    """Realtime setting: the command of step k goes out before the filter sees step k's sensors,
    on the velocity estimated at step k-1; /odom follows at its rate; one command per step."""
    from rclpy.parameter import Parameter

    n = ConvexMpcNode(context=rclpy_context, parameter_overrides=[
        Parameter("embedded_estimator", value=True), Parameter("estimate_after_command", value=True)])
    events = []
    n.pub_command.publish = lambda msg: events.append(("command", wire.decode_motor_command(msg)[1]))
    n.odom.pub_odom.publish = lambda raw: events.append(
        ("odom", cv.ns_from_stamp(wire.decode_odometry(raw).header.stamp)))
    velocities = []
    control = n.trigger._control
    n.trigger._control = lambda stamp_ns, step_sensors, velocity, *a: (
        velocities.append(velocity), control(stamp_ns, step_sensors, velocity, *a))
    update = n.frontend.update
    estimates = []
    n.frontend.update = lambda *m: estimates.append(update(*m)) or estimates[-1]
    try:
        for k in range(4):
            sensors(n, readings, k)
    finally:
        n.destroy_node()
    assert events == [e for k in range(4) for e in (("command", k * STEP_NS), ("odom", k * STEP_NS))]
    assert velocities[0] is None  # no estimate before the first step: that step goes the safe way
    for k in range(1, 4):  # each later step on the estimate of the step before
        np.testing.assert_array_equal(velocities[k], estimates[k - 1].velocity_world)
