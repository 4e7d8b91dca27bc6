"""Where the composed realtime chain's 2 ms go, step by step: a timeline of the control_chain process.

Runs ``benchmarks/graph_realtime.py --form composed`` (the demo's ramp to ``--top-speed``, the
realtime overlay) with the timeline hook (``benchmarks/chain_timeline_hook/sitecustomize.py``) on
PYTHONPATH: in the control_chain process it records the start and end of each part of every step
(the sim's step and publishing, each subscription callback, the controller step, the MPC
hand-off to its worker, the filter update, /odom, garbage collections, rclpy's own dispatch) and
writes them when the process exits. A sampling profiler gives shares of CPU; deadlines are lost in
the tail, and this shows the tail: which part of which step ran long.

Prints, over the last ``--window`` seconds of the run:
- per part: calls, median, p99 and longest duration, and CPU per second of wall time;
- the wake-up lateness of the sim's steps (start minus deadline), and the work a step (its start to
  the end of its last part: over 2 ms, the next step starts late);
- late commands: steps whose command reached the bridge (take_command, or the /motor_command
  callback if it is not handed over) after the deadline of the step that applies it, and the
  first ``--show`` of them as timelines from the step before (ms from its start, duration, part);
then one JSON line. The hook's own cost (a wrapper per part, about 1-2 us each) is included, so
figures run a little above an unhooked run's.

Usage: source scripts/env.sh && python benchmarks/chain_timeline.py [--seconds 20] [--show 3] \\
           [-- graph_realtime options, e.g. --fifo control_chain=50]
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def load(path: Path) -> tuple[list[tuple[str, float, float]], float]:
    """The hook's events sorted by start, and monotonic minus perf_counter [s]."""
    data = json.loads(path.read_text())
    events = sorted(((label, start, end) for label, start, end in data["events"]), key=lambda e: e[1])
    return events, data["monotonic_minus_perf_counter_s"]


def part_of(label: str) -> str:
    return label if label.startswith("cb:") else label.split(":")[0]


