"""teleop_keyboard: drive the robot from a terminal; publishes /cmd_vel (geometry_msgs/Twist).

Keys (teleop.py): w/s or up/down forward speed, a/d lateral speed, left/right yaw rate, in steps
(``forward_step``, ``lateral_step`` [m/s], ``yaw_step`` [rad/s]) within the controller's limits;
space stops; q (or Ctrl-C) quits after publishing a zero command. Publishes at ``rate`` (20 Hz) on
the wall clock whether or not a key was pressed, so the controller's /cmd_vel timeout never stops
a robot the operator is driving, and shows the current command on one line. Needs a terminal:
the keys are read from stdin in cbreak mode, restored on exit.
"""

from __future__ import annotations

import os
import select
import sys
import termios
import tty

from a1_common.config import require_range
from a1_common.node_support import declare_parameters, guard_runtime_parameters, run_node
from geometry_msgs.msg import Twist
from rclpy.node import Node

from gait_policy_node.policy_node import COMMAND_QOS
from gait_policy_node.teleop import KeyDecoder, Teleop

PARAMETERS = {"rate": 20.0, "forward_step": 0.1, "lateral_step": 0.1, "yaw_step": 0.1}


class TeleopNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("teleop_keyboard", **node_kwargs)
        p = declare_parameters(self, PARAMETERS)
        rate = require_range("rate", p["rate"], 1.0, 100.0)
        self.teleop = Teleop(steps=(p["forward_step"], p["lateral_step"], p["yaw_step"]))
        self.decoder = KeyDecoder()
        self.quit = False
        self.pub = self.create_publisher(Twist, "/cmd_vel", COMMAND_QOS)
        self.create_timer(1.0 / rate, self._tick)
        guard_runtime_parameters(self, PARAMETERS)
        self._show()

    def _tick(self) -> None:
        """Read the keys that came since the last tick, publish the command, show it."""
        fd = sys.stdin.fileno()
        changed = False
        while select.select([fd], [], [], 0.0)[0]:
            data = os.read(fd, 64)
            if not data:  # the terminal closed
                self._stop()
                return
            for key in self.decoder.feed(data):
                changed = True
                if not self.teleop.press(key):
                    self._stop()
                    return
        self.pub.publish(self._twist())
        if changed:
            self._show()

    def _twist(self) -> Twist:
        msg = Twist()
        msg.linear.x, msg.linear.y, msg.angular.z = self.teleop.command
        return msg

    def _show(self) -> None:
        sys.stdout.write("\r\x1b[K" + self.teleop.line())
        sys.stdout.flush()

    def _stop(self) -> None:
        """q or a closed terminal: a zero command, then the node ends."""
        self.shutdown()
        self.context.try_shutdown()

    def shutdown(self) -> None:
        """Also on Ctrl-C / SIGTERM (run_node calls it): the last command sent is zero."""
        if self.quit:
            return
        self.quit = True
        self.teleop.press("q")
        self.pub.publish(self._twist())
        self._show()
        sys.stdout.write("\n")


def main(args: list[str] | None = None) -> None:
    if not sys.stdin.isatty():
        raise SystemExit("teleop_keyboard: stdin is not a terminal; run it in a terminal (or use velocity_command)")
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)  # keys arrive one by one, unechoed; Ctrl-C still interrupts
        run_node("teleop_keyboard", TeleopNode, args)
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


if __name__ == "__main__":
    main()
