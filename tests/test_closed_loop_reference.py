"""The in-process closed loop (sim, estimator, controller) replays a committed reference.

Why: a trained gait policy is only valid on the closed loop it was trained on (docs/learning.md);
a refactor, an optimisation or a dependency bump that changes the motor commands changes what the
policy sees. Every field of every command of 1.5 s of a trot to 1 m/s and of a fly trot is compared
with tests/data/closed_loop_reference.npz, to within TOLERANCE. A change that is meant to change
the closed loop regenerates the file (``python tests/test_closed_loop_reference.py --update``) and
says so: the learned-policy run must then be restarted or its policy re-evaluated.

Why not bit for bit: the same wheels round differently on another kind of CPU (measured
2026-12-04: an AVX-512 AMD EPYC differs from the machine that wrote the reference in 20 % of the
fields, by at most 2.3e-9, with no code change, and the difference does not grow over the 750
steps). Any change to gains, models or the solver moves the commands by far more than TOLERANCE.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from convex_mpc_node.gait import load_hand_tuned_gaits
from gait_policy_node.rollout import ClosedLoop

from gait_policy_node import speed_profiles

REFERENCE = Path(__file__).with_name("data") / "closed_loop_reference.npz"
CASES = {"slow_trot": 1.0, "fly_trot": 2.5}  # gait -> ramp target [m/s] at 1 m/s^2
STEPS = 750  # 1.5 s of 2 ms control steps
FIELDS = ("position", "velocity", "kp", "kd", "torque")
TOLERANCE = 1e-6  # [rad, rad/s, N m/rad, N m s/rad, N m]: 400 times the CPU-to-CPU rounding seen


def record(gait: str, target: float) -> np.ndarray:
    """(STEPS, 1 + 5 x 12): the mode and every field of each joint command the controller sent."""
    loop = ClosedLoop(load_hand_tuned_gaits()[gait])
    profile = speed_profiles.ramp(target)
    rows = []
    try:
        for _ in range(STEPS):
            command = loop.control(profile(loop.sim.time))
            rows.append(np.concatenate([[float(command.mode)], *(getattr(command, f) for f in FIELDS)]))
            loop.actuate(command)
    finally:
        loop.sim.close()
    return np.array(rows)


def test_every_motor_command_matches_the_committed_reference():
    reference = np.load(REFERENCE)
    for gait, target in CASES.items():
        now = record(gait, target)
        expected = reference[gait]
        differs = np.flatnonzero(np.any(np.abs(now - expected) > TOLERANCE, axis=1))
        assert not differs.size, (
            f"{gait}: the closed loop's motor commands changed by more than {TOLERANCE:g}, first at step {differs[0]} "
            f"(max difference {np.max(np.abs(now - expected)):.3g}); a trained policy may no longer be valid. "
            "If the change is meant, regenerate with: python tests/test_closed_loop_reference.py --update")


if __name__ == "__main__":
    if sys.argv[1:] != ["--update"]:
        sys.exit("usage: python tests/test_closed_loop_reference.py --update   (rewrites the reference)")
    np.savez_compressed(REFERENCE, **{gait: record(gait, target) for gait, target in CASES.items()})
    print(f"wrote {REFERENCE}")
