"""Start the stack's nodes as real processes (the installed executables) for end-to-end tests."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config"


def executable(pkg: str, exe: str) -> str:
    path = ROOT / "install" / pkg / "lib" / pkg / exe
    assert path.exists(), f"{path} missing: run scripts/setup.sh"
    return str(path)


class Graph:
    """Processes in their own sessions, logs under ``log_dir``; ``stop`` ends every one of them."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, pkg: str, exe: str, *args: str) -> subprocess.Popen:
        log = open(self.log_dir / f"{name}.log", "w")
        proc = subprocess.Popen([executable(pkg, exe), *args], stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        self.procs[name] = proc
        return proc

    def start_stack(self, clock: str = "lockstep", lockstep_timeout: float = 0.5, *controller_params: str) -> None:
        """Sim bridge, estimator, controller, gait policy; ``controller_params`` are extra ``name:=value``
        for the controller (with ``embedded_estimator:=true`` no state_estimator process starts)."""
        sim = ["--ros-args", "--params-file", str(CONFIG / "a1_sim_bridge.yaml"), "-p", f"clock_mode:={clock}",
               "-p", f"lockstep_timeout:={lockstep_timeout}"]
        self.start("sim_bridge", "a1_sim_bridge", "sim_bridge", *sim)
        if "embedded_estimator:=true" not in controller_params:
            self.start("state_estimator", "state_estimator_node", "state_estimator", "--ros-args", "--params-file",
                       str(CONFIG / "state_estimator.yaml"), "-p", "use_sim_time:=true")
        self.start_controller(*controller_params)
        self.start("gait_policy", "gait_policy_node", "gait_policy", "--ros-args", "--params-file",
                   str(CONFIG / "gait_policy.yaml"), "-p", "use_sim_time:=true")

    def start_controller(self, *params: str) -> None:
        extra = [a for p in params for a in ("-p", p)]
        self.start("convex_mpc", "convex_mpc_node", "convex_mpc", "--ros-args", "--params-file",
                   str(CONFIG / "convex_mpc.yaml"), "-p", "use_sim_time:=true", *extra)

    def kill(self, name: str) -> None:
        proc = self.procs.pop(name)
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)

    def alive(self) -> dict[str, bool]:
        return {name: proc.poll() is None for name, proc in self.procs.items()}

    def log(self, name: str) -> str:
        return (self.log_dir / f"{name}.log").read_text(errors="replace")

    def stop(self) -> None:
        for proc in self.procs.values():
            try:
                os.killpg(proc.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        for proc in self.procs.values():
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=10)
        self.procs.clear()
