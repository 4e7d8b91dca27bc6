# Helpers to start the stack's nodes from bash scripts: `ros2 run <pkg> <exe>` where the ros2 CLI
# exists, otherwise the very executable colcon installed (install/<pkg>/lib/<pkg>/<exe>, which is
# what `ros2 run` runs). Source after scripts/env.sh, in a non-interactive script.

_GS_PIDS=()

check_choice() {  # <script> <option> <value> <allowed...>: exit 2 naming the option unless value is allowed
  local script=$1 option=$2 value=$3; shift 3
  local allowed
  for allowed in "$@"; do [ "$value" = "$allowed" ] && return 0; done
  echo "$script: $option must be one of: $*; got '$value'" >&2
  exit 2
}

GAIT_POLICIES=(learned scheduled walk slow_trot rapid_trot fly_trot)  # gait_policy's named policies

resolve_policy() {  # <script> <policy>: set POLICY to a named policy or the absolute path of a .npz, else exit 2
  local script=$1
  POLICY=$2
  case "$POLICY" in
    *.npz) [ -f "$POLICY" ] || { echo "$script: --policy file '$POLICY' does not exist" >&2; exit 2; }
           POLICY="$(cd "$(dirname "$POLICY")" && pwd)/$(basename "$POLICY")" ;;  # nodes run elsewhere
    *) check_choice "$script" --policy "$POLICY" "${GAIT_POLICIES[@]}" ;;
  esac
}

_node_command() {  # <pkg> <exe>: set the array _GS_CMD to the command that runs a node
  local pkg=$1 exe=$2
  if command -v ros2 >/dev/null 2>&1; then
    _GS_CMD=(ros2 run "$pkg" "$exe")
  else
    local path="$GAIT_STACK_ROOT/install/$pkg/lib/$pkg/$exe"
    [ -x "$path" ] || { echo "nodes.sh: no executable $path; run scripts/setup.sh" >&2; return 1; }
    _GS_CMD=("$path")
  fi
}

GS_NAMESPACE=${GS_NAMESPACE:-}  # non-empty (/a1_1): every node started here runs in that namespace

_GS_REMAPS=""  # GS_NAMESPACE's ROS arguments, shell-quoted, once _namespace_remaps has run

_namespace_remaps() {  # set _GS_REMAPS from the graph description's rule (a1_bringup.graph), once
  [ -n "$_GS_REMAPS" ] || _GS_REMAPS=$(python -m a1_bringup.graph --remaps-only --namespace "$GS_NAMESPACE")
}

check_namespace() {  # exit 2 with a1_bringup.graph's reason unless GS_NAMESPACE is empty or valid
  [ -z "$GS_NAMESPACE" ] || _namespace_remaps || exit 2
}

start_node() {  # <pkg> <exe> <logdir> [args...]: start in the background, log to <logdir>/<exe>.log
  local pkg=$1 exe=$2 logdir=$3; shift 3
  _node_command "$pkg" "$exe" || return 1
  if [ -n "$GS_NAMESPACE" ]; then
    _namespace_remaps || return 1
    local ros=()
    [[ " $* " == *" --ros-args "* ]] || ros=(--ros-args)
    eval "set -- \"\$@\" \"\${ros[@]}\" $_GS_REMAPS"  # shell-quoted by the describer (shlex.join)
  fi
  # setsid: the node leads its own process group, so stop_nodes reaches its children too.
  setsid "${_GS_CMD[@]}" "$@" >"$logdir/$exe.log" 2>&1 &
  _GS_PIDS+=($!)
  echo "[nodes] started $pkg/$exe (pid $!, log $logdir/$exe.log)"
}

check_nodes() {  # fail with the log's tail if a started node has already exited
  local pid
  for pid in "${_GS_PIDS[@]}"; do
    if ! kill -0 "$pid" 2>/dev/null; then
      echo "[nodes] ERROR: node with pid $pid exited early; see its log above" >&2
      return 1
    fi
  done
}

stop_nodes() {  # SIGINT each started node's process group, then SIGKILL what is left after 5 s
  local pid
  for pid in "${_GS_PIDS[@]}"; do kill -INT -- "-$pid" 2>/dev/null || true; done
  for _ in $(seq 50); do
    local alive=0
    for pid in "${_GS_PIDS[@]}"; do kill -0 -- "-$pid" 2>/dev/null && alive=1; done
    [ "$alive" = 0 ] && break
    sleep 0.1
  done
  for pid in "${_GS_PIDS[@]}"; do kill -KILL -- "-$pid" 2>/dev/null || true; done
  # Reap them before returning: a node killed just now is not gone until its parent (this shell) waits.
  for pid in "${_GS_PIDS[@]}"; do wait "$pid" 2>/dev/null || true; done
  _GS_PIDS=()
}

start_recorder() {  # <logdir> <bag folder> <clock>: every topic into a rosbag2 bag (MCAP), its own process
  local logdir=$1 bag=$2 clock=$3
  start_node bag_recorder record "$logdir" --ros-args -p output:="$bag" \
    -p use_sim_time:=$([ "$clock" = lockstep ] && echo true || echo false)
}

recorder_summary() {  # <logdir>: what the recorder wrote (after stop_nodes closed its bag)
  grep -h -A1000 "bag_recorder: wrote" "$1/record.log" 2>/dev/null || echo "[nodes] the recorder wrote no summary; see $1/record.log"
}

start_graph() {  # <logdir> <world> <clock> <policy> [bridge] [form]: a bridge and the stack nodes (a1_bringup.graph)
  # bridge: sim (default) | hardware (the real A1, realtime) | virtual (hw_bridge + virtual_a1 on loopback)
  # form: separate (default: one process a node) | composed (bridge, estimator, controller in one control_chain)
  local logdir=$1 world=$2 clock=$3 policy=$4 bridge=${5:-sim} form=${6:-separate}
  local sets=(--set "gait_policy.policy=$policy" ${GRAPH_SETS[@]+"${GRAPH_SETS[@]}"})  # GRAPH_SETS: more --set
  [ "$form" = composed ] && sets+=(--composed)
  case "$bridge" in
    sim) sets+=(--set "sim_bridge.world=$world" --set "sim_bridge.flight_recorder_dir=$logdir") ;;  # a fall: its last 5 s
    virtual) sets+=(--set "virtual_a1.world=$world") ;;
  esac
  local lines line spec
  lines=$(python -m a1_bringup.graph --clock "$clock" --bridge "$bridge" --config "$GAIT_STACK_ROOT/config" \
    "${sets[@]}") || return 1
  while IFS= read -r line; do
    eval "spec=($line)"  # shell-quoted by the describer (shlex.join): package, executable, arguments
    start_node "${spec[0]}" "${spec[1]}" "$logdir" "${spec[@]:2}"
  done <<<"$lines"
}
