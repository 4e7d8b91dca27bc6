"""Gait classes, per-speed-band summaries and the gait diagram, shared by demo_report, eval_policy
and sweep_gaits. No ROS.

Per control step data (SI units) arrive as a mapping of equal-length arrays: time [s],
desired_speed and speed [m/s], power [W], frequency [Hz], swing_ratio, phase_offsets (n, 4) [rad]
and contacts (n, 4) (bool, leg order FR, FL, RR, RL).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from a1_common.files import save_png_atomically

LEGS = ("FR", "FL", "RR", "RL")
# Commanded forward speed bands [m/s] of the summaries; the last holds the top of the paper's ramp.
SPEED_BANDS = ((0.0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0), (2.0, 2.5), (2.5, 3.5))
# Offsets (FL, RR, RL) relative to FR of the two-beat gaits [rad].
TWO_BEAT = {"trot": (math.pi, math.pi, 0.0), "pace": (math.pi, 0.0, math.pi), "bound": (0.0, math.pi, math.pi),
            "pronk": (0.0, 0.0, 0.0)}
OFFSET_TOLERANCE = 0.35  # [rad], about 20 degrees
# Above this swing ratio each foot is in the air more than half the cycle: a trot becomes a flying
# trot and a four-beat walk a 4-beat run.
FLIGHT_SWING_RATIO = 0.5


def shortest_arc(start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Signed angle from ``start`` to ``end`` along the shorter way round, in (-pi, pi] [rad]:
    phase offsets 0.1 and 6.2 rad are 0.18 apart, not 6.1."""
    return np.angle(np.exp(1j * (np.asarray(end, dtype=float) - np.asarray(start, dtype=float))))


def _circular_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs(shortest_arc(b, a))


def classify_gait(swing_ratio: float, offsets: np.ndarray) -> str:
    """walk (four-beat: no two legs in phase; p_swing <= 0.5, each foot down at least half the cycle,
    as in the reference's walk at p_swing 0.2) / 4-beat run (four-beat with p_swing > 0.5) / trot /
    fly trot (trot with p_swing > 0.5) / pace / bound / pronk / other, from the phase offsets of FR,
    FL, RR, RL and the swing ratio."""
    offsets = np.asarray(offsets, dtype=float)
    for name, pattern in TWO_BEAT.items():
        if np.all(_circular_distance(offsets[1:], pattern) < OFFSET_TOLERANCE):
            return "fly trot" if name == "trot" and swing_ratio > FLIGHT_SWING_RATIO else name
    pairwise = [_circular_distance(offsets[i], offsets[j]) for i in range(4) for j in range(i + 1, 4)]
    if min(pairwise) < OFFSET_TOLERANCE:
        return "other"
    return "4-beat run" if swing_ratio > FLIGHT_SWING_RATIO else "walk"


def circular_mean(angles: np.ndarray, axis: int = 0) -> np.ndarray:
    """Mean direction of angles [rad], in [0, 2 pi)."""
    return np.angle(np.mean(np.exp(1j * np.asarray(angles, dtype=float)), axis=axis)) % (2 * math.pi)


def summarise_bands(data: dict[str, np.ndarray], mass: float, gravity: float = 9.8,
                    bands: tuple[tuple[float, float], ...] = SPEED_BANDS, min_samples: int = 50) -> list[dict]:
    """Per commanded-speed band: mean commanded and actual speed, mean |error| relative to the command
    (floored at 0.3 m/s), power, cost of transport (P / (m g v)), f, p_swing, offsets and the most
    frequent gait class (sampled every 25 control steps). Bands with fewer samples are left out."""
    cmd, v = np.asarray(data["desired_speed"]), np.asarray(data["speed"])
    out = []
    for lo, hi in bands:
        sel = (cmd >= lo) & (cmd < hi)
        if sel.sum() < min_samples:
            continue
        c, a = float(np.mean(cmd[sel])), float(np.mean(v[sel]))
        power = float(np.mean(data["power"][sel]))
        swing, offsets = data["swing_ratio"][sel], data["phase_offsets"][sel]
        classes = [classify_gait(s, o) for s, o in zip(swing[::25], offsets[::25], strict=True)]
        out.append({
            "band": (lo, hi), "desired_speed": c, "speed": a,
            "speed_error": float(np.mean(np.abs(v[sel] - cmd[sel]))) / max(c, 0.3),
            "power": power, "cost_of_transport": power / (mass * gravity * a) if a > 0.1 else float("nan"),
            "frequency": float(np.mean(data["frequency"][sel])), "swing_ratio": float(np.mean(swing)),
            "phase_offsets": circular_mean(offsets), "gait": max(set(classes), key=classes.count)})
    return out


