"""Keyboard teleop core (no ROS): keys in, a velocity command out, in steps and within the
controller's limits. The node (teleop_node.py) reads the terminal and publishes /cmd_vel.

Keys: w / up arrow and s / down arrow change the forward speed, a / d the lateral speed (a = left,
+y), the left / right arrows the yaw rate (left = counter-clockwise, +z), space stops, q quits.
Frame: base_link (REP-103: x forward, y left, z up); units m/s and rad/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from a1_common.config import ConfigError, require_range
from convex_mpc_node.supervisor import SupervisorConfig

_LIMITS = SupervisorConfig()
# key -> (axis: 0 forward, 1 lateral, 2 yaw rate; direction)
BINDINGS = {"w": (0, 1), "up": (0, 1), "s": (0, -1), "down": (0, -1), "a": (1, 1), "d": (1, -1),
            "left": (2, 1), "right": (2, -1)}
# The terminal's escape sequences of the arrow keys (normal and application cursor mode).
ARROWS = {b"\x1b[A": "up", b"\x1b[B": "down", b"\x1b[C": "right", b"\x1b[D": "left",
          b"\x1bOA": "up", b"\x1bOB": "down", b"\x1bOC": "right", b"\x1bOD": "left"}
HELP = "w/s or up/down: forward, a/d: lateral, left/right: turn, space: stop, q: quit"


CTRL_C = "\x03"  # with the terminal's signal keys off (teleop_node.main), Ctrl-C arrives as this byte


class KeyDecoder:
    """Bytes from a terminal in cbreak mode -> key names; an escape sequence split across reads is
    kept until it completes, and one nothing is bound to is dropped. (A lone Esc key waits for the
    next byte: nothing is bound to it.)"""

    def __init__(self) -> None:
        self._pending = b""

    def feed(self, data: bytes) -> list[str]:
        buf, keys = self._pending + data, []
        while buf:
            if buf[:1] != b"\x1b":
                char = buf[:1].decode("latin-1")
                keys.append({" ": "space", CTRL_C: "q"}.get(char, char.lower()))
                buf = buf[1:]
                continue
            end = _sequence_end(buf)
            if end is None:
                break  # the rest of the sequence is still on its way
            if buf[:end] in ARROWS:
                keys.append(ARROWS[buf[:end]])
            buf = buf[end:]  # a key nothing is bound to (or a lone escape) is dropped whole
        self._pending = buf
        return keys


def _sequence_end(buf: bytes) -> int | None:
    """Length of the escape sequence at the start of ``buf`` (ESC [ params final, ESC O x, or a
    lone ESC), or None while it is incomplete."""
    if len(buf) < 2:
        return None
    if buf[1:2] == b"O":
        return 3 if len(buf) >= 3 else None
    if buf[1:2] != b"[":
        return 1
    for i in range(2, len(buf)):
        if 0x40 <= buf[i] <= 0x7E:  # a CSI sequence's final byte
            return i + 1
    return None


@dataclass
class Teleop:
    """The command the keys have set: forward, lateral [m/s] and yaw rate [rad/s]."""

    steps: tuple[float, float, float] = (0.1, 0.1, 0.1)  # per key press
    limits: tuple[float, float, float] = (_LIMITS.max_forward_speed, _LIMITS.max_lateral_speed,
                                          _LIMITS.max_yaw_rate)
    command: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])

    def __post_init__(self) -> None:
        for name, values, hi in (("steps", self.steps, 1.0), ("limits", self.limits, 6.0)):
            if len(values) != 3:
                raise ConfigError(f"{name} must be [forward, lateral, yaw rate], got {list(values)}")
            for axis, v in zip(("forward", "lateral", "yaw_rate"), values, strict=True):
                require_range(f"{name} {axis}", v, 0.0, hi, low_open=True)

    def press(self, key: str) -> bool:
        """Apply one key; False when it was the quit key (the command is then zero)."""
        if key == "q":
            self.command = [0.0, 0.0, 0.0]
            return False
        if key == "space":
            self.command = [0.0, 0.0, 0.0]
        elif key in BINDINGS:
            axis, sign = BINDINGS[key]
            value = self.command[axis] + sign * self.steps[axis]
            self.command[axis] = round(max(-self.limits[axis], min(self.limits[axis], value)), 6)
        return True

    def line(self) -> str:
        vx, vy, wz = self.command
        return f"forward {vx:+.2f} m/s  lateral {vy:+.2f} m/s  yaw {wz:+.2f} rad/s   ({HELP})"
