#!/usr/bin/env bash
# Entry point of the a1-gait-stack image (docker/Dockerfile): ROS 2 Jazzy from apt plus the
# workspace's install space, then run the given command (default: bash). Also usable with
# `docker exec <container> a1-entrypoint <command>` (docker exec skips the image's ENTRYPOINT).
# No `set -eu`: the setup scripts read unset variables and are not written for errexit.
# shellcheck disable=SC1091
source /opt/ros/jazzy/setup.bash
# shellcheck disable=SC1091
source /ws/install/setup.bash || { echo "a1-entrypoint: /ws/install/setup.bash missing (image not built?)" >&2; exit 1; }
export GAIT_STACK_ROOT=/ws
# As scripts/env.sh: DDS discovery stays on this host (here: this container) unless overridden
# with -e ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET.
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
[ "$#" -gt 0 ] || set -- bash
exec "$@"
