"""Does a publish call hold the GIL while Fast DDS writes? rclpy's, against rcl's through ctypes.

In the composed chain every Python thread shares one interpreter, so a publish call that blocks
inside Fast DDS (a participant joining or leaving: docs/architecture.md, "The joiner stall, where
it sits") stops all of them if it keeps the GIL. This publishes a large serialized message (so one
call takes milliseconds) while a second Python thread loops and records its longest gap:
- ``rclpy``: ``Publisher.publish(bytes)``, what the stack's nodes call (rclpy also copies the
  bytes once under the GIL before the write, so its calls take longer for large messages);
- ``ctypes``: ``rcl_publish_serialized_message`` on the same rcl publisher
  (``Publisher.handle.pointer``), called through ctypes, which releases the GIL for the call.
A variant that holds the GIL shows a longest gap about as long as its longest publish; one that
releases it shows gaps of about the interpreter's switch interval (set to 0.2 ms here). Each
variant first publishes a few times untimed (Fast DDS fills its histories), and the two alternate
over ``--rounds``. Then the cost of one call for a message of the chain's size (a serialized
12-joint JointState), each way, back to back with no other thread running.
Memory: the writer and the unread reader keep one copy each (depth 1), so about 3x the message.

Usage: source scripts/env.sh && python benchmarks/publish_gil.py [--megabytes 16] [--publishes 15] [--rounds 2]
"""

from __future__ import annotations

import argparse
import ctypes
import json
import sys
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from rclpy.publisher import Publisher

SWITCH_INTERVAL = 0.0002  # [s] short, so a thread that releases the GIL lets the other run at once
WARM_UP = 3  # untimed publishes per variant and round
Publish = Callable[[bytes], None]


class _Allocator(ctypes.Structure):  # rcutils_allocator_t
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p), ("reallocate", ctypes.c_void_p),
                ("zero_allocate", ctypes.c_void_p), ("state", ctypes.c_void_p)]


class _ErrorString(ctypes.Structure):  # rcutils_error_string_t (rcl_get_error_string is a macro for it)
    _fields_ = [("str", ctypes.c_char * 1024)]


