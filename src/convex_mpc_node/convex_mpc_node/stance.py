"""Stance control: the convex MPC's ground reaction forces, turned into joint torques (J^T f).

Library core, no ROS. Two parts, each with reset / update / get_action as in the reference's
locomotion controller:
- DriftCorrection integrates the command-minus-velocity error (position, yaw) the MPC tracks, so a
  robot that lags its command catches up instead of drifting.
- StanceController decides when the MPC solves (every ``mpc_period_steps``, at once on a new contact
  set, in this process or a worker process), adopts finished solves, bridges a worker's solve for a
  new contact set with static forces (the stopgap), takes injected failures (fault injection), and
  maps the forces to torques of the stance legs.

Frames: the MPC works in the yaw-aligned frame (world axes turned by the base yaw); forces [N] are
the ground's push on the feet in that frame; torques [N m] per joint.
"""

from __future__ import annotations

import numpy as np
from a1_common.config import require_integer
from a1_common.robot import NUM_LEGS

from convex_mpc_node.mpc import ConvexMpc, MpcCommand, MpcConfig, MpcSolution, MpcState
from convex_mpc_node.mpc_worker import MpcWorkerProcess

MAX_INJECTED_FAILURES = 1_000_000  # control steps of injected MPC failures at most (fault injection)


class DriftCorrection:
    """The integrated tracking errors the MPC steers out: position [m] (yaw-aligned x, y, clamped to
    ``max_position_error``) and yaw [rad] (clamped to ``max_yaw_error``)."""

    def __init__(self, max_position_error: float, max_yaw_error: float) -> None:
        self.max_position_error = max_position_error
        self.max_yaw_error = max_yaw_error
        self.reset()

    def reset(self) -> None:
        self.position_error = np.zeros(2)  # yaw-aligned frame [m]
        self._yaw_target: float | None = None
        self.yaw_error = 0.0  # [rad]

    def update(self, v_cmd: np.ndarray, v_yaw: np.ndarray, yaw: float, yaw_rate_cmd: float, dt: float) -> None:
        """One step of ``dt`` [s] with command ``v_cmd`` [m/s] against the velocity ``v_yaw`` [m/s]
        (yaw-aligned frame), at heading ``yaw`` [rad] commanded to turn at ``yaw_rate_cmd`` [rad/s]."""
        limit = self.max_position_error
        # np.minimum/np.maximum, not np.clip: on arrays this small np.clip costs several times more.
        self.position_error = np.minimum(np.maximum(self.position_error + (v_cmd - v_yaw[:2]) * dt, -limit), limit)
        if self._yaw_target is None:
            self._yaw_target = yaw
        yaw_error = (self._yaw_target - yaw + np.pi) % (2 * np.pi) - np.pi
        self.yaw_error = min(max(float(yaw_error), -self.max_yaw_error), self.max_yaw_error)
        self._yaw_target = yaw + self.yaw_error + yaw_rate_cmd * dt


class StanceController:
    """MPC scheduling and adoption, the stopgap, injected failures, and J^T f for the stance legs."""

    def __init__(self, config: MpcConfig, period_steps: int, asynchronous: bool) -> None:
        self.mpc = ConvexMpc(config)
        self.period_steps = period_steps
        self.fallbacks = 0
        self.qp_failure_steps = 0  # fault injection: the MPC fails for this many more steps
        self._worker = MpcWorkerProcess(config) if asynchronous else None
        self.reset()

    def close(self) -> None:
        """Stop the MPC worker process, if any (it also exits on its own when this process dies)."""
        if self._worker is not None:
            self._worker.close()
            self._worker = None

    def inject_failures(self, steps: int) -> None:
        """Fault injection: the next ``steps`` control steps each take a solver failure's fallback."""
        self.qp_failure_steps = require_integer("inject_qp_failures", steps, 0, MAX_INJECTED_FAILURES)

    def reset(self) -> None:
        if self._worker is not None:
            self._worker.wait()  # a solve still running belongs to the state before the reset
        self.last_solution: MpcSolution | None = None
        self.solved_this_step = False  # False: the last step reused the previous MPC forces
        self._steps_since_solve = 0
        self._solved_contacts = np.zeros(NUM_LEGS, dtype=bool)  # of the newest problem handed to a solver
        self._plan_contacts = self._solved_contacts.copy()  # ... of last_solution
        self.stopgap_steps = 0  # steps that applied static forces while a solve for new contacts ran
        self.plan_delay_steps = 0  # control steps from handing the adopted solve to a solver to adopting it
        self._forces: np.ndarray | None = None

    def update(self, state: MpcState, command: MpcCommand, plan: np.ndarray, stance: np.ndarray) -> None:
        """This step's forces for the contact ``plan`` (horizon x legs, row 0 now) and the legs in
        ``stance``: a finished worker solve is adopted, a new solve started when one is due."""
        self.solved_this_step = False
        worker = self._worker
        finished = worker.poll() if worker is not None else None
        if finished is not None:
            self._adopt(finished, self._solved_contacts, self._steps_since_solve + 1)  # submitted that long ago
        due = (self.last_solution is None or self._steps_since_solve + 1 >= self.period_steps
               or not np.array_equal(plan[0], self._solved_contacts))
        if self.qp_failure_steps > 0:  # fault injection: this step's solve "fails"
            self.qp_failure_steps -= 1
            self._adopt(self.mpc.fallback(plan[0], "injected failure"), plan[0], 0)
            self._steps_since_solve = self.period_steps  # a real solve is due right after
            self._solved_contacts = plan[0].copy()
        elif due and not (worker is not None and worker.pending):
            if worker is not None and self.last_solution is not None:  # the first solve: in this process
                worker.submit(state, command, plan)
            else:
                self._adopt(self.mpc.solve(state, command, plan), plan[0], 0)
            self._steps_since_solve = 0
            self._solved_contacts = plan[0].copy()
        else:
            self._steps_since_solve += 1
        forces = self.last_solution.forces  # yaw-aligned frame [N]
        if not np.array_equal(self._plan_contacts, stance):
            # Only while a worker solves for a new contact set (a touchdown or a lift-off): the plan
            # in hand gives a foot that just landed no force, so the weight shared by the feet in
            # contact bridges those few ms instead of letting the body drop.
            forces = self.mpc.static_forces(stance)
            self.stopgap_steps += 1
        self._forces = forces

    def get_action(self, rot_rp: np.ndarray, jacobians: np.ndarray, stance: np.ndarray) -> np.ndarray:
        """Joint torques (legs x 3) [N m] of this step's forces: the foot pushes on the ground with
        -f, torques = J^T (that force in the base frame); ``rot_rp`` base -> yaw-aligned frame."""
        foot_force_base = -self._forces @ rot_rp
        torques = np.matmul(foot_force_base[:, None, :], jacobians)[:, 0, :]  # (J^T f)^T = f^T J, all legs
        torques[~stance] = 0.0
        return torques

    def _adopt(self, solution: MpcSolution, contacts: np.ndarray, delay_steps: int) -> None:
        self.last_solution = solution
        self._plan_contacts = contacts.copy()
        self.plan_delay_steps = delay_steps
        self.fallbacks += solution.fallback
        self.solved_this_step = True
