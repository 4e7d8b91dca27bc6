"""Hardware bridge core: the real (or virtual) A1 behind the stack's joint-command contract. No ROS.

``BridgeLogic`` decides what goes to the motors (pure: callers pass the time); ``HardwareBridge``
runs it against the robot over UDP in a thread and hands sensor readings to a publish callback.

Start-up, as the reference did on hardware (its A1Robot reset):
1. CONNECTING: send damping commands (the robot answers commands with states) until a valid
   state arrives. Joint readings more than ``start_joint_tolerance`` outside the joint limits
   (a broken state, or a robot in an impossible pose) -> FAULT: damping until restarted.
2. STANDING_UP: joint PD (the robot's stand gains) to a target moved linearly from the measured
   pose to the nominal standing pose over ``stand_up_time``, then held ``stand_hold_time`` while
   the foot-force sensors are read for the standing contact calibration.
3. RUNNING: sensors are published; the pose is held until the controller's first command; then
   its commands go to the motors through a CommandWatchdog: invalid ones are rejected and never
   sent, and ``command_timeout`` without a valid one sends damping. A command counts from the
   moment the sensors it answers (its stamp) were published, not from its arrival, so a slow
   message path cannot stretch the time to damping after the controller's last command; a
   command answering no recent state of this bridge is dropped as late.
Nothing is published on the sensor topics before RUNNING, so the estimator and controller start
on a standing robot with calibrated contacts.

Clocks. ``realtime`` (a real robot): commands go out every ``control_period`` of the monotonic
wall clock, states are published as they arrive, stamped by ``clock_ns`` (the node's clock);
watchdog times are monotonic wall seconds. ``lockstep`` (the virtual A1 only): one command per
received state; sensors are stamped with the robot's ``tick`` (us), which is also /clock; the
bridge waits (up to ``lockstep_timeout`` of wall time) for the controller's command stamped with
the current tick; a lost state is answered by re-sending the last command after
``state_timeout``, as the SDK's send thread would.
"""

from __future__ import annotations

import enum
import os
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from a1_common.clock import ClockGate, require_clock_period
from a1_common.command import CommandWatchdog, DeadlineMonitor, JointCommand
from a1_common.config import ConfigError, require_choice, require_integer, require_range, setting
from a1_common.robot import A1Constants, a1
from a1_interface.sensors import SensorReadings

from a1_hw_bridge.contacts import FootContactCalibrator
from a1_hw_bridge.link import Pacer, RobotLink
from a1_hw_bridge.protocol import (
    DEFAULT_LOCAL_PORT,
    DEFAULT_ROBOT_IP,
    DEFAULT_ROBOT_PORT,
    NUM_ROBOT_MOTORS,
    LowState,
    ProtocolError,
    pack_low_cmd,
)
from a1_hw_bridge.robot_io import low_cmd_from_joint_command, readings_from_low_state

CLOCK_MODES = ("realtime", "lockstep")
TICK_WRAP = 1 << 32  # the robot's microsecond tick is a uint32
STOP_DAMPING_PACKETS = 5  # sent when the bridge stops (UDP: more than one, in case some are lost)
PUBLISHED_STAMPS_KEPT = 100  # realtime: states whose publish time is remembered (0.2 s at 500 Hz)


class Phase(enum.Enum):
    CONNECTING = "connecting"
    STANDING_UP = "standing_up"
    RUNNING = "running"
    FAULT = "fault"


