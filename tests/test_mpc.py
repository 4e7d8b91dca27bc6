"""Convex MPC: discretisation, agreement with a straightforward condensed QP, constraints, fallback."""

from __future__ import annotations

import dataclasses

import numpy as np
import osqp
import pytest
import scipy.linalg
import scipy.sparse as sp
from a1_common.config import ConfigError
from a1_common.kinematics import foot_positions
from a1_common.robot import a1
from convex_mpc_node.mpc import (
    NU,
    NX,
    ConvexMpc,
    MpcCommand,
    MpcConfig,
    MpcState,
    continuous_dynamics,
    discretize,
    force_constraint_block,
    initial_state,
    reference_trajectory,
    rotation_rp,
)


def make_state(rng: np.random.Generator | None = None) -> MpcState:
    robot = a1()
    feet = foot_positions(robot, robot.nominal_joint_angles)
    if rng is None:
        return MpcState(0.0, 0.0, 0.26, np.zeros(3), np.zeros(3), feet)
    return MpcState(rng.normal(0, 0.05), rng.normal(0, 0.05), 0.26 + rng.normal(0, 0.01),
                    rng.normal(0, 0.2, 3), rng.normal(0, 0.3, 3), feet + rng.normal(0, 0.03, (4, 3)))


def condensed_reference_solution(config: MpcConfig, state: MpcState, command: MpcCommand,
                                 plan: np.ndarray) -> np.ndarray:
    """The same QP written the textbook way: X = Phi x0 + Gamma U, dense cost, tight OSQP."""
    h = config.horizon
    a, b = continuous_dynamics(config, state)
    # Exact ZOH by the matrix exponential of the augmented system.
    aug = np.zeros((NX + NU, NX + NU))
    aug[:NX, :NX], aug[:NX, NX:] = a, b
    e = scipy.linalg.expm(aug * config.step)
    a_d, b_d = e[:NX, :NX], e[:NX, NX:]
    phi = np.vstack([np.linalg.matrix_power(a_d, k + 1) for k in range(h)])
    gamma = np.zeros((h * NX, h * NU))
    for i in range(h):
        for j in range(i + 1):
            gamma[i * NX:(i + 1) * NX, j * NU:(j + 1) * NU] = np.linalg.matrix_power(a_d, i - j) @ b_d
    q_bar = np.diag(np.tile(np.append(config.state_weights, 0.0), h))
    x_ref = reference_trajectory(config, state, command).ravel()
    free = phi @ initial_state(config, state)
    hessian = 2 * (gamma.T @ q_bar @ gamma + config.force_weight * np.eye(h * NU))
    gradient = 2 * gamma.T @ q_bar @ (free - x_ref)
    block = force_constraint_block(config.friction_coefficient)
    cons = scipy.linalg.block_diag(*[block] * (h * 4))
    lower, upper = [], []
    for k in range(h):
        for leg in range(4):
            c = plan[k, leg]
            lower += [0, 0, 0, 0, config.min_normal_force if c else 0.0]
            upper += [np.inf if c else 0] * 4 + [config.max_normal_force if c else 0.0]
    solver = osqp.OSQP()
    solver.setup(P=sp.csc_matrix(np.triu(hessian)), q=gradient, A=sp.csc_matrix(cons), l=np.array(lower),
                 u=np.array(upper), eps_abs=1e-9, eps_rel=1e-9, max_iter=200_000, polishing=True,
                 verbose=False)
    result = solver.solve(raise_error=True)
    assert result.info.status == "solved"
    return result.x[:NU].reshape(4, 3)


def test_dynamics_are_the_centroidal_model():
    config = MpcConfig()
    rng = np.random.default_rng(2)
    state = make_state(rng)
    a, b = continuous_dynamics(config, state)
    forces = rng.normal(0, 50, (4, 3))
    rot = rotation_rp(state.roll, state.pitch)
    inertia_world = rot @ np.diag(config.inertia) @ rot.T
    torque = sum(np.cross(state.foot_positions[i], forces[i]) for i in range(4))
    np.testing.assert_allclose((b @ forces.ravel())[6:9], np.linalg.solve(inertia_world, torque), atol=1e-9)
    np.testing.assert_allclose((b @ forces.ravel())[9:12], forces.sum(axis=0) / config.mass, atol=1e-12)
    x = initial_state(config, state)
    assert (a @ x)[11] == -config.gravity  # free fall without forces
    np.testing.assert_allclose((a @ x)[0:3], x[6:9])  # Euler rates = angular velocity


