"""Node plumbing shared by the stack's nodes: the only rclpy-facing module of a1_common.

Numbers are declared with dynamic typing so that ``-p duration:=2`` and ``duration: 2`` in a YAML
file work for a float parameter, then converted and type-checked here with a clear error naming
the parameter, instead of rclpy's exception about INTEGER vs DOUBLE.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult

from a1_common.config import ConfigError

# Parameters rclpy itself understands; any other override the node did not declare is a typo.
_RCLPY_PARAMETERS = {"use_sim_time", "start_type_description_service"}


def declare_parameters(node, defaults: dict[str, Any]) -> dict[str, Any]:
    """Declare every parameter of ``defaults`` on ``node``; return the values, typed like the defaults.

    Overrides (``-p`` or ``--params-file``) naming a parameter the node does not have are an error,
    not silently ignored as rclpy would.
    """
    overrides = set(getattr(node, "_parameter_overrides", {}))
    unknown = sorted(k for k in overrides - set(defaults) - _RCLPY_PARAMETERS
                     if not k.startswith("qos_overrides."))
    if unknown:
        raise ConfigError(f"unknown parameters {unknown} for node {node.get_name()}; "
                          f"allowed: {sorted(defaults)}")
    values = {}
    for name, default in defaults.items():
        descriptor = ParameterDescriptor(dynamic_typing=True)
        value = node.declare_parameter(name, default, descriptor).value
        values[name] = coerce_parameter(name, value, default)
    return values


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


def guard_runtime_parameters(node, defaults: dict[str, Any],
                             validators: dict[str, Callable[[Any], Any]] | None = None) -> None:
    """Validate runtime parameter changes (``ros2 param set``) on ``node`` like its start-up values.

    A parameter in ``validators`` is converted to the type of its default, then given to its
    validator (which raises ConfigError naming the parameter and its range); every other parameter
    of ``defaults`` is read at start-up only, so changing it is refused rather than silently ignored.
    rclpy's own parameters (``use_sim_time``) are left to rclpy.
    """
    validators = validators or {}
    runtime = sorted(validators) or "none"

    def on_set(params) -> SetParametersResult:
        for param in params:
            if param.name in validators:
                try:
                    validators[param.name](coerce_parameter(param.name, param.value, defaults[param.name]))
                except ConfigError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
            elif param.name in defaults:
                return SetParametersResult(
                    successful=False,
                    reason=f"{param.name} is read at start-up only (restart {node.get_name()} with "
                           f"-p {param.name}:=<value>); runtime parameters: {runtime}")
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)


def run_node(name: str, factory: Callable[[], Any], args: list[str] | None = None) -> None:
    """Create the node from ``factory`` and spin it until Ctrl-C / SIGTERM / shutdown.

    Configuration errors end the process with exit code 2 and one readable line; a node that sets
    ``node.failure`` (its own thread died) ends it with exit code 1.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    rclpy.init(args=args)
    node = None
    try:
        node = factory()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
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
        if node is not None:
            if hasattr(node, "shutdown"):
                node.shutdown()
            node.destroy_node()
        rclpy.try_shutdown()
    if getattr(node, "failure", None) is not None:
        raise SystemExit(1)
