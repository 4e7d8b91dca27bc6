"""The shared robot file loads, and bad files fail with the field named."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from a1_common.config import ConfigError, load_node_parameters, require_range
from a1_common.robot import NUM_JOINTS, default_config_path, load_robot_constants


def test_default_robot_file_loads():
    robot = load_robot_constants()
    assert robot.leg_names == ("FR", "FL", "RR", "RL")
    assert len(robot.joint_names) == NUM_JOINTS
    assert robot.nominal_joint_angles.shape == (NUM_JOINTS,)
    np.testing.assert_allclose(robot.nominal_joint_angles[:3], [0.0, 0.9, -1.8])
    assert robot.motor_torque_limit == 33.5
    with pytest.raises(ValueError):
        robot.hip_offsets[0, 0] = 1.0  # shared constants are read-only


def _write(tmp_path, **changes):
    data = yaml.safe_load(default_config_path().read_text())
    data.update(changes)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"thigh_length": -0.2}, "thigh_length"),
        ({"hip_offsets": [[0, 0, 0]]}, "hip_offsets"),
        ({"joint_names": ["a", "b"]}, "joint_names"),
        ({"nominal_joint_angles": [0.0, "x", 1.0]}, "nominal_joint_angles"),
        ({"typo_key": 1}, "typo_key"),
        ({"joint_lower_limits": [1.0, 5.0, 0.0]}, "joint_lower_limits"),
    ],
)
def test_bad_robot_file_names_the_field(tmp_path, changes, field):
    with pytest.raises(ConfigError, match=field):
        load_robot_constants(_write(tmp_path, **changes))


def test_malformed_yaml_is_a_config_error(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("leg_names: [FR, FL\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_robot_constants(path)


def test_yaml_is_loaded_safely(tmp_path):
    path = tmp_path / "evil.yaml"
    path.write_text("leg_names: !!python/object/apply:os.system ['true']\n")
    with pytest.raises(ConfigError):
        load_robot_constants(path)


def test_node_parameter_file_sections():
    params = load_node_parameters(default_config_path().parent / "a1_sim_bridge.yaml", "sim_bridge")
    assert params["world"] == "flat"
    with pytest.raises(ConfigError, match="other_node"):
        load_node_parameters(default_config_path().parent / "a1_sim_bridge.yaml", "other_node")


def test_exponents_without_a_dot_are_floats_as_in_ros_parameter_files(tmp_path):
    """``mpc_force_weight: 1e-5`` is a float to ROS 2's --params-file parser; PyYAML's YAML 1.1
    rules alone would leave it the string '1e-5' for the in-process tools (eval_policy, train_es)."""
    path = tmp_path / "convex_mpc.yaml"
    path.write_text("/**/convex_mpc:\n  ros__parameters:\n    mpc_force_weight: 1e-5\n    a: [2E3, -1e-2, 3]\n"
                    "    b: x1e5\n")
    params = load_node_parameters(path, "convex_mpc")
    assert params == {"mpc_force_weight": 1e-5, "a": [2000.0, -0.01, 3], "b": "x1e5"}
    assert isinstance(params["mpc_force_weight"], float)


def test_require_range_message():
    assert require_range("f", 2, 0, 4, low_open=True) == 2.0
    with pytest.raises(ConfigError, match=r"f must be in \(0, 4\]"):
        require_range("f", 0, 0, 4, low_open=True)
    with pytest.raises(ConfigError, match="f must be in"):
        require_range("f", float("nan"), 0, 4)
