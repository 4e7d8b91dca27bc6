"""The stack's message contract: every topic the nodes exchange, with its type, QoS and frame.

One list (TOPICS) for what a newcomer, a hardware bridge or a recorder needs to know of the graph;
each node takes its names and QoS from here, and ``tests/test_node_interfaces.py`` checks every
node against it. Frames follow REP-105 (odom -> base_link); units are SI (REP-103).

Names are relative: in the root namespace ``joint_states`` is ``/joint_states``; started with
``--ros-args -r __ns:=/a1_1`` a whole graph lives under ``/a1_1/``, so a second robot (or a second
simulated one) runs beside the first. ``clock`` too: the nodes of a namespaced graph remap their
sim-time subscription with ``-r /clock:=clock`` (scripts/lib/nodes.sh does).
"""

from __future__ import annotations

from dataclasses import dataclass

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# --- QoS ----------------------------------------------------------------------------------------
# The 500 Hz sensor -> command chain: only the newest sample matters, but none may be dropped by the
# transport while it is the newest (a lockstep bridge waits for each step's command).
CONTROL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
# Low-rate commands (/cmd_vel, /gait/params): a few queued, none lost (`ros2 topic pub` is reliable).
COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# Latched: a node that starts later (robot_state_publisher, RViz, a recorder) still gets it.
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The e-stop: the newest value only, delivered.
ESTOP_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
# /tf as tf2's listeners subscribe to it.
TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
# /diagnostics as diagnostic_aggregator and rqt subscribe to it.
DIAGNOSTICS_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)

# --- frames -------------------------------------------------------------------------------------
ODOM_FRAME = "odom"  # world-fixed, where the robot started (REP-105)
BASE_FRAME = "base_link"  # the trunk: x forward, y left, z up
IMU_FRAME = "imu_link"  # the IMU, aligned with base_link on the A1


@dataclass(frozen=True)
class Topic:
    name: str
    type: str  # package/msg/Type
    qos: QoSProfile
    frame: str  # header.frame_id ("" for messages without a frame)
    publishers: tuple[str, ...]  # the nodes that publish it (one at a time where several can)
    what: str


JOINT_STATES = "joint_states"
IMU = "imu/data"
FOOT_CONTACTS = "foot_contacts"
MOTOR_COMMAND = "motor_command"
ODOM = "odom"
CMD_VEL = "cmd_vel"
GAIT_PARAMS = "gait/params"
GAIT_STATE = "gait/state"
ESTOP = "estop"
CLOCK = "clock"
TF = "tf"
ROBOT_DESCRIPTION = "robot_description"
GROUND_TRUTH = "sim/ground_truth/odom"
DIAGNOSTICS = "diagnostics"

BRIDGES = ("sim_bridge", "hw_bridge")
TOPICS = (
    Topic(JOINT_STATES, "sensor_msgs/msg/JointState", CONTROL_QOS, BASE_FRAME, BRIDGES,
          "12 joints: position [rad], velocity [rad/s], effort [N m], 500 Hz"),
    Topic(IMU, "sensor_msgs/msg/Imu", CONTROL_QOS, IMU_FRAME, BRIDGES,
          "orientation (odom frame), angular velocity [rad/s], specific force [m/s^2], 500 Hz"),
    Topic(FOOT_CONTACTS, "gait_msgs/msg/FootContacts", CONTROL_QOS, BASE_FRAME, BRIDGES,
          "contact flags and normal forces [N] of FR, FL, RR, RL, 500 Hz"),
    Topic(MOTOR_COMMAND, "gait_msgs/msg/MotorCommand", CONTROL_QOS, BASE_FRAME, ("convex_mpc",),
          "per joint: mode, q, dq, kp, kd, feed-forward torque; stamped with the sensor step it answers"),
    Topic(ODOM, "nav_msgs/msg/Odometry", CONTROL_QOS, ODOM_FRAME, ("state_estimator", "convex_mpc"),
          "base velocity estimate (twist in base_link), 500 Hz (convex_mpc with its embedded estimator)"),
    Topic(CMD_VEL, "geometry_msgs/msg/Twist", COMMAND_QOS, "",
          ("velocity_command", "teleop_keyboard"), "desired base velocity [m/s, rad/s] (TwistStamped optional)"),
    Topic(GAIT_PARAMS, "gait_msgs/msg/GaitParams", COMMAND_QOS, "", ("gait_policy",),
          "stepping frequency [Hz], swing ratio, phase offsets [rad], 20 Hz"),
    Topic(GAIT_STATE, "gait_msgs/msg/GaitState", CONTROL_QOS, BASE_FRAME, ("convex_mpc",),
          "the controller's state, leg phases and scheduled contacts, 500 Hz"),
    Topic(ESTOP, "std_msgs/msg/Bool", ESTOP_QOS, "", (), "true latches motor damping (~/clear_estop releases)"),
    Topic(CLOCK, "rosgraph_msgs/msg/Clock", CONTROL_QOS, "", BRIDGES, "sim time, lockstep graphs"),
    Topic(TF, "tf2_msgs/msg/TFMessage", TF_QOS, ODOM_FRAME, ("state_estimator", "convex_mpc"),
          "odom -> base_link, 50 Hz"),
    Topic(ROBOT_DESCRIPTION, "std_msgs/msg/String", LATCHED_QOS, "", BRIDGES, "the URDF, latched"),
    Topic(GROUND_TRUTH, "nav_msgs/msg/Odometry", CONTROL_QOS, ODOM_FRAME, ("sim_bridge", "virtual_a1"),
          "simulator only: the true base state, for evaluation; never a controller input"),
    Topic(DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray", DIAGNOSTICS_QOS, "",
          ("every node",), "each node's status and figures, 1 Hz"),
)
