"""Hardware-in-the-loop end to end: the graph on the hardware bridge, the robot a virtual A1 over UDP.

Every node is its own process; the only path between the bridge and the (simulated) robot is the
A1's low-level UDP protocol on loopback. Both run in lockstep (one 2 ms robot tick per command
datagram, /clock from the robot's tick), so the runs do not depend on this machine's speed. The
virtual A1 starts with the robot dropped without a settle phase: the bridge's safe start has to
stand it up before the controller gets the sensors.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from graph_helpers import DAMPING_KD, MOTOR_TORQUE_LIMIT, run_until
from ros_helpers import spin_until
from test_graph_e2e import graph  # noqa: F401 (the fixture)

STAND_UP_DONE = 2.5  # [s] robot time: bridge stand-up 1.5 s, then the controller's 1 s stand ramp


def first_damped_tick(joints: list[tuple[float, np.ndarray, np.ndarray]], after: float) -> float | None:
    """Time of the first state after ``after`` whose reported torques are the damping law's.

    Over a tick the motors apply -kd * (velocity at its start); the robot reports it as tauEst,
    to the wire's resolution (1/256 N m, float32 velocities).
    """
    times = np.array([t for t, _, _ in joints])
    velocity = np.array([v for _, v, _ in joints])
    effort = np.array([e for _, _, e in joints])
    damping = np.clip(-DAMPING_KD * velocity[:-1], -MOTOR_TORQUE_LIMIT, MOTOR_TORQUE_LIMIT)
    damped = np.all(np.abs(effort[1:] - damping) <= 4e-3, axis=1) & (times[1:] > after)
    hits = np.flatnonzero(damped)
    return float(times[1:][hits[0]]) if hits.size else None


@pytest.fixture
def hil(request):
    """The e2e graph fixture (process graph, watcher node, executor), the latest /diagnostics by
    name, and ``start(clock, **start_hil arguments)``: the HIL graph; in lockstep its robot is held
    (nothing talks to it, so it does not tick) until the watcher hears its ground truth. A busy
    lockstep graph can take seconds to match a new subscriber, and these tests look at t = 0 on."""
    g, watcher, executor = request.getfixturevalue("graph")
    watcher.watch_joints_and_commands()
    diagnostics: dict[str, dict[str, str]] = {}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        diagnostics.update({s.name: {kv.key: kv.value for kv in s.values} for s in msg.status})

    def robot_heard() -> None:
        assert spin_until(executor, watcher.hears_ground_truth, 30.0), "virtual_a1's ground truth never matched"

    def start(clock: str, **kwargs) -> None:
        # In realtime the robot ticks on its own: waiting would only spend its robot time.
        g.start_hil(clock, robot_started=robot_heard if clock == "lockstep" else None, **kwargs)

    watcher.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    return g, watcher, executor, diagnostics, start


@pytest.mark.ros
@pytest.mark.slow
def test_hil_walks_1_mps_then_damps_within_50_ms_of_controller_death(hil):
    g, watcher, executor, diagnostics, start_hil = hil
    start_hil("lockstep", packet_loss=0.0, lockstep_timeout=0.05)
    watcher.speed = 1.0
    run_until(executor, watcher, g, 7.5, wall_timeout=300)
    assert watcher.lowest() > 0.18, "fell"
    standing = [z for t, _, z in watcher.truth if STAND_UP_DONE - 1.0 < t < STAND_UP_DONE]
    assert standing and max(standing) > 0.24, f"never stood up (ground truth heard from t = {watcher.truth[0][0]} s)"
    # 1 m/s^2 to 1.0 m/s after the stand-up: 5 s into walking is t = 6.5 .. 7.5 s, as with the sim bridge.
    speed = watcher.mean_speed(6.5, 7.5)
    assert speed == pytest.approx(1.0, rel=0.10)
    # The foot contacts were recalibrated from the scheduled swings: the unloaded reading the bridge
    # learned is the virtual sensor's offset (15 raw units in config/virtual_a1.yaml), a little above
    # because a scheduled swing also holds the last moments of ground contact after lift-off is due.
    assert spin_until(executor, lambda: "a1_hw_bridge" in diagnostics, 5.0)
    bridge = diagnostics["a1_hw_bridge"]
    assert int(bridge["swing_calibrations"]) > 20
    unloaded = np.array(json.loads(bridge["foot_unloaded_readings"]))
    assert np.all((unloaded >= 15.0) & (unloaded < 18.0)), unloaded
    assert int(bridge["states_dropped_bad_crc"]) == int(bridge["states_dropped_wrong_size"]) == 0
    g.kill("convex_mpc")
    killed_at = watcher.sim_time()
    run_until(executor, watcher, g, killed_at + 0.1, wall_timeout=60)
    last_command = max(watcher.commands)
    damping_start = first_damped_tick(watcher.joints, after=last_command)
    assert damping_start is not None, "the bridge never sent damping"
    assert damping_start - last_command <= 0.05 + 1e-9, f"damping {damping_start - last_command:.3f} s after"
    print(f"HIL: mean speed {speed:.3f} m/s at 6.5-7.5 s; damping {1e3 * (damping_start - last_command):.0f} ms "
          "(robot time) after the last controller command")


@pytest.mark.ros
@pytest.mark.slow
def test_hil_5_percent_packet_loss_does_not_fall(hil):
    """In the composed form (hw_bridge, estimator and controller one process, as bring-up starts
    them), lockstep; the separate form is the controller-death test's."""
    g, watcher, executor, diagnostics, start_hil = hil
    start_hil("lockstep", packet_loss=0.05, composed_chain=True)
    assert sorted(g.procs) == ["control_chain", "gait_policy", "virtual_a1"]
    watcher.speed = 1.0
    run_until(executor, watcher, g, 6.0, wall_timeout=300)  # 2.5 s at 1.0 m/s (reached at about 3.5 s)
    assert watcher.lowest() > 0.18, "fell"
    speed = watcher.mean_speed(5.0, 6.0)
    assert speed > 0.85, f"walked at {speed:.2f} m/s only"
    # The losses really happened, in both directions, and the bridge saw the lost states.
    assert spin_until(executor, lambda: {"virtual_a1", "a1_hw_bridge"} <= set(diagnostics), 5.0)
    robot, bridge = diagnostics["virtual_a1"], diagnostics["a1_hw_bridge"]
    ticks = int(robot["ticks"])
    assert 0.03 * ticks < int(robot["commands_lost_injected"]) < 0.07 * ticks
    assert 0.03 * ticks < int(robot["states_lost_injected"]) < 0.07 * ticks
    assert int(bridge["state_timeouts"]) >= 0.5 * int(robot["states_lost_injected"])  # snapshots differ in time
    print(f"HIL 5% loss: mean speed {speed:.3f} m/s at 5-6 s over {ticks} ticks; "
          f"lost {robot['commands_lost_injected']} commands, {robot['states_lost_injected']} states")



