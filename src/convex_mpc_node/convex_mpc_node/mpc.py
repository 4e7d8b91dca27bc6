"""Convex MPC for stance control (paper appendix A; Di Carlo et al. 2018), solved with OSQP.

Model: the centroidal dynamics of the paper, a single rigid body of mass m and body inertia I_b with
massless legs, small roll/pitch. State (13) = [roll, pitch, yaw, p (3), omega (3), v (3), g], where
the constant last entry carries gravity. Everything is expressed in the *yaw-aligned frame*: the
world frame rotated by the robot's current yaw, origin at the COM. There the Euler-rate map
R_z(yaw)^T of the paper is the identity at the first step, and foot positions r_i are
R_yaw^T (R p_i) with p_i the base-frame foot positions.

  d/dt [Theta, p, omega, v] = [omega, v, I_w^-1 sum r_i x f_i, sum f_i / m - g e_z]

A is nilpotent (A^3 = 0), so the exact zero-order-hold discretisation over dt is closed form:
  A_d = I + A dt + A^2 dt^2 / 2,   B_d = (I dt + A dt^2 / 2 + A^2 dt^3 / 6) B.

The QP is the sparse (simultaneous) formulation: variables z = [x_1 .. x_H, u_0 .. u_{H-1}],
equality rows for the dynamics, five rows per leg and step for the friction pyramid and the
normal-force bounds (swing legs get f = 0). Its sparsity pattern never changes, so each control
step only updates values (q, bounds, the B_d entries of the constraint matrix) in the persistent
OSQP workspace: no re-setup.

Units: N, m, s, rad. Forces returned are ground reaction forces on the robot, yaw-aligned frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import osqp
import scipy.sparse as sp
from a1_common.config import require_integer, require_numbers, require_range, setting
from a1_common.robot import NUM_LEGS

NX = 13  # state size (with the gravity entry)
NU = 3 * NUM_LEGS  # forces of the four feet
ROWS_PER_FOOT = 5
# The bound OSQP's Python wrapper clips l and u to; ConvexMpc.solve applies it itself (see there).
_OSQP_INFTY = osqp.constant("OSQP_INFTY")


@dataclass(frozen=True)
class MpcConfig:
    horizon: int = setting(10, "MPC horizon [steps]")
    step: float = setting(0.025, "time between MPC horizon steps [s]")
    # Diagonal state weights [roll, pitch, yaw, x, y, z, wx, wy, wz, vx, vy, vz].
    # Reference values except: x, y, yaw tracked (the reference's zeros let a standing robot drift)
    # and v_x, v_y at 1 (its "alternative" weights), for tighter speed tracking.
    state_weights: tuple[float, ...] = setting(
        (1.0, 1.0, 0.5, 2.0, 2.0, 10.0, 0.0, 0.0, 0.1, 1.0, 1.0, 0.0),
        "MPC state weights: roll, pitch, yaw, x, y, z, wx, wy, wz, vx, vy, vz")
    # alpha: cost alpha |u|^2. The reference's 1e-5 makes the finite-horizon optimum trade height
    # for smaller forces late in the horizon, so the first force overshoots m g by about 20% when
    # standing still; 1e-6 keeps it within 5% (tests/test_mpc.py).
    force_weight: float = setting(1e-6, "MPC weight alpha of the force cost alpha |u|^2")
    mass: float = setting(12.458, "robot mass in the MPC model [kg]")
    # Composite inertia of the pybullet_data A1 about its COM at the nominal stance, measured from
    # the simulator's link masses and inertias (the reference used 0.17, 0.57, 0.64 for a heavier URDF).
    inertia: tuple[float, float, float] = setting(
        (0.13, 0.35, 0.39), "body-frame diagonal inertia about the COM in the MPC model [kg m^2]")
    friction_coefficient: float = setting(0.6, "friction coefficient mu of the MPC's friction pyramid")
    # Normal force of a stance foot [N]: at least 0.1 m g as in the reference (a planned stance
    # foot keeps pressing), at most 250 N rather than the reference's 10 m g: about what the
    # 33.5 N m knee can push through a 0.2 m calf, so the plan stays within the motors' reach.
    min_normal_force: float = setting(12.0, "least normal force of a planned stance foot [N]")
    max_normal_force: float = setting(250.0, "largest normal force of a stance foot [N]")
    gravity: float = setting(9.81, "gravity in the MPC model [m/s^2]")
    eps: float = setting(1e-3, "OSQP absolute and relative tolerance")
    max_iter: int = setting(200, "OSQP iterations per solve (warm-started)")
    max_violation: float = setting(1.0, "largest constraint violation accepted from an unfinished solve [N]")

    def validated(self) -> MpcConfig:
        require_integer("horizon", self.horizon, 1, 50)
        require_range("step", self.step, 0.0, 0.2, low_open=True)
        require_numbers("state_weights", self.state_weights, 12, 0.0, 1e6)
        require_range("force_weight", self.force_weight, 0.0, 1.0, low_open=True)
        require_range("mass", self.mass, 1.0, 100.0)
        require_numbers("inertia", self.inertia, 3, 0.0, 100.0, low_open=True)
        require_range("friction_coefficient", self.friction_coefficient, 0.0, 2.0, low_open=True)
        require_range("max_normal_force", self.max_normal_force, 1.0, 5000.0)
        require_range("min_normal_force", self.min_normal_force, 0.0, self.max_normal_force)
        require_range("gravity", self.gravity, 0.0, 20.0, low_open=True)
        require_range("eps", self.eps, 0.0, 1.0, low_open=True)
        require_integer("max_iter", self.max_iter, 1, 100_000)
        require_range("max_violation", self.max_violation, 0.0, 1000.0, low_open=True)
        return self



@dataclass
class MpcState:
    """Current state in the yaw-aligned frame (yaw itself is 0 there by construction)."""

    roll: float
    pitch: float
    height: float  # COM height above the ground [m]
    angular_velocity: np.ndarray  # (3,) [rad/s], yaw-aligned frame
    linear_velocity: np.ndarray  # (3,) [m/s], yaw-aligned frame
    foot_positions: np.ndarray  # (4, 3) feet relative to the COM, yaw-aligned frame [m]


@dataclass
class MpcCommand:
    velocity: np.ndarray  # (2,) desired v_x, v_y in the yaw-aligned frame [m/s]
    yaw_rate: float  # [rad/s]
    height: float  # desired COM height [m]
    # Where the commanded motion says the robot should be now, relative to where it is (yaw-aligned
    # frame): integrated command minus integrated velocity. Tracked with the x, y, yaw weights.
    position_error: np.ndarray = field(default_factory=lambda: np.zeros(2))  # [m]
    yaw_error: float = 0.0  # [rad]


@dataclass
class MpcSolution:
    forces: np.ndarray  # (4, 3) ground reaction forces on the robot at the first step [N]
    status: str
    solved: bool
    iterations: int
    solve_time: float  # [s] wall time of the OSQP update + solve
    build_time: float = 0.0  # [s] wall time to build the QP data
    fallback: bool = False


def rotation_rp(roll: float, pitch: float) -> np.ndarray:
    """R_y(pitch) R_x(roll): body orientation in the yaw-aligned frame."""
    cr, sr, cp, spt = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    return np.array([[cp, spt * sr, spt * cr], [0.0, cr, -sr], [-spt, cp * sr, cp * cr]])


_A_CONTINUOUS = np.zeros((NX, NX))
_A_CONTINUOUS[0:3, 6:9] = np.eye(3)  # Euler rates = omega (yaw-aligned frame, small roll/pitch)
_A_CONTINUOUS[3:6, 9:12] = np.eye(3)
_A_CONTINUOUS[11, 12] = -1.0  # v_z' = -g (state 12 holds g)


def continuous_dynamics(config: MpcConfig, state: MpcState) -> tuple[np.ndarray, np.ndarray]:
    """A (13x13, constant) and B (13x12) of the centroidal model at ``state``."""
    b = _input_matrix(np.diag(1.0 / np.asarray(config.inertia)), np.tile(np.eye(3) / config.mass, NUM_LEGS), state)
    return _A_CONTINUOUS.copy(), b


def _input_matrix(inertia_body_inv: np.ndarray, velocity_rows: np.ndarray, state: MpcState) -> np.ndarray:
    """B of :func:`continuous_dynamics` from its state-independent parts, which ConvexMpc computes
    once instead of every 2 ms: I_b^-1 (3x3 diagonal) and the rows of sum f_i / m (3x12)."""
    rot = rotation_rp(state.roll, state.pitch)
    inertia_world_inv = rot @ inertia_body_inv @ rot.T
    r = np.asarray(state.foot_positions, dtype=float)
    skews = np.zeros((NUM_LEGS, 3, 3))  # [r_i]x for all legs at once
    skews[:, 0, 1], skews[:, 0, 2] = -r[:, 2], r[:, 1]
    skews[:, 1, 0], skews[:, 1, 2] = r[:, 2], -r[:, 0]
    skews[:, 2, 0], skews[:, 2, 1] = -r[:, 1], r[:, 0]
    b = np.zeros((NX, NU))
    b[6:9] = np.einsum("ij,ljk->ilk", inertia_world_inv, skews).reshape(3, NU)
    b[9:12] = velocity_rows
    return b


def discretize(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order hold for nilpotent A (A^3 = 0)."""
    a2 = a @ a
    eye = np.eye(a.shape[0])
    return eye + a * dt + a2 * dt**2 / 2, (eye * dt + a * dt**2 / 2 + a2 * dt**3 / 6) @ b


