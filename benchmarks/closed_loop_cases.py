"""The closed-loop cases of issues 4 and 5, measured: speed tracking, estimator accuracy, power, CoT.

In-process (sim core + Kalman estimator + controller, no ROS), the same runs as
tests/test_closed_loop.py, printing the figures the tests only bound. Speeds are ramped at 1 m/s^2;
means are over the second half of each run; estimator errors from t = 1 s; CoT with the simulated
robot's mass (12.458 kg). Prints a table, then one JSON line.

Usage: source scripts/env.sh && python benchmarks/closed_loop_cases.py
"""

from __future__ import annotations

import json

import numpy as np
from a1_common.command import VelocityCommand
from a1_common.robot import a1
from convex_mpc_node.energy import cost_of_transport
from convex_mpc_node.gait import gait_for_speed, load_hand_tuned_gaits
from gait_policy_node.rollout import run_closed_loop

from gait_policy_node import speed_profiles


def main() -> None:
    gaits = load_hand_tuned_gaits()
    mass = a1().urdf_total_mass

    def fixed(name):
        return lambda t, c: gaits[name]

    cases = [
        ("walk 0.5 m/s", fixed("walk"), speed_profiles.ramp(0.5), 10.0, 0.5),
        ("slow trot 1.0 m/s", fixed("slow_trot"), speed_profiles.ramp(1.0), 10.0, 1.0),
        ("rapid trot 1.5 m/s", fixed("rapid_trot"), speed_profiles.ramp(1.5), 10.0, 1.5),
        ("rapid trot 2.0 m/s", fixed("rapid_trot"), speed_profiles.ramp(2.0), 10.0, 2.0),
        ("fly trot 2.5 m/s", fixed("fly_trot"), speed_profiles.ramp(2.5), 10.0, 2.5),
        ("accel 0-2.5, scheduled", lambda t, c: gait_for_speed(c.vx, gaits), speed_profiles.ramp(2.5), 20.0, 2.5),
        ("trot, yaw 0.5 rad/s", fixed("slow_trot"), lambda t: VelocityCommand(yaw_rate=0.5), 10.0, 0.0),
        ("trot, lateral 0.3 m/s", fixed("slow_trot"), lambda t: VelocityCommand(vy=0.3), 10.0, 0.0),
        ("standing (trot in place)", fixed("slow_trot"), lambda t: VelocityCommand(), 10.0, 0.0),
    ]
    header = (f"{'case':<26}{'fell':>5}{'vx':>7}{'vy':>7}{'yaw/s':>7}{'est rms':>9}{'est bias':>9}"
              f"{'power W':>9}{'CoT':>6}{'drift m':>8}")
    print(header)
    print("-" * len(header))
    results = {}
    for name, schedule, profile, duration, speed in cases:
        traj = run_closed_loop(schedule, profile, duration)
        v = traj.mean_velocity(duration / 2)
        half = len(traj.time) // 2
        yaw_rate = float(np.mean(traj.yaw_rate[half:]))
        rms, bias = traj.estimator_error(1.0)
        power = float(np.mean(traj.power[half:]))
        cot = cost_of_transport(power, mass, v[0]) if speed > 0 else float("nan")
        drift = float(np.linalg.norm(traj.position[-1][:2] - traj.position[0][:2]))
        print(f"{name:<26}{traj.fell!s:>5}{v[0]:>7.3f}{v[1]:>7.3f}{yaw_rate:>7.3f}{rms:>9.4f}{bias:>+9.4f}"
              f"{power:>9.1f}{cot:>6.2f}{drift:>8.3f}")
        key = "".join(ch if ch.isalnum() else "_" for ch in name).strip("_")
        results[key] = {"fell": traj.fell, "mean_vx_m_per_s": float(v[0]), "mean_vy_m_per_s": float(v[1]),
                        "mean_yaw_rate_rad_per_s": yaw_rate, "estimator_rms_m_per_s": rms,
                        "estimator_bias_m_per_s": bias, "mean_power_w": power,
                        "cost_of_transport": None if np.isnan(cot) else cot,
                        "horizontal_displacement_m": drift}
    print(json.dumps(results))


if __name__ == "__main__":
    main()