@pytest.mark.ros
@pytest.mark.slow
def test_hil_realtime_composed_chain_stands_up_and_the_robot_damps_when_it_is_killed(hil):
    """hw_bridge and convex_mpc composed in one control_chain process, against the virtual A1 on the
    wall clock: the bridge's safe start and the controller stand the robot up. SIGKILL of that
    process takes bridge and controller at once, so nothing sends the bridge's last damping
    datagrams: the robot, left without commands, damps its motors on its own after its
    command_loss_timeout (config/virtual_a1.yaml), as the real A1 is assumed to."""
    g, watcher, executor, diagnostics, start_hil = hil
    start_hil("realtime", composed_chain=True)
    assert sorted(g.procs) == ["control_chain", "gait_policy", "virtual_a1"]
    run_until(executor, watcher, g, STAND_UP_DONE + 1.0, wall_timeout=120)
    assert max(z for t, _, z in watcher.truth if t > STAND_UP_DONE - 1.0) > 0.24, "never stood up"
    assert spin_until(executor, lambda: int(diagnostics.get("virtual_a1", {}).get("commands_accepted", 0)) > 0, 5.0)
    fallbacks = int(diagnostics["virtual_a1"]["command_loss_fallbacks"])
    g.kill("control_chain")
    killed_at = watcher.sim_time()
    assert spin_until(executor, lambda: int(diagnostics["virtual_a1"]["command_loss_fallbacks"]) > fallbacks,
                      10.0), "the robot did not go to its command-loss damping"
    run_until(executor, watcher, g, killed_at + 0.5, wall_timeout=30)  # the robot lives on, damped
