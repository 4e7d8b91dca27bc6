"""Flight recorder: the last seconds of a simulated run, step by step, saved when the robot falls.

Why: a fall in a realtime graph cannot be replayed (it depends on when messages arrived), and its
cause lies in the seconds before it. The sim bridge records every step into a ring buffer (a few
microseconds a step) and writes it to an ``.npz`` the moment the base drops below ``fall_height``:
``fall_*.npz``, or ``damped_*.npz`` when the base went down under a damping the controller
commanded while the robot was upright (an e-stop or ``mode damping``: not a fall).
``flight_recorder_plot`` draws such a file. Units SI; frames: world (REP-103: x forward at start,
z up) for positions, base frame for body velocities.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from a1_common.config import ConfigError, require_range
from a1_common.files import save_png_atomically, write_npz_atomically

# Recorded per step: name -> width. The names carry their units.
FIELDS = {
    "time_s": 1,                          # sim time since reset
    "base_position_m": 3,                 # world frame
    "base_orientation_xyzw": 4,           # world frame
    "base_velocity_body_mps": 3,          # base frame, ground truth
    "base_angular_velocity_body_radps": 3,
    "foot_contact": 4,                    # FR, FL, RR, RL; 1 = in contact
    "joint_position_rad": 12,
    "joint_torque_nm": 12,                # applied, after the motor model's clip
    "command_age_s": 1,                   # sim time from the sensors the applied command answered to
                                          # the end of this step: one time_step when it was on time
    "damping": 1,                         # 1 = the motors were in damping (watchdog or command)
    "commanded_damping": 1,               # 1 = ... because the controller commanded it (e-stop, mode
                                          # damping, its own fall or input checks), not the watchdog
}


def require_seconds(seconds: float) -> float:
    """``seconds`` of window if in (0, 600], else ConfigError naming flight_recorder_seconds."""
    return require_range("flight_recorder_seconds", seconds, 0.0, 600.0, low_open=True)


class FlightRecorder:
    """Ring buffer of the last ``seconds`` of steps; ``record`` one step, ``save`` the window."""

    def __init__(self, seconds: float, time_step: float) -> None:
        require_seconds(seconds)
        self.capacity = max(1, math.ceil(seconds / time_step))
        self._columns = {}
        start = 0
        for name, width in FIELDS.items():
            self._columns[name] = slice(start, start + width)
            start += width
        self._rows = np.zeros((self.capacity, start))
        self._count = 0

    def clear(self) -> None:
        """Forget everything (a sim reset starts a new run)."""
        self._count = 0

    def record(self, **values: float | np.ndarray) -> None:
        """One step; every field of FIELDS must be given."""
        row = self._rows[self._count % self.capacity]
        for name, cols in self._columns.items():
            row[cols] = values[name]
        self._count += 1

    def window(self) -> dict[str, np.ndarray]:
        """The recorded steps, oldest first, one array per field ((steps,) or (steps, width))."""
        n = min(self._count, self.capacity)
        order = (np.arange(n) + self._count - n) % self.capacity
        rows = self._rows[order]
        return {name: rows[:, cols] if FIELDS[name] > 1 else rows[:, cols.start]
                for name, cols in self._columns.items()}

    def save(self, path: Path) -> Path:
        """Write the window to ``path`` (.npz) atomically: a reader never sees half a file."""
        path = Path(path)
        write_npz_atomically(path, self.window())
        return path


def load(path: Path) -> dict[str, np.ndarray]:
    """A saved window, checked: every field of FIELDS present with its width (no pickles)."""
    with np.load(path, allow_pickle=False) as data:
        out = {name: data[name] for name in data.files}
    for name, width in FIELDS.items():
        if name not in out:
            raise ConfigError(f"{path}: field {name!r} missing; a flight recorder file has {list(FIELDS)}")
        shape = out[name].shape
        if (width == 1 and len(shape) != 1) or (width > 1 and (len(shape) != 2 or shape[1] != width)):
            raise ConfigError(f"{path}: field {name!r} has shape {shape}, expected (steps,"
                              f"{'' if width == 1 else f' {width}'})")
    norms = np.linalg.norm(out["base_orientation_xyzw"], axis=1)
    if not np.all(np.abs(norms - 1.0) < 1e-3):
        raise ConfigError(f"{path}: field 'base_orientation_xyzw' must hold unit quaternions (norm 1 +- 1e-3)")
    return out


def plot(data: dict[str, np.ndarray], out: Path, title: str = "") -> Path:
    """One figure of a window: height, attitude, velocity, command age, foot contacts, torques."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.spatial.transform import Rotation

    t = data["time_s"]
    rpy = Rotation.from_quat(data["base_orientation_xyzw"]).as_euler("xyz")
    fig, axes = plt.subplots(6, 1, sharex=True, figsize=(11, 14))
    axes[0].plot(t, data["base_position_m"][:, 2])
    axes[0].set_ylabel("base height [m]")
    for i, name in enumerate(("roll", "pitch")):
        axes[1].plot(t, np.degrees(rpy[:, i]), label=name)
    axes[1].set_ylabel("attitude [deg]")
    axes[1].legend(loc="upper left")
    v = data["base_velocity_body_mps"]
    axes[2].plot(t, v[:, 0], label="forward [m/s]")
    axes[2].plot(t, v[:, 1], label="left [m/s]")
    axes[2].plot(t, data["base_angular_velocity_body_radps"][:, 2], label="yaw rate [rad/s]")
    axes[2].set_ylabel("base velocity")
    axes[2].legend(loc="upper left")
    axes[3].plot(t, data["command_age_s"] * 1e3, drawstyle="steps-post", label="command age")
    axes[3].fill_between(t, 0, data["damping"] * np.nanmax(np.append(data["command_age_s"] * 1e3, 1.0)),
                         step="post", alpha=0.3, color="red", label="damping")
    axes[3].set_ylabel("command age [ms]")
    axes[3].legend(loc="upper left")
    for leg in range(4):
        axes[4].fill_between(t, leg, leg + 0.8 * data["foot_contact"][:, leg], step="post")
    axes[4].set_yticks(np.arange(4) + 0.4, ["FR", "FL", "RR", "RL"])
    axes[4].set_ylabel("stance")
    axes[5].plot(t, data["joint_torque_nm"], linewidth=0.7)
    axes[5].set_ylabel("joint torques [N m]")
    axes[5].set_xlabel("sim time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    out = Path(out)
    save_png_atomically(fig, out, dpi=90)
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> None:
    """``flight_recorder_plot FILE.npz [-o FILE.png]``: draw a flight recorder file."""
    import argparse

    parser = argparse.ArgumentParser(description="Plot a sim bridge flight recorder file (.npz).")
    parser.add_argument("file", type=Path)
    parser.add_argument("-o", "--output", type=Path, help="image to write (default: FILE with .png)")
    args = parser.parse_args(argv)
    try:
        data = load(args.file)
    except (OSError, ValueError, ConfigError) as exc:
        parser.exit(2, f"flight_recorder_plot: cannot read {args.file}: {exc}\n")
    out = plot(data, args.output or args.file.with_suffix(".png"), title=args.file.name)
    age = data["command_age_s"]
    print(f"{args.file.name}: {len(data['time_s'])} steps, t {data['time_s'][0]:.3f}-{data['time_s'][-1]:.3f} s, "
          f"lowest base {data['base_position_m'][:, 2].min():.3f} m, command age median "
          f"{np.nanmedian(age) * 1e3:.1f} ms, max {np.nanmax(age) * 1e3:.1f} ms, damping steps "
          f"{int(data['damping'].sum())}; plot: {out}")
