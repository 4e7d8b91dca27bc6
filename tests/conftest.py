"""Shared fixtures. ROS tests run on a private DDS domain so parallel runs do not talk."""

from __future__ import annotations

import os

import pytest

# A domain per test process, set before rclpy is imported anywhere.
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@pytest.fixture
def rclpy_context():
    """An initialised rclpy context, shut down after the test."""
    import rclpy

    context = rclpy.context.Context()
    rclpy.init(context=context)
    yield context
    context.try_shutdown()
