"""a1_common.clock: which sensor stamps a bridge also publishes on /clock (no ROS)."""

import pytest
from a1_common.clock import ClockGate, require_clock_period
from a1_common.config import ConfigError

STEP_NS = 2_000_000  # the bridges' 2 ms step


def test_gate_passes_the_first_stamp_of_each_period_once():
    gate = ClockGate(0.01)
    stamps = [k * STEP_NS for k in range(26)]
    passed = [t for t in stamps if gate.due(t)]
    assert passed == [0, 10_000_000, 20_000_000, 30_000_000, 40_000_000, 50_000_000]
    assert not gate.due(50_000_000)  # a held step offered again


def test_gate_after_a_reset_and_with_stamps_off_the_grid():
    gate = ClockGate(0.01)
    assert gate.due(1_000_000_000)
    assert gate.due(0)  # time went back: the nodes must hear of it
    # Stamps that are not multiples of the period (a robot's tick): the first in each period goes out.
    gate = ClockGate(0.01)
    passed = [t for t in (3_000_000, 7_000_000, 11_000_000, 19_999_999, 20_000_001) if gate.due(t)]
    assert passed == [3_000_000, 11_000_000, 20_000_001]


@pytest.mark.parametrize(("value", "step", "match"), [
    (0.0, None, r"clock_period must be in \[0.001, 0.05\]"),
    (0.1, None, r"clock_period must be in \[0.001, 0.05\]"),
    (0.003, 0.002, r"clock_period must be a multiple of time_step \(0.002 s\), got 0.003"),
    (0.001, 0.002, r"clock_period must be a multiple of time_step"),
])
def test_bad_periods_name_the_field_and_the_range(value, step, match):
    with pytest.raises(ConfigError, match=match):
        require_clock_period(value, step)


def test_whole_numbers_of_steps_are_accepted():
    assert require_clock_period(0.002, 0.002) == 0.002
    assert require_clock_period(0.05, 0.002) == 0.05
