#!/usr/bin/env bash
# Regenerate the figures and tables of docs/results/RESULTS.md for a policy (default: the shipped
# one, `learned`): the paper's acceleration profile (gait diagram, per-band table, transition
# speeds), cost of transport at constant speeds against the hand-tuned gaits (frequency grid
# search), and the training run's learning curve. In-process (no ROS graph), all cores.
#
# Usage: scripts/results.sh [--policy learned|<file>.npz] [--run training/cmaes-staircase] [--out docs/results]
#                           [--skip-sweep]
# Takes about 10 minutes on 2 cores (the sweep is most of it: 4 gaits x 5 speeds x 7 frequencies).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
POLICY=learned RUN="$ROOT/training/cmaes-staircase" OUT="$ROOT/docs/results" SWEEP=1
while [ $# -gt 0 ]; do
  case "$1" in
    --policy) POLICY="${2:?--policy needs a value}"; shift 2 ;;
    --run) RUN="${2:?--run needs a value}"; shift 2 ;;
    --out) OUT="${2:?--out needs a value}"; shift 2 ;;
    --skip-sweep) SWEEP=0; shift ;;
    -h|--help) sed -n '2,9p' "$0"; exit 0 ;;
    *) echo "results.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
[ -f "$RUN/log.csv" ] || { echo "results.sh: --run '$RUN' has no log.csv (not a train_es run folder)" >&2; exit 2; }
"$ROOT/scripts/setup.sh"
# shellcheck disable=SC1091
source "$ROOT/scripts/env.sh"
mkdir -p "$OUT/ramp" "$OUT/sweep"
echo "[results] $POLICY on the paper's profile (0 -> 2.5 m/s at 1 m/s^2, 20 s)"
# eval_policy exits 1 when the policy fell: the figures are still wanted then.
eval_policy "$POLICY" --profile ramp --target-speed 2.5 --acceleration 1.0 --duration 20 --out "$OUT/ramp" \
  | tee "$OUT/ramp/report.txt" || true
rm -f "$OUT/ramp/steps.csv"  # 10 000 rows: regenerated on demand, not kept in the repository
if [ "$SWEEP" = 1 ]; then
  echo "[results] cost of transport at constant speeds: hand-tuned gaits (best frequency) and $POLICY"
  sweep_gaits --policy "$POLICY" --speeds 0.5 1.0 1.5 2.0 2.5 --out "$OUT/sweep" | tee "$OUT/sweep/report.txt"
fi
cp "$RUN/learning_curve.png" "$OUT/learning_curve.png"
cp "$RUN/log.csv" "$OUT/log.csv"
echo "[results] wrote $OUT (ramp/, sweep/, learning_curve.png, log.csv)"
