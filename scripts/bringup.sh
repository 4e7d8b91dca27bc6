#!/usr/bin/env bash
# Bring up the A1 stack: a bridge to the robot, state estimator, convex MPC controller, gait policy.
#
# Usage: scripts/bringup.sh [--world flat|step|rough|soft|slope] [--clock lockstep|realtime]
#                           [--policy learned|scheduled|walk|slow_trot|rapid_trot|fly_trot|<file>.npz]
#                           [--bridge sim|hardware|virtual] [--form composed|separate]
#                           [--record [DIR]] [--namespace /NAME]
# --bridge: sim (default) = the PyBullet sim bridge; hardware = the real A1 over its low-level UDP
#   protocol (config/a1_hw_bridge.yaml, realtime only; read docs/hardware.md first); virtual = the
#   hardware bridge talking UDP on loopback to a virtual A1 that runs the simulation (--world, --clock).
# Then drive it: ros2 topic pub /cmd_vel geometry_msgs/msg/Twist "{linear: {x: 1.0}}"
#   (without the ros2 CLI: install/gait_policy_node/lib/gait_policy_node/velocity_command
#    --ros-args -p profile:=constant -p speed:=1.0 -p use_sim_time:=true; :=false with
#    --bridge hardware, or virtual in realtime: only the sim bridge and lockstep publish /clock)
# --form: composed (default) = the 500 Hz chain (bridge, estimator, controller) as one process,
#   a1_bringup's control_chain: no process hop inside the 2 ms step; separate = one `ros2 run` a node.
#   The gait policy and the tools are their own processes either way.
# --namespace: the whole graph in that namespace (/NAME/joint_states, /NAME/cmd_vel, ...), so a second
#   robot runs beside the first: scripts/bringup.sh --clock lockstep --namespace /a1_2
# --record: every topic into a rosbag2 bag with MCAP storage (DIR, default <log dir>/bag), written by
#   bag_recorder in its own process; `ros2 bag info DIR` / `ros2 bag play DIR` / Foxglove open it.
# Each node is started with `ros2 run` when the ros2 CLI exists, else the installed executable;
# parameters from config/; one log per node in log/bringup/<time>/. Ctrl-C or SIGTERM stops them all.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WORLD=flat CLOCK=realtime POLICY=learned BRIDGE=sim WORLD_GIVEN=0 RECORD=0 BAG="" FORM=""
while [ $# -gt 0 ]; do
  case "$1" in
    --world) WORLD="${2:?--world needs a value}"; WORLD_GIVEN=1; shift 2 ;;
    --bridge) BRIDGE="${2:?--bridge needs a value}"; shift 2 ;;
    --clock) CLOCK="${2:?--clock needs a value}"; shift 2 ;;
    --policy) POLICY="${2:?--policy needs a value}"; shift 2 ;;
    --form) FORM="${2:?--form needs a value}"; shift 2 ;;
    --namespace) GS_NAMESPACE="${2:?--namespace needs a value}"; shift 2 ;;
    --record) RECORD=1; if [ $# -gt 1 ] && [ "${2#--}" = "$2" ]; then BAG=$2; shift; fi; shift ;;
    -h|--help) sed -n '2,23p' "$0"; exit 0 ;;
    *) echo "bringup.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
# shellcheck disable=SC1091
source "$ROOT/scripts/lib/nodes.sh"
check_choice bringup.sh --world "$WORLD" flat step rough soft slope
check_choice bringup.sh --clock "$CLOCK" lockstep realtime
check_choice bringup.sh --bridge "$BRIDGE" sim hardware virtual
FORM=${FORM:-composed}
check_choice bringup.sh --form "$FORM" composed separate
if [ "$BRIDGE" = hardware ]; then
  [ "$CLOCK" = realtime ] || { echo "bringup.sh: --bridge hardware needs --clock realtime (a real robot does not wait for the controller)" >&2; exit 2; }
  [ "$WORLD_GIVEN" = 0 ] || { echo "bringup.sh: --world applies to --bridge sim and virtual, not to the real robot" >&2; exit 2; }
fi
resolve_policy bringup.sh "$POLICY"
# shellcheck disable=SC1091
source "$ROOT/scripts/env.sh"
check_namespace
LOGDIR="$ROOT/log/bringup/$(date +%Y%m%d-%H%M%S)${GS_NAMESPACE:+${GS_NAMESPACE//\//_}}"
mkdir -p "$LOGDIR"
trap 'stop_nodes; [ "$RECORD" = 1 ] && recorder_summary "$LOGDIR"' EXIT
trap 'exit 130' INT TERM
if [ "$RECORD" = 1 ]; then
  BAG="${BAG:-$LOGDIR/bag}"
  [ -e "$BAG" ] && { echo "bringup.sh: --record folder '$BAG' already exists; choose another" >&2; exit 2; }
  start_recorder "$LOGDIR" "$(mkdir -p "$(dirname "$BAG")" && cd "$(dirname "$BAG")" && pwd)/$(basename "$BAG")" "$CLOCK"
fi
start_graph "$LOGDIR" "$WORLD" "$CLOCK" "$POLICY" "$BRIDGE" "$FORM"
echo "[bringup] running (bridge=$BRIDGE world=$WORLD clock=$CLOCK form=$FORM policy=$POLICY); logs in $LOGDIR; Ctrl-C to stop"
while check_nodes; do sleep 1 & wait $! || true; done
echo "[bringup] a node exited; stopping the others" >&2
tail -n 20 "$LOGDIR"/*.log >&2
exit 1
