"""How late this machine's OS wakes a thread that sleeps to a 2 ms deadline, with no ROS at all.

The composed chain's missed deadlines begin with a sim step that started late
(``benchmarks/chain_timeline.py``): its thread woke late, or the steps before it overran. Their
share differs between instances of the same machine type with the same code. This probe separates
the OS and the CPU the hypervisor gives this process from the stack:
one thread sleeps to absolute deadlines every ``--period-ms`` (the sim bridge's step), at
SCHED_FIFO ``--fifo`` when permitted (the realtime bring-up's scheduling), and records how late each
wake-up was. ``--busy N`` starts N processes that spin at normal priority, as the chain's other work
and the gait policy load the cores; a FIFO thread should still wake on time beside them.

``--work-ms W`` does W ms of fixed work (small numpy operations, calibrated at the start) after each
wake-up, as the chain's step does: the duration of the same work, wake-up after wake-up, shows how
steady the CPU this process gets is (a neighbour on the host slows it without any steal time), and
the share of steps that end after the next deadline is what a loop with that much work misses here.

``--wait`` picks how the thread sleeps:
- ``sleep``: ``time.sleep``, the OS timer alone;
- ``executor``: the composed chain's own wait, ``DirectExecutor.spin_direct_once`` over an rclpy
  node with one subscription, every thread of the process at the FIFO priority (as control_chain
  sets it): the OS timer through rcl_wait and Fast DDS's wait set;
- ``publish``: ``executor``, and each wake-up publishes a 12-joint /joint_states-sized message on
  the probe's own topic, which its subscription takes: the chain's traffic in miniature.

Prints the lateness distribution, the share of wake-ups later than 0.1 / 0.5 / 1 / 2 ms (a wake-up
over 0.5 ms late leaves the 2 ms step too little time), the worst, the CPU time the hypervisor
reports stolen (``steal`` in /proc/stat) and this thread's involuntary context switches, then one
JSON line. Compare it with ``graph_realtime.py``'s missed share on the same instance, quiet
(pause a training run with ``kill -STOP`` first).

Usage: source scripts/env.sh && python benchmarks/wakeup_latency.py [--seconds 30] [--period-ms 2.0]
           [--fifo 50] [--busy 1] [--wait sleep|executor|publish] [--work-ms 1.5]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import time
from collections.abc import Callable

import numpy as np

THRESHOLDS_MS = (0.1, 0.5, 1.0, 2.0)


def steal_ticks() -> int:
    """Clock ticks the hypervisor ran something else while this VM's CPUs wanted to run (all CPUs)."""
    with open("/proc/stat") as stat:
        fields = stat.readline().split()  # cpu user nice system idle iowait irq softirq steal ...
    return int(fields[8]) if len(fields) > 8 else 0


def involuntary_switches() -> int:
    """Times this thread was preempted (Linux, per thread)."""
    with open(f"/proc/self/task/{os.getpid()}/status") as status:
        for line in status:
            if line.startswith("nonvoluntary_ctxt_switches"):
                return int(line.split()[1])
    return 0


def spin() -> None:
    """A busy process at normal priority: load for the other core(s)."""
    while True:
        pass


def set_fifo(priority: int) -> int:
    """SCHED_FIFO at ``priority`` for this process; the priority in force (0: not permitted or not asked)."""
    if priority <= 0:
        return 0
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        print(f"wakeup_latency: SCHED_FIFO {priority} not permitted here; measuring at normal priority")
        return 0
    return priority


def measure(seconds: float, period: float, wait_for: Callable[[float], None],
            on_wake: Callable[[], None] = lambda: None) -> tuple[np.ndarray, np.ndarray]:
    """Wait to each absolute deadline for ``seconds`` (``wait_for(seconds)`` returns at the
    earliest then) and call ``on_wake``; each wake-up's lateness and ``on_wake``'s duration [s].
    Behind its deadlines the loop catches up without waiting, and it gives up the deadlines it
    missed only when over 0.1 s behind: the sim bridge's rules."""
    lateness, work = [], []
    start = time.monotonic()
    deadline = start + period
    end = start + seconds
    while deadline < end:
        wait = deadline - time.monotonic()
        while wait > 0.0:  # an executor's wait may return early (a message came)
            wait_for(wait)
            wait = deadline - time.monotonic()
        now = time.monotonic()
        on_wake()
        lateness.append(now - deadline)
        work.append(time.monotonic() - now)
        deadline += period
        if now - deadline > 0.1:
            deadline = now
    return np.asarray(lateness), np.asarray(work)


