"""Timeline hook for benchmarks/chain_timeline.py: loaded by every Python process started with this
folder on PYTHONPATH, it acts only in the control_chain process and only with CHAIN_TIMELINE set.

It wraps the parts of the composed 500 Hz step (the sim bridge's step and publishing, each
subscription callback, the controller step, the MPC hand-off, the filter update, /odom, garbage
collections) to record (label, start, end) on the perf_counter clock, and writes the newest
events as JSON to ``$CHAIN_TIMELINE.<pid>.json`` when the process exits. Benchmark tooling only:
nothing of the stack imports it.
"""

import atexit
import collections
import gc
import importlib
import inspect
import json
import os
import sys
import time

TRACED = (  # module: Class.method, each recorded under "Class.method"
    "convex_mpc_node.node:ConvexMpcNode._control",
    "convex_mpc_node.mpc_worker:MpcWorkerProcess.submit",
    "convex_mpc_node.mpc_worker:MpcWorkerProcess.poll",
    "state_estimator_node.frontend:OdometryFrontend.update",
    "state_estimator_node.node:OdometryPublisher.publish",
    "a1_sim_bridge.node:SimBridgeNode.take_command",
    "a1_sim_bridge.node:SimBridgeNode._publish",
)


def _install(path: str) -> None:
    from a1_common import node_support
    from a1_sim_bridge import node as sim_node

    events: collections.deque = collections.deque(maxlen=600_000)  # about 20 s of a 500 Hz chain
    clock = time.perf_counter
    gc_start = [0.0]

    def on_gc(phase: str, info: dict) -> None:
        if phase == "start":
            gc_start[0] = clock()
        else:
            events.append((f"gc{info['generation']}", gc_start[0], clock()))

    gc.callbacks.append(on_gc)

    def wrap(cls, name: str, label: str) -> None:
        original = getattr(cls, name)

        def traced(self, *args, **kwargs):
            start = clock()
            try:
                return original(self, *args, **kwargs)
            finally:
                events.append((label, start, clock()))

        setattr(cls, name, traced)

    for spec in TRACED:
        module, qualified = spec.split(":")
        cls_name, method = qualified.split(".")
        wrap(getattr(importlib.import_module(module), cls_name), method, qualified)

    advance = sim_node.SimBridgeNode._advance

    def traced_advance(self):  # the step, with its deadline (monotonic) and the commands accepted so far
        start, accepted, deadline = clock(), self.watchdog.accepted, self._next_deadline
        try:
            return advance(self)
        finally:
            events.append((f"advance:{accepted}:{deadline}", start, clock()))

    sim_node.SimBridgeNode._advance = traced_advance

    refresh = node_support.DirectExecutor._refresh_entities

    def traced_refresh(self):  # each (plain) subscription callback, labelled by its topic
        refresh(self)
        for sub in self._subs:
            callback = sub.callback
            if getattr(callback, "_timeline", False) or inspect.iscoroutinefunction(callback):
                continue

            def traced(*args, _callback=callback, _label=f"cb:{sub.topic_name}"):
                start = clock()
                try:
                    return _callback(*args)
                finally:
                    events.append((_label, start, clock()))

            traced._timeline = True
            callback_type = sub._callback_type
            sub.callback = traced
            sub._callback_type = callback_type  # the setter guesses it from the signature: keep the original

    node_support.DirectExecutor._refresh_entities = traced_refresh
    dispatch = node_support.DirectExecutor._dispatch_ready

    def traced_dispatch(self, *args, **kwargs):  # timers, services, parameter events: rclpy's dispatch
        start = clock()
        try:
            return dispatch(self, *args, **kwargs)
        finally:
            events.append(("rclpy_dispatch", start, clock()))

    node_support.DirectExecutor._dispatch_ready = traced_dispatch

    def dump() -> None:
        with open(f"{path}.{os.getpid()}.json", "w") as f:
            json.dump({"monotonic_minus_perf_counter_s": time.monotonic() - clock(), "events": list(events)}, f)

    atexit.register(dump)


if os.environ.get("CHAIN_TIMELINE") and any(arg.endswith("control_chain") for arg in sys.argv[:2]):
    _install(os.environ["CHAIN_TIMELINE"])
