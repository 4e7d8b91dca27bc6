#!/usr/bin/env bash
# Set up the workspace if needed, then run the whole test suite: ruff, then pytest.
# Extra arguments go to pytest (e.g. scripts/test.sh -k sim -x).
# Isolation (docs/reliability.md): pytest claims a DDS domain of its own for the run (not the
# shell's ROS_DOMAIN_ID, nor env.sh's default) with host-only discovery, so that two runs on one
# machine, or a run next to a robot's network, never talk; GAIT_STACK_TEST_DOMAIN_ID pins it.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
"$ROOT/scripts/setup.sh"
# shellcheck disable=SC1091
source "$ROOT/scripts/env.sh"
cd "$ROOT"
echo "[test] ruff check"
ruff check .
echo "[test] pytest"
set +e
python -m pytest "$@"
rc=$?
set -e
if [ "$rc" -eq 5 ]; then
  echo "[test] ERROR: pytest collected no tests (exit 5); the suite must not pass empty" >&2
  exit 1
fi
exit "$rc"
