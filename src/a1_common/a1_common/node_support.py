"""Node plumbing shared by the stack's nodes: the only rclpy-facing module of a1_common.

Numbers are declared with dynamic typing so that ``-p duration:=2`` and ``duration: 2`` in a YAML
file work for a float parameter, then converted and type-checked here with a clear error naming
the parameter, instead of rclpy's exception about INTEGER vs DOUBLE.
"""

from __future__ import annotations

import functools
import gc
import inspect
import sys
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from contextlib import ExitStack
from typing import Any

import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.executors import ExternalShutdownException, ShutdownException, SingleThreadedExecutor, TimeoutException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.subscription import Subscription

from a1_common.config import ConfigError, Constraint, parameter_defaults, parameter_descriptions

WAITABLES_PERIOD = 0.1  # [s] see DirectExecutor.spin_direct_once
# Parameters rclpy itself understands; any other override the node did not declare is a typo.
_RCLPY_PARAMETERS = {"use_sim_time", "start_type_description_service"}


def declare_parameters(node, defaults: dict[str, Any], descriptions: Mapping[str, str]) -> dict[str, Any]:
    """Declare every parameter of ``defaults`` on ``node`` with its description; return the values,
    typed like the defaults.

    Overrides (``-p`` or ``--params-file``) naming a parameter the node does not have are an error,
    not silently ignored as rclpy would. Ranges and ``read_only`` come once the node has validated
    its values (:func:`constrain_parameters`): declared with them, rclpy would refuse a bad start-up
    value with its own exception instead of the validator's message naming the allowed range.
    """
    undescribed = sorted(set(defaults) - set(descriptions))
    if undescribed:
        raise ValueError(f"node {node.get_name()}: parameters without a description: {undescribed}")
    overrides = set(getattr(node, "_parameter_overrides", {}))
    unknown = sorted(k for k in overrides - set(defaults) - _RCLPY_PARAMETERS
                     if not k.startswith("qos_overrides."))
    if unknown:
        raise ConfigError(f"unknown parameters {unknown} for node {node.get_name()}; "
                          f"allowed: {sorted(defaults)}")
    values = {}
    for name, default in defaults.items():
        descriptor = ParameterDescriptor(description=descriptions[name], dynamic_typing=True)
        value = node.declare_parameter(name, default, descriptor).value
        values[name] = coerce_parameter(name, value, default)
    return values


def declare_settings(node, *configs: Any) -> dict[str, Any]:
    """:func:`declare_parameters` for the fields of config dataclass instances (defaults and
    descriptions from a1_common.config.setting); a name in two of them is an error."""
    defaults: dict[str, Any] = {}
    descriptions: dict[str, str] = {}
    for config in configs:
        fields = parameter_defaults(config)
        twice = sorted(set(fields) & set(defaults))
        if twice:
            raise ValueError(f"node {node.get_name()}: parameters {twice} in two configs")
        defaults.update(fields)
        descriptions.update(parameter_descriptions(config))
    return declare_parameters(node, defaults, descriptions)


def constrain_parameters(node, names: Collection[str], constraints: Mapping[str, Constraint],
                         runtime: Collection[str] = ()) -> None:
    """Complete the descriptors of the parameters ``names`` (declared, values validated): the range
    their validators accept (``constraints``, from a1_common.config.recording_constraints) as an
    integer or floating-point range, and ``read_only`` for each one not in ``runtime``.

    What ``ros2 param describe`` shows; rclpy then refuses a read-only or out-of-range
    ``ros2 param set`` itself, before the node's own validation of runtime values. rclpy's
    ``use_sim_time`` is described and made read-only as well.
    """
    for name in [*names, "use_sim_time"]:  # rclpy's own, read at start-up too: the stack's stamps follow it
        declared = node.describe_parameter(name)  # rclpy's own object: changed in place, set_descriptor refuses
        descriptor = ParameterDescriptor(type=declared.type, description=declared.description,
                                         dynamic_typing=declared.dynamic_typing)
        if name == "use_sim_time":
            descriptor.description = "take time from /clock (graphs under a sim bridge) instead of the system clock"
        constraint = constraints.get(name)
        notes = [str(constraint)] if constraint is not None else []
        # A string or a list is described in words only: ROS ranges are for one number.
        if constraint is not None and not constraint.choices and constraint.count is None:
            if constraint.integer:
                descriptor.integer_range = [IntegerRange(from_value=int(constraint.low),
                                                         to_value=int(constraint.high), step=1)]
            else:
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(constraint.low), to_value=float(constraint.high), step=0.0)]
        descriptor.read_only = name not in runtime
        notes.append(f"read at start-up: restart {node.get_name()} with -p {name}:=<value>"
                     if descriptor.read_only else "settable at runtime (ros2 param set)")
        descriptor.additional_constraints = "; ".join(notes)
        node.set_descriptor(name, descriptor)


