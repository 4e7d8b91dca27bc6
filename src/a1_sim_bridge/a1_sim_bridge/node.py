"""Sim bridge node: the A1Sim core behind the same topics a hardware bridge offers.

Publishes at every 2 ms sim step: /joint_states, /imu/data, /foot_contacts and (evaluation only)
/sim/ground_truth/odom, and /clock once per ``clock_period`` (a1_common.clock); subscribes
/motor_command. Clock modes:
- lockstep: after publishing the sensors of step k (stamp t_k), wait for a /motor_command stamped
  t_k, apply it and advance; if none comes within ``lockstep_timeout`` of wall time, advance anyway
  (the watchdog then sends the motors to damping after ``command_timeout`` of sim time).
- realtime: paced by the wall clock at 1/time_step (times ``real_time_factor``, 1 by default); the
  latest valid command is applied.
In both modes the sim holds its start pose (sensors offered again each step, time stopped) until
the first valid command after start-up or ~/reset. ``start_paused`` starts it paused: after the
start pose's sensors nothing is stepped or published until ``~/pause`` false (scripts/demo.sh:
its report unpauses once it has a publisher on every topic it records, so it sees t = 0).
Composed with its controller (a1_bringup.control_chain, ``own_thread=False``) the bridge takes each
command as the controller sends it (``take_command``) and hands each step's sensors over as it
publishes them (``sensor_sinks``); the wire carries the same messages as ever.
QoS of the 500 Hz topics: RELIABLE, KEEP_LAST 1, VOLATILE (see docs/architecture.md).
/diagnostics (1 Hz) counts what the robot sees of its controller: ``uncommanded_steps``, steps
applied with no command accepted since the step before, or (realtime) with one sent after the
step's deadline, and the periods skipped after falling over 0.1 s behind (missed 2 ms deadlines,
out of ``deadline_periods``: steps and skipped periods); ``latency_*_ms``,
wall time from publishing a step's sensors to receiving the first command stamped for it, over the
last second, answers within 0.1 s only; ``lowest_base_height_m`` since the last report;
``last_command_received_s``, the sim time the command in force was accepted at (its watchdog's
reference: damping from ``command_timeout`` after it).
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import math
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import rclpy
from a1_common.clock import ClockGate, require_clock_period
from a1_common.command import CommandWatchdog, DeadlineMonitor, MotorMode
from a1_common.config import (
    ConfigError,
    parameter_defaults,
    recording_constraints,
    require_choice,
    require_range,
    setting,
)
from a1_common.node_support import (
    coerce_parameter,
    constrain_parameters,
    declare_settings,
    diagnostic_array,
    run_node,
)
from a1_common.robot import FALL_HEIGHT
from a1_interface.contract import BASE_FRAME, CONTROL_QOS, IMU_FRAME, LATCHED_QOS
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState
from std_msgs.msg import String
from std_srvs.srv import SetBool, Trigger

from a1_interface import contract, wire
from a1_interface import conversions as cv
from a1_sim_bridge.description import robot_description
from a1_sim_bridge.flight_recorder import FlightRecorder, require_seconds
from a1_sim_bridge.sim import A1Sim, SensorNoise, SimConfig
from gait_msgs.msg import FootContacts, MotorCommand

CLOCK_MODES = ("lockstep", "realtime")
LEFT_WORLD_HEIGHT = -1.0  # [m] a base this far below the ground's surface has fallen through or off it
UPRIGHT_TILT = 0.3  # [rad] body tilt under which a robot stands or walks (the controller's falls start far beyond)
RUNTIME_PARAMETERS = ("world", "seed")  # applied at the next ~/reset


@dataclass(frozen=True)
class NodeParameters:
    """The node's own parameters; the rest configure A1Sim (SimConfig, SensorNoise)."""

    clock_mode: str = setting("lockstep", "lockstep: each step waits for its /motor_command | realtime: wall clock")
    command_timeout: float = setting(0.05, "no valid /motor_command for this long -> damping [s]")
    lockstep_timeout: float = setting(0.5, "lockstep: wall time to wait for a step's /motor_command [s]")
    real_time_factor: float = setting(1.0, "realtime: sim seconds per wall second")
    clock_period: float = setting(0.01, "publish /clock once per this much sim time [s], a multiple of time_step")
    publish_ground_truth: bool = setting(True, "publish the true base state on /sim/ground_truth/odom")
    flight_recorder_dir: str = setting("", "write the last seconds before a fall here as .npz ('': off)")
    flight_recorder_seconds: float = setting(5.0, "seconds the flight recorder keeps [s]")
    fall_height: float = setting(FALL_HEIGHT, "base height under which the robot has fallen [m]")
    start_paused: bool = setting(False, "hold t = 0 until ~/pause false (lets a watcher subscribe first)")


