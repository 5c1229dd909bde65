"""Algorithm 1 end to end: run an agent against the excitation env for a budget of M episodes.

`optimize` is what `inertia-gym optimize` and `inertia-gym benchmark` call; `evaluate_xi` scores a
fixed xi fairly (one episode from the scenario's start, averaged over fresh seeds).
"""

from __future__ import annotations

import contextlib
import dataclasses
import time

import gymnasium as gym
import numpy as np

from inertia_gym.agents.base import AGENTS as AGENT_REGISTRY
from inertia_gym.envs import ENV_ID
from inertia_gym.envs.excitation import check_seed, divergence_cost
from inertia_gym.episode import COSTS, run_episode
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario
from inertia_gym.simulation import initial_state

AGENTS = tuple(AGENT_REGISTRY)  # "bo", "random", "sac", "td3", "ppo"


@dataclasses.dataclass(frozen=True)
class OptimizationResult:
    """One run of Algorithm 1.

    xi_star (3,) (a, b, T_on) with the lowest observed cost (Algorithm 1, line 24); cost_star its
    cost; costs (M,) the cost of each evaluation in order; xis (M, 3) the xi of each evaluation;
    wall_s the wall-clock seconds of the whole run. rel_errors (M,) the true relative inertia
    error after each evaluation (the simulation knows the truth). xi_recommended (3,) the
    evaluated xi with the lowest GP posterior mean cost (inertia_gym.agents.bo.posterior_best): the same
    noise-robust rule for every agent, next to the paper's argmin of the observed cost.
    """

    agent: str
    budget: int
    seed: int
    cost_kind: str
    xi_star: np.ndarray
    cost_star: float
    costs: np.ndarray
    xis: np.ndarray
    wall_s: float
    rel_errors: np.ndarray | None = None
    xi_recommended: np.ndarray | None = None

    def to_json(self) -> dict:
        """Return the keys of docs/contracts.md (optimize's result.json) as plain JSON."""
        out = {
            "agent": self.agent,
            "budget": int(self.budget),
            "seed": int(self.seed),
            "cost_kind": self.cost_kind,
            "xi_star": [float(x) for x in self.xi_star],
            "cost_star": float(self.cost_star),
            "costs": [float(c) for c in self.costs],
            "xis": np.asarray(self.xis, dtype=float).tolist(),
            "wall_s": float(self.wall_s),
        }
        if self.rel_errors is not None:
            out["rel_errors"] = [float(e) for e in self.rel_errors]
        if self.xi_recommended is not None:
            out["xi_recommended"] = [float(x) for x in self.xi_recommended]
        return out


class EvaluationLog(gym.Wrapper):
    """Records xi (3,), cost and true relative inertia error of every step, in order."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.xis: list[np.ndarray] = []
        self.costs: list[float] = []
        self.rel_errors: list[float] = []

    def step(self, action):
        """Step the env and log the evaluation."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.xis.append(np.asarray(info["xi"], dtype=float))
        self.costs.append(float(info["cost"]))
        self.rel_errors.append(float(info["rel_error"]))
        return obs, reward, terminated, truncated, info


@contextlib.contextmanager
def torch_threads(n: int = 1):
    """Run torch (GP fits, SB3 networks) on `n` intra-op threads, restoring the count after.

    The models here are tiny; on a shared machine several torch threads oversubscribe the cores
    and one GP fit or SAC update can take 50x longer than on one thread.
    """
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def make_env(sc: Scenario, budget: int, cost: str = "info", carry_over: bool = True) -> gym.Env:
    """``gym.make`` of the excitation env on `sc`, truncated after `budget` steps."""
    return gym.make(ENV_ID, scenario=sc, cost=cost, budget=budget, carry_over=carry_over,
                    max_episode_steps=budget)


def _check_common(sc: Scenario, cost: str) -> None:
    if not isinstance(sc, Scenario):
        raise ConfigError(f"sc must be a Scenario, got {type(sc).__name__}")
    if cost not in COSTS:
        raise ConfigError(f"cost must be one of {COSTS}, got {cost!r}")


