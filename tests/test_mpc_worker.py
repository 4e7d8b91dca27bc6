"""The MPC worker process: same answers as in-process, never blocks the step, no orphans."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from convex_mpc_node.mpc import ConvexMpc, MpcCommand, MpcConfig
from convex_mpc_node.mpc_worker import MpcWorkerProcess
from test_mpc import make_state


def _wait_for(worker: MpcWorkerProcess, timeout: float = 10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        solution = worker.poll()
        if solution is not None:
            return solution
        time.sleep(0.001)
    raise AssertionError("the worker returned no solution in time")


@pytest.fixture
def worker():
    w = MpcWorkerProcess(MpcConfig())
    yield w
    w.close()


def test_worker_solves_like_the_in_process_mpc(worker):
    config = MpcConfig()
    plan = np.ones((config.horizon, 4), dtype=bool)
    plan[3:6, [0, 3]] = False
    rng = np.random.default_rng(3)
    local = ConvexMpc(config)
    for _ in range(3):  # warm starts stay in step: both solve the same sequence
        state, command = make_state(rng), MpcCommand(np.array([0.8, 0.1]), 0.2, 0.26)
        assert worker.poll() is None  # nothing pending: nothing to adopt
        worker.submit(state, command, plan)
        remote = _wait_for(worker)
        expected = local.solve(state, command, plan)
        assert remote.status == expected.status
        np.testing.assert_allclose(remote.forces, expected.forces, atol=1e-9)


def test_one_solve_at_a_time(worker):
    config = MpcConfig()
    worker.submit(make_state(), MpcCommand(np.zeros(2), 0.0, 0.26), np.ones((config.horizon, 4), dtype=bool))
    with pytest.raises(RuntimeError, match="already pending"):
        worker.submit(make_state(), MpcCommand(np.zeros(2), 0.0, 0.26), np.ones((config.horizon, 4), dtype=bool))
    assert worker.wait().solved
    assert worker.wait() is None  # nothing pending any more


def test_child_exits_when_closed_and_a_dead_child_is_reported():
    worker = MpcWorkerProcess(MpcConfig())
    pid = worker._process.pid
    worker.close()
    assert worker._process.poll() is not None
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)

    worker = MpcWorkerProcess(MpcConfig())
    try:
        worker._process.kill()
        worker._process.wait()
        config = MpcConfig()
        with pytest.raises(RuntimeError, match="the MPC worker process died"):
            worker.submit(make_state(), MpcCommand(np.zeros(2), 0.0, 0.26), np.ones((config.horizon, 4), dtype=bool))
            worker.wait()
    finally:
        worker.close()


@pytest.mark.parametrize(("parent_priority", "child_policy", "child_priority"),
                         [(2, os.SCHED_FIFO, 1), (1, os.SCHED_OTHER, 0)])
def test_child_runs_below_a_realtime_parent(parent_priority, child_policy, child_priority):
    """Spawned from a SCHED_FIFO thread, the solver drops one level (or to SCHED_OTHER from 1): it
    takes only CPU the 2 ms path leaves idle."""
    before = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(parent_priority))
    except PermissionError:
        pytest.skip("SCHED_FIFO is not permitted here")
    try:
        worker = MpcWorkerProcess(MpcConfig())  # the parent waits for "ready": the child has set its priority
    finally:
        os.sched_setscheduler(0, *before)
    try:
        pid = worker._process.pid
        assert os.sched_getscheduler(pid) == child_policy
        assert os.sched_getparam(pid).sched_priority == child_priority
    finally:
        worker.close()


def test_child_of_an_idle_parent_starts_and_stays_idle():
    """A parent run as SCHED_IDLE (a background job, in a process of its own here): the worker
    keeps that policy, and starts."""
    script = ("import os\n"
              "os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))\n"
              "from convex_mpc_node.mpc import MpcConfig\n"
              "from convex_mpc_node.mpc_worker import MpcWorkerProcess\n"
              "worker = MpcWorkerProcess(MpcConfig())\n"
              "print(os.sched_getscheduler(worker._process.pid))\n"
              "worker.close()\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert int(result.stdout.split()[-1]) == os.SCHED_IDLE


def test_child_of_a_plain_parent_never_preempts_it_on_wake_up():
    """From a SCHED_OTHER parent the solver runs as SCHED_BATCH: a submit's wake-up does not take
    the CPU of the step that submitted."""
    if os.sched_getscheduler(0) != os.SCHED_OTHER:
        pytest.skip("this test process is not SCHED_OTHER")
    worker = MpcWorkerProcess(MpcConfig())
    try:
        assert os.sched_getscheduler(worker._process.pid) == os.SCHED_BATCH
        assert os.getpriority(os.PRIO_PROCESS, worker._process.pid) == os.getpriority(os.PRIO_PROCESS, 0)
    finally:
        worker.close()


def test_a_plain_script_can_start_it(tmp_path):
    """Started as its own interpreter: a user's script needs no ``if __name__ == "__main__"`` guard
    (multiprocessing's spawn would run the script again in the child, and fail)."""
    script = tmp_path / "no_guard.py"
    script.write_text(textwrap.dedent("""
        import numpy as np
        from convex_mpc_node.mpc import MpcCommand, MpcConfig, MpcState
        from convex_mpc_node.mpc_worker import MpcWorkerProcess
        worker = MpcWorkerProcess(MpcConfig())
        feet = np.array([[0.18, -0.13, -0.26], [0.18, 0.13, -0.26], [-0.18, -0.13, -0.26], [-0.18, 0.13, -0.26]])
        worker.submit(MpcState(0.0, 0.0, 0.26, np.zeros(3), np.zeros(3), feet),
                      MpcCommand(np.zeros(2), 0.0, 0.26), np.ones((MpcConfig().horizon, 4), dtype=bool))
        print("solved", worker.wait().solved)
        worker.close()
    """))
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "solved True" in result.stdout
