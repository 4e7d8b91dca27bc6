"""Shared fixtures. ROS tests run on a private DDS domain so parallel runs do not talk.

Isolation (docs/reliability.md): before rclpy is imported anywhere, this process claims a DDS
domain that no other test run on this machine holds (a lock file per domain in the temp folder,
held until the process ends) and keeps discovery on this host. Child processes (bringup.sh, nodes)
inherit both. The shell's ROS_DOMAIN_ID is deliberately not used: a shell set up for a real
robot must not put the tests on the robot's domain. Pin the test domain with
GAIT_STACK_TEST_DOMAIN_ID=<0..232> if needed.

Property tests (tests/test_fuzz_*.py) run under the hypothesis profile "ci": derandomized, no
example database, no deadline, so CI never flakes; GAIT_STACK_HYPOTHESIS_PROFILE=thorough tries
20x more (random) examples. The number of cases each fuzz target tried is printed at the end.
"""

from __future__ import annotations

import collections
import fcntl
import os
import signal
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

SCRIPTS_DEFAULT_DOMAIN_ID = 42  # scripts/env.sh's default: tests never use it unless pinned
_held_locks = []  # open lock files of the domains this process claimed, kept until it ends


def _terminate_like_ctrl_c(signum, frame) -> None:
    raise KeyboardInterrupt


# SIGTERM (e.g. `timeout`, a CI job cancelled) ends the run like Ctrl-C, so pytest still tears the
# fixtures down: the node processes the end-to-end tests started in their own sessions are stopped
# instead of living on as orphans that load the machine.
signal.signal(signal.SIGTERM, _terminate_like_ctrl_c)


def claim_ros_domain_id(exclude: tuple[int, ...] = ()) -> int | None:
    """A DDS domain in [1, 100] that no other process holding these locks uses (None if all are).

    The claim is a lock on ``<tmp>/gait_stack_ros_domain_<id>.lock``, released when this process ends.
    """
    candidates = [d for d in range(1, 101) if d != SCRIPTS_DEFAULT_DOMAIN_ID and d not in exclude]
    start = os.getpid() % len(candidates)
    for i in range(len(candidates)):
        domain = candidates[(start + i) % len(candidates)]
        try:
            lock = open(Path(tempfile.gettempdir()) / f"gait_stack_ros_domain_{domain}.lock", "a")
        except OSError:  # another user's lock file
            continue
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        _held_locks.append(lock)
        return domain
    return None


def _test_domain_id() -> int:
    pinned = os.environ.get("GAIT_STACK_TEST_DOMAIN_ID", "").strip()
    if pinned:
        if not pinned.isdigit() or int(pinned) > 232:
            raise pytest.UsageError(f"GAIT_STACK_TEST_DOMAIN_ID must be an integer in [0, 232], got {pinned!r}")
        return int(pinned)
    claimed = claim_ros_domain_id()
    return claimed if claimed is not None else 1 + os.getpid() % 100


# Before rclpy is imported anywhere.
os.environ["ROS_DOMAIN_ID"] = str(_test_domain_id())
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
for _var in ("ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY"):  # static peers would reach past localhost
    os.environ.pop(_var, None)

settings.register_profile("ci", derandomize=True, database=None, deadline=None, max_examples=60,
                          print_blob=True, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", settings.get_profile("ci"), derandomize=False, max_examples=1200)
settings.load_profile(os.environ.get("GAIT_STACK_HYPOTHESIS_PROFILE", "ci"))

_FUZZ_CASES: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)


@pytest.fixture(scope="session")
def fuzz_cases() -> dict[str, collections.Counter]:
    """Cases tried per fuzz target, by outcome: ``fuzz_cases["target"]["rejected"] += 1``."""
    return _FUZZ_CASES


_FAULT_SCENARIOS: list[dict] = []


@pytest.fixture(scope="session")
def fault_scenarios() -> list[dict]:
    """Outcome rows of the fault-injection scenarios (tests/test_fault_scenarios.py), printed at the end."""
    return _FAULT_SCENARIOS


def pytest_terminal_summary(terminalreporter) -> None:
    if _FAULT_SCENARIOS:
        terminalreporter.section("fault-injection scenarios")
        for row in _FAULT_SCENARIOS:
            terminalreporter.write_line(" | ".join(f"{k}: {v}" for k, v in row.items()))
    if not _FUZZ_CASES:
        return
    terminalreporter.section("fuzz cases tried")
    for target, outcomes in sorted(_FUZZ_CASES.items()):
        detail = ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items()))
        terminalreporter.write_line(f"{target}: {sum(outcomes.values())} ({detail})")
    terminalreporter.write_line(f"total: {sum(sum(c.values()) for c in _FUZZ_CASES.values())}")


@pytest.fixture
def spare_ros_domain() -> int:
    """Another claimed DDS domain, for tests that run a second, separate graph."""
    domain = claim_ros_domain_id(exclude=(int(os.environ["ROS_DOMAIN_ID"]),))
    if domain is None:
        pytest.skip("no free DDS domain in [1, 100] on this machine")
    return domain


@pytest.fixture
def rclpy_context():
    """An initialised rclpy context, shut down after the test."""
    import rclpy

    context = rclpy.context.Context()
    rclpy.init(context=context)
    yield context
    context.try_shutdown()