def work_unit(vector: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """A slice of work like the controller's: small numpy operations and Python between them."""
    for _ in range(8):
        vector = matrix @ vector
        vector = vector / (1.0 + float(np.abs(vector).sum()))
    return vector


def calibrated_work(milliseconds: float) -> Callable[[], None]:
    """A function whose median duration here and now is about ``milliseconds``."""
    rng = np.random.default_rng(0)
    vector, matrix = rng.normal(size=3), rng.normal(size=(3, 3))
    durations = []
    for _ in range(200):
        began = time.perf_counter()
        work_unit(vector, matrix)
        durations.append(time.perf_counter() - began)
    units = max(1, round(milliseconds * 1e-3 / float(np.median(durations))))

    def work() -> None:
        for _ in range(units):
            work_unit(vector, matrix)

    return work


def executor_waiting(priority: int, publish: bool) -> tuple[Callable[[float], None], Callable[[], None],
                                                             Callable[[], None], int]:
    """The chain's wait in a probe node: (wait_for, on_wake, close, FIFO priority in force)."""
    import rclpy
    from a1_bringup.control_chain import use_realtime_priority
    from a1_common.node_support import DirectExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    rclpy.init(args=[])
    node = Node("wakeup_latency_probe")
    taken = []
    node.create_subscription(JointState, "~/joint_states", taken.append, 10)
    publisher = node.create_publisher(JointState, "~/joint_states", 10)
    executor = DirectExecutor()
    executor.add_node(node)
    priority = priority if use_realtime_priority(priority) else 0  # after rclpy's threads exist
    message = JointState(name=[f"joint_{i}" for i in range(12)], position=[0.0] * 12, velocity=[0.0] * 12,
                         effort=[0.0] * 12)

    def on_wake() -> None:
        if publish:
            publisher.publish(message)
        taken.clear()

    def close() -> None:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()

    return executor.spin_direct_once, on_wake, close, priority


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="measuring time [s] (default 30)")
    parser.add_argument("--period-ms", type=float, default=2.0, help="sleep period [ms] (default 2.0: 500 Hz)")
    parser.add_argument("--fifo", type=int, default=50,
                        help="SCHED_FIFO priority 1-99 of the sleeping thread, 0 for normal scheduling (default 50)")
    parser.add_argument("--busy", type=int, default=0, help="busy processes at normal priority beside it (default 0)")
    parser.add_argument("--work-ms", type=float, default=0.0,
                        help="fixed work after each wake-up [ms] (default 0: none; the chain's step is about 1.5)")
    parser.add_argument("--wait", choices=("sleep", "executor", "publish"), default="sleep",
                        help="how the thread waits (default sleep; see the module's docstring)")
    args = parser.parse_args()
    if not 1.0 <= args.seconds <= 3600.0:
        parser.error(f"--seconds {args.seconds}: allowed 1 to 3600")
    if not 0.1 <= args.period_ms <= 100.0:
        parser.error(f"--period-ms {args.period_ms}: allowed 0.1 to 100")
    if not 0 <= args.fifo <= 99:
        parser.error(f"--fifo {args.fifo}: allowed 0 (normal scheduling) to 99")
    if not 0 <= args.busy <= 64:
        parser.error(f"--busy {args.busy}: allowed 0 to 64")
    if not 0.0 <= args.work_ms < args.period_ms:
        parser.error(f"--work-ms {args.work_ms}: allowed 0 to under --period-ms ({args.period_ms})")

    busy = [multiprocessing.Process(target=spin, daemon=True) for _ in range(args.busy)]
    for process in busy:
        process.start()
    try:
        if args.wait == "sleep":
            priority = set_fifo(args.fifo)
            wait_for, on_wake, close = time.sleep, (lambda: None), (lambda: None)
        else:
            wait_for, on_wake, close, priority = executor_waiting(args.fifo, args.wait == "publish")
        if args.work_ms > 0.0:
            work, wake_only = calibrated_work(args.work_ms), on_wake

            def on_wake() -> None:
                wake_only()
                work()
        try:
            steal0, switches0, wall0 = steal_ticks(), involuntary_switches(), time.monotonic()
            lateness, work_s = measure(args.seconds, args.period_ms * 1e-3, wait_for, on_wake)
            lateness_ms, work_ms = 1e3 * lateness, 1e3 * work_s
            wall = time.monotonic() - wall0
            steal_s = (steal_ticks() - steal0) / os.sysconf("SC_CLK_TCK")
            switches = involuntary_switches() - switches0
        finally:
            close()
    finally:
        for process in busy:
            process.terminate()

    print(f"wake-ups every {args.period_ms:g} ms by {args.wait} for {wall:.1f} s, SCHED_FIFO {priority or 'off'}, "
          f"{args.busy} busy process(es) beside, {os.cpu_count()} CPUs")
    print(f"{'wake-ups':>9} {'median':>8} {'p99':>8} {'p99.9':>8} {'max':>8}   [ms late]")
    quantiles = np.percentile(lateness_ms, [50, 99, 99.9])
    print(f"{lateness_ms.size:>9d} {quantiles[0]:8.3f} {quantiles[1]:8.3f} {quantiles[2]:8.3f} "
          f"{lateness_ms.max():8.3f}")
    shares = {t: float(np.mean(lateness_ms > t)) for t in THRESHOLDS_MS}
    print("late by more than: " + ", ".join(f"{t:g} ms {100 * s:.3f} %" for t, s in shares.items()))
    print(f"stolen by the hypervisor: {steal_s:.2f} CPU-s over {wall:.1f} s; involuntary switches: {switches}")
    figures = {}
    if args.work_ms > 0.0:
        # A step's output is due by the next deadline (the chain's command for the next sim step).
        missed = lateness_ms + work_ms > args.period_ms
        per_half_second = np.convolve(work_ms, np.ones(250) / 250, mode="valid") if work_ms.size >= 250 else work_ms
        print(f"work after each wake-up [ms]: median {np.median(work_ms):.3f}, p90 {np.percentile(work_ms, 90):.3f}, "
              f"p99 {np.percentile(work_ms, 99):.3f}; its mean over 250 wake-ups ranged "
              f"{per_half_second.min():.3f} to {per_half_second.max():.3f}")
        print(f"steps that ended after the next deadline: {100 * missed.mean():.2f} %")
        figures = {"work_median_s": round(float(np.median(work_ms)) * 1e-3, 7),
                   "work_p99_s": round(float(np.percentile(work_ms, 99)) * 1e-3, 7),
                   "work_mean_250_min_s": round(float(per_half_second.min()) * 1e-3, 7),
                   "work_mean_250_max_s": round(float(per_half_second.max()) * 1e-3, 7),
                   "missed_fraction": round(float(missed.mean()), 6)}
    print(json.dumps({
        "wait": args.wait, "period_s": args.period_ms * 1e-3, "seconds": round(wall, 3), "fifo_priority": priority,
        "busy_processes": args.busy, "cpus": os.cpu_count(), "wakeups": int(lateness_ms.size),
        "lateness_median_s": round(quantiles[0] * 1e-3, 7), "lateness_p99_s": round(quantiles[1] * 1e-3, 7),
        "lateness_p999_s": round(quantiles[2] * 1e-3, 7), "lateness_max_s": round(float(lateness_ms.max()) * 1e-3, 7),
        **{f"share_late_over_{t:g}ms": round(s, 6) for t, s in shares.items()},
        "steal_cpu_s": round(steal_s, 3), "involuntary_switches": switches, "work_ms": args.work_ms, **figures,
    }))


if __name__ == "__main__":
    main()