@dataclass(frozen=True)
class BridgeConfig:
    """Bridge settings (the node's parameters); ``validated()`` names a bad field and its range."""

    robot_ip: str = setting(DEFAULT_ROBOT_IP, "IPv4 address of the A1's low-level endpoint (motor controller board)")
    robot_port: int = setting(DEFAULT_ROBOT_PORT, "the A1's low-level UDP port")
    local_ip: str = setting("0.0.0.0", "IPv4 address of this computer to bind (0.0.0.0: any)")
    local_port: int = setting(DEFAULT_LOCAL_PORT, "local UDP port (0: any free port)")
    clock_mode: str = setting("realtime", "realtime (real robot) | lockstep (virtual A1 only; publishes /clock)")
    control_period: float = setting(0.002, "command period in realtime mode [s] (0.002: 500 Hz)")
    command_timeout: float = setting(0.04, "no valid /motor_command for this long -> damping [s]")
    lockstep_timeout: float = setting(0.5, "lockstep: wall time to wait for the controller's command [s]")
    clock_period: float = setting(0.01, "lockstep: publish /clock once per this much robot time [s]")
    state_timeout: float = setting(0.05, "lockstep: wall time to wait for a state reply before re-sending [s]")
    stand_up_time: float = setting(1.0, "safe start: interpolation from the measured pose to the standing pose [s]")
    stand_hold_time: float = setting(0.5, "safe start: hold, reading the feet for the contact calibration [s]")
    start_joint_tolerance: float = setting(
        0.2, "start refused if a joint reads further than this outside its limits [rad]")
    contact_standing_ratio: float = setting(0.8, "contact threshold as a fraction of the mean standing foot reading")
    contact_swing_margin: float = setting(10.0, "contact threshold above the mean swing foot reading [raw units]")
    foot_force_offset: float = setting(0.0, "foot reading when unloaded, until the first swing calibration [raw units]")
    foot_force_scale: float = setting(1.0, "foot force per raw unit, for /foot_contacts normal_force [N]")
    swing_recalibration: bool = setting(True, "recalibrate contact thresholds from the swings in /gait/state")
    realtime_priority: int = setting(0, "SCHED_FIFO priority 1-99 of the bridge's threads (0: normal scheduling)")

    def validated(self) -> BridgeConfig:
        require_choice("clock_mode", self.clock_mode, CLOCK_MODES)
        for name in ("robot_ip", "local_ip"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                raise ConfigError(f"{name} must be an IPv4 address string, got {getattr(self, name)!r}")
        require_integer("robot_port", self.robot_port, 1, 65535)
        require_integer("local_port", self.local_port, 0, 65535)
        require_range("control_period", self.control_period, 0.001, 0.01)
        require_range("command_timeout", self.command_timeout, 0.0, 1.0, low_open=True)
        require_range("lockstep_timeout", self.lockstep_timeout, 0.0, 10.0, low_open=True)
        require_clock_period(self.clock_period)  # the robot's tick, not control_period, paces lockstep
        require_range("state_timeout", self.state_timeout, 0.0, 1.0, low_open=True)
        require_range("stand_up_time", self.stand_up_time, 0.1, 10.0)
        require_range("stand_hold_time", self.stand_hold_time, 0.01, 10.0)
        require_range("start_joint_tolerance", self.start_joint_tolerance, 0.0, 1.0)
        require_range("contact_standing_ratio", self.contact_standing_ratio, 0.0, 1.0, low_open=True)
        require_range("contact_swing_margin", self.contact_swing_margin, 0.0, 1000.0)
        require_range("foot_force_offset", self.foot_force_offset, -32768.0, 32767.0)
        require_range("foot_force_scale", self.foot_force_scale, 0.0, 100.0, low_open=True)
        require_integer("realtime_priority", self.realtime_priority, 0, 99)  # 0: normal scheduling
        return self


class BridgeLogic:
    """Phase machine, contact calibration and watchdog. Times ``now`` are seconds of the bridge's clock."""

    def __init__(self, config: BridgeConfig, robot: A1Constants | None = None) -> None:
        self.config = config
        self.robot = robot or a1()
        self.phase = Phase.CONNECTING
        self.fault = ""
        self.watchdog = CommandWatchdog(config.command_timeout)
        self.contacts = FootContactCalibrator(config.contact_standing_ratio, config.contact_swing_margin,
                                              config.foot_force_offset, config.foot_force_scale)
        self.measured_q = self.robot.nominal_joint_angles.copy()
        self._start_q = self.measured_q.copy()
        self._phase_start = 0.0
        self.packing_errors = 0

    def on_state(self, state: LowState, now: float) -> SensorReadings | None:
        """Advance the phase with a received state; the readings to publish (RUNNING only)."""
        q = state.q[:NUM_ROBOT_MOTORS]
        if self.phase == Phase.CONNECTING:
            self._check_start_pose(q)
            if self.phase == Phase.FAULT:
                return None
            self._start_q = np.clip(q, self.robot.joint_lower_limits, self.robot.joint_upper_limits)
            self._enter(Phase.STANDING_UP, now)
        self.measured_q = q.copy()
        if self.phase == Phase.STANDING_UP:
            elapsed = now - self._phase_start
            if elapsed >= self.config.stand_up_time:
                self.contacts.add_standing(state.foot_force)
            if elapsed >= self.config.stand_up_time + self.config.stand_hold_time:
                self.contacts.finish_standing()
                self._enter(Phase.RUNNING, now)
        if self.phase != Phase.RUNNING:
            return None
        raw = state.foot_force
        return readings_from_low_state(state, now, self.contacts.contact(raw), self.contacts.force(raw))

    def _check_start_pose(self, q: np.ndarray) -> None:
        tol = self.config.start_joint_tolerance
        low, high = self.robot.joint_lower_limits - tol, self.robot.joint_upper_limits + tol
        bad = np.flatnonzero(~np.isfinite(q) | (q < low) | (q > high))
        if bad.size:
            i = int(bad[0])
            self.fault = (f"start refused: {self.robot.joint_names[i]} reads {q[i]:.3f} rad, outside its limits "
                          f"[{self.robot.joint_lower_limits[i]:.3f}, {self.robot.joint_upper_limits[i]:.3f}] "
                          f"by more than {tol} rad")
            self.phase = Phase.FAULT

    def _enter(self, phase: Phase, now: float) -> None:
        self.phase = phase
        self._phase_start = now

    def joint_command(self, now: float) -> JointCommand:
        """The command in force at ``now`` for the current phase."""
        if self.phase == Phase.STANDING_UP:
            return JointCommand.stand_up(self.robot, self._start_q, now - self._phase_start, self.config.stand_up_time)
        if self.phase == Phase.RUNNING:
            if self.watchdog.accepted == 0:  # the controller has not taken over yet: keep standing
                return JointCommand.hold(self.robot)
            return self.watchdog.active(now)
        return JointCommand.damping()

    def motor_command(self, now: float) -> bytes:
        """The datagram to send at ``now`` (damping if the command cannot be packed: never wrapped)."""
        low = low_cmd_from_joint_command(self.joint_command(now), self.robot, self.measured_q)
        try:
            return pack_low_cmd(low, position_limits=self._limits())
        except ProtocolError:
            self.packing_errors += 1
            return self.damping_packet()

    def damping_packet(self) -> bytes:
        low = low_cmd_from_joint_command(JointCommand.damping(), self.robot, self.measured_q)
        return pack_low_cmd(low, position_limits=self._limits(), clip=True)

    def _limits(self) -> tuple[np.ndarray, np.ndarray]:
        return self.robot.joint_lower_limits, self.robot.joint_upper_limits


@dataclass
class BridgeCounters:
    state_timeouts: int = 0  # lockstep: no state reply within state_timeout (lost), command re-sent
    lockstep_timeouts: int = 0  # lockstep: no controller command within lockstep_timeout
    late_commands: int = 0  # commands answering another step (lockstep) or no recent state (realtime)
    published: int = 0


class HardwareBridge:
    """Runs BridgeLogic against the robot over UDP in its own thread.

    ``publish(readings, stamp_ns)`` is called from that thread for every state while RUNNING;
    ``publish_clock(stamp_ns)`` (lockstep) for the first state in each ``clock_period``; ``clock_ns()``
    stamps states in realtime;
    ``on_failure(exc)`` if the thread dies (after it has sent damping datagrams).
    """

    def __init__(self, config: BridgeConfig, publish: Callable[[SensorReadings, int], None],
                 clock_ns: Callable[[], int], publish_clock: Callable[[int], None] | None = None,
                 robot: A1Constants | None = None, on_failure: Callable[[Exception], None] | None = None) -> None:
        self.config = config.validated()
        self.logic = BridgeLogic(self.config, robot)
        self.counters = BridgeCounters()
        self.failure: Exception | None = None
        self._on_failure = on_failure
        self._publish = publish
        self._publish_clock = publish_clock
        self._clock_gate = ClockGate(self.config.clock_period)
        self._clock_ns = clock_ns
        self._lock = threading.Condition()
        self._running = False
        self._stamp_ns = -1  # stamp of the latest state handed out
        self._commanded_stamp_ns = -1  # lockstep: stamp of the command accepted for the current step
        self._last_state_wall = float("-inf")
        self._prev_stamp_ns = -1  # stamp of the state handled before the latest one
        self._published_at: dict[int, float] = {}  # realtime: stamp -> monotonic time it was published
        # Realtime: the sends on the control period from the first command on, those with no new
        # command since the send before or with one that came over a period after its state was
        # published (missed deadlines), and state-to-command latency.
        self.deadlines = DeadlineMonitor(self.config.control_period)
        self._command_late = False  # realtime: the newest command came over a control period late
        self._raw_forces: deque[tuple[int, np.ndarray]] = deque(maxlen=100)
        self._schedules: list[tuple[int, np.ndarray]] = []
        self._tick_wraps = 0
        self._last_tick = None
        self.link = RobotLink(self.config.robot_ip, self.config.robot_port, self.config.local_ip,
                              self.config.local_port)
        self.pacer = Pacer(self.config.control_period)  # realtime mode: the command period
        self.scheduling = "not started"
        self._thread = threading.Thread(target=self._run, name="a1_link", daemon=True)

    # --- called from other threads (the node's callbacks) ----------------------------------------
    def start(self) -> str:
        """Start the link thread; with ``realtime_priority``, first make the calling thread (the node's
        executor) SCHED_FIFO, which the link thread inherits. Returns how the scheduling went."""
        scheduling = "normal"
        if os.sched_getscheduler(0) == os.SCHED_FIFO:  # e.g. composed: control_chain's priority
            scheduling = f"SCHED_FIFO {os.sched_getparam(0).sched_priority} (inherited)"
        if self.config.realtime_priority:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.config.realtime_priority))
                scheduling = f"SCHED_FIFO {self.config.realtime_priority}"
            except OSError as exc:  # no root / CAP_SYS_NICE / rtprio limit: run anyway, say so
                scheduling = f"normal (SCHED_FIFO refused: {exc.strerror})"
        self.scheduling = scheduling
        self._running = True
        self._thread.start()
        return scheduling

    def stop(self) -> None:
        """Stop the link thread, then leave the motors in damping (the robot keeps its last command)."""
        with self._lock:
            self._running = False
            self._lock.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self._send_damping()
        self.link.close()

    def _send_damping(self) -> None:
        for _ in range(STOP_DAMPING_PACKETS):
            self.link.send(self.logic.damping_packet())

    def offer_command(self, command: JointCommand, stamp_ns: int) -> str:
        """A controller command computed from the sensors stamped ``stamp_ns``: accepted, rejected or late."""
        with self._lock:
            valid = self.logic.watchdog.check(command)
            if valid is None:
                return "rejected"
            if self.logic.phase != Phase.RUNNING:  # not computed from anything this bridge published
                self.counters.late_commands += 1
                return "late"
            if self.config.clock_mode == "lockstep":
                issued = stamp_ns * 1e-9 if stamp_ns == self._stamp_ns else None
            else:  # the command is as old as the sensors it answers: when were they published?
                issued = self._published_at.get(stamp_ns)
                if issued is not None and time.monotonic() - issued >= self.config.command_timeout:
                    issued = None
                if issued is not None and stamp_ns != self._commanded_stamp_ns:  # the first answer counts
                    latency = time.monotonic() - issued
                    self.deadlines.latency(latency)
                    self._command_late = latency > self.config.control_period
            if issued is None:  # not an answer to a recent state of this bridge
                self.counters.late_commands += 1
                return "late"
            self.logic.watchdog.accept(valid, issued)
            self._commanded_stamp_ns = stamp_ns
            self._lock.notify_all()
            return "accepted"

    def observe_gait_state(self, stamp_ns: int, desired_contact: np.ndarray) -> None:
        """The controller's scheduled contacts at ``stamp_ns`` (for the swing recalibration)."""
        if self.config.swing_recalibration:
            with self._lock:
                self._schedules.append((stamp_ns, np.asarray(desired_contact, dtype=bool)))
                del self._schedules[:-100]

    def diagnostics(self) -> dict[str, object]:
        """Counts since the start; the latency and gap figures over the window since the last call."""
        with self._lock:
            logic, wd, link = self.logic, self.logic.watchdog, self.link.stats
            return {
                "sends": self.deadlines.periods, "uncommanded_sends": self.deadlines.uncommanded,
                **self.deadlines.window(),
                "phase": logic.phase.value, "fault": logic.fault, "clock_mode": self.config.clock_mode,
                "scheduling": self.scheduling,
                "robot": f"{self.config.robot_ip}:{self.config.robot_port}",
                "state_age_s": f"{time.monotonic() - self._last_state_wall:.3f}",
                "states_received": link.received, "states_accepted": link.accepted,
                "states_dropped_wrong_size": link.wrong_size, "states_dropped_bad_crc": link.bad_crc,
                "commands_sent": link.sent, "send_errors": link.send_errors,
                "commands_accepted": wd.accepted, "commands_rejected": wd.rejected, "last_rejection": wd.last_error,
                "damping_fallbacks": wd.timeouts, "in_damping": wd.in_fallback and wd.accepted > 0,
                "late_commands": self.counters.late_commands, "state_timeouts": self.counters.state_timeouts,
                "lockstep_timeouts": self.counters.lockstep_timeouts, "packing_errors": logic.packing_errors,
                "realtime_overruns": self.pacer.overruns,
                "contact_thresholds": np.round(logic.contacts.thresholds, 1).tolist(),
                "foot_unloaded_readings": np.round(logic.contacts.unloaded, 1).tolist(),
                "swing_calibrations": logic.contacts.swing_calibrations,
                "legs_unloaded_at_stand_up": logic.contacts.unloaded_legs,
            }

    # --- the link thread -------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            if self.config.clock_mode == "lockstep":
                self._run_lockstep()
            else:
                self._run_realtime()
        except Exception as exc:  # a dead link thread must be loud, and leave the motors damped
            self.failure = exc
            traceback.print_exc()
            self._send_damping()
            if self._on_failure is not None:
                self._on_failure(exc)

    def _run_realtime(self) -> None:
        """Send every control period; between sends, publish each state as it arrives."""
        while self._running:
            state = self.link.receive(self.pacer.remaining())
            if state is not None:
                self._handle_state(state, self._clock_ns(), time.monotonic())
            if self.pacer.remaining() <= 0:
                with self._lock:
                    packet = self.logic.motor_command(time.monotonic())
                    self._count_send()
                self.link.send(packet)
                skipped = self.pacer.advance()
                if skipped and self.logic.watchdog.accepted:  # sends that never happened: missed deadlines
                    with self._lock:
                        self.deadlines.skipped(skipped)

    def _count_send(self) -> None:
        """Realtime: one period's send, and whether a new command came since the last (lock held)."""
        accepted = self.logic.watchdog.accepted
        if accepted:  # before the first command there is no deadline to miss
            self.deadlines.count(accepted, late=self._command_late)
        self._command_late = False

    def _run_lockstep(self) -> None:
        with self._lock:
            packet = self.logic.motor_command(0.0)
        self.link.send(packet)
        while self._running:
            state = self.link.receive(self.config.state_timeout)
            if state is None:  # lost (or not up yet): the robot still ran a tick; ask again
                self.counters.state_timeouts += 1
                self.link.send(packet)
                continue
            stamp_ns = self._robot_time_ns(state.tick)
            readings = self._handle_state(state, stamp_ns, stamp_ns * 1e-9)
            if readings is not None:
                self._wait_for_command(readings, stamp_ns)
            with self._lock:
                packet = self.logic.motor_command(stamp_ns * 1e-9)
            self.link.send(packet)

    def _wait_for_command(self, readings: SensorReadings, stamp_ns: int) -> None:
        """Lockstep: wait for the controller's command of this step; before its first, wait indefinitely."""
        with self._lock:
            while self._running and self._commanded_stamp_ns != stamp_ns:
                if self._lock.wait(self.config.lockstep_timeout):
                    continue
                self.counters.lockstep_timeouts += 1
                if self.logic.watchdog.accepted > 0:
                    return  # the controller went silent: its watchdog decides (damping after the timeout)
                # Nobody has commanded yet (start-up, discovery): the virtual robot waits with us.
                self._lock.release()
                try:
                    self._publish(readings, stamp_ns)
                finally:
                    self._lock.acquire()

    def _robot_time_ns(self, tick: int) -> int:
        """The robot's tick [us], unwrapped, in nanoseconds."""
        if self._last_tick is not None and tick < self._last_tick - TICK_WRAP // 2:
            self._tick_wraps += 1
        self._last_tick = tick
        return (tick + self._tick_wraps * TICK_WRAP) * 1000

    def _handle_state(self, state: LowState, stamp_ns: int, now: float) -> SensorReadings | None:
        with self._lock:
            self._last_state_wall = time.monotonic()
            self._recalibrate(stamp_ns, state.foot_force)
            readings = self.logic.on_state(state, now)
            if readings is not None:
                self._stamp_ns = stamp_ns
                self._published_at[stamp_ns] = time.monotonic()
                if len(self._published_at) > PUBLISHED_STAMPS_KEPT:
                    del self._published_at[next(iter(self._published_at))]
        if self._publish_clock is not None and self._clock_gate.due(stamp_ns):
            self._publish_clock(stamp_ns)
        if readings is not None:
            self._publish(readings, stamp_ns)
            self.counters.published += 1
        return readings

    def _recalibrate(self, stamp_ns: int, raw_force: np.ndarray) -> None:
        """Pair the schedules of steps before the previous one with the raw forces of their steps (lock held).

        The controller publishes /gait/state(t) right after /motor_command(t); in lockstep the bridge
        has waited for the command of the previous step, published after every schedule older than
        that step, so which schedules are in does not depend on timing (lockstep stays deterministic).
        """
        forces = dict(self._raw_forces)
        ready = sorted((s for s in self._schedules if s[0] < self._prev_stamp_ns), key=lambda s: s[0])
        for sched_ns, desired in ready:
            if sched_ns in forces:
                self.logic.contacts.observe_schedule(desired, forces[sched_ns])
        self._schedules = [s for s in self._schedules if s[0] >= self._prev_stamp_ns]
        self._prev_stamp_ns = stamp_ns
        self._raw_forces.append((stamp_ns, np.asarray(raw_force, dtype=float)))

