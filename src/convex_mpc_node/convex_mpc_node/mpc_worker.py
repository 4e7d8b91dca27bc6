"""The convex MPC in a child process, for realtime graphs on small computers.

Why a process and not a thread: a worker thread shares the controller's GIL, so on two cores its
solves slow the 2 ms step, and at SCHED_FIFO the step starves it (same-priority FIFO threads do not
time-slice) while the step keeps applying an ageing force plan. A child process has its own
interpreter; it runs one realtime priority below its parent when the parent is SCHED_FIFO (as a
SCHED_BATCH task otherwise), so it takes only CPU the 2 ms path leaves idle, and it never holds a
lock the step needs.

The pipe carries the MPC's own dataclasses between two processes of this program (pickled by
``multiprocessing``); nothing a user passes in is ever unpickled. The child exits when the pipe
closes, so a killed controller leaves no orphan.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from multiprocessing.connection import Connection

import numpy as np

from convex_mpc_node.mpc import ConvexMpc, MpcCommand, MpcConfig, MpcSolution, MpcState


def _serve(conn: Connection) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group: the parent decides
    _below_parent_priority()
    mpc = ConvexMpc(conn.recv())
    conn.send("ready")
    while True:
        try:
            request = conn.recv()
            if request is None:
                return
            conn.send(mpc.solve(*request))
        except (EOFError, OSError):  # the parent closed the pipe (a solve may have been pending) or died
            return


def _below_parent_priority() -> None:
    """At a realtime priority p (SCHED_FIFO or SCHED_RR, inherited), drop to p - 1: the solve yields
    to every thread of the 2 ms path. At SCHED_OTHER, SCHED_BATCH (same nice): a request written to
    the pipe wakes the solver, and a SCHED_OTHER solver then often took the CPU of the step that woke
    it (submit took 0.66 ms median in the realtime graph, 1.6 ms at worst, the step's commands late);
    a batch task never preempts on wake-up and runs on the idle core or once the step sleeps (submit
    0.08-0.13 ms median). Any other policy (SCHED_IDLE, SCHED_BATCH) is kept, and a change the
    system refuses leaves the inherited one: the solver still runs, only less politely."""
    policy = os.sched_getscheduler(0)
    try:
        if policy in (os.SCHED_FIFO, os.SCHED_RR):
            priority = os.sched_getparam(0).sched_priority
            if priority > 1:
                os.sched_setscheduler(0, policy, os.sched_param(priority - 1))
            else:
                os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        elif policy == os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except OSError as exc:
        print(f"mpc_worker: kept the inherited scheduling policy {policy} ({exc})", file=sys.stderr, flush=True)


class MpcWorkerProcess:
    """One MPC solve at a time in a child process: ``submit``, then ``poll`` each step until done."""

    def __init__(self, config: MpcConfig, start_timeout: float = 60.0) -> None:
        # A fresh interpreter running this module, not multiprocessing's spawn: spawn re-imports the
        # parent's main script, which breaks scripts without a __main__ guard; and no fork, since
        # the parent has DDS threads whose locks a forked child would inherit.
        parent_end, child_end = socket.socketpair()
        self._process = subprocess.Popen([sys.executable, "-m", __name__, str(child_end.fileno())],
                                         pass_fds=[child_end.fileno()], stdin=subprocess.DEVNULL)
        child_end.close()
        self._conn = Connection(parent_end.detach())
        self.pending = False
        try:
            self._conn.send(config)
            started = self._conn.poll(start_timeout) and self._conn.recv() == "ready"
        except (EOFError, OSError):
            started = False
        if not started:
            self.close()
            raise RuntimeError(f"the MPC worker process did not start within {start_timeout} s "
                               f"(exit code {self._process.returncode}; its error output is above)")

    def submit(self, state: MpcState, command: MpcCommand, contact_plan: np.ndarray) -> None:
        if self.pending:
            raise RuntimeError("an MPC solve is already pending in the worker process")
        try:
            self._conn.send((state, command, contact_plan))
        except OSError:  # BrokenPipeError included
            raise RuntimeError(f"the MPC worker process died (exit code {self._process.poll()})") from None
        self.pending = True

    def poll(self) -> MpcSolution | None:
        """The finished solve, or None while it runs (never blocks)."""
        if not self.pending or not self._conn.poll():
            return None
        return self.wait()

    def wait(self) -> MpcSolution | None:
        """Block until the pending solve is done; None if nothing is pending."""
        if not self.pending:
            return None
        try:
            solution = self._conn.recv()
        except (EOFError, OSError):
            raise RuntimeError(f"the MPC worker process died (exit code {self._process.poll()})") from None
        self.pending = False
        return solution

    def close(self) -> None:
        try:
            self._conn.send(None)
        except OSError:  # the child is gone already
            pass
        self._conn.close()
        try:
            self._process.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()


if __name__ == "__main__":
    _serve(Connection(int(sys.argv[1])))
