"""What the fault relay does to each message of its topic: the library core (no rclpy).

Faults, all optional, each in a window of the messages' own time: seconds of header stamp since
the first message the relay received (sim time under a sim bridge, whose first stamp is 0; wall
time under a hardware bridge), so that a run is reproducible in lockstep:
- drop / duplicate / reorder with a probability per message (seeded), inside [start, end);
- delay: every message held ``delay`` seconds. ``delay_mode`` "wall" holds it that long on the
  wall clock with its stamp untouched (realtime graphs). "steps" is the lockstep equivalent: the
  message published at step k is the one received ``delay / period`` messages earlier, stamped
  with step k (a lockstep bridge pairs a command to its step by stamp, so a stale stamp would
  never be applied); when the delay starts, nothing goes out until the line is full, as with a
  real latency step;
- reorder in lockstep: a bridge that waits for each step's command publishes nothing new while a
  message is held, so a held message goes out after its successor only once the bridge stepped
  without it (a lockstep timeout): it arrives late, behind a newer one;
- freeze: in [freeze_start, freeze_start + freeze_duration) the content stays that of the first
  message of the window (a sensor that stopped updating), stamps advance;
- NaN burst: in [nan_start, nan_start + nan_duration) every floating-point field is NaN (stamps
  kept), as a broken driver would send.
Messages are rclpy message objects, but only their fields are touched, so the core stays free of
rclpy: copies with ``copy.deepcopy``, NaN through ``get_fields_and_field_types``.
"""

from __future__ import annotations

import array
import copy
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from a1_common.config import ConfigError, require_choice, require_range, setting

DELAY_MODES = ("wall", "steps")
NEVER = 1.0e9  # [s] "no window": later than any run (times count from the first message)


@dataclass(frozen=True)
class FaultConfig:
    drop_probability: float = setting(0.0, "probability of dropping each message in the fault window")
    duplicate_probability: float = setting(0.0, "probability of sending each message twice in the fault window")
    reorder_probability: float = setting(0.0, "probability of holding a message back until after the next one")
    start: float = setting(
        0.0, "start of the drop / duplicate / reorder / delay window, header time since the first message [s]")
    end: float = setting(NEVER, "end of that window [s]")
    delay: float = setting(0.0, "delay added to each message in the window [s]")
    delay_mode: str = setting("wall", "delay clock: wall (wall time) | steps (message periods, for lockstep)")
    period: float = setting(0.002, "message period, for delay_mode steps [s]")
    freeze_start: float = setting(
        NEVER, "start of the freeze: the content stays that of the window's first message, stamps advance [s]")
    freeze_duration: float = setting(0.0, "length of the freeze [s]")
    nan_start: float = setting(NEVER, "start of the NaN burst: every floating-point field NaN, stamps kept [s]")
    nan_duration: float = setting(0.0, "length of the NaN window [s]")
    seed: int = setting(0, "seed of the random faults")

    def validated(self) -> FaultConfig:
        for name in ("drop_probability", "duplicate_probability", "reorder_probability"):
            require_range(name, getattr(self, name), 0.0, 1.0)
        for name in ("start", "end", "freeze_start", "nan_start"):
            require_range(name, getattr(self, name), 0.0, NEVER)
        if self.end < self.start:
            raise ConfigError(f"end must be >= start ({self.start}), got {self.end}")
        require_range("delay", self.delay, 0.0, 10.0)
        require_choice("delay_mode", self.delay_mode, DELAY_MODES)
        require_range("period", self.period, 0.0, 1.0, low_open=True)
        if self.delay_mode == "steps" and abs(self.delay / self.period - round(self.delay / self.period)) > 1e-6:
            raise ConfigError(f"delay must be a multiple of period ({self.period} s) with delay_mode steps, "
                              f"got {self.delay}")
        require_range("freeze_duration", self.freeze_duration, 0.0, 3600.0)
        require_range("nan_duration", self.nan_duration, 0.0, 3600.0)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**32:
            raise ConfigError(f"seed must be an integer in [0, 2^32), got {self.seed!r}")
        return self

    @property
    def delay_steps(self) -> int:
        return round(self.delay / self.period)


