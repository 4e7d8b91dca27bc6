"""scripts/setup.sh refuses bad setups with a clear message instead of a deep CMake failure."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SETUP = ROOT / "scripts" / "setup.sh"


def run_setup(tmp_path: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "VENV": str(tmp_path / "venv"), **env}
    return subprocess.run(["bash", str(SETUP), *args], capture_output=True, text=True, env=full_env,
                          timeout=60, check=False)


def test_wrong_python_version_is_named(tmp_path):
    fake = tmp_path / "python3.10"
    fake.write_text("#!/bin/sh\necho 3.10\n")
    fake.chmod(0o755)
    result = run_setup(tmp_path, PYTHON=str(fake))
    assert result.returncode == 1
    assert "Python 3.10" in result.stderr and "3.11 is required" in result.stderr
    assert not (tmp_path / "venv").exists()


def test_missing_compiler_is_named(tmp_path):
    # A PATH with python and bash basics but no C compiler or cmake.
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("bash", "dirname", "uname", "sed", "cat", "sha256sum", "cut"):
        path = shutil.which(tool)
        if path:
            (bin_dir / tool).symlink_to(path)
    result = run_setup(tmp_path, PYTHON=sys.executable, PATH=str(bin_dir))
    assert result.returncode == 1
    assert "not found" in result.stderr and ("cmake" in result.stderr or "cc" in result.stderr)


def test_unknown_argument(tmp_path):
    result = run_setup(tmp_path, "--frobnicate")
    assert result.returncode == 2
    assert "--frobnicate" in result.stderr


def test_env_sh_defines_what_a_sourced_ros_install_defines():
    env = {k: v for k, v in os.environ.items() if k not in ("ROS_DISTRO", "ROS_VERSION", "ROS_PYTHON_VERSION")}
    script = f'source "{ROOT}/scripts/env.sh" && echo "$ROS_DISTRO $ROS_VERSION $ROS_PYTHON_VERSION"'
    result = subprocess.run(["bash", "-c", script], env=env, capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[-2] == "jazzy 2 3"  # what `ros2 doctor` found unset


@pytest.mark.parametrize("script", ["demo.sh", "test.sh", "setup.sh", "bringup.sh", "results.sh"])
def test_scripts_are_valid_bash(script):
    subprocess.run(["bash", "-n", str(ROOT / "scripts" / script)], check=True)
