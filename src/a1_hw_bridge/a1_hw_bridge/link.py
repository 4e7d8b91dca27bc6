"""UDP sockets of the A1 low-level link, both ends, with counted drops. No ROS.

Client (bridge) side as the SDK does it: bound to a local port, ``connect()``ed to the robot's
address, so only datagrams from exactly that address arrive. Server (virtual A1) side: bound to
the robot's port, replying from it to whoever last sent a valid command.
"""

from __future__ import annotations

import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from a1_hw_bridge.protocol import LowCmd, LowState, ProtocolError, unpack_low_cmd, unpack_low_state

MAX_DATAGRAM = 2048  # [bytes] larger than any A1 datagram, so an oversized one is seen whole
T = TypeVar("T")


@dataclass
class LinkStats:
    """Datagram counters of one end of the link (diagnostics)."""

    sent: int = 0
    send_errors: int = 0  # robot unreachable (ICMP) or socket buffer full
    received: int = 0
    accepted: int = 0
    wrong_size: int = 0
    bad_crc: int = 0
    bad_level: int = 0  # commands whose levelFlag is not low level (server side only)

    @property
    def dropped(self) -> int:
        return self.wrong_size + self.bad_crc + self.bad_level


def _count_drop(stats: LinkStats, error: ProtocolError) -> None:
    if error.reason == "size":
        stats.wrong_size += 1
    elif error.reason == "crc":
        stats.bad_crc += 1
    else:
        stats.bad_level += 1


def accept_state(data: bytes, stats: LinkStats) -> LowState | None:
    """Decode a state datagram, or count it as dropped (wrong size, bad CRC) and return None."""
    stats.received += 1
    try:
        state = unpack_low_state(data)
    except ProtocolError as exc:
        _count_drop(stats, exc)
        return None
    stats.accepted += 1
    return state


def accept_command(data: bytes, stats: LinkStats) -> LowCmd | None:
    """Decode a command datagram; wrong size, bad CRC or a non-low-level flag is counted and dropped."""
    stats.received += 1
    try:
        cmd = unpack_low_cmd(data)
        if cmd.header.level_flag != 0xFF:
            raise ProtocolError("level_flag", f"levelFlag 0x{cmd.header.level_flag:02X} is not low level")
    except ProtocolError as exc:
        _count_drop(stats, exc)
        return None
    stats.accepted += 1
    return cmd


def _drain(receive: Callable[[], T]) -> list[T]:
    """Every datagram queued on a non-blocking socket (``receive`` reads one)."""
    datagrams = []
    while True:
        try:
            datagrams.append(receive())
        except (BlockingIOError, InterruptedError):
            return datagrams


class Pacer:
    """Deadlines every ``period`` seconds of the monotonic clock, for a fixed-rate loop.

    A late deadline is counted (``overruns``); after a stall of more than 0.1 s (a suspended
    process) the schedule restarts from now instead of rushing through the missed periods.
    """

    def __init__(self, period: float) -> None:
        self.period = period
        self.deadline = time.monotonic()
        self.overruns = 0

    def remaining(self) -> float:
        """Seconds until the current deadline (negative once it has passed)."""
        return self.deadline - time.monotonic()

    def advance(self) -> int:
        """Move to the next deadline; the number of periods skipped (none unless over 0.1 s behind,
        when it starts again from now instead of catching up)."""
        self.deadline += self.period
        late = -self.remaining()
        if late > 0:
            self.overruns += 1
            if late > 0.1:
                self.deadline = time.monotonic()
                return int(late / self.period)
        return 0

    def sleep(self) -> None:
        """Sleep until the current deadline."""
        remaining = self.remaining()
        if remaining > 0:
            time.sleep(remaining)


class RobotLink:
    """The client end: sends LowCmd datagrams to the robot, returns the newest valid LowState."""

    def __init__(self, robot_ip: str, robot_port: int, local_ip: str = "0.0.0.0", local_port: int = 0) -> None:
        self.stats = LinkStats()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((local_ip, local_port))
            self._sock.connect((robot_ip, robot_port))
        except OSError as exc:
            self._sock.close()
            raise OSError(f"cannot open the A1 link {local_ip}:{local_port} -> {robot_ip}:{robot_port}: "
                          f"{exc.strerror or exc}") from None
        self._sock.setblocking(False)

    @property
    def local_address(self) -> tuple[str, int]:
        return self._sock.getsockname()

    def send(self, packet: bytes) -> bool:
        try:
            self._sock.send(packet)
        except (ConnectionRefusedError, BlockingIOError, OSError):
            self.stats.send_errors += 1
            return False
        self.stats.sent += 1
        return True

    def receive(self, timeout: float) -> LowState | None:
        """Wait up to ``timeout`` [s] for datagrams, read all that are queued, return the newest valid one."""
        deadline = time.monotonic() + max(timeout, 0.0)
        while True:
            ready, _, _ = select.select([self._sock], [], [], max(deadline - time.monotonic(), 0.0))
            if not ready:
                return None
            newest = None
            for data in self._drain():
                state = accept_state(data, self.stats)
                if state is not None:
                    newest = state
            if newest is not None or time.monotonic() >= deadline:
                return newest

    def _drain(self) -> list[bytes]:
        try:
            return _drain(lambda: self._sock.recv(MAX_DATAGRAM))
        except ConnectionRefusedError:  # ICMP: nothing listens at the robot's address (yet)
            self.stats.send_errors += 1
            return []

    def close(self) -> None:
        self._sock.close()


class ServerSocket:
    """The robot end: bound to the robot's port; replies go to the last client that sent a valid command."""

    def __init__(self, host: str, port: int) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            raise OSError(f"cannot bind the virtual A1 to {host}:{port}: {exc.strerror or exc}") from None
        self._sock.setblocking(False)
        self.client: tuple[str, int] | None = None

    @property
    def address(self) -> tuple[str, int]:
        return self._sock.getsockname()

    def wait(self, timeout: float) -> bool:
        ready, _, _ = select.select([self._sock], [], [], max(timeout, 0.0))
        return bool(ready)

    def drain(self) -> list[tuple[bytes, tuple[str, int]]]:
        return _drain(lambda: self._sock.recvfrom(MAX_DATAGRAM))

    def reply(self, packet: bytes, stats: LinkStats) -> None:
        if self.client is None:
            return
        try:
            self._sock.sendto(packet, self.client)
        except OSError:
            stats.send_errors += 1
            return
        stats.sent += 1

    def close(self) -> None:
        self._sock.close()
