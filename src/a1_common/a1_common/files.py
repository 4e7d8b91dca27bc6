"""Files that must survive a crash at any moment (training checkpoints, policy files, flight records),
and output folders that two runs never share."""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np

TEMPORARY_MARK = ".tmp-"  # the atomic writers' temporary file: .<name>.tmp-<pid> beside <name>


def _write_atomically(path: Path, write: Callable[[BinaryIO], None]) -> None:
    """``write`` into a temporary file beside ``path``, flushed to disk, then renamed over ``path``:
    a crash or a full disk at any moment leaves the old file or the new one, never half of one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}{TEMPORARY_MARK}{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_npz_atomically(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez into ``path`` so that a crash at any moment leaves the old file or the new one."""
    _write_atomically(path, lambda fh: np.savez(fh, **arrays))


def save_png_atomically(fig, path: Path, dpi: int = 100) -> None:
    """``fig.savefig`` (a matplotlib Figure) as PNG into ``path``, so that a crash or a full disk
    leaves the old plot or the new one, never half a file; closes nothing."""
    _write_atomically(path, lambda fh: fig.savefig(fh, dpi=dpi, format="png"))


def new_timestamped_folder(parent: Path, prefix: str = "") -> Path:
    """Create and return a new, empty ``parent/<prefix>-<YYYYmmdd-HHMMSS>`` (``-2``, ``-3``... when
    taken): a tool's default output folder, so that two runs started in the same second never write
    into one folder."""
    parent.mkdir(parents=True, exist_ok=True)
    name = f"{prefix}-{time.strftime('%Y%m%d-%H%M%S')}" if prefix else time.strftime("%Y%m%d-%H%M%S")
    for n in itertools.count(1):
        path = parent / (name if n == 1 else f"{name}-{n}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return path
    raise AssertionError("unreachable")