def diagnostic_array(node, status: DiagnosticStatus, values: dict[str, Any],
                     stamp: Time | None = None) -> DiagnosticArray:
    """``status`` with ``values`` as its key/value pairs, in a /diagnostics message stamped on the node's
    clock (sim time under ``use_sim_time``), or at ``stamp`` for a node that keeps the clock itself."""
    status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
    msg = DiagnosticArray(status=[status])
    msg.header.stamp = stamp if stamp is not None else node.get_clock().now().to_msg()
    return msg


def coerce_parameter(name: str, value: Any, default: Any) -> Any:
    """``value`` converted to the type of ``default`` (int -> float allowed), or ConfigError."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"parameter {name} must be true or false, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"parameter {name} must be a number, got {value!r}")
        return float(value)
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"parameter {name} must be an integer, got {value!r}")
        return value
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ConfigError(f"parameter {name} must be a string, got {value!r}")
        return value
    return value


class DirectExecutor(SingleThreadedExecutor):
    """A SingleThreadedExecutor that takes messages straight out of its wait set and calls the
    subscription callbacks (plain functions); everything else (timers, services, parameter
    requests, clients, coroutine callbacks, tasks) goes through rclpy's own dispatch.

    Why: rclpy's dispatch rebuilds a wait set over every entity of the node and wraps each message
    in a Task: about 0.35 ms of CPU per message on the 2-core machine, measured, which at three
    sensor topics x 500 Hz is more than half a core. Taken directly a message costs about 0.1 ms.

    The entities are gathered once and their handles held (as rclpy holds them during a wait, so
    that a destroy from a callback or another thread waits until they are let go); rclpy wakes the
    executor on every change, and the next wait gathers them anew.
    """

    def __init__(self, *, context: Context | None = None) -> None:
        self._entities_stale = True  # before super(): it may wake us
        super().__init__(context=context)
        self._held = ExitStack()  # the handles of the gathered entities
        self._wait_sets: dict[bool, Any] = {}  # with / without the waitables
        self._next_waitables = 0.0  # monotonic time [s] the waitables are next waited on

    def wake(self) -> None:
        self._entities_stale = True  # an entity or node came or went (rclpy wakes us then), or work
        super().wake()

    def add_node(self, node) -> bool:
        self._entities_stale = True
        return super().add_node(node)

    def remove_node(self, node) -> None:
        self._entities_stale = True
        super().remove_node(node)

    def spin(self, poll: Callable[[], float] | None = None) -> None:
        """Spin until shutdown; ``poll`` (if given) runs between waits, does the work due outside
        callbacks (a simulation step) and returns how long the next wait may last [s]."""
        try:
            while self._context.ok() and not self._is_shutdown:
                self.spin_direct_once(None if poll is None else poll())
        finally:
            self._held.close()

    def spin_direct_once(self, timeout_sec: float | None = None) -> None:
        """Wait for any entity (up to ``timeout_sec``, None: no limit), then run what is ready.

        Waitables (the QoS event handlers every publisher and subscription has) are waited on every
        WAITABLES_PERIOD only: filling 20 of them into the wait set cost 60 us a wake-up, measured.
        While rclpy has a task in progress (a coroutine callback, a future's callback), a whole
        iteration is rclpy's: it runs tasks and respects callback groups.
        """
        if self._tasks_pending():
            SingleThreadedExecutor.spin_once(self, timeout_sec)
            return
        self._refresh_entities()
        now = time.monotonic()
        with_waitables = now >= self._next_waitables
        if with_waitables:
            self._next_waitables = now + WAITABLES_PERIOD
        limit = -1 if timeout_sec is None else round(timeout_sec * 1e9)
        if not with_waitables and self._waitables:
            until_waitables = round((self._next_waitables - now) * 1e9)
            limit = until_waitables if limit < 0 else min(limit, until_waitables)
        wait_set = self._fill(with_waitables)
        wait_set.wait(limit)
        if self._is_shutdown:
            return
        if not self._context.ok():
            raise ExternalShutdownException()
        ready_subs = set(wait_set.get_ready_entities("subscription"))
        for sub, with_info in self._direct:
            if sub.handle.pointer in ready_subs:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
                if taken is not None:
                    sub.callback(*taken) if with_info else sub.callback(taken[0])
                    if self._is_shutdown:  # the callback shut the executor down
                        return
        ready_guards = wait_set.get_ready_entities("guard_condition")
        node_guards = [guard for guard in self._guards[2:] if guard.handle.pointer in ready_guards]
        for guard in node_guards:
            guard.trigger()  # this wait took the trigger: offer it again to rclpy's dispatch
        if (node_guards or any(sub.handle.pointer in ready_subs for sub in self._left_to_rclpy)
                or wait_set.get_ready_entities("timer") or wait_set.get_ready_entities("client")
                or wait_set.get_ready_entities("service") or self._tasks_pending()
                or (with_waitables and any(waitable.is_ready(wait_set) for waitable in self._waitables))):
            self._dispatch_ready()

    def _tasks_pending(self) -> bool:
        """rclpy has a task not done (its list keeps finished ones until its next pass)."""
        with self._tasks_lock:
            return any(not task.done() for task, _, _ in self._tasks)

    def _refresh_entities(self) -> None:
        """Gather the nodes' entities and hold their handles, after a change (see wake)."""
        if not self._entities_stale:
            return
        self._entities_stale = False
        self._held.close()  # destroys requested meanwhile happen now
        self._held = ExitStack()
        self._held.enter_context(self._context.handle)
        held = []
        for entity in [self._guard, self._sigint_gc]:  # the executor's own first: wake-ups only
            self._held.enter_context(entity.handle)
            held.append(entity)
        self._guards = held
        self._subs, self._timers, self._clients, self._services, self._waitables = [], [], [], [], []
        for node in self.get_nodes():
            for target, entities in ((self._subs, node.subscriptions), (self._timers, node.timers),
                                     (self._clients, node.clients), (self._services, node.services),
                                     (self._guards, node.guards), (self._waitables, node.waitables)):
                for entity in entities:
                    try:
                        self._held.enter_context(entity if target is self._waitables else entity.handle)
                    except InvalidHandle:
                        continue  # destroyed already
                    target.append(entity)
        self._direct = [(sub, sub._callback_type == Subscription.CallbackType.WithMessageInfo)
                        for sub in self._subs if not inspect.iscoroutinefunction(sub.callback)]
        self._left_to_rclpy = [sub for sub in self._subs if inspect.iscoroutinefunction(sub.callback)]
        self._wait_sets.clear()

    def _fill(self, with_waitables: bool):
        """The wait set (made once per set of entities), filled with them."""
        wait_set = self._wait_sets.get(with_waitables)
        if wait_set is None:
            counts = [len(self._subs), len(self._guards), len(self._timers), len(self._clients),
                      len(self._services), 0]
            for waitable in self._waitables if with_waitables else ():
                n = waitable.get_num_entities()
                counts = [a + b for a, b in zip(counts, (
                    n.num_subscriptions, n.num_guard_conditions, n.num_timers, n.num_clients, n.num_services,
                    n.num_events), strict=True)]
            wait_set = self._wait_sets[with_waitables] = _rclpy.WaitSet(*counts, self._context.handle)
        wait_set.clear_entities()
        for entity in self._subs:
            wait_set.add_subscription(entity.handle)
        for entity in self._timers:
            wait_set.add_timer(entity.handle)
        for entity in self._clients:
            wait_set.add_client(entity.handle)
        for entity in self._services:
            wait_set.add_service(entity.handle)
        for entity in self._guards:
            wait_set.add_guard_condition(entity.handle)
        for waitable in self._waitables if with_waitables else ():
            waitable.add_to_wait_set(wait_set)
        return wait_set

    def _dispatch_ready(self) -> None:
        """Run every callback rclpy's own dispatch finds ready now, without waiting."""
        while True:
            try:
                handler, _, _ = self.wait_for_ready_callbacks(timeout_sec=0)
            except (TimeoutException, ShutdownException):
                return
            handler()
            if handler.exception() is not None:
                raise handler.exception()


def run_node(name: str, factory: Callable[[], Any], args: list[str] | None = None) -> None:
    """Create the node from ``factory`` and spin it until Ctrl-C / SIGTERM / shutdown (see run_nodes)."""
    run_nodes(name, [factory], args)


def run_nodes(name: str, factories: Sequence[Callable[[], Any]], args: list[str] | None = None, *,
              poll: Callable[[Sequence[Any]], float] | None = None,
              connect: Callable[[Sequence[Any]], None] | None = None) -> None:
    """Create the nodes from ``factories`` (in order) and spin them in one DirectExecutor until
    Ctrl-C / SIGTERM / shutdown; one node a process (``ros2 run`` of a node) or several composed in
    one (a1_bringup's control_chain), each its own rclpy node with its own name and parameters.

    Configuration errors end the process with exit code 2 and one readable line; a node that sets
    ``node.failure`` (its own thread died) ends it with exit code 1. The nodes are shut down in the
    reverse order of their creation (a controller stops before the bridge it commands). ``poll``,
    given the nodes, runs between the executor's waits (see DirectExecutor.spin); ``connect``, given
    the nodes, runs once they all exist (in-process hand-offs between them).
    """
    rclpy.init(args=args)
    nodes: list[Any] = []
    try:
        executor = DirectExecutor()
        for factory in factories:
            nodes.append(factory())
            executor.add_node(nodes[-1])
        if connect is not None:
            connect(nodes)
        # Start-up objects (modules, the nodes) are never garbage: keeping them out of the cyclic
        # collector's full passes keeps those passes from stalling a 2 ms control step.
        gc.freeze()
        executor.spin(None if poll is None else functools.partial(poll, nodes))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:  # rclpy's RCLError derives from it
        if rclpy.ok():
            raise
        # Ctrl-C / SIGTERM shut the context down under a running spin: a normal stop.
    except ConfigError as exc:
        print(f"{name}: configuration error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    finally:
        for node in reversed(nodes):
            if hasattr(node, "shutdown"):
                node.shutdown()
            node.destroy_node()
        rclpy.try_shutdown()
    if any(getattr(node, "failure", None) is not None for node in nodes):
        raise SystemExit(1)
