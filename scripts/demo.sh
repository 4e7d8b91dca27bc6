#!/usr/bin/env bash
# Main demo: set up the workspace if needed, bring up the simulated A1 headless and show its state.
#
# Usage: scripts/demo.sh [--world flat|step|rough|soft|slope] [--duration SECONDS] [--clock lockstep|realtime]
#
# Starts the sim bridge, the joint_hold stand-up tool (joint PD to the standing pose, what the
# controller's stand mode will replace) and the robot_state_monitor, which prints the robot's
# state and stops after --duration seconds of sim time. Every node started here is stopped on
# exit, Ctrl-C or SIGTERM. Per-node logs: log/demo/<node>.log.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WORLD=flat
DURATION=5
CLOCK=lockstep
while [ $# -gt 0 ]; do
  case "$1" in
    --world) WORLD="${2:?--world needs a value}"; shift 2 ;;
    --duration) DURATION="${2:?--duration needs a value}"; shift 2 ;;
    --clock) CLOCK="${2:?--clock needs a value}"; shift 2 ;;
    -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
    *) echo "demo.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
case "$WORLD" in flat|step|rough|soft|slope) ;; *) echo "demo.sh: --world must be flat|step|rough|soft|slope, got '$WORLD'" >&2; exit 2 ;; esac
case "$CLOCK" in lockstep|realtime) ;; *) echo "demo.sh: --clock must be lockstep|realtime, got '$CLOCK'" >&2; exit 2 ;; esac
[[ "$DURATION" =~ ^[0-9]+([.][0-9]+)?$ ]] && awk "BEGIN{exit !($DURATION > 0 && $DURATION <= 3600)}" \
  || { echo "demo.sh: --duration must be a number of seconds in (0, 3600], got '$DURATION'" >&2; exit 2; }

"$ROOT/scripts/setup.sh"
# shellcheck disable=SC1091
source "$ROOT/scripts/env.sh"
# shellcheck disable=SC1091
source "$ROOT/scripts/lib/nodes.sh"

LOGDIR="$ROOT/log/demo"
mkdir -p "$LOGDIR"
trap stop_nodes EXIT
trap 'exit 130' INT TERM

echo "[demo] world=$WORLD clock=$CLOCK duration=${DURATION}s (logs in $LOGDIR)"
start_node a1_sim_bridge sim_bridge "$LOGDIR" --ros-args --params-file "$ROOT/config/a1_sim_bridge.yaml" \
  -p world:="$WORLD" -p clock_mode:="$CLOCK"
start_node a1_sim_bridge joint_hold "$LOGDIR"
# The monitor runs in the foreground of a `wait`, so Ctrl-C / SIGTERM reach the traps at once, and
# under a wall-clock cap, so a graph that never publishes cannot hang the demo.
cap=$(awk "BEGIN{print int($DURATION * 5 + 60)}")
_node_command a1_sim_bridge robot_state_monitor
setsid timeout "$cap" "${_GS_CMD[@]}" --ros-args -p duration:="$DURATION" -p print_period:=0.5 &
monitor=$!
_GS_PIDS+=("$monitor")  # stopped with the others on exit
while kill -0 "$monitor" 2>/dev/null; do
  if ! check_nodes; then
    tail -n 20 "$LOGDIR"/*.log >&2
    kill "$monitor" 2>/dev/null || true
    exit 1
  fi
  sleep 0.5 & wait $! || true
done
wait "$monitor" || { rc=$?; [ "$rc" = 124 ] && echo "[demo] ERROR: no robot state after ${cap}s; logs in $LOGDIR" >&2; exit "$rc"; }
