"""Isolation (issue 9): tests and scripts keep to their own DDS domain, discovered on this host only.

Two graphs running at the same time on different domains must not see each other's nodes or
topics nor receive each other's messages; concurrent test runs must get different domains; the
scripts (scripts/env.sh) must use the stack's own domain unless ROS_DOMAIN_ID is set, honour it
when it is, and refuse a malformed one. (No fuzzing here: the file sits with the issue's other tests.)
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
from conftest import SCRIPTS_DEFAULT_DOMAIN_ID
from geometry_msgs.msg import Twist
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import spin_until

ROOT = Path(__file__).resolve().parents[1]
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def test_this_run_is_on_a_private_domain_with_host_only_discovery(rclpy_context):
    domain = int(os.environ["ROS_DOMAIN_ID"])
    assert rclpy_context.get_domain_id() == domain
    if not os.environ.get("GAIT_STACK_TEST_DOMAIN_ID"):
        assert domain not in (0, SCRIPTS_DEFAULT_DOMAIN_ID)  # not the ROS default, not a bringup's
    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert "ROS_STATIC_PEERS" not in os.environ


class _Graph:
    """A talker and a listener on /cmd_vel, plus a domain-specific topic, on one domain."""

    def __init__(self, domain: int, tag: float) -> None:
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node(f"isolation_{domain}", context=self.context)
        self.pub = self.node.create_publisher(Twist, "/cmd_vel", QOS)
        self.only_here = self.node.create_publisher(Twist, f"/only_on_domain_{domain}", QOS)
        self.received: list[float] = []
        self.node.create_subscription(Twist, "/cmd_vel", lambda m: self.received.append(m.linear.x), QOS)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.tag = tag

    def publish(self) -> None:
        msg = Twist()
        msg.linear.x = self.tag
        self.pub.publish(msg)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def test_two_graphs_on_different_domains_do_not_talk(spare_ros_domain):
    """Both graphs publish /cmd_vel at the same time: each hears only itself, sees only its nodes."""
    here, there = int(os.environ["ROS_DOMAIN_ID"]), spare_ros_domain
    a, b = _Graph(here, 1.0), _Graph(there, 2.0)
    try:
        assert a.context.get_domain_id() == here and b.context.get_domain_id() == there

        def both_heard_themselves() -> bool:
            a.publish()
            b.publish()
            b.executor.spin_once(timeout_sec=0.01)
            return a.received.count(1.0) >= 20 and b.received.count(2.0) >= 20

        assert spin_until(a.executor, both_heard_themselves, timeout_s=20.0)
        for _ in range(20):  # a further while of concurrent traffic
            a.publish()
            b.publish()
            a.executor.spin_once(timeout_sec=0.01)
            b.executor.spin_once(timeout_sec=0.01)
        assert set(a.received) == {1.0} and set(b.received) == {2.0}
        # Neither graph's discovery knows the other's node or topics.
        assert f"isolation_{there}" not in a.node.get_node_names()
        assert f"isolation_{here}" not in b.node.get_node_names()
        assert f"/only_on_domain_{there}" not in dict(a.node.get_topic_names_and_types())
        assert f"/only_on_domain_{here}" not in dict(b.node.get_topic_names_and_types())
        assert f"/only_on_domain_{here}" in dict(a.node.get_topic_names_and_types())  # (discovery works)
        assert a.pub.get_subscription_count() == 1 and b.pub.get_subscription_count() == 1
    finally:
        a.close()
        b.close()


def test_a_concurrent_test_run_claims_another_domain():
    if os.environ.get("GAIT_STACK_TEST_DOMAIN_ID"):
        pytest.skip("the test domain is pinned with GAIT_STACK_TEST_DOMAIN_ID")
    env = {k: v for k, v in os.environ.items() if k != "ROS_DOMAIN_ID"}
    code = "import os, conftest; print(os.environ['ROS_DOMAIN_ID'])"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT / "tests", env=env, capture_output=True,
                         text=True, timeout=120, check=True).stdout.split()
    other = int(out[-1])
    assert other != int(os.environ["ROS_DOMAIN_ID"]) and other not in (0, SCRIPTS_DEFAULT_DOMAIN_ID)


def _env_sh(**env: str) -> subprocess.CompletedProcess:
    base = {k: v for k, v in os.environ.items() if k not in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    script = f'source "{ROOT}/scripts/env.sh" && echo "$ROS_DOMAIN_ID $ROS_AUTOMATIC_DISCOVERY_RANGE"'
    return subprocess.run(["bash", "-c", script], env={**base, **env}, capture_output=True, text=True, timeout=60,
                          check=False)


@pytest.mark.parametrize(("env", "expected"), [
    ({}, f"{SCRIPTS_DEFAULT_DOMAIN_ID} LOCALHOST"),  # the stack's own domain, this host only
    ({"ROS_DOMAIN_ID": ""}, f"{SCRIPTS_DEFAULT_DOMAIN_ID} LOCALHOST"),
    ({"ROS_DOMAIN_ID": "7"}, "7 LOCALHOST"),  # the user's choice is honoured
    ({"ROS_DOMAIN_ID": "0", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, "0 SUBNET"),  # opened up for a robot
    ({"ROS_DOMAIN_ID": "007"}, "7 LOCALHOST"),
])
def test_env_sh_domain_and_discovery(env, expected):
    result = _env_sh(**env)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[-2] == expected


@pytest.mark.parametrize(("env", "named"), [
    ({"ROS_DOMAIN_ID": "233"}, "ROS_DOMAIN_ID must be an integer in [0, 232]"),
    ({"ROS_DOMAIN_ID": "robot"}, "ROS_DOMAIN_ID must be an integer in [0, 232]"),
    ({"ROS_DOMAIN_ID": "-1"}, "ROS_DOMAIN_ID must be an integer in [0, 232]"),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "subnet"}, "ROS_AUTOMATIC_DISCOVERY_RANGE must be one of LOCALHOST, SUBNET"),
])
def test_env_sh_refuses_a_malformed_setting(env, named):
    result = _env_sh(**env)
    assert result.returncode != 0 and named in result.stderr