def format_band_table(rows: list[dict]) -> str:
    lines = [f"{'band [m/s]':<11}{'cmd':>6}{'actual':>8}{'err %':>7}  {'gait':<11}{'f Hz':>6}{'p_sw':>6}"
             f"{'offsets FL/RR/RL deg':>22}{'power W':>9}{'CoT':>6}"]
    for r in rows:
        lo, hi = r["band"]
        offs = "/".join(f"{math.degrees(o):.0f}" for o in r["phase_offsets"][1:])
        lines.append(f"{lo:>4.1f}-{hi:<6.1f}{r['desired_speed']:>6.2f}{r['speed']:>8.2f}{100 * r['speed_error']:>7.1f}"
                     f"  {r['gait']:<11}{r['frequency']:>6.2f}{r['swing_ratio']:>6.2f}{offs:>22}{r['power']:>9.1f}"
                     f"{r['cost_of_transport']:>6.2f}")
    return "\n".join(lines)


def transition_speeds(data: dict[str, np.ndarray]) -> list[tuple[float, str, str]]:
    """(commanded speed [m/s], from gait, to gait) where the gait class changes to one that then holds
    for at least 0.5 s; the class is sampled every 25 control steps (once per policy step)."""
    cmd = np.asarray(data["desired_speed"])[::25]
    classes = [classify_gait(s, o) for s, o in zip(data["swing_ratio"][::25], data["phase_offsets"][::25],
                                                    strict=True)]
    hold = 10
    out, current = [], None
    for i in range(len(classes) - hold + 1):
        window = classes[i:i + hold]
        if all(c == window[0] for c in window) and window[0] != current:
            if current is not None:
                out.append((float(cmd[i]), current, window[0]))
            current = window[0]
    return out


def plot_gait_diagram(path: str | Path, data: dict[str, np.ndarray], title: str) -> Path:
    """Contacts of each leg against time with the speed, f and p_swing curves (the paper's Fig. 4)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.asarray(data["time"])
    contact = np.asarray(data["contacts"], dtype=bool)
    fig, axes = plt.subplots(4, 1, figsize=(10, 7), sharex=True, gridspec_kw={"height_ratios": [2, 1.2, 1, 1]})
    for leg in range(4):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], contact[:, leg].astype(int), [0]])))
        spans = [(t[s], t[min(e, len(t) - 1)] - t[s]) for s, e in zip(edges[::2], edges[1::2], strict=True)]
        axes[0].broken_barh(spans, (3 - leg - 0.4, 0.8), color="tab:blue")
    axes[0].set_yticks(range(4), LEGS[::-1])
    axes[0].set_title(title)
    axes[1].plot(t, data["desired_speed"], label="desired")
    axes[1].plot(t, data["speed"], label="actual (ground truth)", alpha=0.8)
    axes[1].set_ylabel("speed [m/s]")
    axes[1].legend(loc="upper left")
    axes[2].plot(t, data["frequency"], color="tab:green")
    axes[2].set_ylabel("f [Hz]")
    axes[3].plot(t, data["swing_ratio"], color="tab:red")
    axes[3].set_ylabel("swing ratio")
    axes[3].set_xlabel("time [s]")
    fig.tight_layout()
    path = Path(path)
    save_png_atomically(fig, path, dpi=110)
    plt.close(fig)
    return path