def reference_trajectory(config: MpcConfig, state: MpcState, command: MpcCommand) -> np.ndarray:
    """Desired states x_1..x_H (H, 13): level body, commanded velocities, integrated position."""
    t = config.step * np.arange(1, config.horizon + 1)
    ref = np.zeros((config.horizon, NX))
    ref[:, 2] = command.yaw_error + command.yaw_rate * t
    ref[:, 3] = command.position_error[0] + command.velocity[0] * t
    ref[:, 4] = command.position_error[1] + command.velocity[1] * t
    ref[:, 5] = command.height
    ref[:, 8] = command.yaw_rate
    ref[:, 9] = command.velocity[0]
    ref[:, 10] = command.velocity[1]
    ref[:, 12] = config.gravity
    return ref


def initial_state(config: MpcConfig, state: MpcState) -> np.ndarray:
    x0 = np.zeros(NX)
    x0[0], x0[1] = state.roll, state.pitch
    x0[5] = state.height
    x0[6:9] = state.angular_velocity
    x0[9:12] = state.linear_velocity
    x0[12] = config.gravity
    return x0


def force_constraint_block(mu: float) -> np.ndarray:
    """Rows per foot on (f_x, f_y, f_z): f_x +- mu f_z, f_y +- mu f_z (pyramid), f_z."""
    return np.array([[1.0, 0.0, mu], [-1.0, 0.0, mu], [0.0, 1.0, mu], [0.0, -1.0, mu], [0.0, 0.0, 1.0]])


