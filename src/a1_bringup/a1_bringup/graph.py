"""The node graph, described once: which nodes run for a clock and a bridge, each with its package,
executable, parameter files (from ``config/``) and parameters. No ROS import.

scripts/lib/nodes.sh (bring-up and demo) starts the lines this prints; tests/graph_helpers.py (the
end-to-end tests and benchmarks) starts the same NodeSpecs. The rules:

- bridge ``sim``: sim_bridge; ``virtual``: virtual_a1 (the simulated robot behind the A1's UDP
  protocol) and hw_bridge on loopback; ``hardware``: hw_bridge to the real A1 (realtime only).
- lockstep: every stack node on sim time; the state estimator is its own process unless the
  controller embeds it (``embedded_estimator``).
- realtime: wall clock; the controller embeds the estimator and loads the realtime overlay
  config/convex_mpc_realtime.yaml (docs/architecture.md, "Realtime on a small computer").

- composed: the 500 Hz chain (sim_bridge or hw_bridge, state_estimator, convex_mpc) as one
  process, a1_bringup's control_chain; virtual_a1 (it plays the robot) and gait_policy stay apart.
  In realtime the chain's process runs at SCHED_FIFO ``CHAIN_PRIORITY`` (where permitted); the
  separate form keeps every node at normal priority.

    python -m a1_bringup.graph --clock lockstep --config config --set gait_policy.policy=learned \
        [--composed] [--namespace /a1_2]

prints one shell-quoted line per process: package, executable, arguments. With ``--remaps-only
--namespace /a1_2`` it prints just the arguments that put any node (a tool's) in that namespace.
"""

from __future__ import annotations

import argparse
import re
import shlex
import sys
from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path

CLOCKS = ("lockstep", "realtime")
# SCHED_FIFO priority of the composed 500 Hz chain in realtime: above every normal process (a
# user's tool starting beside it). A PREEMPT_RT kernel runs its threaded interrupts at 50 too, so a
# robot computer with that kernel may want 49 or less.
CHAIN_PRIORITY = 50
BRIDGES = ("sim", "virtual", "hardware")
NAMESPACE = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")


@dataclass
class NodeSpec:
    name: str  # the node's name (and its log's)
    package: str
    executable: str
    param_files: list[str]  # file names under config/, in load order (later ones override)
    params: dict[str, str] = field(default_factory=dict)  # -p name:=value, after the files
    options: list[str] = field(default_factory=list)  # the executable's own, before --ros-args
    members: tuple[str, ...] = ()  # a composed process: the nodes in it (else just this one)
    priority: int = 0  # SCHED_FIFO priority its process gets when composed (0: normal scheduling)

    @property
    def nodes(self) -> tuple[str, ...]:
        """The names of the rclpy nodes this process runs."""
        return self.members or (self.name,)

    def arguments(self, config_dir: Path, namespace: str = "") -> list[str]:
        """The node's command-line arguments (after the executable), in ``namespace`` if not ""."""
        args = [*self.options, "--ros-args"]
        for name in self.param_files:
            args += ["--params-file", str(config_dir / name)]
        for key, value in self.params.items():
            args += ["-p", f"{key}:={value}"]
        return args + namespace_remaps(namespace)


def describe(clock: str, bridge: str = "sim", *, embedded_estimator: bool | None = None) -> list[NodeSpec]:
    """The graph for ``clock`` and ``bridge`` (``embedded_estimator`` None: embedded in realtime only)."""
    if clock not in CLOCKS:
        raise ValueError(f"clock must be one of {list(CLOCKS)}, got {clock!r}")
    if bridge not in BRIDGES:
        raise ValueError(f"bridge must be one of {list(BRIDGES)}, got {bridge!r}")
    if bridge == "hardware" and clock != "realtime":
        raise ValueError("bridge hardware needs clock realtime (a real robot does not wait for the controller)")
    embedded = clock == "realtime" if embedded_estimator is None else embedded_estimator
    # Sim time in lockstep only: in realtime the nodes work on the sensors' stamps, and 500 Hz /clock
    # callbacks in every node would cost a good part of a core on a small computer.
    sim_time = {"use_sim_time": "true" if clock == "lockstep" else "false"}
    priority = CHAIN_PRIORITY if clock == "realtime" else 0
    nodes = {
        "sim": [NodeSpec("sim_bridge", "a1_sim_bridge", "sim_bridge", ["a1_sim_bridge.yaml"], {"clock_mode": clock},
                         priority=priority)],
        "virtual": [NodeSpec("virtual_a1", "a1_hw_bridge", "virtual_a1", ["virtual_a1.yaml"], {"clock_mode": clock}),
                    NodeSpec("hw_bridge", "a1_hw_bridge", "hw_bridge", ["a1_hw_bridge.yaml"],
                             {"robot_ip": "127.0.0.1", "clock_mode": clock}, priority=priority)],
        "hardware": [NodeSpec("hw_bridge", "a1_hw_bridge", "hw_bridge", ["a1_hw_bridge.yaml"], priority=priority)],
    }[bridge]
    if not embedded:
        nodes.append(NodeSpec("state_estimator", "state_estimator_node", "state_estimator", ["state_estimator.yaml"],
                              dict(sim_time)))
    controller_files = ["convex_mpc.yaml", *(["convex_mpc_realtime.yaml"] if clock == "realtime" else [])]
    controller = {**sim_time, **({"embedded_estimator": "true"} if embedded and clock == "lockstep" else {})}
    nodes.append(NodeSpec("convex_mpc", "convex_mpc_node", "convex_mpc", controller_files, controller,
                          priority=priority))
    nodes.append(NodeSpec("gait_policy", "gait_policy_node", "gait_policy", ["gait_policy.yaml"], dict(sim_time)))
    return nodes