NODE_PARAMETERS = parameter_defaults(NodeParameters())


class SimBridgeNode(Node):
    def __init__(self, *, own_thread: bool = True, **node_kwargs) -> None:
        """``node_kwargs`` go to rclpy's Node (tests pass ``context`` and ``parameter_overrides``).

        ``own_thread``: the simulation steps in a thread of its own (a node alone in its process);
        False: in the executor's thread, through ``poll`` (a composed process: no second Python
        thread contends for the GIL inside the 2 ms step)."""
        super().__init__("sim_bridge", **node_kwargs)
        with recording_constraints() as constraints:
            params = declare_settings(self, SimConfig(), SensorNoise(), NodeParameters())
            self.clock_mode = require_choice("clock_mode", params["clock_mode"], CLOCK_MODES)
            self.sim = A1Sim(SimConfig.from_parameters(params, ignore=tuple(NODE_PARAMETERS)))
            self.watchdog = CommandWatchdog(params["command_timeout"])
            self.lockstep_timeout = require_range("lockstep_timeout", params["lockstep_timeout"], 0.0, 10.0,
                                                  low_open=True)
            # realtime: sim seconds per wall second. Under 1 a computer too slow for the graph at full
            # speed still runs it with every deadline scaled alike (commands are stamped in sim time).
            self.real_time_factor = require_range("real_time_factor", params["real_time_factor"], 0.0, 1.0,
                                                  low_open=True)
            self.clock_gate = ClockGate(require_clock_period(params["clock_period"], self.sim.config.time_step))
            self.publish_ground_truth = bool(params["publish_ground_truth"])
            # Flight recorder (off with no directory): the last seconds before a fall, as an .npz.
            self.recorder_dir = str(params["flight_recorder_dir"])
            recorder_seconds = require_seconds(params["flight_recorder_seconds"])  # checked even while off
            self.recorder = (FlightRecorder(recorder_seconds, self.sim.config.time_step)
                             if self.recorder_dir else None)
            self.fall_height = require_range("fall_height", params["fall_height"], 0.0, 1.0)
        constrain_parameters(self, params, constraints, runtime=RUNTIME_PARAMETERS)
        self._recorded_stamp_ns = -1
        self._fall_recorded = False  # one file per fall: re-armed when the base is up again, or on reset
        self._applied_damping = False
        self._commanded_damping = False  # the damping applied is the controller's command, not the watchdog's
        self._damping_began_upright: bool | None = None  # of the commanded damping in force; None: none
        self._applied_stamp_ns = -1  # stamp of the command applied in the last step (-1: none yet)
        self.dt_ns = round(self.sim.config.time_step * 1e9)
        self.joint_names = list(self.sim.robot.joint_names)
        self.encoders = wire.SensorEncoders(self.joint_names, BASE_FRAME, IMU_FRAME)

        self.pub_joints = self.create_publisher(JointState, contract.JOINT_STATES, CONTROL_QOS)
        self.pub_imu = self.create_publisher(Imu, contract.IMU, CONTROL_QOS)
        self.pub_contacts = self.create_publisher(FootContacts, contract.FOOT_CONTACTS, CONTROL_QOS)
        self.pub_clock = self.create_publisher(Clock, contract.CLOCK, CONTROL_QOS)
        self.pub_truth = self.create_publisher(Odometry, contract.GROUND_TRUTH, CONTROL_QOS)
        self._truth_encoder = wire.OdometryEncoder()  # 500 Hz, as bytes like the sensors
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.DIAGNOSTICS_QOS)
        # The URDF, once, latched (what robot_state_publisher and RViz read); its joints are /joint_states'.
        self.pub_description = self.create_publisher(String, contract.ROBOT_DESCRIPTION, LATCHED_QOS)
        self.pub_description.publish(String(data=robot_description()))
        self.create_subscription(MotorCommand, contract.MOTOR_COMMAND, self._on_command, CONTROL_QOS, raw=True)
        self.create_service(Trigger, "~/reset", self._on_reset)
        self.create_service(SetBool, "~/pause", self._on_pause)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(1.0, self._publish_diagnostics)

        self._lock = threading.Condition()
        self._pending_stamp_ns = -1  # lockstep: stamp of the command received for the current step
        self._late_commands = 0
        self._lockstep_timeouts = 0
        self._paused = bool(params["start_paused"])
        self._reset_requested = False
        self._running = True
        self._published = 0
        self._rate_window = (time.monotonic(), 0)
        self._achieved_rate = 0.0
        self._overruns = 0
        # Steps applied with no command accepted since the step before (missed deadlines), and the
        # sensor-to-command latency as the robot sees it, over the last /diagnostics period.
        self.deadlines = DeadlineMonitor(self.sim.config.time_step)
        self._lowest_base_height = float("inf")  # [m] since the last /diagnostics
        # Each step's sensors: when they went out (monotonic [s], for the latency of the command stamped
        # with them) and the deadline of the step that is to apply that command (system clock [ns]).
        self._published_at: collections.OrderedDict[int, tuple[float, float]] = collections.OrderedDict()
        self.failure: Exception | None = None
        self.own_thread = own_thread  # False: stepped by poll, in the caller's (the executor's) thread
        self._thread = threading.Thread(target=self._loop, name="sim_loop", daemon=True) if own_thread else None
        self._period = self.sim.config.time_step / self.real_time_factor  # realtime pacing, wall seconds
        self._next_deadline: float | None = None  # poll: monotonic time of the next step (None: not begun)
        self._waiting_since = 0.0  # poll, lockstep: when the current step's sensors went out
        # poll, realtime in the executor's thread: the deadline at which poll last let the executor
        # take what was published before stepping (see poll)
        self._drained_for: float | None = None
        self._command_late = False  # realtime: the newest command was sent after the deadline it was for
        # realtime: (stamp, sent [ns]) of a command handed over before its deadline was settled (_take)
        self._answered_before_deadline: tuple[int, int] | None = None
        self._taken_raw: bytes | None = None  # the last command handed over in-process (take_command)
        # Composed with its controller in one process (a1_bringup.control_chain): each step's sensor
        # messages (IMU, contacts, joint states, as bytes) handed over as they are published.
        self.sensor_sinks: list[Callable[[bytes, bytes, bytes], None]] = []
        self.get_logger().info(
            f"A1 sim ready: world={self.sim.config.world} clock_mode={self.clock_mode} "
            f"dt={self.sim.config.time_step}s command_timeout={self.watchdog.timeout}s "
            f"({'own thread' if own_thread else 'stepped by the executor'})")
        if self._thread is not None:
            self._thread.start()

    # --- callbacks (executor thread) ---------------------------------------------------------
    def take_command(self, raw: bytes) -> None:
        """A /motor_command's CDR bytes handed over by a controller in this process as it sends
        them (a1_bringup.control_chain): taken at once, not after the executor's next wait. The
        copy that then comes over the wire is dropped (_on_command), whatever became of this one."""
        self._taken_raw = raw
        self._take(raw, time.time_ns())

    def _on_command(self, raw: bytes, info: dict) -> None:
        """A /motor_command off the wire as its CDR bytes (see wire.py: this runs 500 times a
        second), and its DDS message info (the source timestamp: when it was sent)."""
        if raw != self._taken_raw:
            self._take(raw, info["source_timestamp"])

    def _take(self, raw: bytes, sent_ns: int) -> None:
        """One command, sent at ``sent_ns`` (system clock [ns]): rejected, stale or accepted."""
        with self._lock:
            # Invalid commands are rejected (and counted) whatever their stamp.
            command, stamp_ns = wire.decode_motor_command(raw)
            valid = self.watchdog.check(command)
            if valid is None:
                self.get_logger().warning(f"rejected /motor_command: {self.watchdog.last_error}",
                                          throttle_duration_sec=1.0)
                return
            published = self._published_at.pop(stamp_ns, None)  # the first command for a step counts
            if published is not None:
                self.deadlines.latency(time.monotonic() - published[0])
            now_ns = self.sim.steps * self.dt_ns
            if self.clock_mode == "lockstep":
                stale = stamp_ns != now_ns  # stamped for another step: not for this one
            else:  # realtime: the latest command counts, unless its stamp is far from now (pre-reset)
                # or older than the one in force (never an older step's answer over a newer one's)
                stale = abs(stamp_ns - now_ns) * 1e-9 > self.watchdog.timeout or stamp_ns < self._pending_stamp_ns
            if stale:
                self._late_commands += 1
                return
            self.watchdog.accept(valid, self.sim.time)
            self._pending_stamp_ns = stamp_ns
            if published is not None and math.isinf(published[1]):
                # Handed over within the poll that published its sensors (sensor_sinks): the deadline
                # of the step that applies it is settled when that poll ends (_set_answer_deadline).
                self._answered_before_deadline = (stamp_ns, sent_ns)
            elif published is not None:  # sent after the step that was to apply it was due?
                self._command_late = sent_ns > published[1]
            self._lock.notify_all()

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self._lock:
            self._reset_requested = True
            self._lock.notify_all()
        response.success = True
        response.message = f"reset requested (world={self.get_parameter('world').value})"
        return response

    def _on_pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        with self._lock:
            self._paused = bool(request.data)
            self._lock.notify_all()
            now = self.sim.time  # no step happens while paused: the time the pause holds at [s]
        response.success = True
        response.message = f"paused at {now:.6f} s" if request.data else f"running from {now:.6f} s"
        return response

    def _on_set_parameters(self, params) -> SetParametersResult:
        """Validate runtime changes (world, seed: applied at the next ~/reset; the other parameters
        are read-only descriptors, refused by rclpy)."""
        for param in params:
            if param.name not in RUNTIME_PARAMETERS:
                continue
            try:
                value = coerce_parameter(param.name, param.value, getattr(self.sim.config, param.name))
                dataclasses.replace(self.sim.config, **{param.name: value}).validated()
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    # --- simulation loop (own thread) --------------------------------------------------------
    def _loop(self) -> None:
        """``poll`` in a thread of its own, so that both forms step by the same rules: between calls
        it waits on the lock (this step's command, a reset, a pause or unpause, or shutdown ends the
        wait early) or, in realtime, sleeps to the next deadline."""
        try:
            while self._running and rclpy.ok(context=self.context):
                wait = self.poll()
                if wait <= 0.0:
                    continue
                if self.clock_mode == "realtime" and not self._paused:
                    time.sleep(wait)
                    continue
                with self._lock:
                    self._lock.wait_for(functools.partial(self._poll_due, self._paused), timeout=wait)
        except Exception as exc:  # a dead sim loop must be loud, never silent
            if not rclpy.ok(context=self.context):
                return  # shutting down (Ctrl-C): publishers are gone, nothing is lost
            self.get_logger().fatal(f"simulation loop failed, stopping the node: {exc!r}\n"
                                    f"{traceback.format_exc()}")
            self.failure = exc
            self.context.try_shutdown()  # ends spin() in main(), which exits non-zero

    def _poll_due(self, paused: bool) -> bool:
        """Own thread's wake-up condition (lock held), ``paused`` as the wait began: poll has something
        to do before the wait ends (a pause or unpause, a reset, shutdown, or this step's command)."""
        return (self._paused != paused or self._reset_requested or not self._running
                or (not self._paused and self._lockstep_ready()))

    def _advance(self):
        """One 2 ms step with the command in force (lock held); its sensor readings."""
        late, self._command_late = self._command_late, False
        if self.watchdog.accepted_since_reset == 0:
            # Nobody has commanded this run yet (start-up, discovery): hold the sim in its start pose
            # and offer the sensors again, so every run starts alike (a robot left in damping while
            # its controller starts folds to the ground).
            return self.sim.sensors()
        command = self.watchdog.active(self.sim.time)
        self._applied_damping = command.mode == MotorMode.DAMPING
        self._commanded_damping = self._applied_damping and not self.watchdog.in_fallback
        self._applied_stamp_ns = self._pending_stamp_ns
        # A missed 2 ms deadline: nothing new to apply, or a command sent only after the deadline
        self.deadlines.count(self.watchdog.accepted, late=late)
        return self.sim.step(command)

    def poll(self) -> float:
        """The simulation loop without its thread (``own_thread=False``), called by the executor's
        thread between waits (and by ``_loop`` in the node's own thread): does what is due now (a
        reset, a step) and returns how long the caller may wait before calling again [s]. Lockstep
        steps once the step's command is in or ``lockstep_timeout`` passed; realtime on the wall
        clock's deadlines."""
        now = time.monotonic()
        with self._lock:
            if self._next_deadline is None:  # the first call: the start pose's sensors go out
                readings = self.sim.sensors()
            elif self._reset_requested:
                self._do_reset()  # publishes the new run's sensors; the new run's time starts after it
                self._next_deadline = self._waiting_since = time.monotonic()
                self._set_answer_deadline(self._next_deadline)
                return 0.0
            elif self._paused:
                self._next_deadline = self._waiting_since = now
                return 0.05
            elif self.clock_mode == "lockstep":
                if not self._lockstep_ready():
                    remaining = self._waiting_since + self.lockstep_timeout - now
                    if remaining > 0.0:
                        return remaining
                    self._lockstep_timeouts += 1
                readings = self._advance()
            elif now < self._next_deadline:
                return self._next_deadline - now
            elif (self._thread is None and self._drained_for != self._next_deadline
                  and self._pending_stamp_ns != self.sim.steps * self.dt_ns):
                # Due, and this step's command is not in, but in one thread with the controller it
                # may be published and not yet taken: the controller's work after the command (the
                # filter update, /odom) can run past the deadline. One wait that does not block
                # first (return 0), so the step applies that command instead of the previous one;
                # one sent after the deadline still counts as a missed deadline (_take, _advance).
                self._drained_for = self._next_deadline
                return 0.0
            else:
                readings = self._advance()
        self._publish(readings)
        if self._next_deadline is None:
            self._next_deadline = now
        self._next_deadline += self._period
        after = time.monotonic()
        self._waiting_since = after
        skipped = 0
        if self.clock_mode == "realtime" and after > self._next_deadline:
            self._overruns += 1
            if after - self._next_deadline > 0.1:  # far behind (e.g. suspended): do not try to catch up
                if self.watchdog.accepted_since_reset:  # (before any command no step is counted either)
                    skipped = int((after - self._next_deadline) / self._period)
                self._next_deadline = after
        if self.clock_mode == "lockstep":
            return 0.0
        with self._lock:
            # The periods skipped were deadlines the robot passed with no new command: in one
            # process with the controller, a stall of both shows only here.
            if skipped:
                self.deadlines.skipped(skipped)
            self._set_answer_deadline(after)
        return max(0.0, self._next_deadline - after)

    def _set_answer_deadline(self, now: float) -> None:
        """Realtime (lock held): the deadline of the step that applies the answer to the sensors just
        published, ``now`` being monotonic time, kept on the system clock of DDS source timestamps
        [ns]. Set once poll has settled it (a catch-up or a reset moves it); until then none."""
        if self.clock_mode != "realtime":  # (a reset in lockstep: no deadline)
            return
        stamp_ns = self.sim.steps * self.dt_ns
        deadline_ns = time.time_ns() + round((self._next_deadline - now) * 1e9)
        published = self._published_at.get(stamp_ns)
        if published is not None:
            self._published_at[stamp_ns] = (published[0], deadline_ns)
        elif self._answered_before_deadline is not None and self._answered_before_deadline[0] == stamp_ns:
            self._command_late = self._answered_before_deadline[1] > deadline_ns
        self._answered_before_deadline = None

    def _lockstep_ready(self) -> bool:
        """Lockstep wait condition (lock held): this step's command arrived, or stop/reset."""
        current_ns = self.sim.steps * self.dt_ns
        return (self._pending_stamp_ns == current_ns or self._reset_requested or self._paused
                or not self._running)

    def _do_reset(self) -> None:
        world = coerce_parameter("world", self.get_parameter("world").value, "")
        seed = coerce_parameter("seed", self.get_parameter("seed").value, 0)
        readings = self.sim.reset(world=world, seed=seed)
        self.watchdog.clear_command()
        self._applied_damping = self._commanded_damping = False
        self._pending_stamp_ns = self._applied_stamp_ns = -1
        self._taken_raw = None
        self._answered_before_deadline = None
        self._published_at.clear()
        self._lowest_base_height = float("inf")  # a fall before the reset is not this run's
        if self.recorder is not None:
            self.recorder.clear()
            self._fall_recorded = False
            self._damping_began_upright = None
            self._recorded_stamp_ns = -1
        self._reset_requested = False
        self.get_logger().info(f"simulation reset: world={world} seed={seed}")
        self._publish(readings)

    def _publish(self, readings) -> None:
        """This step's messages: the controller's sensors first (the time from the step to the last of
        them counts against a realtime controller's 2 ms), handed to ``sensor_sinks`` (composed: the
        controller's whole step runs here), then /clock and the ground truth, only when someone
        listens: at 500 Hz every message costs CPU a small computer does not have."""
        stamp_ns = self.sim.steps * self.dt_ns
        joints, imu, contacts = self.encoders.encode(readings, stamp_ns)  # as bytes: see wire.py
        self.pub_imu.publish(imu)
        self.pub_contacts.publish(contacts)
        # Joint states last: in lockstep a controller may take it as "this step's sensors are out".
        with self._lock:  # before publishing: a fast answer must find its step
            # (the answer's deadline: none yet; realtime poll sets it, lockstep waits for the answer)
            self._published_at[stamp_ns] = (time.monotonic(), math.inf)
            while len(self._published_at) > 50:  # 0.1 s: an answer later than that is no answer
                self._published_at.popitem(last=False)
        self.pub_joints.publish(joints)
        self._published += 1
        for sink in self.sensor_sinks:  # in this thread: a composed controller's step runs here
            sink(imu, contacts, joints)
        if self.pub_clock.get_subscription_count() and self.clock_gate.due(stamp_ns):
            self.pub_clock.publish(Clock(clock=cv.stamp_from_ns(stamp_ns)))
        if self.publish_ground_truth or self.recorder is not None:
            truth = self.sim.ground_truth()
            if self.recorder is not None and stamp_ns != self._recorded_stamp_ns:  # steps, not re-offers
                self._recorded_stamp_ns = stamp_ns
                self._record(readings, truth, stamp_ns)
        if self.publish_ground_truth:
            with self._lock:
                self._lowest_base_height = min(self._lowest_base_height, float(truth.base_position[2]))
            if self.pub_truth.get_subscription_count():
                self.pub_truth.publish(self._truth_encoder.encode(wire.ground_truth_odometry(truth, stamp_ns)))

    def _record(self, readings, truth, stamp_ns: int) -> None:
        """One step into the flight recorder; on a fall, its window to ``flight_recorder_dir``."""
        age = (stamp_ns - self._applied_stamp_ns) * 1e-9 if self._applied_stamp_ns >= 0 else math.nan
        self.recorder.record(
            time_s=truth.time, base_position_m=truth.base_position, base_orientation_xyzw=truth.base_orientation,
            base_velocity_body_mps=truth.base_linear_velocity_body,
            base_angular_velocity_body_radps=truth.base_angular_velocity_body,
            foot_contact=readings.foot_contact, joint_position_rad=readings.joint_position,
            joint_torque_nm=readings.joint_torque, command_age_s=age, damping=self._applied_damping,
            commanded_damping=self._commanded_damping)
        height = float(truth.base_position[2])
        if not self._commanded_damping:
            self._damping_began_upright = None
        elif self._damping_began_upright is None:
            x, y = truth.base_orientation[:2]
            tilt = math.acos(min(1.0, max(-1.0, 1.0 - 2.0 * (x * x + y * y))))
            self._damping_began_upright = tilt < UPRIGHT_TILT and height > self.fall_height + 0.05
        if height < self.fall_height and not self._fall_recorded:
            self._fall_recorded = True
            # Lying down under a damping the controller chose while the robot stood is not a fall.
            commanded = bool(self._damping_began_upright)
            what = "damped" if commanded else "fall"
            path = Path(self.recorder_dir) / f"{what}_{time.strftime('%Y%m%d_%H%M%S')}_t{truth.time:.3f}s.npz"
            log = self.get_logger().warning if commanded else self.get_logger().error
            cause = ("base lowered under commanded damping (e-stop or mode damping), not a fall" if commanded
                     else "fall")
            try:
                self.recorder.save(path)
                log(f"{cause} (base {height:.3f} m < fall_height {self.fall_height} m) at "
                    f"t={truth.time:.3f} s; flight recorder: {path}")
            except OSError as exc:
                log(f"{cause} at t={truth.time:.3f} s; flight recorder not written: {exc}")
        elif height > self.fall_height + 0.05:
            self._fall_recorded = False

    def _publish_diagnostics(self) -> None:
        with self._lock:  # the totals with the window: a skip lands wholly in one report
            window = self.deadlines.window()
            missed, periods = self.deadlines.uncommanded, self.deadlines.periods
            lowest, self._lowest_base_height = self._lowest_base_height, float("inf")
        now = time.monotonic()
        t0, n0 = self._rate_window
        self._achieved_rate = (self._published - n0) / max(now - t0, 1e-9)
        self._rate_window = (now, self._published)
        wd = self.watchdog
        status = DiagnosticStatus(name="a1_sim_bridge", hardware_id="a1_sim")
        base_z = float(self.sim.base_position[2])
        if base_z < LEFT_WORLD_HEIGHT:
            status.level = DiagnosticStatus.ERROR
            status.message = f"the base left the world: z = {base_z:.1f} m (reset the simulation)"
            self.get_logger().error(status.message, throttle_duration_sec=10.0)
        elif wd.in_fallback:
            status.level = DiagnosticStatus.WARN
            status.message = "damping: no valid /motor_command"
        else:
            status.level = DiagnosticStatus.OK
            status.message = "commanded"
        values = {
            "clock_mode": self.clock_mode, "world": self.sim.config.world,
            "sim_time_s": f"{self.sim.time:.3f}",
            "steps": self.sim.steps, "publish_rate_hz": f"{self._achieved_rate:.1f}",
            "commands_accepted": wd.accepted, "commands_rejected": wd.rejected,
            "last_rejection": wd.last_error, "damping_fallbacks": wd.timeouts,
            "last_command_received_s": f"{wd.received_at:.3f}" if math.isfinite(wd.received_at) else "none",
            "late_commands": self._late_commands, "lockstep_timeouts": self._lockstep_timeouts,
            "realtime_overruns": self._overruns, "paused": self._paused,
            "uncommanded_steps": missed, "deadline_periods": periods, **window,
            "lowest_base_height_m": f"{lowest:.3f}" if self.publish_ground_truth else "n/a",
            "base_height_m": f"{base_z:.3f}",
        }
        self.pub_diag.publish(diagnostic_array(self, status, values, cv.stamp_from_ns(self.sim.steps * self.dt_ns)))

    def shutdown(self) -> None:
        with self._lock:
            self._running = False
            self._lock.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._thread is not None and self._thread.is_alive():  # never pull PyBullet from under a step
            self.get_logger().error("simulation thread did not stop within 2 s; leaving PyBullet open")
        else:
            self.sim.close()


def main(args: list[str] | None = None) -> None:
    run_node("sim_bridge", SimBridgeNode, args)


if __name__ == "__main__":
    main()
