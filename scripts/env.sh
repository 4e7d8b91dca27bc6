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
# What a sourced ROS 2 install defines (its ros_environment package) and the PyPI wheels leave out:
# `ros2 doctor` and tools that branch on the distro read them. A full install's own values stay.
export ROS_VERSION="${ROS_VERSION:-2}" ROS_PYTHON_VERSION="${ROS_PYTHON_VERSION:-3}" ROS_DISTRO="${ROS_DISTRO:-jazzy}"
[ "$ROS_DISTRO" = jazzy ] || echo "env.sh: warning: ROS_DISTRO is '$ROS_DISTRO'; this stack is built for jazzy" >&2
export GAIT_STACK_ROOT="$_gs_root"
# The offline tools (train_es, eval_policy, sweep_gaits, velocity_command) by name, as without ROS.
export PATH="$_gs_root/install/gait_policy_node/lib/gait_policy_node:$PATH"
unset _gs_root _gs_nounset
# Isolation (docs/reliability.md): the stack's own DDS domain and discovery on this host only,
# unless the user chose otherwise, so that a run here never talks to another run or to a robot's
# network. To join other machines (a real robot), set both before sourcing this file, e.g.
#   ROS_DOMAIN_ID=0 ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET source scripts/env.sh
# (The test suite picks a private domain per run by itself: see tests/conftest.py.)
GAIT_STACK_DEFAULT_DOMAIN_ID=42
export GAIT_STACK_DEFAULT_DOMAIN_ID
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$GAIT_STACK_DEFAULT_DOMAIN_ID}"
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
case "$ROS_DOMAIN_ID" in
  *[!0-9]*) _gs_bad_domain=1 ;;
  *) [ "${#ROS_DOMAIN_ID}" -le 3 ] && [ "$((10#$ROS_DOMAIN_ID))" -le 232 ] && _gs_bad_domain=0 || _gs_bad_domain=1 ;;
esac
if [ "$_gs_bad_domain" = 1 ]; then
  echo "env.sh: ROS_DOMAIN_ID must be an integer in [0, 232] (0-101 are safe on Linux), got '$ROS_DOMAIN_ID'" >&2
  unset _gs_bad_domain
  return 1 2>/dev/null || exit 1
fi
unset _gs_bad_domain
export ROS_DOMAIN_ID="$((10#$ROS_DOMAIN_ID))"  # 042 -> 42
case "$ROS_AUTOMATIC_DISCOVERY_RANGE" in
  LOCALHOST|SUBNET|OFF|SYSTEM_DEFAULT) ;;
  *) echo "env.sh: ROS_AUTOMATIC_DISCOVERY_RANGE must be one of LOCALHOST, SUBNET, OFF, SYSTEM_DEFAULT;" \
          "got '$ROS_AUTOMATIC_DISCOVERY_RANGE'" >&2
     return 1 2>/dev/null || exit 1 ;;
esac
# The controller's matrices are tiny: multithreaded BLAS only adds overhead and jitter.
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}"