def namespace_remaps(namespace: str) -> list[str]:
    """The ROS arguments that run a node in ``namespace`` ("": none): the stack's topics are relative,
    so ``__ns`` moves them all; sim time comes from the graph's own ``<namespace>/clock``."""
    if not namespace:
        return []
    if not NAMESPACE.fullmatch(namespace):
        raise ValueError(f"namespace must look like /a1_2 (letters, digits, _), got {namespace!r}")
    return ["-r", f"__ns:={namespace}", "-r", "/clock:=clock"]


CHAIN = ("sim_bridge", "hw_bridge", "state_estimator", "convex_mpc")  # what control_chain composes


def composed(nodes: list[NodeSpec]) -> list[NodeSpec]:
    """``nodes`` with the 500 Hz chain's members replaced by one control_chain process, started
    where its first member was; each member keeps its parameter files and parameters."""
    members = [n for n in nodes if n.name in CHAIN]
    if not members:
        return nodes
    options = ["--bridge", "sim" if members[0].name == "sim_bridge" else "hardware"]
    options += ["--estimator"] * any(n.name == "state_estimator" for n in members)
    for member in members:
        options += [a for key, value in member.params.items() for a in ("--set", f"{member.name}.{key}={value}")]
    priority = max(n.priority for n in members)
    options += ["--realtime-priority", str(priority)] * (priority > 0)
    files = list(dict.fromkeys(f for n in members for f in n.param_files))
    chain = NodeSpec("control_chain", "a1_bringup", "control_chain", files, options=options,
                     members=tuple(n.name for n in members), priority=priority)
    first = nodes.index(members[0])
    return [*nodes[:first], chain, *(n for n in nodes[first:] if n.name not in CHAIN)]


def parse_setting(item: str, nodes: Collection[str], where: str = "graph") -> tuple[str, str, str]:
    """(node, parameter, value) of a ``node.param=value`` item; ValueError naming a bad one."""
    target, sep, value = item.partition("=")
    node, dot, param = target.partition(".")
    if not sep or not dot or not param:
        raise ValueError(f"--set must look like node.parameter=value, got {item!r}")
    if node not in nodes:
        raise ValueError(f"--set {item!r}: no node {node!r} in this {where}; nodes: {sorted(nodes)}")
    return node, param, value


def with_settings(nodes: list[NodeSpec], settings: list[str]) -> list[NodeSpec]:
    """``node.param=value`` settings applied to ``nodes``; ValueError naming a node not in the graph."""
    by_name = {n.name: n for n in nodes}
    for item in settings:
        node, param, value = parse_setting(item, by_name)
        by_name[node].params[param] = value
    return nodes


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m a1_bringup.graph", description=__doc__.split("\n")[0])
    parser.add_argument("--clock", choices=CLOCKS, help="required unless --remaps-only")
    parser.add_argument("--bridge", default="sim", choices=BRIDGES)
    parser.add_argument("--config", type=Path, help="the config/ folder (required unless --remaps-only)")
    parser.add_argument("--set", action="append", default=[], metavar="NODE.PARAM=VALUE")
    parser.add_argument("--composed", action="store_true",
                        help="the 500 Hz chain (bridge, estimator, controller) as one control_chain process")
    parser.add_argument("--namespace", default="", help="run every node in this namespace, e.g. /a1_2")
    parser.add_argument("--remaps-only", action="store_true",
                        help="print only the ROS arguments that put a node in --namespace (for a tool's node)")
    args = parser.parse_args(argv)
    if not args.remaps_only and (args.clock is None or args.config is None):
        parser.error("--clock and --config are required (unless --remaps-only)")
    try:
        if args.remaps_only:
            print(shlex.join(namespace_remaps(args.namespace)))
            return 0
        nodes = with_settings(describe(args.clock, args.bridge), args.set)
        nodes = composed(nodes) if args.composed else nodes
        lines = [shlex.join([n.package, n.executable, *n.arguments(args.config, args.namespace)]) for n in nodes]
    except ValueError as exc:
        print(f"a1_bringup.graph: {exc}", file=sys.stderr)
        return 2
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
