"""teleop_keyboard: the key core, and the installed executable driven in a real (pseudo-)terminal,
checked by what reaches /cmd_vel."""

from __future__ import annotations

import os
import pty
import select
import signal

import pytest
from a1_common.config import ConfigError
from a1_interface.contract import COMMAND_QOS
from gait_policy_node.teleop import KeyDecoder, Teleop
from geometry_msgs.msg import Twist
from graph_helpers import executable
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from ros_helpers import spin_until


def test_keys_step_the_command_within_the_limits():
    teleop = Teleop(steps=(0.5, 0.25, 1.0), limits=(1.0, 0.5, 2.0))
    for key in ("w", "up", "w", "a", "left", "left", "left", "d", "x"):  # x: not bound, ignored
        assert teleop.press(key)
    assert teleop.command == [1.0, 0.0, 2.0]  # forward and yaw clamped at their limits
    assert teleop.press("s") and teleop.press("down") and teleop.press("right")
    assert teleop.command == [0.0, 0.0, 1.0]
    assert teleop.press("space") and teleop.command == [0.0, 0.0, 0.0]
    teleop.press("w")
    assert not teleop.press("q") and teleop.command == [0.0, 0.0, 0.0]  # quitting stops the robot
    assert "forward +0.00 m/s" in teleop.line()
    with pytest.raises(ConfigError, match="steps forward"):
        Teleop(steps=(0.0, 0.1, 0.1))


def test_ctrl_c_is_the_quit_key():
    assert KeyDecoder().feed(b"w\x03") == ["w", "q"]


def test_escape_sequences_split_across_reads():
    decoder = KeyDecoder()
    assert decoder.feed(b"W\x1b[A\x1b") == ["w", "up"]  # the last sequence is incomplete
    assert decoder.feed(b"[D \x1bOB") == ["left", "space", "down"]
    assert decoder.feed(b"\x1b[Zq\x1b[1;5A") == ["q"]  # unbound sequences are dropped whole, not typed


@pytest.mark.ros
def test_teleop_keyboard_in_a_terminal(rclpy_context):
    received: list[tuple[float, float, float]] = []
    node = Node("teleop_probe", context=rclpy_context)
    node.create_subscription(Twist, "/cmd_vel", lambda m: received.append((m.linear.x, m.linear.y, m.angular.z)),
                             COMMAND_QOS)
    executor = SingleThreadedExecutor(context=rclpy_context)
    executor.add_node(node)
    exe = executable("gait_policy_node", "teleop_keyboard")
    pid, terminal = pty.fork()
    if pid == 0:  # the child: the installed executable, its stdin/stdout a terminal
        os.execv(exe, [exe])
    screen = bytearray()

    def read_screen() -> None:
        while select.select([terminal], [], [], 0.0)[0]:
            try:
                screen.extend(os.read(terminal, 4096))
            except OSError:  # the child closed the terminal
                return

    def command_becomes(expected: tuple[float, float, float]) -> bool:
        def done() -> bool:
            read_screen()
            return bool(received) and received[-1] == pytest.approx(expected)
        return spin_until(executor, done, 30.0)

    def screen_shows(text: bytes) -> bool:  # the status line may reach the terminal after /cmd_vel
        def done() -> bool:
            read_screen()
            return text in screen
        return spin_until(executor, done, 30.0)

    try:
        assert command_becomes((0.0, 0.0, 0.0)), f"no /cmd_vel; screen: {bytes(screen)!r}"
        os.write(terminal, b"ww\x1b[A")  # w, w, up arrow
        assert command_becomes((0.3, 0.0, 0.0)), received[-3:]
        os.write(terminal, b"a\x1b[D\x1b[D")  # a, left, left
        assert command_becomes((0.3, 0.1, 0.2)), received[-3:]
        os.write(terminal, b" ")
        assert command_becomes((0.0, 0.0, 0.0))
        os.write(terminal, b"w")
        assert command_becomes((0.1, 0.0, 0.0))
        assert screen_shows(b"forward +0.10 m/s  lateral +0.00 m/s  yaw +0.00 rad/s"), bytes(screen[-300:])
        os.write(terminal, b"\x03")  # Ctrl-C: a key like q (a SIGINT would end it before the zero command)
        assert command_becomes((0.0, 0.0, 0.0))  # quitting sends a zero command last
        _, status = os.waitpid(pid, 0)
        pid = 0
        assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
    finally:
        if pid:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        os.close(terminal)
        executor.shutdown()
        node.destroy_node()