class ConvexMpc:
    """Persistent OSQP problem; ``solve`` updates values only and warm-starts from the last solve."""

    def __init__(self, config: MpcConfig | None = None) -> None:
        self.config = cfg = (config or MpcConfig()).validated()
        h = cfg.horizon
        self._n_x = h * NX
        self.n_var = h * (NX + NU)
        n_dyn = h * NX
        n_force = h * NUM_LEGS * ROWS_PER_FOOT
        self.n_con = n_dyn + n_force
        # Cost: sum_k |x_k - ref_k|_Q^2 + alpha |u_k|^2  ->  1/2 z' P z + q' z
        q_diag = np.append(np.asarray(cfg.state_weights, dtype=float), 0.0)
        self._q_diag = np.tile(q_diag, h)
        # Constants of build(), computed once (the same operations, so the same values).
        self._q_ref_gain = -2.0 * self._q_diag  # q = -2 Q x_ref
        self._q_forces = np.zeros(h * NU)
        self._inertia_body_inv = np.diag(1.0 / np.asarray(cfg.inertia))
        self._velocity_rows = np.tile(np.eye(3) / cfg.mass, NUM_LEGS)
        # Force-row bounds of a stance foot; a swing foot's are all 0 (f = 0).
        self._stance_lower = np.array([0.0, 0.0, 0.0, 0.0, cfg.min_normal_force])
        self._stance_upper = np.array([np.inf, np.inf, np.inf, np.inf, cfg.max_normal_force])
        p_diag = np.concatenate([2 * self._q_diag, np.full(h * NU, 2 * cfg.force_weight)])
        p_mat = sp.diags(p_diag, format="csc")
        # Structural sparsity of A_d (constant) and B_d (values change every step), found from a
        # generic state; only these entries enter the constraint matrix, which keeps the KKT system
        # OSQP factorises small.
        rng = np.random.default_rng(0)
        generic = MpcState(0.1, -0.1, 0.3, rng.normal(size=3), rng.normal(size=3), rng.normal(size=(4, 3)))
        a_cont, b_generic_cont = continuous_dynamics(cfg, generic)
        self.a_d, b_generic = discretize(a_cont, b_generic_cont, cfg.step)
        # A is constant, so B_d = (I dt + A dt^2/2 + A^2 dt^3/6) B: the factor is computed once here.
        dt = cfg.step
        self._b_factor = np.eye(NX) * dt + a_cont * dt**2 / 2 + a_cont @ a_cont * dt**3 / 6
        a_mask = self.a_d != 0
        self._b_mask = b_generic != 0
        a_r, a_c = np.nonzero(a_mask)
        b_r, b_c = np.nonzero(self._b_mask)
        block = force_constraint_block(cfg.friction_coefficient)
        f_r, f_c = np.nonzero(block)
        rows, cols = [], []
        for k in range(h):
            r0 = k * NX
            rows.append(r0 + np.arange(NX))  # +I on x_{k+1}
            cols.append(k * NX + np.arange(NX))
            if k > 0:  # -A_d on x_k
                rows.append(r0 + a_r)
                cols.append((k - 1) * NX + a_c)
            rows.append(r0 + b_r)  # -B_d on u_k
            cols.append(self._n_x + k * NU + b_c)
            for leg in range(NUM_LEGS):
                rows.append(n_dyn + (k * NUM_LEGS + leg) * ROWS_PER_FOOT + f_r)
                cols.append(self._n_x + k * NU + 3 * leg + f_c)
        rows = np.concatenate(rows)
        cols = np.concatenate(cols)
        pattern = sp.csc_matrix((np.arange(1, len(rows) + 1, dtype=float), (rows, cols)),
                                shape=(self.n_con, self.n_var))
        pattern.sort_indices()
        # Position of each (row, col) entry in the CSC data array, to write values without re-setup.
        # The data were 1..nnz in append order, so they tell where each appended entry landed.
        position = np.empty(len(rows), dtype=int)
        position[pattern.data.astype(int) - 1] = np.arange(pattern.nnz)
        self._a_values = np.zeros(pattern.nnz)
        i = 0
        b_slots = []
        for k in range(h):
            self._a_values[position[i:i + NX]] = 1.0
            i += NX
            if k > 0:
                self._a_values[position[i:i + len(a_r)]] = -self.a_d[a_mask]
                i += len(a_r)
            b_slots.append(position[i:i + len(b_r)])
            i += len(b_r)
            for _ in range(NUM_LEGS):
                self._a_values[position[i:i + len(f_r)]] = block[f_r, f_c]
                i += len(f_r)
        self._b_positions = np.array(b_slots)  # (h, nnz of B_d)
        self._lower = np.zeros(self.n_con)
        self._upper = np.zeros(self.n_con)
        self._solver = osqp.OSQP()
        self._solver.setup(P=sp.triu(p_mat, format="csc"), q=np.zeros(self.n_var),
                           A=sp.csc_matrix((self._a_values.copy(), pattern.indices, pattern.indptr),
                                           shape=pattern.shape),
                           l=self._lower, u=self._upper, verbose=False, warm_starting=True, polishing=False,
                           eps_abs=cfg.eps, eps_rel=cfg.eps, max_iter=cfg.max_iter,
                           adaptive_rho_interval=25, check_termination=5)
        extension = getattr(self._solver, "_solver", None)  # solve() calls the wrapper's extension solver
        if not all(hasattr(extension, name) for name in ("update_data_vec", "update_data_mat", "solve", "info")):
            raise RuntimeError(f"osqp {osqp.__version__}: OSQP._solver lacks what ConvexMpc.solve calls; "
                               "this stack pins osqp 1.1.3 (requirements.txt)")

    def build(self, state: MpcState, command: MpcCommand, contact_plan: np.ndarray) -> dict:
        """QP data (q, l, u, A values) for this step; exposed for tests and benchmarks."""
        cfg = self.config
        h = cfg.horizon
        plan = np.asarray(contact_plan, dtype=bool)
        if plan.shape != (h, NUM_LEGS):
            raise ValueError(f"contact_plan must have shape ({h}, {NUM_LEGS}), got {plan.shape}")
        b = _input_matrix(self._inertia_body_inv, self._velocity_rows, state)
        a_d, b_d = self.a_d, self._b_factor @ b
        values = self._a_values
        values[self._b_positions] = -b_d[self._b_mask][None, :]
        x0 = initial_state(cfg, state)
        ref = reference_trajectory(cfg, state, command)
        q = np.concatenate([self._q_ref_gain * ref.ravel(), self._q_forces])
        n_dyn = h * NX
        lower, upper = self._lower, self._upper
        lower[:NX] = upper[:NX] = a_d @ x0  # x_1 - B_d u_0 = A_d x_0
        lower[NX:n_dyn] = upper[NX:n_dyn] = 0.0
        contact = plan[:, :, None]
        lower[n_dyn:] = np.where(contact, self._stance_lower, 0.0).ravel()
        upper[n_dyn:] = np.where(contact, self._stance_upper, 0.0).ravel()
        return {"q": q, "l": lower, "u": upper, "Ax": values, "a_d": a_d, "b_d": b_d, "x0": x0, "ref": ref}

    def solve(self, state: MpcState, command: MpcCommand, contact_plan: np.ndarray) -> MpcSolution:
        """Forces for the first horizon step. On solver failure: a static force split (fallback)."""
        t0 = time.perf_counter()
        data = self.build(state, command, contact_plan)
        t1 = time.perf_counter()
        # Straight to the wrapper's extension solver (osqp 1.1.3, pinned), with the wrapper's own
        # clipping of l and u: at 500 Hz OSQP.update and OSQP.solve cost more in Python (a module
        # lookup of OSQP_INFTY per update, a namespace of every info field per solve) than the
        # vector update. Failures are handled below, not raised.
        solver = self._solver._solver
        solver.update_data_vec(q=data["q"], l=np.maximum(data["l"], -_OSQP_INFTY),
                               u=np.minimum(data["u"], _OSQP_INFTY))
        solver.update_data_mat(P_x=None, P_i=None, A_x=data["Ax"], A_i=None)
        solver.solve()
        t2 = time.perf_counter()
        info = solver.info
        status = info.status
        x = solver.solution.x
        # An iterate stopped by max_iter is still used if its constraint violation is small (in N):
        # at 500 Hz the warm-started iterates are close, and a static split is a worse fallback.
        usable = status in ("solved", "solved inaccurate") or (
            status == "maximum iterations reached" and info.prim_res < self.config.max_violation)
        solved = usable and x is not None and bool(np.all(np.isfinite(x)))
        if solved:
            forces = np.asarray(x[self._n_x:self._n_x + NU]).reshape(NUM_LEGS, 3).copy()
            forces[~np.asarray(contact_plan, dtype=bool)[0]] = 0.0
            return MpcSolution(forces, status, True, info.iter, t2 - t1, t1 - t0)
        return self.fallback(np.asarray(contact_plan)[0], status, info.iter, t2 - t1, t1 - t0)

    def fallback(self, contacts: np.ndarray, status: str, iterations: int = 0, solve_time: float = 0.0,
                 build_time: float = 0.0) -> MpcSolution:
        """What a failed solve gives: the static force split for the ``contacts`` of its first step."""
        return MpcSolution(self.static_forces(contacts), status, False, iterations, solve_time, build_time,
                           fallback=True)

    def static_forces(self, contact: np.ndarray) -> np.ndarray:
        """Fallback: the weight shared equally by the feet in contact, straight up."""
        forces = np.zeros((NUM_LEGS, 3))
        n = int(np.count_nonzero(contact))
        if n:
            forces[np.asarray(contact, dtype=bool), 2] = self.config.mass * self.config.gravity / n
        return forces
