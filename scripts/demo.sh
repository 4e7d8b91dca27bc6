#!/usr/bin/env bash
# Main demo: set up the workspace if needed, bring up the whole A1 stack headless, drive the paper's
# speed profile (0 -> 2.5 m/s at 1 m/s^2, then hold), and report.
#
# Usage: scripts/demo.sh [--world flat|step|rough|soft|slope] [--duration SECONDS] [--clock lockstep|realtime]
#                        [--policy learned|scheduled|walk|slow_trot|rapid_trot|fly_trot|<file>.npz] [--no-record]
#                        [--form separate|composed]
#
# Starts sim_bridge, state_estimator, convex_mpc and gait_policy (scripts/lib/nodes.sh), the
# velocity_command ramp and demo_report, which after --duration seconds of sim time (default 20)
# prints distance, speed tracking, gait, power and cost of transport per speed band, and writes
# a gait diagram PNG (log/demo/gait_diagram.png), and records every topic into a rosbag2 bag with
# MCAP storage, log/demo/bag (unless --no-record). Every node started here is stopped on exit,
# Ctrl-C or SIGTERM. Per-node logs: log/demo/<node>.log. --form as in scripts/bringup.sh: composed
# (default: the bridge, estimator and controller in one control_chain process; lockstep runs about
# 0.5x real time on 2 cores with the bag, against 0.15-0.4x separate, with a summary alike;
# benchmarks/lockstep_pace.py compares the forms) or separate (a process a node).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WORLD=flat DURATION=20 CLOCK=lockstep POLICY=learned RECORD=1 FORM=""
while [ $# -gt 0 ]; do
  case "$1" in
    --world) WORLD="${2:?--world needs a value}"; shift 2 ;;
    --duration) DURATION="${2:?--duration needs a value}"; shift 2 ;;
    --clock) CLOCK="${2:?--clock needs a value}"; shift 2 ;;
    --policy) POLICY="${2:?--policy needs a value}"; shift 2 ;;
    --no-record) RECORD=0; shift ;;
    --form) FORM="${2:?--form needs a value}"; shift 2 ;;
    -h|--help) sed -n '2,17p' "$0"; exit 0 ;;
    *) echo "demo.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
# shellcheck disable=SC1091
source "$ROOT/scripts/lib/nodes.sh"
check_choice demo.sh --world "$WORLD" flat step rough soft slope
check_choice demo.sh --clock "$CLOCK" lockstep realtime
FORM=${FORM:-composed}
check_choice demo.sh --form "$FORM" composed separate
resolve_policy demo.sh "$POLICY"
[[ "$DURATION" =~ ^[0-9]+([.][0-9]+)?$ ]] && awk "BEGIN{exit !($DURATION > 0 && $DURATION <= 3600)}" \
  || { echo "demo.sh: --duration must be a number of seconds in (0, 3600], got '$DURATION'" >&2; exit 2; }

"$ROOT/scripts/setup.sh"
# shellcheck disable=SC1091
source "$ROOT/scripts/env.sh"

LOGDIR="$ROOT/log/demo"
mkdir -p "$LOGDIR"
trap stop_nodes EXIT
trap 'exit 130' INT TERM

echo "[demo] world=$WORLD clock=$CLOCK form=$FORM policy=$POLICY duration=${DURATION}s of sim time (logs in $LOGDIR)"
if [ "$RECORD" = 1 ]; then
  rm -rf "$LOGDIR/bag"  # the demo's logs are the last run's
  start_recorder "$LOGDIR" "$LOGDIR/bag" "$CLOCK"
fi
# The graph starts with its sim paused, and the report unpauses it once it has a publisher on every
# topic it records: a busy graph can take seconds to match a new subscriber (once 4 s of the ramp
# went unseen). The report runs in the foreground of a `wait` below, so Ctrl-C / SIGTERM reach the
# traps at once, and under a wall-clock cap, so a graph that stalls cannot hang the demo.
cap=$(awk "BEGIN{print int($DURATION * 10 + 120)}")
_node_command gait_policy_node demo_report
report_args=(--ros-args -p use_sim_time:=true -p duration:="$(awk "BEGIN{print $DURATION + 1.5}")"
             -p output:="$LOGDIR/gait_diagram.png" -p start_sim:=sim_bridge/pause)
if [ -n "$GS_NAMESPACE" ]; then  # the report joins the graph's namespace (GS_NAMESPACE, scripts/lib/nodes.sh)
  _namespace_remaps
  eval "report_args+=($_GS_REMAPS)"  # shell-quoted by the describer (shlex.join)
fi
setsid timeout "$cap" "${_GS_CMD[@]}" "${report_args[@]}" &
report=$!
_GS_PIDS+=("$report")  # stopped with the others on exit
GRAPH_SETS=(--set sim_bridge.start_paused=true)
start_graph "$LOGDIR" "$WORLD" "$CLOCK" "$POLICY" sim "$FORM"
# The ramp starts at 1.5 s of sim time: the controller stands up first (stand_time in
# config/convex_mpc.yaml). start_time 0 counts from the sim's t = 0, not from this process's first
# /clock, which on a busy machine came up to 3.3 s late and shifted the whole ramp (37.4 m instead of about 45).
start_node gait_policy_node velocity_command "$LOGDIR" --ros-args -p use_sim_time:=true -p profile:=ramp \
  -p speed:=2.5 -p acceleration:=1.0 -p start_delay:=1.5 -p start_time:=0.0
while kill -0 "$report" 2>/dev/null; do
  if ! check_nodes; then
    tail -n 20 "$LOGDIR"/*.log >&2
    exit 1
  fi
  sleep 0.5 & wait $! || true
done
wait "$report" || { rc=$?; [ "$rc" = 124 ] && echo "[demo] ERROR: no report after ${cap}s; logs in $LOGDIR" >&2; exit "$rc"; }
stop_nodes
if [ "$RECORD" = 1 ]; then
  recorder_summary "$LOGDIR" | head -n 1
  echo "[demo] bag: $LOGDIR/bag (ros2 bag info $LOGDIR/bag; opens in Foxglove and PlotJuggler)"
fi
echo "[demo] gait diagram: $LOGDIR/gait_diagram.png; logs: $LOGDIR"
