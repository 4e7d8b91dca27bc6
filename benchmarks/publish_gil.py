"""Does a publish call hold the GIL while Fast DDS writes? rclpy's, against rcl's through ctypes.

In the composed chain every Python thread shares one interpreter, so a publish call that blocks
inside Fast DDS (a participant joining or leaving: docs/architecture.md, "The joiner stall, where
it sits") stops all of them if it keeps the GIL. This publishes a large serialized message (so one
call takes milliseconds) while a second Python thread loops and records its longest gap:
- ``rclpy``: ``Publisher.publish(bytes)``, what the stack's nodes call;
- ``ctypes``: ``rcl_publish_serialized_message`` on the same rcl publisher
  (``Publisher.handle.pointer``), called through ctypes, which releases the GIL for the call.
A variant that holds the GIL shows a longest gap close to its longest publish; one that releases
it shows gaps of about the interpreter's switch interval (set to 0.2 ms here). Then the cost of
one call for a message of the chain's size (a 12-joint JointState), each way, back to back.

Usage: source scripts/env.sh && python benchmarks/publish_gil.py [--megabytes 16] [--publishes 30]
"""

from __future__ import annotations

import argparse
import ctypes
import json
import sys
import threading
import time

import numpy as np

SWITCH_INTERVAL = 0.0002  # [s] short, so a thread that releases the GIL lets the other run at once


class _Allocator(ctypes.Structure):  # rcutils_allocator_t
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p), ("reallocate", ctypes.c_void_p),
                ("zero_allocate", ctypes.c_void_p), ("state", ctypes.c_void_p)]


class _SerializedMessage(ctypes.Structure):  # rcl_serialized_message_t (rcutils_uint8_array_t)
    _fields_ = [("buffer", ctypes.c_void_p), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


def ctypes_publisher(publisher):
    """A function publishing serialized bytes on ``publisher``'s rcl publisher without the GIL."""
    rcl = ctypes.CDLL("librcl.so")
    rcl.rcl_publish_serialized_message.argtypes = [ctypes.c_void_p, ctypes.POINTER(_SerializedMessage),
                                                   ctypes.c_void_p]
    rcl.rcl_publish_serialized_message.restype = ctypes.c_int32
    address = publisher.handle.pointer

    def publish(raw: bytes) -> None:
        buffer = ctypes.c_char_p(raw)  # points into ``raw`` (kept alive by the caller), no copy
        message = _SerializedMessage(ctypes.cast(buffer, ctypes.c_void_p), len(raw), len(raw), _Allocator())
        ret = rcl.rcl_publish_serialized_message(address, ctypes.byref(message), None)
        if ret != 0:
            raise RuntimeError(f"rcl_publish_serialized_message returned {ret}")
    return publish


def measure(publish, raw: bytes, count: int) -> dict:
    """``count`` publishes 50 ms apart; their durations and the other thread's longest gap [s]."""
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
    for _ in range(count):
        start = time.perf_counter()
        publish(raw)
        durations.append(time.perf_counter() - start)
        time.sleep(0.05)
    stop.set()
    thread.join()
    return {"publish_median_s": float(np.median(durations)), "publish_max_s": max(durations),
            "other_thread_longest_gap_s": longest[0]}


def per_call(publish, raw: bytes, count: int = 20000) -> float:
    """Mean time of one publish of ``raw`` [s], back to back."""
    start = time.perf_counter()
    for _ in range(count):
        publish(raw)
    return (time.perf_counter() - start) / count


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--megabytes", type=float, default=16.0, help="serialized message size [MB]")
    parser.add_argument("--publishes", type=int, default=30)
    args = parser.parse_args()
    if not 0.1 <= args.megabytes <= 256:
        parser.error(f"--megabytes must be in [0.1, 256], got {args.megabytes}")
    if not 1 <= args.publishes <= 1000:
        parser.error(f"--publishes must be in [1, 1000], got {args.publishes}")

    import rclpy
    from rclpy.node import Node
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import UInt8MultiArray

    sys.setswitchinterval(SWITCH_INTERVAL)
    rclpy.init()
    node = Node("publish_gil_probe")
    publisher = node.create_publisher(UInt8MultiArray, "/publish_gil_probe", 10)
    node.create_subscription(UInt8MultiArray, "/publish_gil_probe", lambda _: None, 10, raw=True)  # a reader
    message = UInt8MultiArray()
    message.data = bytes(int(args.megabytes * 1e6))
    raw = serialize_message(message)
    results = {"rclpy": measure(publisher.publish, raw, args.publishes),
               "ctypes": measure(ctypes_publisher(publisher), raw, args.publishes)}
    joints = node.create_publisher(JointState, "/publish_gil_probe_joints", 10)
    node.create_subscription(JointState, "/publish_gil_probe_joints", lambda _: None, 10, raw=True)
    small = JointState(name=[f"joint_{i}" for i in range(12)], position=[0.1] * 12, velocity=[0.2] * 12,
                       effort=[0.3] * 12)
    small_raw = serialize_message(small)
    for name, publish in (("rclpy", joints.publish), ("ctypes", ctypes_publisher(joints))):
        results[name]["small_message_publish_mean_s"] = per_call(publish, small_raw)
    node.destroy_node()
    rclpy.shutdown()

    print(f"{args.publishes} publishes of {len(raw) / 1e6:.1f} MB, switch interval {SWITCH_INTERVAL * 1e3:.1f} ms")
    print(f"{'variant':8} {'publish median':>15} {'publish max':>12} {'other thread longest gap':>25} "
          f"{f'one {len(small_raw)} B JointState':>24}")
    for name, r in results.items():
        print(f"{name:8} {r['publish_median_s'] * 1e3:12.2f} ms {r['publish_max_s'] * 1e3:9.2f} ms "
              f"{r['other_thread_longest_gap_s'] * 1e3:22.2f} ms {r['small_message_publish_mean_s'] * 1e6:21.2f} us")
    print(json.dumps({"message_bytes": len(raw), "small_message_bytes": len(small_raw), "publishes": args.publishes,
                      "switch_interval_s": SWITCH_INTERVAL,
                      **{f"{name}_{key}": value for name, r in results.items() for key, value in r.items()}}))


if __name__ == "__main__":
    main()
