"""DirectExecutor (a1_common.node_support), the executor every node process spins in.

It takes messages straight out of its wait set; these tests hold it to what rclpy's own executor
does in the cases a review found it getting wrong: entities destroyed from callbacks, callbacks
with message info, tasks, shutdown from a callback.
"""

from __future__ import annotations

import time
import uuid

import pytest
from a1_common.node_support import DirectExecutor
from rclpy.node import Node
from std_msgs.msg import Int32


@pytest.fixture
def node_and_executor(rclpy_context):
    node = Node("direct_executor_test", context=rclpy_context)
    node.topic = f"/direct_test_{uuid.uuid4().hex[:8]}"  # its own: earlier tests' endpoints may linger in discovery
    executor = DirectExecutor(context=rclpy_context)
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()


def spin_until(executor: DirectExecutor, done, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while not done() and time.monotonic() < deadline:
        executor.spin_direct_once(0.05)
    return done()


def test_messages_reach_plain_and_message_info_callbacks(node_and_executor):
    node, executor = node_and_executor
    pub = node.create_publisher(Int32, node.topic, 10)
    plain, with_info = [], []
    node.create_subscription(Int32, node.topic, lambda m: plain.append(m.data), 10)
    node.create_subscription(Int32, node.topic, lambda m, info: with_info.append((m.data, info)), 10)
    assert spin_until(executor, lambda: pub.get_subscription_count() == 2)
    for i in range(5):
        pub.publish(Int32(data=i))
    assert spin_until(executor, lambda: len(plain) == 5 and len(with_info) == 5)
    assert plain == [0, 1, 2, 3, 4]
    assert [d for d, _ in with_info] == plain and all("source_timestamp" in info for _, info in with_info)


def test_a_subscription_destroying_itself_leaves_the_rest_running(node_and_executor):
    node, executor = node_and_executor
    pub = node.create_publisher(Int32, node.topic, 10)
    got, ticks = [], []

    def on_message(msg: Int32) -> None:
        got.append(msg.data)
        if msg.data == 2:
            node.destroy_subscription(sub)

    sub = node.create_subscription(Int32, node.topic, on_message, 10)
    node.create_timer(0.01, lambda: ticks.append(1))
    assert spin_until(executor, lambda: pub.get_subscription_count() == 1)
    for i in range(3):
        pub.publish(Int32(data=i))
    assert spin_until(executor, lambda: got == [0, 1, 2])
    ticks.clear()
    pub.publish(Int32(data=3))
    assert spin_until(executor, lambda: len(ticks) >= 10), "the timer stopped after the destroy"
    assert got == [0, 1, 2]


def test_a_task_created_in_a_callback_runs_without_waiting_for_a_timer(node_and_executor):
    node, executor = node_and_executor
    pub = node.create_publisher(Int32, node.topic, 10)
    done = []
    node.create_subscription(Int32, node.topic, lambda m: executor.create_task(lambda: done.append(m.data)), 10)
    assert spin_until(executor, lambda: pub.get_subscription_count() == 1)
    pub.publish(Int32(data=7))
    start = time.monotonic()
    assert spin_until(executor, lambda: done == [7], timeout=0.5)  # no timer in this node at all
    assert time.monotonic() - start < 0.5


def test_shutdown_from_a_callback_ends_spin(node_and_executor):
    node, executor = node_and_executor
    pub = node.create_publisher(Int32, node.topic, 10)
    node.create_subscription(Int32, node.topic, lambda m: executor.shutdown(), 10)
    assert spin_until(executor, lambda: pub.get_subscription_count() == 1)
    pub.publish(Int32(data=1))
    node.create_timer(2.0, lambda: pytest.fail("spin went on after shutdown"))
    start = time.monotonic()
    executor.spin()  # returns once the callback has shut the executor down
    assert time.monotonic() - start < 2.0
