"""Episode rollouts for the trainers, run in this process, a local process pool, or on Ray.

Every worker owns one GaitEnv (one PyBullet world, rebuilt on each reset) and one policy whose
parameters each task replaces. An episode depends only on (parameters, seed), never on which
worker ran it or what it ran before, so every backend gives the same returns for the same seed.
"""

from __future__ import annotations

import multiprocessing
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from a1_common.config import ConfigError
from convex_mpc_node.gait import GaitParams

from gait_policy_node.env import ControlRecord, GaitEnv, StepInfo
from gait_policy_node.learned_policy import NetworkPolicy
from gait_policy_node.speed_profiles import SpeedProfile
from gait_policy_node.train_config import TrainConfig, train_config_from_mapping


@dataclass(frozen=True)
class RolloutTask:
    params: np.ndarray
    seed: int


@dataclass(frozen=True)
class EpisodeStats:
    episode_return: float
    policy_steps: int
    fell: bool
    speed_error: float  # mean over policy steps of the clipped relative speed error, squared
    cost_of_transport: float  # mean over policy steps of power / (m g max(v_des, min_speed))
    mean_speed: float  # [m/s]
    wall_time: float  # [s]


def run_episode(env: GaitEnv, policy: Callable[[np.ndarray], GaitParams], seed: int,
                profile: SpeedProfile | None = None, record: bool = False,
                steps: int | None = None,
                on_step: Callable[[float, StepInfo], None] | None = None) -> tuple[EpisodeStats, ControlRecord | None]:
    """One episode of ``steps`` policy steps (default: the env's) or until a fall; ``on_step(reward,
    info)`` sees every policy step (e.g. the reward's terms against the commanded speed)."""
    start = time.perf_counter()
    obs = env.reset(seed, profile=profile, record=record)
    total, n, fell = 0.0, 0, False
    speed_error = cot = speed = 0.0
    limit = steps or env.config.episode_steps
    while n < limit:
        obs, reward, done, info = env.step(policy(obs))
        if on_step is not None:
            on_step(reward, info)
        total += reward
        n += 1
        speed_error += info.terms.relative_speed_error**2
        cot += info.terms.cost_of_transport
        speed += info.speed
        if info.fell:
            fell = True
            break
        if done and steps is None:
            break
    stats = EpisodeStats(total, n, fell, speed_error / n, cot / n, speed / n, time.perf_counter() - start)
    return stats, env.record


class _Worker:
    """One env and one policy; evaluates tasks one after the other."""

    def __init__(self, config_dict: dict) -> None:
        config = train_config_from_mapping(config_dict)
        self.env = GaitEnv(config.env, config.reward)
        self.policy = NetworkPolicy.from_config(config)

    def evaluate(self, task: RolloutTask) -> EpisodeStats:
        self.policy.set_params(task.params)
        return run_episode(self.env, self.policy, task.seed)[0]

    def close(self) -> None:
        self.env.close()


class SerialEvaluator:
    """Rollouts in this process (debugging, tiny runs)."""

    def __init__(self, config: TrainConfig) -> None:
        self.workers = 1
        self._worker = _Worker(config.to_dict())

    def evaluate(self, tasks: list[RolloutTask]) -> list[EpisodeStats]:
        return [self._worker.evaluate(t) for t in tasks]

    def close(self) -> None:
        self._worker.close()


_PROCESS_WORKER: _Worker | None = None


def _init_process_worker(config_dict: dict) -> None:
    global _PROCESS_WORKER
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the trainer's to handle
    _PROCESS_WORKER = _Worker(config_dict)


def _evaluate_in_process(task: RolloutTask) -> EpisodeStats:
    return _PROCESS_WORKER.evaluate(task)


class ProcessEvaluator:
    """A local pool of ``workers`` processes (spawned, so no PyBullet state is forked)."""

    def __init__(self, config: TrainConfig, workers: int) -> None:
        self.workers = workers
        ctx = multiprocessing.get_context("spawn")
        self._pool = ctx.Pool(workers, initializer=_init_process_worker, initargs=(config.to_dict(),))

    def evaluate(self, tasks: list[RolloutTask]) -> list[EpisodeStats]:
        return self._pool.map(_evaluate_in_process, tasks, chunksize=1)

    def close(self) -> None:
        self._pool.terminate()
        self._pool.join()


class RayEvaluator:
    """Ray actors, one env each: a local Ray instance, or a cluster at ``address`` (every node needs
    this workspace installed and sourced, as on this machine)."""

    def __init__(self, config: TrainConfig, workers: int, address: str = "") -> None:
        try:
            import ray
            from ray.util import ActorPool
        except ImportError:
            raise ConfigError("workers.backend 'ray' needs the optional package ray (pip install ray)") from None
        self._ray = ray
        if not ray.is_initialized():
            if address:
                ray.init(address=address, log_to_driver=False)
            else:
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        if address:
            workers = workers or int(ray.cluster_resources().get("CPU", 1))
        self.workers = workers
        actor = ray.remote(num_cpus=1)(_Worker)
        self._actors = [actor.remote(config.to_dict()) for _ in range(workers)]
        self._pool = ActorPool(self._actors)

    def evaluate(self, tasks: list[RolloutTask]) -> list[EpisodeStats]:
        return list(self._pool.map(lambda a, t: a.evaluate.remote(t), tasks))

    def close(self) -> None:
        for a in self._actors:
            self._ray.kill(a)
        self._actors = []


Evaluator = SerialEvaluator | ProcessEvaluator | RayEvaluator


def make_evaluator(config: TrainConfig) -> Evaluator:
    w = config.workers
    if w.backend == "serial":
        return SerialEvaluator(config)
    if w.backend == "ray":
        return RayEvaluator(config, w.count if w.address else w.resolved_count(), w.address)
    return ProcessEvaluator(config, w.resolved_count())
