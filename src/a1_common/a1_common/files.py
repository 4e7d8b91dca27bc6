"""Files that must survive a crash at any moment: training checkpoints, policy files, flight records."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

TEMPORARY_MARK = ".tmp-"  # write_npz_atomically's temporary file: .<name>.tmp-<pid> beside <name>


def write_npz_atomically(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez into ``path`` so that a crash at any moment leaves the old file or the new one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}{TEMPORARY_MARK}{os.getpid()}")
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
