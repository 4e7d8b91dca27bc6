"""control_chain: the 500 Hz chain (bridge, estimator, controller) composed in one process.

The same rclpy nodes as ``ros2 run`` of each (sim_bridge or hw_bridge, state_estimator, convex_mpc),
with their own names, parameters and topics, spun by one executor in one process: a sensor message
and the command it triggers never cross a process boundary, so the 2 ms step pays no wake-up of
another process and no shared-memory transport (Fast DDS delivers within a process directly).
With the sim bridge, the simulation steps in the executor's thread too (SimBridgeNode.poll): one
Python thread does the whole step, and no second one waits for the GIL inside it; the controller
hands each command to the bridge (sim or hardware) as it publishes it (``take_command``), so the
step need not wait for the executor to take it back off the wire; and with the sim bridge and the
estimator embedded in the controller, the bridge hands each step's sensors to the controller as it
publishes them (``sensor_sinks``), so one call runs physics, sensors, control and command. What another
process sees on the wire (``ros2 topic echo``) is unchanged; ``ros2 node info`` then lists no sensor
subscriptions for convex_mpc, since it takes them by hand-off.

    control_chain --bridge sim [--estimator] --set sim_bridge.clock_mode=realtime ... \\
        --ros-args --params-file config/a1_sim_bridge.yaml --params-file config/convex_mpc.yaml ...

Parameter files are keyed by node name (``/**/sim_bridge``), so one process takes them all. A value
for one node is ``--set <node>.<name>=<value>`` (YAML-typed, like ``-p``): ROS's own
``-p <node>:<name>:=<value>`` misses a node that runs in a namespace (``-r __ns:=/a1_1``), and a
plain ``-p`` sets every node. ``--estimator`` adds the state_estimator node (a lockstep graph whose
controller does not embed it). a1_bringup.graph writes these command lines.
Killing the process stops the bridge with the controller: the simulated robot is gone with it, and
the real (or virtual) A1 damps its motors on its own once the commands stop, as with a dead controller.

``--realtime-priority N`` (realtime bring-up: a1_bringup.graph's ``CHAIN_PRIORITY``) runs the
process at SCHED_FIFO N, so a user's tool starting beside it (a new Python process takes most of a
core for a second) does not delay its 2 ms steps; where that is not permitted it says so and runs at
normal priority. Its threads, Fast DDS's included, inherit it; the MPC worker runs one lower.
With the hardware bridge its UDP link thread shares the interpreter with the executor's thread, so
the process hands the GIL over after 0.5 ms instead of Python's 5 ms (``LINK_SWITCH_INTERVAL``).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import os
import sys
from collections.abc import Callable
from typing import Any

import yaml
from a1_common.config import parse_yaml
from rclpy.parameter import Parameter
from rclpy.utilities import remove_ros_args

from a1_bringup.graph import parse_setting

CHAIN_BRIDGES = ("sim", "hardware")
# [s] sys.setswitchinterval with the hardware bridge: a state that arrives while the executor's thread
# runs Python waits at most this long for the GIL (Python's default 5 ms is over two control
# periods). Measured against the virtual A1: docs/architecture.md, "Realtime priority by default".
LINK_SWITCH_INTERVAL = 0.0005


def chain_nodes(bridge: str, estimator: bool) -> list[tuple[str, Callable[..., Any]]]:
    """(node name, node class) of the chain in start order: bridge, estimator (if asked),
    controller. Imported here so that a hardware chain never loads the simulator."""
    if bridge == "sim":
        from a1_sim_bridge.node import SimBridgeNode as Bridge
    elif bridge == "hardware":
        from a1_hw_bridge.node import HardwareBridgeNode as Bridge
    else:
        raise ValueError(f"bridge must be one of {list(CHAIN_BRIDGES)}, got {bridge!r}")
    from convex_mpc_node.node import ConvexMpcNode

    nodes: list[tuple[str, Callable[..., Any]]] = [("sim_bridge" if bridge == "sim" else "hw_bridge", Bridge)]
    if estimator:
        from state_estimator_node.node import StateEstimatorNode

        nodes.append(("state_estimator", StateEstimatorNode))
    nodes.append(("convex_mpc", ConvexMpcNode))
    return nodes


def parse_settings(settings: list[str], names: list[str]) -> dict[str, list[Parameter]]:
    """``node.param=value`` items as each node's parameter overrides; ValueError naming the item."""
    overrides: dict[str, list[Parameter]] = {name: [] for name in names}
    for item in settings:
        node, param, text = parse_setting(item, names, "chain")
        try:
            value = parse_yaml(text) if text else ""
            overrides[node].append(Parameter(param, value=value))
        except (yaml.YAMLError, TypeError) as exc:
            raise ValueError(f"--set {item!r}: not a parameter value: {exc}") from None
    return overrides


