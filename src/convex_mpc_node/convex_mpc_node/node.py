"""convex_mpc node: the 500 Hz locomotion controller behind the robot's contract.

Runs one control step per sensor step: when /odom (the estimator's output, computed from the
joint state stamped t_k) arrives and the joint state, IMU and contacts of t_k are in, it publishes
/motor_command stamped t_k (what the sim bridge's lockstep mode waits for) and /gait/state. If
/odom goes stale, each /joint_states triggers a safe-stance step instead (see supervisor.py). With
no /joint_states there is nothing to command: the bridge's own watchdog damps the motors, and
/diagnostics here says the sensors are missing.

Inputs: /cmd_vel (geometry_msgs/Twist, or TwistStamped with ``cmd_vel_stamped``), /gait/params,
/joint_states, /imu/data, /foot_contacts (composed with the sim bridge and the estimator embedded,
handed over in the process instead: a1_bringup.control_chain), /odom; /estop (std_msgs/Bool, true latches damping) and
~/clear_estop (std_srvs/Trigger). Runtime parameters: ``mode`` (stand | walk | damping) and, for
fault-injection tests, ``inject_qp_failures`` (setting N makes the MPC fail for the next N control steps).

With ``embedded_estimator`` the node runs the state estimator's core itself (parameters from
config/state_estimator.yaml) as soon as a step's three sensor messages are in, and publishes /odom
for the other nodes: one process and one message hop less for realtime graphs on small computers;
the state_estimator node is then not started. With ``estimate_after_command`` as well, each step is
controlled on the previous step's estimate and the filter is updated after the command is out.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from a1_common.config import (
    ConfigError,
    parameter_defaults,
    parameter_descriptions,
    recording_constraints,
    require_choice,
    require_integer,
    setting,
)
from a1_common.kinematics import quat_to_matrix
from a1_common.node_support import (
    coerce_parameter,
    constrain_parameters,
    declare_parameters,
    diagnostic_array,
    run_node,
)
from a1_interface.contract import COMMAND_QOS, CONTROL_QOS, ESTOP_QOS
from a1_interface.conversions import ns_from_stamp
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from state_estimator_node.estimator import load_estimator_config
from state_estimator_node.frontend import OdometryFrontend
from state_estimator_node.node import OdometryPublisher
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from a1_interface import contract, wire
from convex_mpc_node.controller import (
    LocomotionController,
    Observation,
    controller_config_from_parameters,
    controller_parameter_defaults,
    controller_parameter_descriptions,
)
from convex_mpc_node.energy import cost_of_transport, motor_power
from convex_mpc_node.gait import GaitParams, load_hand_tuned_gaits
from convex_mpc_node.stance import MAX_INJECTED_FAILURES
from convex_mpc_node.step_trigger import StepTrigger
from convex_mpc_node.supervisor import ControllerSupervisor, Mode, SupervisorConfig
from gait_msgs.msg import FootContacts, GaitState, MotorCommand
from gait_msgs.msg import GaitParams as GaitParamsMsg


@dataclass(frozen=True)
class NodeParameters:
    """The node's own parameters (the controller's and the supervisor's are their configs')."""

    cmd_vel_stamped: bool = setting(False, "read /cmd_vel as geometry_msgs/TwistStamped instead of Twist")
    mass_for_cot: float = setting(12.458, "robot mass in the reported cost of transport [kg]")
    embedded_estimator: bool = setting(False, "run the state estimator's core in this node and publish /odom")
    estimate_after_command: bool = setting(
        False, "embedded estimator: control on the previous step's estimate, update it after the command")
    estimator_failover: bool = setting(True, "/odom stale: controlled stop on a backup estimate, then safe stance")
    odom_every_steps: int = setting(1, "embedded estimator: publish /odom every N control steps")
    inject_qp_failures: int = setting(0, "fault injection: the next N MPC solves fail")


NODE_PARAMETERS = parameter_defaults(NodeParameters())
RUNTIME_PARAMETERS = ("mode", "inject_qp_failures")




class ConvexMpcNode(Node):
    def __init__(self, **node_kwargs) -> None:
        super().__init__("convex_mpc", **node_kwargs)
        controller_defaults = controller_parameter_defaults()
        supervisor_defaults = parameter_defaults(SupervisorConfig())
        descriptions = {**controller_parameter_descriptions(), **parameter_descriptions(SupervisorConfig()),
                        **parameter_descriptions(NodeParameters())}
        with recording_constraints() as constraints:
            params = declare_parameters(self, {**controller_defaults, **supervisor_defaults, **NODE_PARAMETERS},
                                        descriptions)
            controller_config = controller_config_from_parameters(
                {k: params[k] for k in controller_defaults}, source="parameters of convex_mpc")
            supervisor_config = SupervisorConfig(**{k: params[k] for k in supervisor_defaults}).validated()
            self.odom_every = require_integer("odom_every_steps", params["odom_every_steps"], 1, 500)
            gaits = load_hand_tuned_gaits()
            self.controller = LocomotionController(gaits["slow_trot"], controller_config)
            self.supervisor = ControllerSupervisor(self.controller, gaits, supervisor_config)
            self._inject_qp_failures(params["inject_qp_failures"])
        self.mass = float(params["mass_for_cot"])
        self.period = controller_config.control_period
        self._last_sensor_wall = float("-inf")
        self._solve_times: deque[float] = deque(maxlen=500)
        self._plan_delays: deque[float] = deque(maxlen=500)  # [s] solve hand-over to adoption, whole steps
        self._step_times: deque[float] = deque(maxlen=500)
        self._powers: deque[float] = deque(maxlen=500)
        self._speeds: deque[float] = deque(maxlen=500)
        self._missed = 0
        self._steps = 0
        self._state = "waiting"
        self.frontend = OdometryFrontend(load_estimator_config()) if params["embedded_estimator"] else None
        # Failover: with /odom stale, the estimator core here, started from the last /odom velocity,
        # carries the robot through a controlled stop (supervisor "stopping") before the safe stance.
        backup = (OdometryFrontend(load_estimator_config())
                  if params["estimator_failover"] and self.frontend is None else None)
        # Embedded, realtime (estimate_after_command): control on the estimate of the step before
        # (2 ms old) and update the filter after the motor command is out, off the command's path.
        self.trigger = StepTrigger(
            input_timeout=supervisor_config.input_timeout, frontend=self.frontend, backup=backup,
            estimate_after_command=bool(params["estimate_after_command"]), control=self._control,
            republish=self._republish, on_estimate=self._on_estimate, on_restart=self._on_sim_reset, log=self._log)
        self._last_command: bytes | None = None  # the last step's command (CDR, see a1_interface.wire)
        # Composed with its bridge in one process (a1_bringup.control_chain): the bridge takes each
        # command here at once, as well as from the wire (it drops that copy).
        self.command_sinks: list[Callable[[bytes], None]] = []
        self._command_encoder = wire.MotorCommandEncoder()

        self.pub_command = self.create_publisher(MotorCommand, contract.MOTOR_COMMAND, CONTROL_QOS)
        self.pub_state = self.create_publisher(GaitState, contract.GAIT_STATE, CONTROL_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, contract.DIAGNOSTICS, contract.DIAGNOSTICS_QOS)
        if params["cmd_vel_stamped"]:
            self.create_subscription(TwistStamped, contract.CMD_VEL, lambda m: self._on_cmd_vel(m.twist), COMMAND_QOS)
        else:
            self.create_subscription(Twist, contract.CMD_VEL, self._on_cmd_vel, COMMAND_QOS)
        self.create_subscription(GaitParamsMsg, contract.GAIT_PARAMS, self._on_gait_params, COMMAND_QOS)
        # The 500 Hz sensors arrive as bytes and are decoded to light views (a1_interface.wire); composed
        # with the sim bridge (a1_bringup.control_chain) it hands them over instead (self.sensors.take).
        self.sensors = wire.subscribe_sensors(self, CONTROL_QOS, on_joints=self._on_joints,
                                              on_imu=self.trigger.on_imu, on_contacts=self.trigger.on_contacts)
        if self.frontend is None:  # /odom as bytes, decoded to a light view (a1_interface.wire)
            wire.subscribe_odometry(self, CONTROL_QOS, self._on_odom)
        else:
            self.odom = OdometryPublisher(self)
        self.create_subscription(Bool, contract.ESTOP, self._on_estop, ESTOP_QOS)
        self.create_service(Trigger, "~/clear_estop", self._on_clear_estop)
        constrain_parameters(self, params, constraints, runtime=RUNTIME_PARAMETERS)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(1.0, self._publish_diagnostics)

    def shutdown(self) -> None:
        self.controller.close()

    # --- inputs --------------------------------------------------------------------------------
    def _now(self) -> float:
        return self.trigger.latest_stamp_ns() * 1e-9

    def _on_cmd_vel(self, twist: Twist) -> None:
        if not self.supervisor.on_cmd_vel(twist.linear.x, twist.linear.y, twist.angular.z, self._now()):
            self.get_logger().warning("rejected /cmd_vel with NaN/inf", throttle_duration_sec=1.0)

    def _on_gait_params(self, msg: GaitParamsMsg) -> None:
        params = GaitParams(msg.stepping_frequency, msg.swing_ratio, tuple(float(v) for v in msg.phase_offsets))
        if not self.supervisor.on_gait_params(params, self._now()):
            self.get_logger().warning(
                "rejected /gait/params: f must be in (0, 4] Hz, swing_ratio in (0, 1), phase offsets "
                f"in [0, 2pi) with FR = 0; got {params}", throttle_duration_sec=1.0)

    def _on_estop(self, msg: Bool) -> None:
        if msg.data and not self.supervisor.estopped:
            self.get_logger().error("E-STOP: motors in damping until ~/clear_estop")
            self.supervisor.estop()

    def _on_clear_estop(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.supervisor.clear_estop()
        response.success, response.message = True, "e-stop and fall cleared; standing up"
        return response

    def _validate_parameters(self, params) -> SetParametersResult:
        """on_set: check each runtime change of the batch (the other parameters are read-only
        descriptors, refused by rclpy). Nothing is applied here, so a batch with one bad value
        changes nothing."""
        for param in params:
            try:
                if param.name == "mode":
                    require_choice("mode", coerce_parameter("mode", param.value, ""), [m.value for m in Mode])
                elif param.name == "inject_qp_failures":
                    require_integer(param.name, coerce_parameter(param.name, param.value, 0), 0, MAX_INJECTED_FAILURES)
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params) -> None:
        """post_set: apply the batch rclpy has accepted."""
        for param in params:
            if param.name == "mode":
                self.supervisor.set_mode(param.value)
            elif param.name == "inject_qp_failures":
                self._inject_qp_failures(param.value)

    def _inject_qp_failures(self, count: int) -> None:
        """Fault injection: the MPC fails for the next ``count`` control steps (its fallback takes over)."""
        self.controller.inject_qp_failures(count)
        if count:
            self.get_logger().warning(f"fault injection: the MPC fails for the next {count} control steps")

    def _on_joints(self, msg: JointState) -> None:
        self._last_sensor_wall = time.monotonic()
        self.trigger.on_joints(msg)

    def _on_odom(self, msg: Odometry | wire.OdometryView) -> None:
        """/odom's twist is in base_link: rotated to the world frame [m/s] for the trigger."""
        q, tw = msg.pose.pose.orientation, msg.twist.twist.linear
        velocity = quat_to_matrix(np.array([q.x, q.y, q.z, q.w])) @ np.array([tw.x, tw.y, tw.z])
        self.trigger.on_odom(ns_from_stamp(msg.header.stamp), velocity)

    # --- what the step trigger calls back ------------------------------------------------------
    def _republish(self) -> None:
        if self._last_command is not None:
            self._send_command(self._last_command)

    def _send_command(self, raw: bytes) -> None:
        """To a bridge in this process first (no wait for the executor to take it back off the
        wire), then on the wire for every other subscriber."""
        for sink in self.command_sinks:
            sink(raw)
        self.pub_command.publish(raw)

    def _on_estimate(self, sensors: tuple, estimate) -> None:
        """Embedded estimator: /odom and /tf, every odom_every_steps control steps."""
        if self._steps % self.odom_every == 0:
            self.odom.publish(self.frontend.odometry(sensors[0], sensors[1], estimate))

    def _on_sim_reset(self) -> None:
        self._last_command = None
        self.supervisor.restart()

    def _log(self, level: str, text: str, throttle: bool) -> None:
        """One call site per severity (and for the throttled one): rclpy's logger requires it."""
        logger = self.get_logger()
        if level == "error":
            logger.error(text)
        elif level == "info":
            logger.info(text)
        elif throttle:
            logger.warning(text, throttle_duration_sec=1.0)
        else:
            logger.warning(text)

    # --- the control step ----------------------------------------------------------------------
    def _control(self, stamp_ns: int, sensors: tuple, velocity_world: np.ndarray | None,
                 backup_velocity: np.ndarray | None) -> None:
        """One control step for the sensors stamped ``stamp_ns``; no velocity: the backup estimate's
        controlled stop if there is one, else the safe-stance path."""
        joints, imu, contacts = sensors
        t0 = time.perf_counter()
        o, w = imu.orientation, imu.angular_velocity
        velocity = next((v for v in (velocity_world, backup_velocity) if v is not None), np.zeros(3))
        obs = Observation(np.asarray(joints.position, dtype=float), np.asarray(joints.velocity, dtype=float),
                          np.array([o.x, o.y, o.z, o.w]), np.array([w.x, w.y, w.z]),
                          np.asarray(contacts.contact, dtype=bool), velocity)
        result = self.supervisor.step(stamp_ns * 1e-9, obs, velocity_fresh=velocity_world is not None,
                                      backup_velocity=velocity_world is None and backup_velocity is not None)
        self._last_command = self._command_encoder.encode(result.command, stamp_ns)
        self._send_command(self._last_command)
        elapsed = time.perf_counter() - t0
        self._steps += 1
        if result.state == "fallen" and self._state != "fallen":
            self.get_logger().error("the robot has fallen (tilt over fall_tilt): motors damped until ~/clear_estop")
        self._state = result.state
        self._step_times.append(elapsed)
        self._missed += elapsed > self.period
        if result.state == "walk" and self.controller.solved_this_step:
            self._solve_times.append(self.controller.last_solution.solve_time)
            self._plan_delays.append(self.controller.plan_delay_steps * self.period)
        effort, joint_velocity = np.asarray(joints.effort, dtype=float), np.asarray(joints.velocity, dtype=float)
        if effort.shape == joint_velocity.shape:  # efforts are optional in sensor_msgs/JointState
            self._powers.append(float(motor_power(effort, joint_velocity).sum()))
        self._speeds.append(math.hypot(velocity[0], velocity[1]))
        if self.pub_state.get_subscription_count():  # monitors and plots only: skipped when nobody listens
            self.pub_state.publish(self._gait_state(joints.header.stamp, contacts))

    def _gait_state(self, stamp, contacts: FootContacts) -> GaitState:
        gait = self.controller.gait
        msg = GaitState()
        msg.header.stamp = stamp
        msg.header.frame_id = "base_link"
        msg.phases = gait.phases.tolist()
        msg.desired_contact = [bool(c) for c in gait.desired_contact]
        msg.leg_states = [int(s) for s in gait.leg_states(np.asarray(contacts.contact, dtype=bool))]
        p = gait.params
        msg.params.header.stamp = stamp
        msg.params.stepping_frequency = p.stepping_frequency
        msg.params.swing_ratio = p.swing_ratio
        msg.params.phase_offsets = list(p.phase_offsets)
        return msg

    def _publish_diagnostics(self) -> None:
        sup = self.supervisor
        status = DiagnosticStatus(name="convex_mpc", hardware_id="a1")
        sensors_missing = time.monotonic() - self._last_sensor_wall > 1.0
        if sup.estopped:
            status.level, status.message = DiagnosticStatus.ERROR, "E-STOP latched: damping"
        elif sup.fallen:
            status.level, status.message = DiagnosticStatus.ERROR, "fallen: damping until ~/clear_estop"
        elif sensors_missing:
            status.level, status.message = DiagnosticStatus.ERROR, "no /joint_states: commands stopped (bridge damps)"
        elif self._state == "safe_stand":
            status.level, status.message = DiagnosticStatus.WARN, "no fresh /odom: holding a safe stance"
        elif self._state == "stopping":
            status.level, status.message = DiagnosticStatus.WARN, "no fresh /odom: stopping on the backup estimate"
        else:
            status.level, status.message = DiagnosticStatus.OK, self._state
        gait = self.controller.gait.params
        power = float(np.mean(self._powers)) if self._powers else 0.0
        speed = float(np.mean(self._speeds)) if self._speeds else 0.0
        values = {
            "state": self._state, "requested_mode": sup.requested.value, "steps": self._steps,
            "qp_solve_median_ms": f"{np.median(self._solve_times) * 1e3:.3f}" if self._solve_times else "n/a",
            "mpc_plan_delay_median_ms": f"{np.median(self._plan_delays) * 1e3:.1f}" if self._plan_delays else "n/a",
            "step_median_ms": f"{np.median(self._step_times) * 1e3:.3f}" if self._step_times else "n/a",
            "missed_deadlines": self._missed, "mpc_fallbacks": self.controller.mpc_fallbacks,
            "mpc_stopgap_steps": self.controller.stopgap_steps,
            "stepping_frequency_hz": f"{gait.stepping_frequency:.2f}", "swing_ratio": f"{gait.swing_ratio:.2f}",
            "gait_fallbacks": sup.gait_fallbacks, "falls": sup.falls, "safe_stand_steps": sup.safe_stand_steps,
            "stopping_steps": sup.stopping_steps,
            "rejected_cmd_vel": sup.rejected_cmd_vel, "rejected_gait_params": sup.rejected_gait_params,
            "power_w": f"{power:.1f}",
            "cost_of_transport": f"{cost_of_transport(power, self.mass, speed):.3f}" if speed > 0.1 else "n/a",
        }
        self.pub_diag.publish(diagnostic_array(self, status, values))


def main(args: list[str] | None = None) -> None:
    run_node("convex_mpc", ConvexMpcNode, args)


if __name__ == "__main__":
    main()
