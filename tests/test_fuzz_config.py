"""Property tests (hypothesis) of the configuration loaders and value checks.

Every loader is fed hostile input (malformed YAML, bytes that are not UTF-8, unknown keys, values
of the wrong kind, NaN, inf, integers beyond any float, wrong list lengths) and must either return
a valid configuration or raise ConfigError naming the bad field (and its range where it has one):
never another exception. Case counts are printed at the end of the run (conftest.py).
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
import yaml
from a1_common.config import ConfigError, load_yaml_mapping, require_range
from a1_common.node_support import coerce_parameter
from a1_common.robot import default_config_path, load_robot_constants
from a1_sim_bridge.sim import SensorNoise, SimConfig
from convex_mpc_node.gait import SPEED_SCHEDULE, TWO_PI, load_hand_tuned_gaits
from convex_mpc_node.supervisor import SupervisorConfig
from gait_policy_node.train_config import load_train_config
from gait_policy_node.velocity_command import MAX_SPEED, parse_steps
from hypothesis import example, given
from hypothesis import strategies as st

CONFIG = default_config_path().parent
HUGE_INT = 10**400  # beyond any float: float() raises OverflowError

# --- strategies ------------------------------------------------------------------------------------
text = st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=12)  # YAML-dumpable
numbers = st.one_of(st.floats(), st.integers(), st.sampled_from([HUGE_INT, -HUGE_INT, 1e308, -0.0, 5e-324]))
scalars = st.one_of(st.none(), st.booleans(), numbers, text)
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=14) | st.dictionaries(text, inner, max_size=3),
                      max_leaves=16)
# Bits of YAML syntax, glued at random: unbalanced brackets, tabs, anchors, aliases, tags, directives.
yaml_bits = st.sampled_from([
    ":", ": ", "-", "- ", "[", "]", "{", "}", ",", "&a ", "*a", "*b", "!!python/object:os.system ", "!!binary ",
    "\t", "\n", "  ", "key", "walk", "1e400", ".nan", ".inf", "'", '"', "? ", "|", ">", "%YAML 1.1\n", "---\n",
    "...\n", "#", "2020-01-01", "0x1F", "~", "\\u0000"])
yaml_texts = st.lists(yaml_bits, max_size=30).map("".join)
# Values of the right kind and magnitude, so that valid configurations are tried too.
plausible = st.one_of(st.floats(-1, 10), st.integers(-5, 500), st.lists(st.floats(0, 7), min_size=2, max_size=4),
                      st.sampled_from(["mlp", "linear", "flat", "ramp", "steps", "cmaes", "ars", "serial", "walk"]))


def write_yaml(path, data) -> None:
    path.write_text(yaml.safe_dump(data, allow_unicode=True), encoding="utf-8")


def count(fuzz_cases, target: str, accepted: bool) -> None:
    fuzz_cases[target]["accepted" if accepted else "rejected"] += 1


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_config")


# --- single values -----------------------------------------------------------------------------------
@given(value=st.one_of(values, st.floats(-1100, 2100), st.integers(-1100, 2100)), low=st.floats(-1e3, 1e3),
       width=st.floats(0, 1e3), low_open=st.booleans(), high_open=st.booleans())
@example(value=float("nan"), low=0.0, width=1.0, low_open=False, high_open=False)
@example(value=HUGE_INT, low=0.0, width=1.0, low_open=False, high_open=False)
@example(value="1e400", low=0.0, width=1.0, low_open=False, high_open=False)
def test_require_range_returns_a_value_inside_or_names_field_and_range(fuzz_cases, value, low, width, low_open,
                                                                         high_open):
    high = low + width
    try:
        v = require_range("the_field", value, low, high, low_open=low_open, high_open=high_open)
    except ConfigError as exc:
        count(fuzz_cases, "require_range", False)
        message = str(exc)
        assert message.startswith("the_field must be")
        assert f"{low}, {high}" in message and len(message) < 300  # the range, and no flood of a huge value
        return
    count(fuzz_cases, "require_range", True)
    assert isinstance(v, float) and math.isfinite(v)
    assert (v > low if low_open else v >= low) and (v < high if high_open else v <= high)


@pytest.mark.parametrize("value", [True, False, "0.5", b"0.5"])
def test_require_range_takes_no_bool_or_string_for_a_number(value):
    with pytest.raises(ConfigError, match=r"the_field must be a number in \[0.0, 1.0\]"):
        require_range("the_field", value, 0.0, 1.0)


@given(value=values, default=st.sampled_from([True, 1.5, 3, "text", [1.0, 2.0]]))
def test_coerce_parameter_gives_the_default_type_or_names_the_parameter(fuzz_cases, value, default):
    try:
        result = coerce_parameter("p_name", value, default)
    except ConfigError as exc:
        count(fuzz_cases, "coerce_parameter", False)
        assert str(exc).startswith("parameter p_name must be")
        return
    count(fuzz_cases, "coerce_parameter", True)
    if isinstance(default, (bool, float, str)):
        assert type(result) is type(default)
    elif isinstance(default, int):
        assert isinstance(result, int) and not isinstance(result, bool)


# --- YAML files --------------------------------------------------------------------------------------
@given(content=st.one_of(yaml_texts, st.binary(max_size=60),
                         st.dictionaries(st.sampled_from(["walk", "key", "other"]) | scalars, values, max_size=4).map(
                             lambda v: yaml.safe_dump(v, allow_unicode=True).encode())),
       allowed=st.none() | st.just({"walk", "key"}))
@example(content="[" * 600 + "]" * 600, allowed=None)  # nested deeper than Python's recursion limit
@example(content=b"\xff\xfe key: 1", allowed=None)  # not UTF-8
@example(content="!!python/object/apply:os.system [echo hi]", allowed=None)  # an unsafe tag
@example(content="{1: a, key: b, null: c}", allowed={"key"})  # unknown keys that are not strings
def test_load_yaml_mapping_returns_a_mapping_or_a_config_error(scratch, fuzz_cases, content, allowed):
    path = scratch / "fuzz.yaml"
    if isinstance(content, str):
        path.write_text(content, encoding="utf-8")
    else:
        path.write_bytes(content)
    try:
        data = load_yaml_mapping(path, allowed_keys=allowed)
    except ConfigError as exc:
        count(fuzz_cases, "load_yaml_mapping", False)
        assert str(path) in str(exc)
        return
    count(fuzz_cases, "load_yaml_mapping", True)
    assert isinstance(data, dict)
    assert allowed is None or set(data) <= allowed


ROBOT_DATA = load_yaml_mapping(default_config_path())


@given(key=st.sampled_from([*sorted(ROBOT_DATA), "unknown_key"]), action=st.sampled_from(["replace", "drop"]),
       value=values | plausible)
@example(key="damping_kd", action="replace", value=2.0)  # valid: loads
@example(key="motor_torque_limit", action="replace", value=float("inf"))
@example(key="motor_torque_limit", action="replace", value=HUGE_INT)
@example(key="joint_kp", action="replace", value=[HUGE_INT, 1.0, 1.0])
@example(key="hip_offsets", action="replace", value=[[0.1, 0.1, 0.0]] * 3)
def test_robot_file_is_valid_or_names_the_bad_key(scratch, fuzz_cases, key, action, value):
    data = dict(ROBOT_DATA)
    if action == "drop":
        data.pop(key, None)
    else:
        data[key] = value
    path = scratch / "a1_robot.yaml"
    write_yaml(path, data)
    try:
        robot = load_robot_constants(path)
    except ConfigError as exc:
        count(fuzz_cases, "robot constants file", False)
        assert key in str(exc) or (key == "unknown_key" and "unknown keys" in str(exc))
        return
    count(fuzz_cases, "robot constants file", True)
    for f in dataclasses.fields(robot):
        v = getattr(robot, f.name)
        if isinstance(v, (float, np.ndarray)):
            assert np.all(np.isfinite(v)), f.name
    assert robot.motor_torque_limit > 0 and robot.damping_kd > 0
    assert np.all(robot.joint_lower_limits < robot.joint_upper_limits)


GAITS_DATA = load_yaml_mapping(CONFIG / "gaits.yaml")


@given(gait=st.sampled_from([*sorted(GAITS_DATA), "new_gait"]),
       field=st.sampled_from(["stepping_frequency", "swing_ratio", "phase_offsets", "extra", None]),
       value=values | plausible)
@example(gait="walk", field="phase_offsets", value=["a", 0.0, 0.0, 0.0])
@example(gait="walk", field="phase_offsets", value=[0.0, 1.0, 2.0])
@example(gait="walk", field="stepping_frequency", value=4.5)
@example(gait="rapid_trot", field=None, value=None)  # the schedule needs it
def test_gaits_file_is_valid_or_names_gait_and_field(scratch, fuzz_cases, gait, field, value):
    data = {name: dict(entry) for name, entry in GAITS_DATA.items()}
    if field is None:
        data.pop(gait, None)
    else:
        data.setdefault(gait, dict(GAITS_DATA["walk"]))[field] = value
    path = scratch / "gaits.yaml"
    write_yaml(path, data)
    try:
        gaits = load_hand_tuned_gaits(path)
    except ConfigError as exc:
        count(fuzz_cases, "gaits file", False)
        message = str(exc)
        assert gait in message
        if field in ("stepping_frequency", "swing_ratio", "phase_offsets"):
            assert field in message and re.search(r"must (be|have)", message), message
        return
    count(fuzz_cases, "gaits file", True)
    assert {name for _, name in SPEED_SCHEDULE} <= set(gaits)
    for params in gaits.values():
        assert 0 < params.stepping_frequency <= 4 and 0 < params.swing_ratio < 1
        assert params.phase_offsets[0] == 0 and all(0 <= t < TWO_PI for t in params.phase_offsets)


TRAIN_DATA = load_yaml_mapping(CONFIG / "train_es.yaml")
TRAIN_KEYS = [(s, k) for s, section in TRAIN_DATA.items() for k in section] + [
    ("env", "profile.steps"), ("env", "profile.random_range"), ("env", "unknown_key"), ("unknown_section", "x")]


@given(where=st.sampled_from(TRAIN_KEYS), value=st.one_of(values, plausible, st.dates()))
@example(where=("policy", "hidden_units"), value=HUGE_INT)
@example(where=("trainer", "seed"), value=1.5)
@example(where=("env", "profile.steps"), value=[[0.0, 0.5], [0.0, 1.0]])
@example(where=("env", "episode_steps"), value=yaml.safe_load("2020-01-01"))  # a YAML date
def test_train_config_file_is_valid_or_names_the_key(scratch, fuzz_cases, where, value):
    section, key = where
    data = {s: dict(v) if isinstance(v, dict) else v for s, v in TRAIN_DATA.items()}
    target = data.setdefault(section, {})
    *parents, leaf = key.split(".")
    for part in parents:
        target[part] = dict(target[part])
        target = target[part]
    target[leaf] = value
    path = scratch / "train.yaml"
    write_yaml(path, data)
    try:
        config = load_train_config(path)
    except ConfigError as exc:
        count(fuzz_cases, "training config file", False)
        assert leaf in str(exc) or (section == "unknown_section" and section in str(exc))
        return
    count(fuzz_cases, "training config file", True)
    assert config.validated() is config


@given(override=st.one_of(st.tuples(st.sampled_from([f"{s}.{k}" for s, k in TRAIN_KEYS] + ["", ".", "a..b"]),
                                    yaml_texts | plausible.map(str)).map("=".join), yaml_texts))
@example(override="trainer.population_size=1e400")
@example(override="env=3")
@example(override="env.profile=[1, 2]")
@example(override="trainer.seed=[[[[[[[[[[")
def test_train_config_overrides_are_valid_or_config_errors(fuzz_cases, override):
    try:
        config = load_train_config(CONFIG / "train_es.yaml", [override])
    except ConfigError as exc:
        count(fuzz_cases, "training --set override", False)
        assert str(exc)
        return
    count(fuzz_cases, "training --set override", True)
    assert config.validated() is config


# --- config dataclasses behind node parameters ----------------------------------------------------
def _fields(cls) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


@given(field=st.sampled_from(_fields(SupervisorConfig)), value=values | plausible)
@example(field="max_forward_speed", value=float("inf"))
@example(field="cmd_vel_timeout", value=HUGE_INT)
def test_supervisor_config_is_valid_or_names_field_and_range(fuzz_cases, field, value):
    try:
        SupervisorConfig(**{field: value}).validated()
    except ConfigError as exc:
        count(fuzz_cases, "SupervisorConfig (convex_mpc parameters)", False)
        assert str(exc).startswith(f"{field} must be")
        assert re.search(r"[\[(][-\d.e]+, [-\d.e]+[\])]|one of", str(exc))
        return
    count(fuzz_cases, "SupervisorConfig (convex_mpc parameters)", True)


@given(field=st.sampled_from([f for f in _fields(SimConfig) if f != "noise"] + _fields(SensorNoise)),
       value=values | plausible)
@example(field="time_step", value=float("nan"))
@example(field="seed", value=-1)
@example(field="solver_iterations", value=True)
def test_sim_parameters_are_valid_or_name_field_and_range(fuzz_cases, field, value):
    try:
        config = SimConfig.from_parameters({field: value})
    except ConfigError as exc:
        count(fuzz_cases, "SimConfig (sim_bridge parameters)", False)
        assert str(exc).startswith(f"{field} must be")
        return
    count(fuzz_cases, "SimConfig (sim_bridge parameters)", True)
    assert config.validated() is config


@given(text_=st.one_of(st.text(max_size=40), st.lists(st.tuples(numbers, numbers), min_size=1, max_size=4).map(
    lambda pairs: ",".join(f"{t}:{v}" for t, v in pairs))))
@example(text_="0:nan")
@example(text_="0:1e9")
@example(text_="inf:1.0")
@example(text_="5:1.0,1:0.5")
def test_velocity_command_steps_are_in_range_or_a_config_error(fuzz_cases, text_):
    try:
        steps = parse_steps(text_)
    except ConfigError as exc:
        count(fuzz_cases, "velocity_command steps", False)
        assert "steps" in str(exc)
        return
    count(fuzz_cases, "velocity_command steps", True)
    times = [t for t, _ in steps]
    assert times == sorted(times) and all(0 <= t <= 1e6 for t in times)
    assert all(-MAX_SPEED <= v <= MAX_SPEED for _, v in steps)


# --- the estimator's and the controller's parameters ------------------------------------------------
@given(field=st.sampled_from(["process_noise", "measurement_noise"]), value=values)
@example(field="process_noise", value=["a", "b", "c"])
def test_estimator_config_is_valid_or_names_the_field(fuzz_cases, field, value):
    from state_estimator_node.estimator import EstimatorConfig

    try:
        EstimatorConfig(**{field: value}).validated()
    except ConfigError as exc:
        assert field in str(exc)


@given(field=st.sampled_from(["body_height", "swing_apex_height", "raibert_feedback_gain", "max_position_error",
                              "control_period", "mpc_gravity", "mpc_eps"]), value=st.floats())
@example(field="body_height", value=float("nan"))
def test_controller_parameters_are_valid_or_name_the_field(fuzz_cases, field, value):
    from convex_mpc_node.controller import controller_config_from_parameters

    try:
        config = controller_config_from_parameters({field: value})
    except ConfigError as exc:
        assert field.removeprefix("mpc_") in str(exc)
        return
    flat = {**dataclasses.asdict(config), **{f"mpc_{k}": v for k, v in dataclasses.asdict(config.mpc).items()}}
    assert math.isfinite(flat[field]) and flat[field] >= 0  # 0 is valid for gains and clamps
