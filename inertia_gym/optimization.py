"""Optimise the excitation: run an agent against the excitation env for a budget of M episodes.

`optimize` is what `inertia-gym optimize` and `inertia-gym benchmark` call: it returns the xi
the agent recommends (xi_star) next to the lowest observed cost (Algorithm 1, line 24).
`evaluate_many` / `evaluate_xi` score a fixed xi fairly (one episode from the scenario's start,
averaged over fresh seeds); `validated_error` validates it over a long horizon.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time

import gymnasium as gym
import numpy as np

from inertia_gym.agents.base import AGENTS as AGENT_REGISTRY
from inertia_gym.agents.base import candidates, extra_module
from inertia_gym.envs import ENV_ID
from inertia_gym.envs.excitation import check_seed, divergence_cost
from inertia_gym.episode import COSTS, run_episode
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario
from inertia_gym.simulation import initial_state
from inertia_gym.validation import validate

AGENTS = tuple(AGENT_REGISTRY)  # "bo", "random", "sac", "td3", "ppo"


#: The objective `optimize` and `benchmark` use unless told otherwise, chosen by measurement
#: (docs/benchmark.md, the default objective): every evaluation is one episode from the
#: scenario's start (a stationary objective), scored by the posterior cost (change of
#: log det P_theta). The paper's Algorithm 1 is ``cost="info", carry_over=True``.
DEFAULT_COST = "posterior"
DEFAULT_CARRY_OVER = False


@dataclasses.dataclass(frozen=True)
class OptimizationResult:
    """One optimisation run: M evaluations of the excitation env and the xi to use.

    xi_star (3,) (a, b, T_on): the recommended xi, the one a user should apply, picked from
    the evaluated xi by the agent's rule (:meth:`inertia_gym.agents.base.Agent.recommend`:
    lowest GP posterior mean cost); cost_star its predicted cost (that posterior mean, in the
    units of `costs`). xi_observed_best (3,) and cost_observed_best: the evaluation with the
    lowest observed cost (Algorithm 1, line 24), kept for comparison. costs (M,) the cost of
    each evaluation in order; xis (M, 3) the xi of each evaluation; wall_s the wall-clock
    seconds of the whole run; rel_errors (M,) the true relative inertia error after each
    evaluation (the simulation knows the truth); carry_over: the estimator carried over between
    evaluations (Algorithm 1) or every evaluation started from the scenario's start;
    recommendation: the rule behind xi_star, in words. Under the scenario's mission limits:
    impulses (M,) N·m·s each evaluation spent, impulse_demands (M,) what its burst law asked
    for, within_limits (M,) bool: the limits let its bursts fire as designed (demand within the
    budget, no burst cut by the rate monitor). xi_star is picked among those when there are any.
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
    rel_errors: np.ndarray
    xi_observed_best: np.ndarray
    cost_observed_best: float
    carry_over: bool
    recommendation: str
    impulses: np.ndarray | None = None
    impulse_demands: np.ndarray | None = None
    within_limits: np.ndarray | None = None

    @property
    def xi_recommended(self) -> np.ndarray:
        """The recommended xi (3,): xi_star, under result.json's contract key xi_recommended."""
        return self.xi_star

    @property
    def star_index(self) -> int:
        """0-based index of xi_star among the evaluations."""
        return int(np.flatnonzero(np.all(self.xis == self.xi_star, axis=1))[0])

    def to_json(self) -> dict:
        """Return the keys of docs/contracts.md (optimize's result.json) as plain JSON."""
        return {
            "agent": self.agent,
            "budget": int(self.budget),
            "seed": int(self.seed),
            "cost_kind": self.cost_kind,
            "carry_over": bool(self.carry_over),
            "xi_star": [float(x) for x in self.xi_star],
            "cost_star": float(self.cost_star),
            "recommendation": self.recommendation,
            "xi_recommended": [float(x) for x in self.xi_star],
            "xi_observed_best": [float(x) for x in self.xi_observed_best],
            "cost_observed_best": float(self.cost_observed_best),
            "costs": [float(c) for c in self.costs],
            "xis": np.asarray(self.xis, dtype=float).tolist(),
            "rel_errors": [float(e) for e in self.rel_errors],
            "wall_s": float(self.wall_s),
            **({"impulses": [float(e) for e in self.impulses],
                "impulse_demands": [float(e) for e in self.impulse_demands],
                "within_limits": [bool(e) for e in self.within_limits]}
               if self.impulses is not None else {}),
        }


