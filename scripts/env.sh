# Source this file (bash) to use the built workspace: the virtual environment plus the colcon
# install space (messages, packages, executables). Run scripts/setup.sh first.
_gs_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
if [ ! -f "$_gs_root/install/setup.bash" ] || [ ! -x "${VENV:-$_gs_root/.venv}/bin/python" ]; then
  echo "env.sh: workspace not built; run $_gs_root/scripts/setup.sh first" >&2
  return 1 2>/dev/null || exit 1
fi
# shellcheck disable=SC1091
source "${VENV:-$_gs_root/.venv}/bin/activate"
export AMENT_PREFIX_PATH="${VIRTUAL_ENV}${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
# colcon's setup scripts reference unset variables; relax nounset while sourcing them.
_gs_nounset=$(set +o | grep nounset); set +u
# shellcheck disable=SC1091
source "$_gs_root/install/setup.bash"
eval "$_gs_nounset"
export GAIT_STACK_ROOT="$_gs_root"
# The offline tools (train_es, eval_policy, sweep_gaits, velocity_command) by name, as without ROS.
export PATH="$_gs_root/install/gait_policy_node/lib/gait_policy_node:$PATH"
unset _gs_root _gs_nounset
# Keep DDS discovery on this host unless the user chose otherwise (the robot's network is
# configured explicitly when a hardware bridge runs).
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# The controller's matrices are tiny: multithreaded BLAS only adds overhead and jitter.
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
