"""Phase integrator (paper section 3.2), hand-tuned gaits and the energy model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from a1_common.config import ConfigError
from convex_mpc_node.energy import cost_of_transport, motor_power
from convex_mpc_node.gait import GaitParams, LegState, PhaseIntegrator, load_hand_tuned_gaits

PI = math.pi
DT = 0.002


def trot(f: float = 2.0, p: float = 0.5) -> GaitParams:
    return GaitParams(f, p, (0.0, PI, PI, 0.0))


def test_phase_advances_by_two_pi_f_dt():
    gait = PhaseIntegrator(trot(f=2.0))
    for _ in range(10):
        gait.step(DT)
    assert gait.phase_fr == pytest.approx(2 * PI * 2.0 * DT * 10)
    np.testing.assert_allclose(gait.phases, (gait.phase_fr + np.array([0, PI, PI, 0])) % (2 * PI))
    for _ in range(240):  # 250 steps of 2 ms at 2 Hz = one full cycle
        gait.step(DT)
    assert gait.phase_fr == pytest.approx(0.0, abs=1e-9) or gait.phase_fr == pytest.approx(2 * PI)


def test_swing_then_stance_within_a_cycle():
    gait = PhaseIntegrator(trot(f=2.0, p=0.3))
    contact_fr = []
    for _ in range(250):
        contact_fr.append(gait.desired_contact[0])
        gait.step(DT)
    contact_fr = np.array(contact_fr)
    # FR starts in swing (phi = 0), swings for 30% of the 0.5 s cycle, then stands.
    assert not contact_fr[0]
    # Stance begins at phase 2 pi * 0.3, i.e. after 75 steps (76 if rounding lands just below).
    assert np.flatnonzero(contact_fr)[0] in (75, 76)
    assert contact_fr.mean() == pytest.approx(0.7, abs=0.01)
    assert gait.stance_duration == pytest.approx(0.35) and gait.swing_duration == pytest.approx(0.15)


def test_trot_diagonal_pairs():
    gait = PhaseIntegrator(trot())
    for _ in range(37):
        gait.step(DT)
        c = gait.desired_contact
        assert c[0] == c[3] and c[1] == c[2] and c[0] != c[1]


def test_parameter_change_mid_cycle_keeps_leg_one_continuous():
    gait = PhaseIntegrator(trot(f=2.0))
    for _ in range(60):
        gait.step(DT)
    before = gait.phase_fr
    gait.set_params(GaitParams(3.5, 0.6, (0.0, 0.5 * PI, PI, 1.5 * PI)))
    assert gait.phase_fr == before  # no jump in phi_1
    np.testing.assert_allclose(gait.phases, (before + np.array([0, 0.5 * PI, PI, 1.5 * PI])) % (2 * PI))
    gait.step(DT)
    assert gait.phase_fr == pytest.approx(before + 2 * PI * 3.5 * DT)


def test_contact_schedule_prediction():
    gait = PhaseIntegrator(trot(f=2.0, p=0.5))
    plan = gait.contact_schedule(horizon=10, step=0.025)
    assert plan.shape == (10, 4)
    # Half-cycle = 0.25 s = 10 rows: FR swings for the whole horizon, FL stands throughout.
    assert not plan[:, 0].any() and plan[:, 1].all()
    # Predicted rows agree with actually integrating forward.
    for k in range(1, 10):
        probe = PhaseIntegrator(trot(f=2.0, p=0.5))
        for _ in range(round(k * 0.025 / DT)):
            probe.step(DT)
        np.testing.assert_array_equal(plan[k], probe.desired_contact)


def test_measured_leg_states():
    gait = PhaseIntegrator(trot(f=2.0, p=0.5))
    for _ in range(100):  # FR/RL at 80% of swing, FL/RR at 80% of stance
        gait.step(DT)
    states = gait.leg_states(np.array([True, False, True, False]))
    assert states[0] == LegState.EARLY_CONTACT  # touching down late in swing
    assert states[1] == LegState.LOST_CONTACT  # no ground late in stance
    assert states[2] == LegState.STANCE
    assert states[3] == LegState.SWING
    plan = gait.contact_schedule(3, 0.025, foot_contact=np.array([True, False, True, False]))
    np.testing.assert_array_equal(plan[0], [True, True, True, False])


@pytest.mark.parametrize(
    ("params", "field"),
    [
        (GaitParams(0.0, 0.5, (0, PI, PI, 0)), "stepping_frequency"),
        (GaitParams(4.5, 0.5, (0, PI, PI, 0)), "stepping_frequency"),
        (GaitParams(2.0, 1.0, (0, PI, PI, 0)), "swing_ratio"),
        (GaitParams(2.0, float("nan"), (0, PI, PI, 0)), "swing_ratio"),
        (GaitParams(2.0, 0.5, (0, 2 * PI, PI, 0)), r"phase_offsets\[1\]"),
        (GaitParams(2.0, 0.5, (0.1, PI, PI, 0)), r"phase_offsets\[0\]"),
        (GaitParams(2.0, 0.5, (0, PI, PI)), "phase_offsets must have 4"),
    ],
)
def test_bad_gait_parameters_name_the_field(params, field):
    with pytest.raises(ConfigError, match=field):
        PhaseIntegrator(params)


def test_hand_tuned_gaits_of_the_paper():
    gaits = load_hand_tuned_gaits()
    assert set(gaits) == {"walk", "slow_trot", "rapid_trot", "fly_trot"}
    assert gaits["walk"] == GaitParams(2.0, 0.3, (0.0, PI, 1.5 * PI, 0.5 * PI))
    assert gaits["fly_trot"].stepping_frequency == 4.0 and gaits["fly_trot"].swing_ratio == 0.6


def test_energy_model():
    tau = np.array([10.0, -10.0, 5.0, 0.0])
    omega = np.array([2.0, 2.0, -20.0, 3.0])
    # 10*2 + 0.3*100 = 50; -20 + 30 = 10; -100 + 7.5 < 0 -> 0 (no regeneration); 0.
    np.testing.assert_allclose(motor_power(tau, omega), [50.0, 10.0, 0.0, 0.0])
    assert cost_of_transport(147.15, mass=15.0, speed=1.0, gravity=9.81) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="mass"):
        cost_of_transport(1.0, mass=0.0, speed=1.0)
