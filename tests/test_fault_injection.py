"""The fault relay's core (fault_injection.faults) on real message objects, no DDS."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from a1_common.config import ConfigError
from a1_interface.conversions import ns_from_stamp, stamp_from_ns
from fault_injection.faults import FaultConfig, FaultInjector, poison
from fault_injection.node import message_class
from sensor_msgs.msg import Imu, JointState

from gait_msgs.msg import MotorCommand

PERIOD_NS = 2_000_000


def joint_state(k: int) -> JointState:
    msg = JointState()
    msg.header.stamp = stamp_from_ns(k * PERIOD_NS)
    msg.name = ["a", "b"]
    msg.position = [float(k), -float(k)]
    return msg


def feed(injector: FaultInjector, n: int, start: int = 0) -> list[JointState]:
    out = []
    for k in range(start, start + n):
        out += injector.on_message(joint_state(k), k * PERIOD_NS * 1e-9, 0.0)
    return out


def steps(msgs) -> list[int]:
    return [int(m.position[0]) for m in msgs]


def test_no_fault_passes_everything_unchanged():
    out = feed(FaultInjector(FaultConfig()), 50)
    assert steps(out) == list(range(50))


def test_drop_is_seeded_and_only_inside_its_window():
    config = FaultConfig(drop_probability=0.1, start=0.1, end=1.1, seed=7)
    a, b = feed(FaultInjector(config), 1000), feed(FaultInjector(config), 1000)
    assert steps(a) == steps(b)
    lost = sorted(set(range(1000)) - set(steps(a)))
    assert all(50 <= k < 550 for k in lost)  # the window is steps 50..549
    assert 30 <= len(lost) <= 70  # about 10 % of 500


def test_windows_count_from_the_first_message_so_wall_clock_stamps_work():
    injector = FaultInjector(FaultConfig(drop_probability=1.0, start=0.1005, end=0.2005))
    wall = 1.7e9  # [s] a hardware bridge's stamps (resolution about 0.2 us at this size)
    kept = [k for k in range(200) if injector.on_message(joint_state(k), wall + k * 0.002, 0.0)]
    assert kept == list(range(51)) + list(range(101, 200))


def test_duplicate_and_reorder_lose_nothing():
    injector = FaultInjector(FaultConfig(duplicate_probability=0.2, reorder_probability=0.2, seed=3))
    out = steps(feed(injector, 500) + feed(injector, 1, start=500))  # one more to release a held message
    counts = injector.counts
    assert counts.duplicated > 50 and counts.reordered > 50
    assert len(out) == 501 + counts.duplicated
    assert sorted(set(out)) == list(range(501))
    assert any(later < earlier for earlier, later in itertools.pairwise(out))


def test_step_delay_sends_the_message_of_n_steps_ago_stamped_now():
    injector = FaultInjector(FaultConfig(delay=0.02, delay_mode="steps", start=0.1, end=0.3))
    out = feed(injector, 200)
    stamps = [ns_from_stamp(m.header.stamp) // PERIOD_NS for m in out]
    # Before the window: straight through; its first 10 steps: nothing (the line fills); then step
    # k carries the content of k - 10; after it: straight through again.
    assert steps(out[:50]) == list(range(50))
    assert 50 not in stamps[:60] and stamps[50] == 60
    delayed = [(s, c) for s, c in zip(stamps, steps(out), strict=True) if 60 <= s < 150]
    assert delayed and all(c == s - 10 for s, c in delayed)
    assert steps(out)[-1] == 199 and stamps[-1] == 199


def test_wall_delay_holds_each_message_and_keeps_its_stamp():
    injector = FaultInjector(FaultConfig(delay=0.02, delay_mode="wall"))
    assert injector.on_message(joint_state(0), 0.0, now=100.0) == []
    assert injector.due(100.019) == []
    out = injector.due(100.02)
    assert steps(out) == [0] and ns_from_stamp(out[0].header.stamp) == 0


def test_freeze_repeats_the_first_window_message_with_new_stamps():
    injector = FaultInjector(FaultConfig(freeze_start=0.02, freeze_duration=0.01))
    out = feed(injector, 20)
    assert steps(out) == list(range(10)) + [10] * 5 + list(range(15, 20))
    assert [ns_from_stamp(m.header.stamp) // PERIOD_NS for m in out] == list(range(20))


def test_nan_burst_poisons_every_float_and_nothing_else():
    injector = FaultInjector(FaultConfig(nan_start=0.0, nan_duration=0.004))
    out = feed(injector, 3)
    assert all(math.isnan(v) for m in out[:2] for v in m.position)
    assert out[0].name == ["a", "b"] and steps(out[2:]) == [2]
    imu = Imu()
    imu.header.frame_id = "imu_link"
    poison(imu)
    assert math.isnan(imu.orientation.w) and math.isnan(imu.linear_acceleration.z)
    assert np.isnan(imu.orientation_covariance).all() and imu.header.frame_id == "imu_link"
    command = MotorCommand()
    poison(command)
    assert np.isnan(command.torque).all() and command.mode == 0


@pytest.mark.parametrize(("field", "value", "expected"), [
    ("drop_probability", 1.5, "drop_probability"), ("delay", -0.1, "delay"), ("delay_mode", "late", "delay_mode"),
    ("seed", -1, "seed"), ("end", -1.0, "end"), ("period", 0.0, "period"),
])
def test_bad_config_names_the_field(field, value, expected):
    with pytest.raises(ConfigError, match=expected):
        FaultConfig(**{field: value}).validated()
    with pytest.raises(ConfigError, match="multiple of period"):  # 1.5 steps cannot be delayed in lockstep
        FaultConfig(delay=0.003, delay_mode="steps").validated()


@pytest.mark.parametrize(("name", "expected"), [
    ("sensor_msgs/Imu", "must look like"), ("nope_msgs/msg/Imu", "no such message"),
    ("geometry_msgs/msg/Twist", "no header"),
])
def test_message_type_errors_are_clear(name, expected):
    with pytest.raises(ConfigError, match=expected):
        message_class(name)
    assert message_class("sensor_msgs/msg/Imu") is Imu
