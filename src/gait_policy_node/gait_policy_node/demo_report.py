"""demo_report: watch a running graph, then summarise the run and draw its gait diagram.

Records /gait/state, /joint_states, /cmd_vel and the sim's /sim/ground_truth/odom for ``duration``
seconds of sensor time, then prints per speed band: commanded and actual speed, tracking error,
the gait used (walk / trot / fly trot from phase offsets and swing ratio), power and cost of
transport; plus distance, falls and the controller's missed deadlines. Writes a PNG like the
paper's acceleration figure: contacts per leg over time with speed, frequency and swing ratio.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from a1_common.config import require_range
from a1_common.node_support import declare_parameters, run_node
from a1_sim_bridge.conversions import ns_from_stamp
from a1_sim_bridge.node import CONTROL_QOS
from convex_mpc_node.energy import cost_of_transport, motor_power
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from gait_msgs.msg import GaitState

BANDS = ((0.0, 0.8), (0.8, 1.5), (1.5, 2.0), (2.0, 3.01))  # commanded forward speed [m/s]
LEGS = ("FR", "FL", "RR", "RL")


def classify_gait(swing_ratio: float, offsets: np.ndarray) -> str:
    """walk / trot / fly trot / other, from the paper's parameterisation."""
    wrapped = np.angle(np.exp(1j * (np.asarray(offsets) - np.array([0, math.pi, math.pi, 0]))))
    trot_like = np.all(np.abs(wrapped) < 0.3)
    if trot_like:
        return "fly trot" if swing_ratio > 0.52 else "trot"
    return "walk" if swing_ratio < 0.45 else "other"


class DemoReportNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("demo_report", **node_kwargs)
        p = declare_parameters(self, {"duration": 20.0, "output": "log/demo/gait_diagram.png", "mass": 12.458})
        self.duration = require_range("duration", p["duration"], 0.1, 3600.0)
        self.output = Path(p["output"])
        self.mass = require_range("mass", p["mass"], 1.0, 100.0)
        self.rows: list[tuple] = []
        self.truth: Odometry | None = None
        self.joints: JointState | None = None
        self.cmd = np.zeros(3)
        self.missed = "n/a"
        self.first_ns: int | None = None
        self.create_subscription(GaitState, "/gait/state", self._on_state, CONTROL_QOS)
        self.create_subscription(Odometry, "/sim/ground_truth/odom", lambda m: setattr(self, "truth", m), CONTROL_QOS)
        self.create_subscription(JointState, "/joint_states", lambda m: setattr(self, "joints", m), CONTROL_QOS)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(Twist, "/cmd_vel", self._on_cmd, reliable)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)

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
            self.first_ns = now
        t = (now - self.first_ns) * 1e-9
        pos = self.truth.pose.pose.position
        power = float(motor_power(np.asarray(self.joints.effort), np.asarray(self.joints.velocity)).sum())
        self.rows.append((t, self.cmd[0], self.truth.twist.twist.linear.x, pos.x, pos.y, pos.z, power,
                          msg.params.stepping_frequency, msg.params.swing_ratio, *msg.params.phase_offsets,
                          *[bool(c) for c in msg.desired_contact], *[s != GaitState.LEG_SWING for s in msg.leg_states]))
        if t >= self.duration:
            self.finish()
            self.context.try_shutdown()

    def finish(self) -> None:
        data = np.array(self.rows, dtype=float)
        t, cmd, v, x, y, z, power, freq, swing = (data[:, i] for i in range(9))
        offsets = data[:, 9:13]
        contact = data[:, 17:21] > 0.5
        print(f"\n=== demo summary: {t[-1]:.1f} s of sim time ===")
        print(f"distance {np.hypot(x[-1] - x[0], y[-1] - y[0]):.2f} m, mean speed {np.mean(v):.2f} m/s, "
              f"lowest base height {np.min(z):.3f} m ({'FELL' if np.min(z) < 0.18 else 'no fall'}), "
              f"controller steps over their 2 ms budget: {self.missed}")
        print(f"{'band [m/s]':<12}{'cmd':>6}{'actual':>8}{'err %':>7}  {'gait':<9}{'f Hz':>6}{'p_sw':>6}"
              f"{'power W':>9}{'CoT':>6}")
        moving = np.cumsum(cmd > 0) > 0  # from the first non-zero command on (skips the stand-up)
        for lo, hi in BANDS:
            sel = moving & (cmd >= lo) & (cmd < hi)
            if sel.sum() < 50:
                continue
            c, a = np.mean(cmd[sel]), np.mean(v[sel])
            err = 100 * np.mean(np.abs(v[sel] - cmd[sel])) / max(c, 0.3)
            gaits = [classify_gait(s, o) for s, o in zip(swing[sel][::25], offsets[sel][::25], strict=True)]
            gait = max(set(gaits), key=gaits.count)
            cot = cost_of_transport(np.mean(power[sel]), self.mass, a) if a > 0.1 else float("nan")
            print(f"{lo:>4.1f}-{min(hi, 3.0):<7.1f}{c:>6.2f}{a:>8.2f}{err:>7.1f}  {gait:<9}{np.mean(freq[sel]):>6.2f}"
                  f"{np.mean(swing[sel]):>6.2f}{np.mean(power[sel]):>9.1f}{cot:>6.2f}")
        self.plot(t, cmd, v, freq, swing, contact)

    def plot(self, t, cmd, v, freq, swing, contact) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(4, 1, figsize=(10, 7), sharex=True, gridspec_kw={"height_ratios": [2, 1.2, 1, 1]})
        for leg in range(4):
            on = contact[:, leg]
            edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(int), [0]])))
            spans = [(t[s], t[min(e, len(t) - 1)] - t[s]) for s, e in zip(edges[::2], edges[1::2], strict=True)]
            axes[0].broken_barh(spans, (3 - leg - 0.4, 0.8), color="tab:blue")
        axes[0].set_yticks(range(4), LEGS[::-1])
        axes[0].set_title("Foot contact (measured stance) during the run")
        axes[1].plot(t, cmd, label="commanded")
        axes[1].plot(t, v, label="actual (ground truth)", alpha=0.8)
        axes[1].set_ylabel("speed [m/s]")
        axes[1].legend(loc="upper left")
        axes[2].plot(t, freq, color="tab:green")
        axes[2].set_ylabel("f [Hz]")
        axes[3].plot(t, swing, color="tab:red")
        axes[3].set_ylabel("swing ratio")
        axes[3].set_xlabel("time [s]")
        fig.tight_layout()
        self.output.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(self.output, dpi=110)
        plt.close(fig)
        print(f"gait diagram written to {self.output.resolve()}")


def main(args: list[str] | None = None) -> None:
    run_node("demo_report", DemoReportNode, args)


if __name__ == "__main__":
    main()
