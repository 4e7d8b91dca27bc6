"""teleop_keyboard: drive the robot from a terminal; publishes /cmd_vel (geometry_msgs/Twist).

Keys (teleop.py): w/s or up/down forward speed, a/d lateral speed, left/right yaw rate, in steps
(``forward_step``, ``lateral_step`` [m/s], ``yaw_step`` [rad/s]) within the controller's limits;
space stops; q or Ctrl-C quits after publishing a zero command (SIGTERM quits without one: the
controller's cmd_vel_timeout then stops the robot). Publishes at ``rate`` (20 Hz) on
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
from dataclasses import dataclass

from a1_common.config import recording_constraints, require_range, setting
from a1_common.node_support import constrain_parameters, declare_settings, run_node
from a1_interface.contract import COMMAND_QOS
from geometry_msgs.msg import Twist
from rclpy.duration import Duration
from rclpy.node import Node

from a1_interface import contract
from gait_policy_node.teleop import KeyDecoder, Teleop

QUIT_ACK_TIMEOUT = 1.0  # [s] the zero command on quitting waits this long at most for its subscribers


@dataclass(frozen=True)
class NodeParameters:
    rate: float = setting(20.0, "/cmd_vel publish rate [Hz]")
    forward_step: float = setting(0.1, "forward speed change per key press [m/s]")
    lateral_step: float = setting(0.1, "lateral speed change per key press [m/s]")
    yaw_step: float = setting(0.1, "yaw rate change per key press [rad/s]")


PARAMETERS = NodeParameters()


class TeleopNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("teleop_keyboard", **node_kwargs)
        with recording_constraints() as constraints:
            p = declare_settings(self, PARAMETERS)
            rate = require_range("rate", p["rate"], 1.0, 100.0)
            self.teleop = Teleop(steps=(p["forward_step"], p["lateral_step"], p["yaw_step"]))
        constrain_parameters(self, p, constraints)  # all read-only: read at start-up
        self.decoder = KeyDecoder()
        self.quit = False
        self.pub = self.create_publisher(Twist, contract.CMD_VEL, COMMAND_QOS)
        self.create_timer(1.0 / rate, self._tick)
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
        if self.context.ok():  # not after SIGTERM: rclpy's handler has shut the context down already
            self.pub.publish(self._twist())
            # Reliable: wait until the subscribers have it, or the context may go down with it in
            # flight (the robot would walk on until the controller's cmd_vel_timeout).
            self.pub.wait_for_all_acked(Duration(seconds=QUIT_ACK_TIMEOUT))
        self._show()
        sys.stdout.write("\n")


def main(args: list[str] | None = None) -> None:
    if not sys.stdin.isatty():
        raise SystemExit("teleop_keyboard: stdin is not a terminal; run it in a terminal (or use velocity_command)")
    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)  # keys arrive one by one, unechoed
        # Ctrl-C as a key (the quit key) rather than SIGINT: rclpy's SIGINT handler would shut the
        # context down before the zero command could be sent.
        attributes = termios.tcgetattr(fd)
        attributes[3] &= ~termios.ISIG
        termios.tcsetattr(fd, termios.TCSANOW, attributes)
        run_node("teleop_keyboard", TeleopNode, args)
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


if __name__ == "__main__":
    main()