class _SerializedMessage(ctypes.Structure):  # rcl_serialized_message_t (rcutils_uint8_array_t)
    _fields_ = [("buffer", ctypes.c_void_p), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


def ctypes_publisher(publisher: Publisher) -> Publish:
    """A function publishing serialized bytes on ``publisher``'s rcl publisher without the GIL: the
    call a publishing thread would need so that a wait inside Fast DDS holds no other thread. It
    does not hold the publisher's handle the way rclpy does, so the publisher must outlive it."""
    # rclpy has loaded librcl.so and librcutils.so already: CDLL finds those copies by their names.
    rcl = ctypes.CDLL("librcl.so")
    rcl.rcl_publish_serialized_message.argtypes = [ctypes.c_void_p, ctypes.POINTER(_SerializedMessage),
                                                   ctypes.c_void_p]
    rcl.rcl_publish_serialized_message.restype = ctypes.c_int32
    rcutils = ctypes.CDLL("librcutils.so")
    rcutils.rcutils_get_error_string.restype = _ErrorString
    address = publisher.handle.pointer

    def publish(raw: bytes) -> None:
        buffer = ctypes.c_char_p(raw)  # points into ``raw`` (kept alive by the caller), no copy
        message = _SerializedMessage(ctypes.cast(buffer, ctypes.c_void_p), len(raw), len(raw), _Allocator())
        ret = rcl.rcl_publish_serialized_message(address, ctypes.byref(message), None)
        if ret != 0:
            error = rcutils.rcutils_get_error_string().str.decode(errors="replace")
            rcutils.rcutils_reset_error()
            raise RuntimeError(f"rcl_publish_serialized_message returned {ret}: {error}")
    return publish


def measure(publish: Publish, raw: bytes, count: int) -> tuple[list[float], float]:
    """``count`` publishes, each followed by 50 ms of sleep (the other thread runs alone then):
    their durations and the other thread's longest gap [s]."""
    for _ in range(WARM_UP):
        publish(raw)
    stop = threading.Event()
    longest = [0.0]

    def loop() -> None:
        last = time.perf_counter()
        while not stop.is_set():
            now = time.perf_counter()
            longest[0] = max(longest[0], now - last)
            last = now

    thread = threading.Thread(target=loop)
    thread.start()
    durations = []
    try:
        for _ in range(count):
            start = time.perf_counter()
            publish(raw)
            durations.append(time.perf_counter() - start)
            time.sleep(0.05)
    finally:
        stop.set()
        thread.join()
    return durations, longest[0]


def per_call(publish: Publish, raw: bytes, count: int = 20000) -> float:
    """Mean time of one publish of ``raw`` [s], back to back: what a variant costs the 2 ms step
    for each of its small messages."""
    start = time.perf_counter()
    for _ in range(count):
        publish(raw)
    return (time.perf_counter() - start) / count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--megabytes", type=float, default=16.0, help="serialized message size [MB]")
    parser.add_argument("--publishes", type=int, default=15, help="timed publishes per variant and round")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of both variants, alternating")
    args = parser.parse_args()
    if not 0.1 <= args.megabytes <= 256:
        parser.error(f"--megabytes must be in [0.1, 256], got {args.megabytes}")
    if not 1 <= args.publishes <= 1000:
        parser.error(f"--publishes must be in [1, 1000], got {args.publishes}")
    if not 1 <= args.rounds <= 20:
        parser.error(f"--rounds must be in [1, 20], got {args.rounds}")

    import rclpy
    from rclpy.node import Node
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import UInt8MultiArray

    sys.setswitchinterval(SWITCH_INTERVAL)
    rclpy.init()
    try:
        node = Node("publish_gil_probe")
        publisher = node.create_publisher(UInt8MultiArray, "/publish_gil_probe", 1)
        node.create_subscription(UInt8MultiArray, "/publish_gil_probe", lambda _: None, 1, raw=True)  # a reader
        message = UInt8MultiArray()
        message.data = bytes(int(args.megabytes * 1e6))
        raw = serialize_message(message)
        variants = {"rclpy": publisher.publish, "ctypes": ctypes_publisher(publisher)}
        durations: dict[str, list[float]] = {name: [] for name in variants}
        gap: dict[str, float] = dict.fromkeys(variants, 0.0)
        for round_ in range(args.rounds):
            for name in (list(variants) if round_ % 2 == 0 else list(variants)[::-1]):
                round_durations, round_gap = measure(variants[name], raw, args.publishes)
                durations[name] += round_durations
                gap[name] = max(gap[name], round_gap)
        message_bytes = len(raw)
        del raw, message
        joints = node.create_publisher(JointState, "/publish_gil_probe_joints", 10)
        node.create_subscription(JointState, "/publish_gil_probe_joints", lambda _: None, 10, raw=True)
        small_raw = serialize_message(JointState(name=[f"joint_{i}" for i in range(12)], position=[0.1] * 12,
                                                 velocity=[0.2] * 12, effort=[0.3] * 12))
        small = {"rclpy": per_call(joints.publish, small_raw), "ctypes": per_call(ctypes_publisher(joints), small_raw)}
        node.destroy_node()
    finally:
        rclpy.try_shutdown()

    results = {name: {"publish_median_s": float(np.median(durations[name])), "publish_max_s": max(durations[name]),
                      "other_thread_longest_gap_s": gap[name], "small_message_publish_mean_s": small[name]}
               for name in variants}
    print(f"{args.rounds} x {args.publishes} publishes of {args.megabytes:g} MB a variant, "
          f"switch interval {SWITCH_INTERVAL * 1e3:.1f} ms")
    print(f"{'variant':8} {'publish median':>15} {'publish max':>12} {'other thread longest gap':>25} "
          f"{f'one {len(small_raw)} B JointState':>24}")
    for name, r in results.items():
        print(f"{name:8} {r['publish_median_s'] * 1e3:12.2f} ms {r['publish_max_s'] * 1e3:9.2f} ms "
              f"{r['other_thread_longest_gap_s'] * 1e3:22.2f} ms {r['small_message_publish_mean_s'] * 1e6:21.2f} us")
    print(json.dumps({"message_bytes": message_bytes, "small_message_bytes": len(small_raw),
                      "publishes_per_variant": args.publishes * args.rounds, "switch_interval_s": SWITCH_INTERVAL,
                      **{f"{name}_{key}": value for name, r in results.items() for key, value in r.items()}}))


if __name__ == "__main__":
    main()