def main(args: list[str] | None = None) -> None:
    argv = sys.argv if args is None else args
    parser = argparse.ArgumentParser(prog="control_chain", description=__doc__.split("\n")[0])
    parser.add_argument("--bridge", choices=CHAIN_BRIDGES, default="sim",
                        help="sim: the PyBullet A1 (sim_bridge); hardware: an A1 over UDP (hw_bridge)")
    parser.add_argument("--estimator", action="store_true",
                        help="also run the state_estimator node (for a controller without embedded_estimator)")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.PARAM=VALUE",
                        help="a parameter of one node of the chain (repeatable; after its parameter files)")
    parser.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                        help="run at SCHED_FIFO N, 1-99 (0: normal scheduling; refused: a message, then normal)")
    options = parser.parse_args(remove_ros_args(argv)[1:])
    if not 0 <= options.realtime_priority <= 99:
        parser.error(f"--realtime-priority must be in [0, 99], got {options.realtime_priority}")
    prepare_process(options.bridge, options.realtime_priority)
    nodes = chain_nodes(options.bridge, options.estimator)
    try:
        overrides = parse_settings(options.set, [name for name, _ in nodes])
    except ValueError as exc:
        parser.error(str(exc))
    from a1_common.node_support import run_nodes

    factories = [functools.partial(cls, parameter_overrides=overrides[name]) for name, cls in nodes]
    if options.bridge == "sim":  # the simulation steps in the executor's thread: one Python thread
        factories[0] = functools.partial(factories[0], own_thread=False)
    run_nodes("control_chain", factories, argv, poll=_poll_sim if options.bridge == "sim" else None,
              connect=functools.partial(connect_chain, estimator=options.estimator))


def prepare_process(bridge: str, realtime_priority: int) -> None:
    """Scheduling and interpreter settings, before rclpy starts its threads (they inherit them)."""
    use_realtime_priority(realtime_priority)
    if bridge == "hardware":  # two Python threads in the 2 ms path: the executor's and the link's
        sys.setswitchinterval(LINK_SWITCH_INTERVAL)


def use_realtime_priority(priority: int) -> bool:
    """This process at SCHED_FIFO ``priority`` (0: leave it): the threads it has (importing rclpy
    starts two) and, by inheritance, those rclpy and the MPC worker start later. True if set. A
    refusal (no root, CAP_SYS_NICE or rtprio limit) is reported on stderr and the chain runs at
    normal priority: slower to recover from a busy machine, not unsafe."""
    if priority <= 0:
        return False
    try:
        for tid in sorted(os.listdir("/proc/self/task"), key=lambda t: int(t) != os.getpid()):  # main first
            with contextlib.suppress(ProcessLookupError):  # a thread that has ended since
                os.sched_setscheduler(int(tid), os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        print(f"control_chain: SCHED_FIFO {priority} is not permitted here (needs root, CAP_SYS_NICE or an "
              "rtprio limit); running at normal priority", file=sys.stderr, flush=True)
        return False
    return True


def _poll_sim(nodes: list[Any]) -> float:
    """Between the executor's waits: the sim bridge (created first) steps when due."""
    return nodes[0].poll()


def connect_chain(nodes: list[Any], estimator: bool) -> None:
    """The in-process hand-offs between the chain's nodes (bridge first, controller last), each
    only where the wire itself links the two: a remap (a fault relay's, tests/graph_helpers.py)
    that sends a topic elsewhere leaves it to the wire, so what the relay does reaches the node.

    - The controller hands each command to the bridge as it sends it: in one thread the bridge would
      otherwise take it off the wire only after the controller's work after the command (the filter
      update, /odom) and the executor's next wait.
    - With the sim bridge stepped in this thread and no estimator node in the chain, the bridge hands each
      step's sensors to the controller as it publishes them, and the controller leaves their wire
      copies: physics, sensors, control and command are one call in one thread, with no executor
      wake-up and intake in between (measured: docs/architecture.md, "The sensors handed over").
      With an estimator node the controller waits for its /odom off the wire anyway.
    """
    bridge, controller = nodes[0], nodes[-1]
    if _wire_links(controller.pub_command, bridge):
        controller.command_sinks.append(bridge.take_command)
    if (hasattr(bridge, "sensor_sinks") and not bridge.own_thread and not estimator
            and all(_wire_links(p, controller) for p in (bridge.pub_imu, bridge.pub_contacts, bridge.pub_joints))):
        bridge.sensor_sinks.append(controller.sensors.take)
        controller.sensors.leave_wire()


def _wire_links(publisher: Any, node: Any) -> bool:
    """``node`` subscribes to the topic ``publisher`` publishes on (resolved names, remaps applied)."""
    return any(subscription.topic_name == publisher.topic_name for subscription in node.subscriptions)


if __name__ == "__main__":
    main()