@dataclass
class FaultCounts:
    received: int = 0
    published: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    frozen: int = 0
    poisoned: int = 0


class FaultInjector:
    """Feed every received message to :meth:`on_message`; publish what it (and :meth:`due`) returns."""

    def __init__(self, config: FaultConfig) -> None:
        self.config = config.validated()
        self.counts = FaultCounts()
        self._rng = np.random.default_rng(config.seed)
        self._held: Any = None  # reorder: the message waiting for its successor
        self._line: deque = deque()  # delay "steps": the last delay_steps messages
        self._timed: deque = deque()  # delay "wall": (release time, message)
        self._frozen: Any = None
        self._first_stamp: float | None = None

    def on_message(self, msg: Any, stamp: float, now: float) -> list:
        """Messages to publish now, in order. ``stamp``: the message's time [s]; ``now``: wall time [s]."""
        cfg = self.config
        self.counts.received += 1
        if self._first_stamp is None:
            self._first_stamp = stamp
        stamp -= self._first_stamp
        msg = self._freeze_or_poison(msg, stamp)
        active = cfg.start <= stamp < cfg.end
        if active and self._rng.random() < cfg.drop_probability:
            self.counts.dropped += 1
            return self._sent([])
        out = [msg]
        if active and cfg.delay > 0 and cfg.delay_mode == "steps":
            out = self._through_line(msg)
        elif self._line:  # the delay window ended: what was in the line is too old to matter
            self._line.clear()
        if active and out and self._rng.random() < cfg.duplicate_probability:
            self.counts.duplicated += 1
            out = [*out, copy.deepcopy(out[-1])]
        if self._held is not None:
            out, self._held = [*out, self._held], None
        elif active and len(out) == 1 and self._rng.random() < cfg.reorder_probability:
            self.counts.reordered += 1
            self._held, out = out[0], []
        if active and cfg.delay > 0 and cfg.delay_mode == "wall":
            self._timed.extend((now + cfg.delay, m) for m in out)
            out = []
        return self._sent(out)

    def due(self, now: float) -> list:
        """Delayed messages (delay_mode "wall") whose time has come."""
        out = []
        while self._timed and self._timed[0][0] <= now:
            out.append(self._timed.popleft()[1])
        return self._sent(out)

    def _sent(self, out: list) -> list:
        self.counts.published += len(out)
        return out

    def _through_line(self, msg: Any) -> list:
        """Delay "steps": the message of ``delay_steps`` messages ago, stamped like ``msg``."""
        self._line.append(msg)
        if len(self._line) <= self.config.delay_steps:
            return []
        old = self._line.popleft()
        old.header.stamp = copy.deepcopy(msg.header.stamp)
        return [old]

    def _freeze_or_poison(self, msg: Any, stamp: float) -> Any:
        cfg = self.config
        if cfg.freeze_start <= stamp < cfg.freeze_start + cfg.freeze_duration:
            if self._frozen is None:
                self._frozen = copy.deepcopy(msg)
            frozen = copy.deepcopy(self._frozen)
            frozen.header = msg.header
            self.counts.frozen += 1
            msg = frozen
        else:
            self._frozen = None
        if cfg.nan_start <= stamp < cfg.nan_start + cfg.nan_duration:
            msg = copy.deepcopy(msg)
            poison(msg)
            self.counts.poisoned += 1
        return msg


def poison(msg: Any) -> None:
    """Set every floating-point field of ``msg`` (nested messages too, headers excepted) to NaN."""
    for name, kind in msg.get_fields_and_field_types().items():
        if name == "header":
            continue
        value = getattr(msg, name)
        if kind in ("double", "float"):
            setattr(msg, name, math.nan)
        elif isinstance(value, np.ndarray) and value.dtype.kind == "f":
            value[:] = np.nan
        elif isinstance(value, array.array) and value.typecode in "fd":
            setattr(msg, name, array.array(value.typecode, [math.nan] * len(value)))
        elif hasattr(value, "get_fields_and_field_types"):
            poison(value)
        elif isinstance(value, list):
            for item in value:
                if hasattr(item, "get_fields_and_field_types"):
                    poison(item)