def test_closed_form_discretisation_is_exact():
    config = MpcConfig()
    a, b = continuous_dynamics(config, make_state(np.random.default_rng(0)))
    a_d, b_d = discretize(a, b, config.step)
    aug = np.zeros((NX + NU, NX + NU))
    aug[:NX, :NX], aug[:NX, NX:] = a, b
    e = scipy.linalg.expm(aug * config.step)
    np.testing.assert_allclose(a_d, e[:NX, :NX], atol=1e-12)
    np.testing.assert_allclose(b_d, e[:NX, NX:], atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_matches_condensed_reference_formulation(seed):
    rng = np.random.default_rng(seed)
    config = MpcConfig(eps=1e-8, max_iter=100_000)
    mpc = ConvexMpc(config)
    state = make_state(rng)
    command = MpcCommand(rng.uniform(-1, 2, 2), rng.uniform(-0.5, 0.5), 0.26)
    plan = rng.random((config.horizon, 4)) < 0.6
    plan[0, [0, 3]] = True
    ours = mpc.solve(state, command, plan)
    assert ours.solved
    reference = condensed_reference_solution(config, state, command, plan)
    np.testing.assert_allclose(ours.forces, reference, atol=0.05)


def test_standing_forces_carry_the_weight_within_friction():
    # Tight tolerance: this checks the formulation. (The default eps 1e-3, the reference's OSQP
    # setting, is chosen for speed: standing, its first-step forces can be about 10% off.)
    config = MpcConfig(eps=1e-6, max_iter=10_000)
    mpc = ConvexMpc(config)
    plan = np.ones((config.horizon, 4), dtype=bool)
    for _ in range(5):  # warm-started, as at 500 Hz
        sol = mpc.solve(make_state(), MpcCommand(np.zeros(2), 0.0, 0.26), plan)
    assert sol.solved
    weight = config.mass * config.gravity
    assert sol.forces[:, 2].sum() == pytest.approx(weight, rel=0.05)
    assert np.all(np.abs(sol.forces[:, :2]) <= config.friction_coefficient * sol.forces[:, 2:3] + 1e-3)


def test_swing_legs_get_no_force():
    config = MpcConfig()
    mpc = ConvexMpc(config)
    plan = np.zeros((config.horizon, 4), dtype=bool)
    plan[:, [0, 3]] = True  # trot: FR and RL in stance
    sol = mpc.solve(make_state(), MpcCommand(np.array([1.0, 0.0]), 0.0, 0.26), plan)
    np.testing.assert_array_equal(sol.forces[[1, 2]], 0.0)
    assert np.all(sol.forces[[0, 3], 2] > 0)


def test_unsolved_qp_falls_back_to_static_forces():
    config = MpcConfig(max_iter=1, max_violation=1e-9)
    mpc = ConvexMpc(config)
    plan = np.ones((config.horizon, 4), dtype=bool)
    plan[0, 1] = False
    sol = mpc.solve(make_state(), MpcCommand(np.array([1.0, 0.0]), 0.0, 0.26), plan)
    assert sol.fallback and not sol.solved
    share = config.mass * config.gravity / 3
    np.testing.assert_allclose(sol.forces[:, 2], [share, 0.0, share, share])
    assert np.all(np.isfinite(sol.forces))


def test_fallback_is_the_static_split_marked_as_a_failure():
    mpc = ConvexMpc()
    contacts = np.array([True, False, False, True])
    sol = mpc.fallback(contacts, "injected failure")
    assert sol.fallback and not sol.solved and sol.status == "injected failure"
    assert np.allclose(sol.forces, mpc.static_forces(contacts))
    assert np.allclose(sol.forces[contacts, 2], mpc.config.mass * mpc.config.gravity / 2)
    assert not sol.forces[~contacts].any()


def test_bad_contact_plan_shape():
    mpc = ConvexMpc()
    with pytest.raises(ValueError, match="contact_plan"):
        mpc.solve(make_state(), MpcCommand(np.zeros(2), 0.0, 0.26), np.ones((3, 4), dtype=bool))


def test_controller_config_file_loads_and_rejects_unknown_keys(tmp_path):
    from convex_mpc_node.controller import ControllerConfig, load_controller_config

    config = load_controller_config()
    assert config == ControllerConfig()  # the file and the library defaults agree
    bad = tmp_path / "convex_mpc.yaml"
    bad.write_text("convex_mpc:\n  ros__parameters:\n    mpc_horizn: 10\n")
    with pytest.raises(ConfigError, match="mpc_horizn"):
        load_controller_config(bad)
    bad.write_text("convex_mpc:\n  ros__parameters:\n    mpc_friction_coefficient: -1.0\n")
    with pytest.raises(ConfigError, match="friction_coefficient"):
        load_controller_config(bad)


def test_controller_config_overlay_overrides_only_its_keys_and_is_named_in_errors(tmp_path):
    """The realtime overlay, as a second --params-file: its values win, the rest is the base file's."""
    from a1_common.config import config_dir
    from convex_mpc_node.controller import load_controller_config

    realtime = load_controller_config(overlays=(config_dir() / "convex_mpc_realtime.yaml",))
    assert realtime.mpc_async and realtime.mpc_period_steps == 5 and realtime.mpc.force_weight == 1.0e-5
    base = dataclasses.replace(load_controller_config(), mpc_async=True, mpc_period_steps=5)
    assert realtime == dataclasses.replace(base, mpc=dataclasses.replace(base.mpc, force_weight=1.0e-5))
    bad = tmp_path / "overlay.yaml"
    bad.write_text("/**/convex_mpc:\n  ros__parameters:\n    mpc_period_steps: 0\n")
    with pytest.raises(ConfigError, match=r"overlay\.yaml.*mpc_period_steps"):
        load_controller_config(overlays=(bad,))