class EvaluationLog(gym.Wrapper):
    """Records xi (3,), cost, true relative inertia error, impulse spent and demanded, and
    whether the limits let the bursts fire as designed (:func:`within_limits`), of every step.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.xis: list[np.ndarray] = []
        self.costs: list[float] = []
        self.rel_errors: list[float] = []
        self.impulses: list[float] = []
        self.impulse_demands: list[float] = []
        self.within: list[bool] = []

    def step(self, action):
        """Step the env and log the evaluation."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.xis.append(np.asarray(info["xi"], dtype=float))
        self.costs.append(float(info["cost"]))
        self.rel_errors.append(float(info["rel_error"]))
        self.impulses.append(float(info["impulse"]))
        self.impulse_demands.append(float(info["impulse_demand"]))
        self.within.append(within_limits(info["impulse_budget"], info["impulse_demand"],
                                         info["rate_cuts"]))
        return obs, reward, terminated, truncated, info


def within_limits(budget: float | None, demand: float, rate_cuts: int) -> bool:
    """An episode's bursts fired as designed: the impulse its law demanded (N·m·s) is within
    the budget (None: there is none) and the rate monitor cut none of them.
    """
    return bool((budget is None or demand <= budget) and rate_cuts == 0)


@contextlib.contextmanager
def torch_threads(n: int = 1):
    """Run torch (GP fits, SB3 networks) on `n` intra-op threads, restoring the count after.

    The models here are tiny; on a shared machine several torch threads oversubscribe the cores
    and one GP fit or SAC update can take 50x longer than on one thread. Without torch installed,
    nothing to set.
    """
    try:
        import torch
    except ModuleNotFoundError:  # an agent without torch (random search, without an extra)
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def make_env(sc: Scenario, budget: int, cost: str = DEFAULT_COST,
             carry_over: bool = DEFAULT_CARRY_OVER) -> gym.Env:
    """``gym.make`` of the excitation env on `sc`, truncated after `budget` steps."""
    return gym.make(ENV_ID, scenario=sc, cost=cost, budget=budget, carry_over=carry_over,
                    max_episode_steps=budget)


def _check_common(sc: Scenario, cost: str) -> None:
    if not isinstance(sc, Scenario):
        raise ConfigError(f"sc must be a Scenario, got {type(sc).__name__}")
    if cost not in COSTS:
        raise ConfigError(f"cost must be one of {COSTS}, got {cost!r}")


def optimize(agent: str, sc: Scenario, budget: int, seed: int, cost: str = DEFAULT_COST,
             progress: bool = False, carry_over: bool = DEFAULT_CARRY_OVER,
             **agent_options) -> OptimizationResult:
    """Run `agent` for `budget` episodes of the env built on `sc`; recommend the xi to use.

    agent : one of AGENTS.  budget : M >= 1 evaluations.  seed : integer >= 0; it seeds the env
    (dwell times, measurement times and noise) and the agent.  cost : "info" (the paper's J) or
    "posterior" (change of log det P_theta).  carry_over : True carries the estimator over from
    one evaluation to the next (Algorithm 1), False restarts it at every evaluation (a stationary
    objective).  The defaults are DEFAULT_COST and DEFAULT_CARRY_OVER; the paper's Algorithm 1
    is cost="info", carry_over=True.  agent_options : passed to the agent's constructor (e.g.
    ``kappa`` or ``refit_every``).
    """
    from inertia_gym.agents import make_agent
    from inertia_gym.envs.excitation import xi_to_action

    _check_common(sc, cost)
    if agent not in AGENTS:
        raise ConfigError(f"agent must be one of {AGENTS}, got {agent!r}")
    # every agent's xi* is a GP's recommendation: without its extra, say so before the run
    extra_module("optimize", "optimize's recommended xi (a GP fitted to the costs, for every agent)")
    if isinstance(budget, bool) or not isinstance(budget, (int, np.integer)) or budget < 1:
        raise ConfigError(f"budget must be an integer >= 1, got {budget!r}")
    seed = check_seed(seed)
    if seed is None:
        raise ConfigError("seed must be an integer >= 0, got None")
    t0 = time.perf_counter()
    env = EvaluationLog(make_env(sc, budget, cost, carry_over))
    with torch_threads(1):
        runner = make_agent(agent, seed, budget, **agent_options)
        runner.run(env, budget, progress=progress)
        env.close()
        costs, xis = np.array(env.costs[:budget]), np.array(env.xis[:budget])
        within = np.array(env.within[:budget], dtype=bool)
        actions = np.array([xi_to_action(sc, x) for x in xis], dtype=float)
        star, cost_star = runner.recommend(actions, costs, within if sc.limited else None)
    pool = candidates(within if sc.limited else None, len(costs))
    best = int(pool[np.argmin(costs[pool])])
    return OptimizationResult(
        agent=agent, budget=int(budget), seed=seed, cost_kind=cost, xi_star=xis[star],
        cost_star=cost_star, costs=costs, xis=xis, wall_s=time.perf_counter() - t0,
        rel_errors=np.array(env.rel_errors[:budget]), xi_observed_best=xis[best],
        cost_observed_best=float(costs[best]), carry_over=bool(carry_over),
        recommendation=runner.recommendation_rule + (
            ", among those the limits let fire as designed" if sc.limited else ""),
        **({"impulses": np.array(env.impulses[:budget]),
            "impulse_demands": np.array(env.impulse_demands[:budget]),
            "within_limits": within} if sc.limited else {}),
    )


