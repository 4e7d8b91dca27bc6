"""A virtual A1: the robot's end of the low-level UDP protocol, served from the A1Sim core. No ROS.

It receives 610-byte LowCmd datagrams, applies them to the simulated robot through the motor
model (servo mode: tau = tau_ff + Kp (q* - q) + Kd (dq* - dq), idle mode: no torque) and answers
with 771-byte LowState datagrams, so a client -- the hardware bridge, or anything speaking the
SDK's format -- cannot tell it from the robot except by what the simulation lacks.

Clock modes:
- ``realtime``: the robot's own 500 Hz loop (1 / time_step of wall time): each tick applies the
  newest valid command, steps, and sends a state to the client (once one has sent a command).
- ``lockstep``: one tick per received datagram: the robot runs exactly as fast as its client
  commands it, so a slow machine changes nothing but the wall time (deterministic HIL tests).

Undocumented robot behaviour, made settings (see docs/hardware.md):
- ``on_command_loss``: what the motors do once no valid command came for ``command_loss_timeout``
  of robot time: ``hold`` the last command, ``damping`` (tau = -damping_kd dq) or ``zero_torque``.
  Before the first command the robot is in damping, as after L2+B on the remote.
- ``packet_loss``: probability with which each datagram is lost, in each direction independently
  (seeded by ``loss_seed``). A lost command leaves the previous one in force for that tick; a lost
  state is simply not sent.
- The foot-force sensor: raw = ``foot_force_offset`` + ``foot_force_gain`` x normal force [N].
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from a1_common.command import CommandError, JointCommand
from a1_common.config import ConfigError, require_choice, require_integer, require_range, setting
from a1_sim_bridge.sim import A1Sim, SimConfig

from a1_hw_bridge.link import LinkStats, Pacer, ServerSocket, accept_command
from a1_hw_bridge.protocol import DEFAULT_ROBOT_PORT, IDLE_MODE, NUM_ROBOT_MOTORS, pack_low_state
from a1_hw_bridge.robot_io import joint_command_from_low_cmd, low_state_from_readings

CLOCK_MODES = ("realtime", "lockstep")
COMMAND_LOSS_BEHAVIOURS = ("hold", "damping", "zero_torque")


@dataclass(frozen=True)
class VirtualA1Config:
    """Settings of the robot side; ``validated()`` names a bad field and its range."""

    host: str = setting("127.0.0.1", "IPv4 address the virtual A1 serves on")
    port: int = setting(DEFAULT_ROBOT_PORT, "UDP port the virtual A1 serves on (0: any free port)")
    clock_mode: str = setting("realtime", "realtime: steps on the wall clock | lockstep: each step waits for a command")
    packet_loss: float = setting(0.0, "probability of losing each datagram, each direction")
    loss_seed: int = setting(0, "seed of the injected datagram losses")
    on_command_loss: str = setting(
        "damping", "motors after command_loss_timeout without commands: hold | damping | zero_torque")
    command_loss_timeout: float = setting(0.1, "no command for this long -> on_command_loss [s of robot time]")
    foot_force_gain: float = setting(1.0, "foot sensor reading per newton [raw units per N]")
    foot_force_offset: float = setting(15.0, "foot sensor reading when unloaded [raw units]")

    def validated(self) -> VirtualA1Config:
        require_choice("clock_mode", self.clock_mode, CLOCK_MODES)
        require_choice("on_command_loss", self.on_command_loss, COMMAND_LOSS_BEHAVIOURS)
        require_integer("port", self.port, 0, 65535)
        if not isinstance(self.loss_seed, int) or isinstance(self.loss_seed, bool) or self.loss_seed < 0:
            raise ConfigError(f"loss_seed must be a non-negative integer, got {self.loss_seed!r}")
        require_range("packet_loss", self.packet_loss, 0.0, 1.0, high_open=True)
        require_range("command_loss_timeout", self.command_loss_timeout, 0.0, 10.0, low_open=True)
        require_range("foot_force_gain", self.foot_force_gain, 0.0, 100.0, low_open=True)
        require_range("foot_force_offset", self.foot_force_offset, -1000.0, 1000.0)
        return self


@dataclass
class VirtualA1Counters:
    ticks: int = 0
    commands_lost: int = 0  # dropped by the injected packet loss
    states_lost: int = 0
    commands_refused: int = 0  # valid on the wire, but gains outside the simulated motor model's range
    command_loss_fallbacks: int = 0  # times the motors went to on_command_loss


class VirtualA1:
    """The simulated robot behind the protocol: ``receive`` datagrams, ``tick`` once per 2 ms."""

    def __init__(self, config: VirtualA1Config, sim_config: SimConfig | None = None) -> None:
        self.config = config.validated()
        self.sim = A1Sim(sim_config)
        self.stats = LinkStats()
        self.counters = VirtualA1Counters()
        self.last_error = ""
        self._rng = np.random.default_rng(self.config.loss_seed)
        self._command: JointCommand | None = None
        self._modes = np.zeros(NUM_ROBOT_MOTORS, dtype=int)
        self._command_time = float("-inf")  # robot time of the newest valid command [s]
        self._in_fallback = True

    def receive(self, datagram: bytes) -> bool:
        """Take a command datagram; True if it is valid and now in force (it may also be lost or refused)."""
        low = accept_command(datagram, self.stats)
        if low is None:
            return False
        if self.config.packet_loss and self._rng.random() < self.config.packet_loss:
            self.counters.commands_lost += 1
            return False
        try:
            command = joint_command_from_low_cmd(low).validated()
        except CommandError as exc:
            self.counters.commands_refused += 1
            self.last_error = str(exc)
            return False
        self._command = command
        self._modes = np.asarray(low.mode[:NUM_ROBOT_MOTORS], dtype=int)
        self._command_time = self.sim.time
        return True

    def active_command(self) -> JointCommand:
        """What the motors apply this tick: the command in force, or the command-loss behaviour."""
        lost = self._command is None or (self.sim.time - self._command_time
                                         >= self.config.command_loss_timeout - 1e-9)
        if lost and not self._in_fallback:
            self.counters.command_loss_fallbacks += 1
        self._in_fallback = lost
        if self._command is None or (lost and self.config.on_command_loss == "damping"):
            return JointCommand.damping()
        if lost and self.config.on_command_loss == "zero_torque":
            return JointCommand()
        return self._command

    def tick(self) -> bytes | None:
        """Advance the robot one time step; the state datagram to send, or None if it is lost."""
        readings = self.sim.step(self.active_command())
        self.counters.ticks += 1
        modes = self._modes if not self._in_fallback else np.full(NUM_ROBOT_MOTORS, IDLE_MODE)
        state = low_state_from_readings(readings, round(self.sim.time * 1e6), modes,
                                        self.config.foot_force_gain, self.config.foot_force_offset)
        packet = pack_low_state(state, clip=True)
        if self.config.packet_loss and self._rng.random() < self.config.packet_loss:
            self.counters.states_lost += 1
            return None
        return packet

    def close(self) -> None:
        self.sim.close()


class VirtualA1Server:
    """Serves a VirtualA1 on a UDP socket until ``stop``; ``on_tick()`` runs after every tick."""

    def __init__(self, robot: VirtualA1, on_tick: Callable[[], None] | None = None) -> None:
        self.robot = robot
        self.socket = ServerSocket(robot.config.host, robot.config.port)
        self._on_tick = on_tick
        self._running = threading.Event()
        self.pacer = Pacer(robot.sim.config.time_step)  # realtime mode: the robot's 500 Hz loop

    @property
    def address(self) -> tuple[str, int]:
        return self.socket.address

    def serve(self) -> None:
        """Run until ``stop()`` (call from the thread that owns the robot)."""
        self._running.set()
        try:
            if self.robot.config.clock_mode == "lockstep":
                self._serve_lockstep()
            else:
                self._serve_realtime()
        finally:
            self.socket.close()

    def stop(self) -> None:
        self._running.clear()

    def _take(self, datagram: bytes, sender: tuple[str, int]) -> None:
        if self.robot.receive(datagram):
            self.socket.client = sender

    def _tick(self) -> None:
        packet = self.robot.tick()
        if packet is not None:
            self.socket.reply(packet, self.robot.stats)
        if self._on_tick is not None:
            self._on_tick()

    def _serve_realtime(self) -> None:
        while self._running.is_set():
            for datagram, sender in self.socket.drain():
                self._take(datagram, sender)
            self._tick()
            self.pacer.advance()
            self.pacer.sleep()

    def _serve_lockstep(self) -> None:
        while self._running.is_set():
            if not self.socket.wait(0.1):
                continue
            for datagram, sender in self.socket.drain():
                self._take(datagram, sender)
                self._tick()  # every datagram is one tick of the robot's loop, lost or not