def optimize(agent: str, sc: Scenario, budget: int, seed: int, cost: str = "info",
             progress: bool = False, carry_over: bool = True,
             **agent_options) -> OptimizationResult:
    """Run `agent` for `budget` episodes of the env built on `sc` (Algorithm 1).

    agent : one of AGENTS.  budget : M >= 1 evaluations.  seed : integer >= 0; it seeds the env
    (dwell times, measurement times and noise) and the agent.  cost : "info" (the paper's J) or
    "posterior" (change of log det P_theta).  carry_over : False restarts the estimator at
    every evaluation (a stationary objective) instead of Algorithm 1's carry-over.
    agent_options : passed to the agent's constructor (e.g. ``kappa`` or ``refit_every``).
    """
    from inertia_gym.agents import make_agent
    from inertia_gym.agents.bo import posterior_best
    from inertia_gym.envs.excitation import action_to_xi, xi_to_action

    _check_common(sc, cost)
    if agent not in AGENTS:
        raise ConfigError(f"agent must be one of {AGENTS}, got {agent!r}")
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 1:
        raise ConfigError(f"budget must be an integer >= 1, got {budget!r}")
    seed = check_seed(seed)
    if seed is None:
        raise ConfigError("seed must be an integer >= 0, got None")
    t0 = time.perf_counter()
    env = EvaluationLog(make_env(sc, budget, cost, carry_over))
    with torch_threads(1):
        make_agent(agent, seed, budget, **agent_options).run(env, budget, progress=progress)
        env.close()
        costs, xis = np.array(env.costs[:budget]), np.array(env.xis[:budget])
        actions = np.array([xi_to_action(sc, x) for x in xis], dtype=float)
        recommended = (action_to_xi(sc, posterior_best(actions, costs, seed)) if budget >= 2
                       else None)
    best = int(np.argmin(costs))
    return OptimizationResult(
        agent=agent, budget=int(budget), seed=seed, cost_kind=cost, xi_star=xis[best],
        cost_star=float(costs[best]), costs=costs, xis=xis,
        wall_s=time.perf_counter() - t0, rel_errors=np.array(env.rel_errors[:budget]),
        xi_recommended=recommended,
    )


def evaluate_many(sc: Scenario, xis, seeds, cost: str = "info") -> tuple[np.ndarray, np.ndarray]:
    """Cost and final relative inertia error of one episode from the scenario's start.

    xis (K, 3), seeds (S,) integers >= 0: every xi is run with every seed (common random
    numbers: seed s draws the same dwell times, measurement times and noise for every xi), all
    K*S runs in one batched call. Returns (costs, rel_errors), each (K, S); a diverged run costs
    :func:`~inertia_gym.envs.excitation.divergence_cost`.
    """
    _check_common(sc, cost)
    xis = np.atleast_2d(np.asarray(xis, dtype=float))
    seeds = [check_seed(s) for s in seeds]
    if not seeds or any(s is None for s in seeds):
        raise ConfigError(f"seeds must be a non-empty list of integers >= 0, got {seeds}")
    if xis.ndim != 2 or xis.shape[1] != 3:
        raise ConfigError(f"xi must have shape (3,) or (K, 3), got {xis.shape}")
    rngs = [np.random.default_rng(s) for _ in range(len(xis)) for s in seeds]
    state = initial_state(sc, rngs)
    _, results = run_episode(sc, state, np.repeat(xis, len(seeds), axis=0), rngs, cost=cost)
    penalty = divergence_cost(sc, cost)
    costs = np.array([penalty if r.diverged else r.cost for r in results])
    errors = np.array([r.rel_error for r in results])
    return costs.reshape(len(xis), len(seeds)), errors.reshape(len(xis), len(seeds))


def evaluate_xi(sc: Scenario, xi, seeds, cost: str = "info") -> float:
    """Mean cost of one episode of xi (3,) from the scenario's start over `seeds` (batched)."""
    xi = np.asarray(xi, dtype=float)
    if xi.shape != (3,):
        raise ConfigError(f"xi must have shape (3,), got {xi.shape}")
    return float(evaluate_many(sc, xi[None], seeds, cost)[0].mean())
