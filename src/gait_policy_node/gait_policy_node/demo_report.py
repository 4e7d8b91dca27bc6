"""demo_report: watch a running graph, then summarise the run and draw its gait diagram.

Records /gait/state, /joint_states, /cmd_vel and the sim's /sim/ground_truth/odom until ``duration``
seconds of sensor (sim) time, counted from 0, not from when it joined (start it before the graph;
with ``start_sim`` it unpauses a graph started paused once it hears every topic). Prints one line
per second of sim time while it runs (commanded and actual speed, gait, the controller's missed
deadlines), then per speed band: commanded and actual speed, tracking error, the gait used
(gait_analysis.classify_gait), power and cost of transport; plus distance, falls and the
controller's missed deadlines. Writes a PNG like the paper's acceleration figure: contacts per leg
over time with speed, frequency and swing ratio.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from a1_common.config import recording_constraints, require_range, setting
from a1_common.node_support import constrain_parameters, declare_settings, run_node
from a1_common.robot import FALL_HEIGHT
from a1_interface.contract import COMMAND_QOS, CONTROL_QOS
from a1_interface.conversions import ns_from_stamp
from convex_mpc_node.energy import motor_power
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

from a1_interface import contract
from gait_msgs.msg import GaitState
from gait_policy_node.gait_analysis import (
    classify_gait,
    format_band_table,
    plot_gait_diagram,
    summarise_bands,
    transition_speeds,
)


@dataclass(frozen=True)
class NodeParameters:
    duration: float = setting(20.0, "report after this much sim time [s]")
    output: str = setting("log/demo/gait_diagram.png", "where to write the gait diagram (PNG)")
    mass: float = setting(12.458, "robot mass in the reported cost of transport [kg]")
    start_sim: str = setting("", "a sim bridge's std_srvs/SetBool pause service (sim_bridge/pause) to call "
                                 "with false once every recorded topic has a publisher ('': none)")


PARAMETERS = NodeParameters()


class DemoReportNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("demo_report", **node_kwargs)
        with recording_constraints() as constraints:
            p = declare_settings(self, PARAMETERS)
            self.duration = require_range("duration", p["duration"], 0.1, 3600.0)
            self.output = Path(p["output"])
            self.mass = require_range("mass", p["mass"], 1.0, 100.0)
        constrain_parameters(self, p, constraints)  # all read-only: read at start-up
        self.rows: list[tuple] = []
        self.truth: Odometry | None = None
        self.joints: JointState | None = None
        self.cmd = np.zeros(3)
        self.missed = "n/a"
        self.first_ns: int | None = None
        self.first_wall = 0.0  # [s] monotonic wall time of the first sample: the run's pace
        self.next_line = 0.0  # [s] of sim time: when the next progress line is due
        self._recorded = [  # what the summary is made of: the sim starts once each has a publisher
            self.create_subscription(GaitState, contract.GAIT_STATE, self._on_state, CONTROL_QOS),
            self.create_subscription(Odometry, contract.GROUND_TRUTH, lambda m: setattr(self, "truth", m), CONTROL_QOS),
            self.create_subscription(JointState, contract.JOINT_STATES, lambda m: setattr(self, "joints", m),
                                     CONTROL_QOS),
            self.create_subscription(Twist, contract.CMD_VEL, self._on_cmd, COMMAND_QOS)]
        self.create_subscription(DiagnosticArray, contract.DIAGNOSTICS, self._on_diag, 10)
        # A graph started paused (the sim bridge's start_paused) runs once this node hears it all: a
        # busy lockstep graph can take seconds to match a new subscriber, and the report must see t = 0.
        self.start_sim = self.create_client(SetBool, p["start_sim"]) if p["start_sim"] else None
        self._start_request: tuple[Future, float] | None = None  # (reply, monotonic time sent)
        self._waited = 0  # start-sim checks so far (10 a second)
        # On the wall clock: the sim time (use_sim_time) stands still until the sim is started.
        wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._start_timer = self.create_timer(0.1, self._start_when_heard, clock=wall) if self.start_sim else None

    def _start_when_heard(self) -> None:
        """Unpause the sim once each recorded subscription has a matched publisher; asked again if no
        successful reply comes within 2 s (a lost request must not leave the graph paused)."""
        if self._start_request is not None:
            reply, sent = self._start_request
            if reply.done() and reply.result() is not None and reply.result().success:
                self._start_timer.cancel()
                print(f"[demo_report] every topic has a publisher: started the simulation "
                      f"({self.start_sim.srv_name}: {reply.result().message})", flush=True)
                return
            if not reply.done() and time.monotonic() - sent < 2.0:
                return
        silent = [sub.topic_name for sub in self._recorded if sub.get_publisher_count() == 0]
        if silent or not self.start_sim.service_is_ready():
            self._waited += 1
            if self._waited % 100 == 0:
                waiting = silent or [f"service {self.start_sim.srv_name}"]
                self.get_logger().warning(f"still waiting for {waiting} before starting the simulation")
            return
        self._start_request = (self.start_sim.call_async(SetBool.Request(data=False)), time.monotonic())

    def _on_cmd(self, msg: Twist) -> None:
        self.cmd = np.array([msg.linear.x, msg.linear.y, msg.angular.z])

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == "convex_mpc":
                self.missed = next((kv.value for kv in status.values if kv.key == "missed_deadlines"), self.missed)

    def _on_state(self, msg: GaitState) -> None:
        if self.truth is None or self.joints is None:
            return
        now = ns_from_stamp(msg.header.stamp)
        if self.first_ns is None:
            self.first_ns, self.first_wall = now, time.monotonic()
            self.next_line = math.floor(now * 1e-9)
            if now * 1e-9 > 0.5:
                print(f"[demo_report] WARNING: first sample at t = {now * 1e-9:.1f} s of sim time: the summary "
                      "misses the start of the run (its topics were matched late)", flush=True)
        t = now * 1e-9  # [s] sim time
        pos = self.truth.pose.pose.position
        power = float(motor_power(np.asarray(self.joints.effort), np.asarray(self.joints.velocity)).sum())
        self.rows.append((t, self.cmd[0], self.truth.twist.twist.linear.x, pos.x, pos.y, pos.z, power,
                          msg.params.stepping_frequency, msg.params.swing_ratio, *msg.params.phase_offsets,
                          *[bool(c) for c in msg.desired_contact], *[s != GaitState.LEG_SWING for s in msg.leg_states]))
        if t >= self.next_line:
            self.next_line += 1.0
            gait = classify_gait(msg.params.swing_ratio, tuple(msg.params.phase_offsets))
            print(f"t {t:5.1f} s  command {self.cmd[0]:4.2f} m/s  actual {self.truth.twist.twist.linear.x:5.2f} m/s  "
                  f"{gait:<8} f {msg.params.stepping_frequency:.2f} Hz  p_swing {msg.params.swing_ratio:.2f}  "
                  f"base {pos.z:.2f} m  missed deadlines {self.missed}", flush=True)
        if t >= self.duration:
            self.finish()
            self.context.try_shutdown()

    def finish(self) -> None:
        data = np.array(self.rows, dtype=float)
        t, cmd, v, x, y, z, power, freq, swing = (data[:, i] for i in range(9))
        wall = time.monotonic() - self.first_wall
        print(f"\n=== demo summary: {t[-1] - t[0]:.1f} s of sim time in {wall:.1f} s of wall time "
              f"({(t[-1] - t[0]) / wall:.2f}x real time) ===")
        print(f"distance {np.hypot(x[-1] - x[0], y[-1] - y[0]):.2f} m, mean speed {np.mean(v):.2f} m/s, "
              f"lowest base height {np.min(z):.3f} m ({'FELL' if np.min(z) < FALL_HEIGHT else 'no fall'}), "
              f"controller steps over their 2 ms budget: {self.missed}")
        series = {"time": t, "desired_speed": cmd, "speed": v, "power": power, "frequency": freq,
                  "swing_ratio": swing, "phase_offsets": data[:, 9:13], "contacts": data[:, 17:21] > 0.5}
        moving = np.cumsum(cmd > 0) > 0  # from the first non-zero command on (skips the stand-up)
        in_motion = {k: np.asarray(a)[moving] for k, a in series.items()}
        print(format_band_table(summarise_bands(in_motion, self.mass, gravity=9.81)))
        changes = transition_speeds(in_motion)
        print("gait transitions: " + (", ".join(f"{a} -> {b} at {s:.2f} m/s" for s, a, b in changes) or "none"))
        path = plot_gait_diagram(self.output, series, "Foot contact (measured stance) during the run")
        print(f"gait diagram written to {path.resolve()}")


def main(args: list[str] | None = None) -> None:
    run_node("demo_report", DemoReportNode, args)


if __name__ == "__main__":
    main()