def analyse(events: list[tuple[str, float, float]], offset: float, window: float, show: int) -> dict:
    steps = [(i, e) for i, e in enumerate(events) if e[0].startswith("advance:")]
    if len(steps) < 10:
        raise SystemExit(f"chain_timeline: only {len(steps)} sim steps recorded: did the chain run?")
    end = steps[-1][1][2]
    steps = [(i, e) for i, e in steps if e[1] > end - window]
    durations: dict[str, list[float]] = collections.defaultdict(list)
    for label, start, stop in events:
        if start > end - window:
            durations[part_of(label)].append(stop - start)
    receipt = "SimBridgeNode.take_command" if "SimBridgeNode.take_command" in durations else "cb:/motor_command"
    late = []
    started_late: dict[int, float] = {}  # step index: its start minus its deadline [s]
    idle_before: dict[int, float] = {}  # step index: how long the thread had been idle when it started [s]
    busy = []  # per step: from its start to the end of the last part that began before the next step [s]
    for k in range(1, len(steps)):
        i, step = steps[k]
        previous_index = steps[k - 1][0]
        busy_until = max(e[2] for e in events[previous_index:i])
        idle_before[k] = max(0.0, step[1] - busy_until)
        busy.append(busy_until - steps[k - 1][1][1])
        deadline = step[0].split(":")[2]
        if deadline == "None":
            continue
        deadline_pc = float(deadline) - offset  # this step's deadline on the perf_counter clock
        started_late[k] = step[1] - deadline_pc
        taken = [e for e in events[previous_index:i] if e[0] == receipt]
        if taken and taken[-1][1] > deadline_pc:
            late.append((k, previous_index, i, taken[-1][1] - deadline_pc))
    print(f"{'part':<36} {'calls':>7} {'median ms':>10} {'p99 ms':>8} {'max ms':>8} {'ms per s':>9}")
    table = {}
    for part, values in sorted(durations.items()):
        v = np.array(values) * 1e3
        table[part] = {"calls": len(v), "median_s": float(np.median(v)) / 1e3,
                       "p99_s": float(np.percentile(v, 99)) / 1e3, "max_s": float(v.max()) / 1e3,
                       "cpu_fraction": float(v.sum()) / 1e3 / window}
        print(f"{part:<36} {len(v):>7} {np.median(v):>10.3f} {np.percentile(v, 99):>8.3f} {v.max():>8.3f} "
              f"{v.sum() / window:>9.1f}")
    wake = np.array(list(started_late.values())) * 1e3
    print(f"\nsim step start minus its deadline: median {np.median(wake):.3f} ms, "
          f"p99 {np.percentile(wake, 99):.3f} ms, max {wake.max():.3f} ms")
    # A late step makes the next ones start late too (the sim catches up with the wall clock): the
    # first late command of each run of them is where the time went.
    firsts = [entry for n, entry in enumerate(late) if n == 0 or late[n - 1][0] != entry[0] - 1]
    print(f"late commands (reached the bridge after their step's deadline): {len(late)} of {len(steps) - 1} steps "
          f"({100 * len(late) / max(1, len(steps) - 1):.2f} %), in {len(firsts)} runs of consecutive steps")
    for k, previous_index, i, by in firsts[:show]:
        origin = events[previous_index][1]
        before = steps[max(0, k - 2)][0]
        print(f"--- the first of a run: a command {by * 1e3:.3f} ms late; the step it answers started "
              f"{started_late.get(k - 1, float('nan')) * 1e3:.3f} ms after its deadline (ms from that step's "
              "start, duration, part; gaps are waits):")
        for label, start, stop in events[before:i + 1]:
            print(f"   {(start - origin) * 1e3:8.3f} {(stop - start) * 1e3:7.3f}  {part_of(label)}")
    # A step that starts late either found the thread busy until then (the steps before it ran past
    # its deadline: the chain's own work) or idle for a while first (its wake-up came late: the OS).
    started_late_first = [k - 1 for k, *_ in firsts if started_late.get(k - 1, 0.0) > 0.5e-3]
    woke_late = sum(idle_before.get(k, 0.0) > 0.2e-3 for k in started_late_first)
    overrun = len(started_late_first) - woke_late
    work = np.array(busy) * 1e3
    print(f"of the {len(firsts)} runs, {len(started_late_first)} began with a step that started over 0.5 ms after "
          f"its deadline: {overrun} because the steps before it were still working (the chain's own work), "
          f"{woke_late} after the thread had waited over 0.2 ms (a late wake-up: the OS)")
    print(f"work a step (its start to the end of its last part): median {np.median(work):.3f} ms, p99 "
          f"{np.percentile(work, 99):.3f} ms; over 2 ms in {100 * np.mean(work > 2.0):.2f} % of steps")
    return {"window_s": window, "steps": len(steps), "late_commands": len(late), "late_runs": len(firsts),
            "late_runs_after_a_late_wake_up": woke_late, "late_runs_after_an_overrun": overrun,
            "step_work_median_s": float(np.median(work)) / 1e3, "step_work_p99_s": float(np.percentile(work, 99)) / 1e3,
            "step_work_over_2ms_fraction": float(np.mean(work > 2.0)),
            "late_command_fraction": len(late) / max(1, len(steps) - 1),
            "step_start_lateness_p99_s": float(np.percentile(wake, 99)) / 1e3,
            "parts": table}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="graph_realtime's window, wall time [s]")
    parser.add_argument("--window", type=float, default=15.0, help="analyse the last this many seconds [s]")
    parser.add_argument("--show", type=int, default=3, help="late steps to print as timelines")
    parser.add_argument("graph_realtime_args", nargs="*", help="after --: more graph_realtime.py options")
    args = parser.parse_args()
    if not 5.0 <= args.seconds <= 600.0:
        parser.error(f"--seconds must be in [5, 600], got {args.seconds}")
    if not 1.0 <= args.window <= args.seconds:
        parser.error(f"--window must be in [1, --seconds], got {args.window}")
    if args.show < 0:
        parser.error(f"--show must be at least 0, got {args.show}")
    folder = Path(tempfile.mkdtemp(prefix="chain_timeline_"))
    path = [str(HERE / "chain_timeline_hook"), os.environ.get("PYTHONPATH", "")]
    env = dict(os.environ, CHAIN_TIMELINE=str(folder / "timeline"), PYTHONPATH=os.pathsep.join(filter(None, path)))
    command = [sys.executable, str(HERE / "graph_realtime.py"), "--form", "composed", "--seconds", str(args.seconds),
               *args.graph_realtime_args]
    result = subprocess.run(command, env=env, capture_output=True, text=True)
    summary = [line for line in result.stdout.splitlines() if not line.startswith("composed t=")]
    print("\n".join(summary[:-1]))
    if result.returncode != 0:
        raise SystemExit(f"chain_timeline: graph_realtime.py failed ({result.returncode}):\n{result.stderr[-2000:]}")
    files = sorted(folder.glob("timeline.*.json"))
    if not files:
        raise SystemExit(f"chain_timeline: no timeline was written in {folder} (the control_chain process "
                         "did not exit normally?)")
    events, offset = load(files[-1])
    print()
    figures = analyse(events, offset, args.window, args.show)
    print(json.dumps({"graph_realtime": json.loads(summary[-1]) if summary else None, "timeline": figures}))


if __name__ == "__main__":
    main()
