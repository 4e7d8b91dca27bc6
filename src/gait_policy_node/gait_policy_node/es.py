"""Evolution strategies over the policy's flat parameters: CMA-ES (pycma) and ARS (Mania et al. 2018).

Both are ask/tell optimisers that maximise episode return. Their whole state follows from the seed
and the returns told so far, so a checkpoint stores only the return history and ``restore``
replays it: the resumed optimiser then asks for exactly the candidates an uninterrupted run would.
Neither touches numpy's global random state (rollouts may run in the same process).
"""

from __future__ import annotations

import cma
import numpy as np

from gait_policy_node.train_config import TrainerConfig


class CmaEs:
    """pycma's CMA-ES with the paper's settings: mean 0 (or ``x0``), sigma0 0.03, population 32."""

    name = "cmaes"

    def __init__(self, num_params: int, cfg: TrainerConfig, x0: np.ndarray | None = None) -> None:
        self.cfg = cfg
        self.num_params = num_params
        rng = np.random.default_rng([cfg.seed, 7])
        options = {"popsize": cfg.population_size, "seed": cfg.seed, "verbose": -9,
                   "randn": lambda *shape: rng.standard_normal(shape)}
        self._es = cma.CMAEvolutionStrategy(_start(num_params, x0), cfg.sigma0, options)
        self._asked: list[np.ndarray] | None = None

    @property
    def population_size(self) -> int:
        return self.cfg.population_size

    def ask(self) -> list[np.ndarray]:
        if self._asked is None:
            self._asked = [np.asarray(x, dtype=float) for x in self._es.ask()]
        return self._asked

    def tell(self, returns: np.ndarray) -> None:
        returns = np.asarray(returns, dtype=float)
        if self._asked is None or returns.shape != (len(self._asked),):
            raise ValueError(f"tell needs one return per asked candidate ({self.population_size})")
        self._es.tell(self._asked, list(-returns))  # pycma minimises
        self._asked = None

    @property
    def mean(self) -> np.ndarray:
        """The search distribution's mean: the policy that is evaluated and shipped."""
        return np.asarray(self._es.mean, dtype=float).copy()

    @property
    def step_size(self) -> float:
        return float(self._es.sigma)


class Ars:
    """Augmented Random Search (V1-t with all directions kept): for each of N directions d,
    returns r+ and r- at theta +/- sigma d; theta += step / (N std(r)) sum (r+ - r-) d.
    The paper: 16 directions, sigma 0.03, step 0.02, theta_0 = 0 (or ``x0``)."""

    name = "ars"

    def __init__(self, num_params: int, cfg: TrainerConfig, x0: np.ndarray | None = None) -> None:
        self.cfg = cfg
        self.num_params = num_params
        self.theta = _start(num_params, x0)
        self.iteration = 0
        self._directions: np.ndarray | None = None

    @property
    def population_size(self) -> int:
        return 2 * self.cfg.ars_directions

    def ask(self) -> list[np.ndarray]:
        if self._directions is None:
            rng = np.random.default_rng([self.cfg.seed, 11, self.iteration])
            self._directions = rng.standard_normal((self.cfg.ars_directions, self.num_params))
        sigma = self.cfg.ars_sigma
        plus = [self.theta + sigma * d for d in self._directions]
        minus = [self.theta - sigma * d for d in self._directions]
        return plus + minus  # candidate i and i + N share direction i

    def tell(self, returns: np.ndarray) -> None:
        returns = np.asarray(returns, dtype=float)
        n = self.cfg.ars_directions
        if self._directions is None or returns.shape != (2 * n,):
            raise ValueError(f"tell needs one return per asked candidate ({2 * n})")
        spread = float(np.std(returns))
        if spread > 0:
            diff = returns[:n] - returns[n:]
            self.theta = self.theta + self.cfg.ars_step_size / (n * spread) * (diff @ self._directions)
        self._directions = None
        self.iteration += 1

    @property
    def mean(self) -> np.ndarray:
        return self.theta.copy()

    @property
    def step_size(self) -> float:
        return self.cfg.ars_sigma


Optimizer = CmaEs | Ars


def _start(num_params: int, x0: np.ndarray | None) -> np.ndarray:
    """The search's starting point: zeros (the paper), or a given parameter vector (a warm start)."""
    if x0 is None:
        return np.zeros(num_params)
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (num_params,) or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0 must be {num_params} finite parameters, got shape {x0.shape}")
    return x0.copy()


def make_optimizer(num_params: int, cfg: TrainerConfig, x0: np.ndarray | None = None) -> Optimizer:
    return CmaEs(num_params, cfg, x0) if cfg.algorithm == "cmaes" else Ars(num_params, cfg, x0)


def restore(num_params: int, cfg: TrainerConfig, return_history: np.ndarray, x0: np.ndarray | None = None) -> Optimizer:
    """A new optimiser started at ``x0`` and brought to the state after the iterations in
    ``return_history`` (one row of candidate returns per iteration)."""
    opt = make_optimizer(num_params, cfg, x0)
    for returns in np.asarray(return_history, dtype=float).reshape(-1, opt.population_size):
        opt.ask()
        opt.tell(returns)
    return opt