def recommendation_checkpoints(budget: int, count: int = 8) -> np.ndarray:
    """Evaluation counts (1-based, ascending, the last = budget) at which a learning curve
    asks for the recommendation: about `count` of them, spaced geometrically from 2.
    """
    start = min(2, budget)
    return np.unique(np.round(np.geomspace(start, budget, num=min(budget, count))).astype(int))


def recommendation_path(sc: Scenario, result: OptimizationResult, checkpoints) -> np.ndarray:
    """Index of the recommended evaluation had the run stopped after each of `checkpoints`.

    The agent's own rule (:meth:`~inertia_gym.agents.base.Agent.recommend`) applied to the first
    i evaluations of `result` (a run on `sc`), for i in checkpoints (1-based counts). Returns
    (len(checkpoints),) indices; at i = budget it is xi_star's.
    """
    from inertia_gym.agents import make_agent
    from inertia_gym.envs.excitation import xi_to_action

    agent = make_agent(result.agent, result.seed, result.budget)
    actions = np.array([xi_to_action(sc, x) for x in result.xis], dtype=float)
    within = result.within_limits
    with torch_threads(1):
        return np.array([agent.recommend(actions[:i], result.costs[:i],
                                         None if within is None else within[:i])[0]
                         for i in checkpoints], dtype=int)


def validated_error(sc: Scenario, xi, duration: float, seeds) -> dict:
    """Long-horizon validation of xi (3,) (None: no torque): does applying it identify the inertia?

    Runs :func:`~inertia_gym.validation.validate` for `duration` s on each of `seeds` (no torque
    record, no batch-ML refinement) and returns {"val_rel_error": median of ||J_hat - J||_F /
    ||J||_F over the runs that did not diverge (None if all did), "val_rel_errors": per seed
    (None where diverged), "val_diverged": count, "val_scale_identified": the scale was
    identified on most runs that did not diverge, "val_duration": s, "val_seeds": list}.
    """
    xi = None if xi is None else np.asarray(xi, dtype=float)
    res = validate(sc, xi, duration, seeds, record_torque=False)
    ok = ~res.diverged
    return {
        "val_rel_error": float(np.median(res.rel_errors[ok])) if ok.any() else None,
        "val_rel_errors": [float(e) if k else None for e, k in zip(res.rel_errors, ok)],
        "val_diverged": int(res.diverged.sum()),
        "val_scale_identified": bool(ok.any() and res.scale_identified[ok].mean() > 0.5),
        "val_duration": float(duration),
        "val_seeds": [int(s) for s in res.seeds],
    }


@dataclasses.dataclass(frozen=True)
class Evaluations:
    """One episode from the scenario's start of each of K xi with each of S seeds, each (K, S):
    costs, rel_errors (true relative inertia error at the end), impulses (N·m·s spent),
    impulse_demands (N·m·s the burst law asked for), within (bool: the limits let the bursts
    fire as designed, :func:`within_limits`).
    """

    costs: np.ndarray
    rel_errors: np.ndarray
    impulses: np.ndarray
    impulse_demands: np.ndarray
    within: np.ndarray


def evaluate_many(sc: Scenario, xis, seeds, cost: str = "info") -> tuple[np.ndarray, np.ndarray]:
    """(costs, rel_errors) of :func:`evaluate_episodes`, each (K, S)."""
    ev = evaluate_episodes(sc, xis, seeds, cost)
    return ev.costs, ev.rel_errors


def evaluate_episodes(sc: Scenario, xis, seeds, cost: str = "info") -> Evaluations:
    """Cost, final relative inertia error and impulse of one episode from the scenario's start.

    xis (K, 3), seeds (S,) integers >= 0: every xi is run with every seed (common random
    numbers: seed s draws the same dwell times, measurement times and noise for every xi), all
    K*S runs in one batched call. A diverged run costs
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
    shape = (len(xis), len(seeds))

    def grid(values, dtype=float):
        return np.array(values, dtype=dtype).reshape(shape)

    return Evaluations(
        costs=grid([penalty if r.diverged else r.cost for r in results]),
        rel_errors=grid([r.rel_error for r in results]),
        impulses=grid([r.impulse for r in results]),
        impulse_demands=grid([r.impulse_demand for r in results]),
        within=grid([within_limits(sc.impulse_budget, r.impulse_demand, r.rate_cuts)
                     for r in results], bool))


def evaluate_xi(sc: Scenario, xi, seeds, cost: str = "info") -> float:
    """Mean cost of one episode of xi (3,) from the scenario's start over `seeds` (batched)."""
    xi = np.asarray(xi, dtype=float)
    if xi.shape != (3,):
        raise ConfigError(f"xi must have shape (3,), got {xi.shape}")
    return float(evaluate_many(sc, xi[None], seeds, cost)[0].mean())
