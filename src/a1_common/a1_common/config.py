"""Safe YAML loading for the stack's configuration files.

Two kinds of file live in ``config/``: plain YAML (the robot constants) and ROS 2 parameter
files (``<node>: ros__parameters: {...}``), which the nodes get through ``--params-file`` and the
library cores (tests, trainer) read with :func:`load_node_parameters`. Both are read with a safe
loader (:func:`parse_yaml`); unknown keys are errors, so a typo never silently falls back to a default.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Collection, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import yaml


class ConfigError(ValueError):
    """A configuration file or value is missing, malformed or out of range."""


class _Loader(yaml.SafeLoader):
    """yaml.SafeLoader reading ``1e-5`` as a float, as ROS 2's parameter-file parser does (PyYAML's
    YAML 1.1 rules want ``1.0e-5`` and would leave ``1e-5`` a string)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def parse_yaml(text: str) -> Any:
    """YAML text to Python values (safe: no objects), numbers as ROS 2 reads them."""
    return yaml.load(text, Loader=_Loader)


def load_yaml_mapping(path: str | os.PathLike, allowed_keys: set[str] | None = None) -> dict[str, Any]:
    """Load a YAML file whose top level is a mapping; reject unknown keys if a set is given."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read config file {path}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    try:
        data = parse_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid YAML: nested too deeply") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: top level must be a mapping, got {type(data).__name__}")
    if allowed_keys is not None:
        unknown = sorted_keys(set(data) - allowed_keys)
        if unknown:
            raise ConfigError(f"{path}: unknown keys {unknown}; allowed: {sorted(allowed_keys)}")
    return data


def sorted_keys(keys) -> list:
    """Keys sorted for an error message, whatever their types (YAML keys may be numbers, null...)."""
    return sorted(keys, key=lambda k: (not isinstance(k, str), repr(k)))


def load_node_parameters(path: str | os.PathLike, node_name: str) -> dict[str, Any]:
    """The ``ros__parameters`` mapping of ``node_name`` in a ROS 2 parameter file: under the node's
    name in any namespace (``/**/name``, the stack's files), its plain name, or ``/**``."""
    data = load_yaml_mapping(path)
    section = next((data[key] for key in (f"/**/{node_name}", node_name, "/**") if key in data), None)
    if not isinstance(section, dict) or not isinstance(section.get("ros__parameters"), dict):
        raise ConfigError(f"{path}: no '/**/{node_name}: ros__parameters:' mapping")
    return dict(section["ros__parameters"])


def parameter_defaults(config: Any, prefix: str = "", skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """A config dataclass instance as flat ROS parameter defaults: ``prefix + field`` -> value.

    Tuples become lists (ROS array parameters); nested dataclass fields and ``skip`` are left out.
    """
    flat = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if f.name in skip or dataclasses.is_dataclass(value):
            continue
        flat[prefix + f.name] = list(value) if isinstance(value, tuple) else value
    return flat


def setting(default: Any, doc: str) -> Any:
    """A config dataclass field with its one-line description (units in brackets).

    The description is what ``ros2 param describe`` shows for the parameter the field becomes
    (see :func:`parameter_descriptions`); it lives beside the default so the two cannot drift.
    """
    return dataclasses.field(default=default, metadata={"doc": doc})


def parameter_descriptions(config: Any, prefix: str = "", skip: tuple[str, ...] = ()) -> dict[str, str]:
    """The descriptions of the parameters :func:`parameter_defaults` makes of ``config``, by name.

    A field declared without :func:`setting` has none: a ValueError naming it, so that every
    parameter a node declares is described.
    """
    docs = {}
    for f in dataclasses.fields(config):
        if f.name in skip or dataclasses.is_dataclass(getattr(config, f.name)):
            continue
        if "doc" not in f.metadata:
            raise ValueError(f"{type(config).__name__}.{f.name} has no description: declare it with setting()")
        docs[prefix + f.name] = f.metadata["doc"]
    return docs


@dataclasses.dataclass(frozen=True)
class Constraint:
    """What a validator accepts for one setting: a number interval (integer or not, for each entry
    of a list of ``count``) or a set of ``choices``. Recorded by :func:`recording_constraints`."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False
    count: int | None = None  # a list of this many numbers, each in the interval
    choices: tuple[str, ...] = ()

    def __str__(self) -> str:
        if self.choices:
            return "one of " + " | ".join(self.choices)
        interval = f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"
        kind = "an integer" if self.integer else "a number"
        return f"{self.count} numbers, each in {interval}" if self.count is not None else f"{kind} in {interval}"


_constraints: ContextVar[dict[str, Constraint] | None] = ContextVar("a1_constraints", default=None)


@contextmanager
def recording_constraints(prefix: str = "") -> Iterator[dict[str, Constraint]]:
    """Collect, by setting name (``prefix`` + the name the validator uses), what every
    require_range / require_integer / require_numbers / require_choice call inside accepts.

    Why: a node validates its parameters with those calls; recorded while it does, they give the
    parameter descriptors' ranges, so each range is written once, in its validator. Nested inside
    another recording (a sub-config whose fields carry a prefix), entries go to the outer one too.
    """
    outer = _constraints.get()
    recorded: dict[str, Constraint] = {}
    token = _constraints.set(recorded)
    try:
        yield recorded
    finally:
        _constraints.reset(token)
        named = {prefix + name: c for name, c in recorded.items()}
        recorded.clear()
        recorded.update(named)
        if outer is not None:
            outer.update(named)


def _record(name: str, constraint: Constraint) -> None:
    recorded = _constraints.get()
    if recorded is not None and "[" not in name:  # list entries: the list itself is recorded
        recorded[name] = constraint


def config_dir() -> Path:
    """The repository's ``config/`` folder, or the installed copy of the robot file's folder."""
    from a1_common.robot import default_config_path  # local: robot imports this module

    return default_config_path().parent


def require_range(name: str, value: float, low: float, high: float, *, low_open: bool = False,
                  high_open: bool = False) -> float:
    """Return ``value`` as float if inside the interval, else raise naming the field and range. A bool
    or a string is not a number here (``true`` or ``"0.5"`` in a YAML file is a typo, not 1.0 or 0.5)."""
    _record(name, Constraint(low, high, low_open, high_open))
    try:
        if isinstance(value, (bool, str, bytes)):
            raise TypeError
        v = float(value)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond any float
        raise ConfigError(f"{name} must be a number in {'(' if low_open else '['}{low}, {high}"
                          f"{')' if high_open else ']'}, got {_short(value)}") from None
    lo_ok = v > low if low_open else v >= low
    hi_ok = v < high if high_open else v <= high
    if not (lo_ok and hi_ok) or v != v:
        lb = "(" if low_open else "["
        hb = ")" if high_open else "]"
        raise ConfigError(f"{name} must be in {lb}{low}, {high}{hb}, got {_short(value)}")
    return v


def require_integer(name: str, value: Any, low: int, high: int) -> int:
    """Return ``value`` if it is an integer (a bool is not) in [low, high], else raise naming the field."""
    _record(name, Constraint(low, high, integer=True))
    if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= high:
        raise ConfigError(f"{name} must be an integer in [{low}, {high}], got {_short(value)}")
    return value


def require_numbers(name: str, values: Any, count: int, low: float, high: float, *,
                    low_open: bool = False) -> tuple[float, ...]:
    """``count`` numbers, each checked like require_range as ``name[i]``; a wrong count names ``name``."""
    _record(name, Constraint(low, high, low_open, count=count))
    values = tuple(values) if isinstance(values, (list, tuple)) else (values,)
    if len(values) != count:
        raise ConfigError(f"{name} must have {count} entries, got {len(values)}")
    return tuple(require_range(f"{name}[{i}]", v, low, high, low_open=low_open) for i, v in enumerate(values))


def require_choice(name: str, value: Any, choices: Collection[str]) -> str:
    """Return ``value`` if it is one of ``choices``, else raise naming the field and the choices."""
    _record(name, Constraint(choices=tuple(choices)))
    if not isinstance(value, str) or value not in choices:
        raise ConfigError(f"{name} must be one of {list(choices)}, got {_short(value)}")
    return value


def _short(value: Any, limit: int = 80) -> str:
    """repr() of a rejected value, cut short so a huge one cannot flood a log line."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, (list, tuple)):
        return "a list"
    return type(value).__name__


def dataclass_from_mapping(cls: type, data: Any, where: str) -> Any:
    """Build the (nested) config dataclass ``cls`` from a mapping such as a YAML section.

    Fields missing from ``data`` keep their defaults; unknown keys and values of the wrong kind
    (number, string, boolean, list) raise ConfigError naming ``where.key``. Lists become tuples
    (nested ones too), so configs compare and hash like their defaults.
    Value ranges are the dataclass's own business (its ``validated()``).
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping, got {type(data).__name__}")
    template = cls()
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted_keys(set(data) - set(names))
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown}; allowed: {names}")
    kwargs = {}
    for key, value in data.items():
        default = getattr(template, key)
        name = f"{where}.{key}" if where else key
        if dataclasses.is_dataclass(default):
            kwargs[key] = dataclass_from_mapping(type(default), value, name)
            continue
        expected, got = _kind(default), _kind(value)
        if default is not None and expected != got and not (expected == "a number" and got == "a number"):
            raise ConfigError(f"{name} must be {expected}, got {_short(value)}")
        kwargs[key] = _tuples(value)
    return cls(**kwargs)


def _tuples(value: Any) -> Any:
    return tuple(_tuples(v) for v in value) if isinstance(value, (list, tuple)) else value
