"""Agents compared across seeds at equal budgets: the sweep behind `inertia-gym benchmark`.

A sweep is a set of tasks, one per (agent, seed). A task runs the agent for M evaluations of the
excitation env (:func:`inertia_gym.optimization.optimize`), then scores the xi it found the same
way for every agent, so that agents are compared on what they found and not on the noise of
their own runs:

* **re-evaluated cost**: the mean cost of one episode from the scenario's start over fixed
  evaluation seeds (common random numbers, :func:`~inertia_gym.optimization.evaluate_many`), for
  xi* (the xi the agent recommends: lowest GP posterior mean over its evaluated points) and for
  the observed best (Algorithm 1, line 24: the lowest observed cost);
* **validated inertia error**: median over fixed validation seeds of ||J_hat - J||_F / ||J||_F
  after a long-horizon validation of xi*
  (:func:`~inertia_gym.optimization.validated_error`).

The dense-grid reference ``grid`` scores every point of an n x n x n grid over the bounds of xi
the same way and keeps the best: the attainable optimum. An agent's **regret** is its re-evaluated
cost minus the grid optimum's (negative when it found a better xi between the grid's points).

Each finished task is one JSON record (:func:`run_task`); the resumable store and the sweep
driver live in :mod:`inertia_gym.benchmark_store`, the report in
:mod:`inertia_gym.benchmark_report`, the figures in :mod:`inertia_gym.plots` and the backends in
:mod:`inertia_gym.executors`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time

import numpy as np

from inertia_gym.agents.base import candidates
from inertia_gym.envs.excitation import check_seed
from inertia_gym.episode import COSTS
from inertia_gym.errors import ConfigError
from inertia_gym.optimization import AGENTS as OPTIMIZER_AGENTS
from inertia_gym.optimization import (
    DEFAULT_CARRY_OVER,
    DEFAULT_COST,
    evaluate_episodes,
    optimize,
    recommendation_checkpoints,
    recommendation_path,
    validated_error,
)
from inertia_gym.scenario import Scenario

GRID = "grid"
AGENTS = (*OPTIMIZER_AGENTS, GRID)
# Runs per batched call of evaluate_many when scoring many xi (bounds the memory of one batch).
EVAL_CHUNK = 384


@dataclasses.dataclass(frozen=True)
class SweepSettings:
    """Everything that changes the result of a task, apart from its agent and seed.

    scenario : the experiment.  budget : M evaluations per agent run.  cost : "info" (the paper's
    J) or "posterior".  carry_over : the estimator carries over from one evaluation to the next
    (Algorithm 1) or every evaluation restarts from the scenario's start (a stationary
    objective); cost and carry_over default to the optimiser's defaults (from-start episodes,
    posterior cost); the paper's Algorithm 1 is cost="info", carry_over=True.
    eval_seeds : seeds of the from-start re-evaluation (common to all agents).
    val_seeds, val_duration (s) : the long-horizon validation of xi*.
    grid_points : points per axis of the dense-grid reference.
    """

    scenario: Scenario
    budget: int
    cost: str = DEFAULT_COST
    carry_over: bool = DEFAULT_CARRY_OVER
    eval_seeds: tuple = tuple(range(10_000, 10_008))
    val_seeds: tuple = (0, 1, 2, 3)
    val_duration: float = 1000.0
    grid_points: int = 9

    def __post_init__(self) -> None:
        if not isinstance(self.scenario, Scenario):
            raise ConfigError(f"scenario must be a Scenario, got {type(self.scenario).__name__}")
        for name in ("budget", "grid_points"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ConfigError(f"{name} must be an integer >= 1, got {value!r}")
        if self.cost not in COSTS:
            raise ConfigError(f"cost must be one of {COSTS}, got {self.cost!r}")
        if self.grid_points < 2:
            raise ConfigError(f"grid_points must be >= 2, got {self.grid_points}")
        for name in ("eval_seeds", "val_seeds"):
            seeds = tuple(getattr(self, name))
            try:
                checked = tuple(check_seed(s) for s in seeds)
            except ConfigError:
                checked = ()
            if not checked or None in checked:
                raise ConfigError(f"{name} must be a non-empty list of integers >= 0, got {seeds}")
            object.__setattr__(self, name, checked)
        if not (np.isfinite(self.val_duration) and self.val_duration > 0):
            raise ConfigError(f"val_duration must be a positive number of seconds, "
                              f"got {self.val_duration}")

    def to_json(self) -> dict:
        """Plain-JSON form (the scenario as its full field dict)."""
        return {
            "scenario": self.scenario.to_dict(), "budget": int(self.budget), "cost": self.cost,
            "carry_over": bool(self.carry_over), "eval_seeds": list(self.eval_seeds),
            "val_seeds": list(self.val_seeds), "val_duration": float(self.val_duration),
            "grid_points": int(self.grid_points),
        }

    @classmethod
    def from_json(cls, data: dict) -> "SweepSettings":
        """Inverse of :meth:`to_json`."""
        return cls(**{**data, "scenario": Scenario.from_mapping(data["scenario"])})

    def key(self) -> str:
        """A short hash of :meth:`to_json`: records made under other settings do not mix."""
        text = json.dumps(self.to_json(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclasses.dataclass(frozen=True)
class Task:
    """One unit of a sweep: `agent` run with `seed` (the grid reference has seed None)."""

    agent: str
    seed: int | None

    def __post_init__(self) -> None:
        if self.agent not in AGENTS:
            raise ConfigError(f"agent must be one of {AGENTS}, got {self.agent!r}")
        if (self.agent == GRID) != (self.seed is None):
            raise ConfigError(f"the grid reference takes no seed and every other agent one; "
                              f"got agent {self.agent!r} with seed {self.seed!r}")

    @property
    def name(self) -> str:
        """File-name-safe identifier, e.g. ``bo-seed3`` or ``grid``."""
        return self.agent if self.seed is None else f"{self.agent}-seed{self.seed}"


def sweep_tasks(agents, n_seeds: int) -> list[Task]:
    """The tasks of a sweep: each agent with seeds 0..n_seeds-1, the grid reference once.

    The grid comes first: it is the longest task, so it starts while the agents run.
    """
    agents = list(dict.fromkeys(agents))
    unknown = [a for a in agents if a not in AGENTS]
    if unknown or not agents:
        raise ConfigError(f"agents (--agents) must be a non-empty list from {AGENTS}, "
                          f"got {agents}")
    tasks = [Task(GRID, None)] if GRID in agents else []
    return tasks + [Task(a, s) for s in range(n_seeds) for a in agents if a != GRID]


def dense_grid(sc: Scenario, points_per_axis: int) -> np.ndarray:
    """Every xi of a regular grid over ``sc.xi_bounds``, shape (n**3, 3), bounds included."""
    lo, hi = sc.xi_bounds
    g = np.linspace(0.0, 1.0, points_per_axis)
    u = np.array(np.meshgrid(g, g, g, indexing="ij")).reshape(3, -1).T
    return lo + u * (hi - lo)


@dataclasses.dataclass(frozen=True)
class Scores:
    """Each of K xi scored over the evaluation seeds, each (K,): cost (mean from-start cost),
    rel_error (median final relative inertia error), impulse (mean N·m·s spent), within (share
    of the seeds on which the limits let the bursts fire as designed).
    """

    cost: np.ndarray
    rel_error: np.ndarray
    impulse: np.ndarray
    within: np.ndarray


def reevaluate(sc: Scenario, xis, seeds, cost: str = "info") -> Scores:
    """Score each xi (K, 3) over `seeds` (common to all), in batches of at most EVAL_CHUNK runs."""
    xis = np.atleast_2d(np.asarray(xis, dtype=float))
    per_chunk = max(1, EVAL_CHUNK // len(seeds))
    parts = [evaluate_episodes(sc, xis[i:i + per_chunk], seeds, cost)
             for i in range(0, len(xis), per_chunk)]
    return Scores(
        cost=np.concatenate([p.costs.mean(axis=1) for p in parts]),
        rel_error=np.concatenate([np.median(p.rel_errors, axis=1) for p in parts]),
        impulse=np.concatenate([p.impulses.mean(axis=1) for p in parts]),
        within=np.concatenate([p.within.mean(axis=1) for p in parts]))


def _limit_keys(sc: Scenario, scores: Scores, k: int) -> dict:
    """The record's keys of xi k's use of the limits (none without limits)."""
    if not sc.limited:
        return {}
    return {"impulse_star": float(scores.impulse[k]), "within_limits_star": float(scores.within[k])}


def run_task(settings: SweepSettings, task: Task) -> dict:
    """Run one task and score it; returns its JSON record (plain types only).

    Agent record: agent, seed, budget, costs (M,), xis (M, 3), rel_errors (M,) (true inertia
    error after each evaluation); xi_star (the recommended xi), cost_star (its GP-predicted
    cost), recommendation (the rule); xi_observed_best and best_cost (the lowest observed cost);
    reeval_cost and reeval_cost_observed_best (from-start cost of xi* and of the observed best
    over the evaluation seeds); recommended_curve {"evaluations": checkpoints i, "reeval_cost":
    the re-evaluated cost of the xi the agent would have recommended after i evaluations} (its
    learning curve, free of the noise of single episodes); xi_recommended and
    reeval_cost_recommended (= xi_star and reeval_cost: contract keys, never renamed);
    val_rel_error / val_rel_errors / val_diverged /
    val_scale_identified (validation of xi*); wall_s (the optimisation), score_wall_s
    (re-evaluation and validation), settings_key.
    Grid record: agent "grid", seed None, n_points, xi_star (the best grid point), reeval_cost,
    top (the ten best points with their costs), the validation of xi*, wall_s.
    Under the scenario's limits both records add impulse_star (mean N·m·s xi* spent over the
    evaluation seeds) and within_limits_star (the share of them on which the limits let its
    bursts fire as designed); the grid's optimum is then the best point within the limits on
    every seed, and its record adds grid: [a, b, T_on, cost, impulse, within] of every point.
    """
    t0 = time.perf_counter()
    sc = settings.scenario
    if task.agent == GRID:
        xis = dense_grid(sc, settings.grid_points)
        scores = reevaluate(sc, xis, settings.eval_seeds, settings.cost)
        costs = scores.cost
        # Under limits the optimum is a design the limits let fire as designed on every seed,
        # as an agent's xi* is one of its evaluations that fired so.
        pool = candidates(scores.within == 1.0 if sc.limited else None, len(xis))
        order = pool[np.argsort(costs[pool], kind="stable")]
        record = {
            "agent": GRID, "seed": None, "n_points": len(xis),
            "xi_star": xis[order[0]].tolist(), "reeval_cost": float(costs[order[0]]),
            "top": [[*xis[k].tolist(), float(costs[k])] for k in order[:10]],
            **_limit_keys(sc, scores, order[0]),
        }
        if sc.limited:  # the trade-off curve: every grid point's impulse and cost
            record["grid"] = [[*xis[k].tolist(), float(costs[k]), float(scores.impulse[k]),
                               float(scores.within[k])] for k in range(len(xis))]
            record["tradeoff"] = _tradeoff(settings, xis, scores)
        record.update(_validation(settings, xis[order[0]]))
        record["wall_s"] = time.perf_counter() - t0
    else:
        result = optimize(task.agent, sc, settings.budget, task.seed, cost=settings.cost,
                          carry_over=settings.carry_over)
        t1 = time.perf_counter()
        checkpoints = recommendation_checkpoints(settings.budget)
        path = recommendation_path(sc, result, checkpoints)  # path[-1] is xi_star's index
        best = int(np.flatnonzero(np.all(result.xis == result.xi_observed_best, axis=1))[0])
        scored = np.unique(np.append(path, best))
        scores = reevaluate(sc, result.xis[scored], settings.eval_seeds, settings.cost)
        cost_of = dict(zip(scored.tolist(), scores.cost.tolist()))
        record = {
            "agent": task.agent, "seed": task.seed, "budget": int(settings.budget),
            "costs": result.costs.tolist(), "xis": result.xis.tolist(),
            "rel_errors": result.rel_errors.tolist(),
            "xi_star": result.xi_star.tolist(), "cost_star": float(result.cost_star),
            "recommendation": result.recommendation,
            "xi_observed_best": result.xi_observed_best.tolist(),
            "best_cost": float(result.cost_observed_best),
            "reeval_cost": cost_of[int(path[-1])], "reeval_cost_observed_best": cost_of[best],
            # Contract keys equal to xi_star and reeval_cost (docs/contracts.md: never renamed).
            "xi_recommended": result.xi_star.tolist(),
            "reeval_cost_recommended": cost_of[int(path[-1])],
            "recommended_curve": {"evaluations": checkpoints.tolist(),
                                  "reeval_cost": [cost_of[int(k)] for k in path]},
            **_limit_keys(sc, scores, int(np.searchsorted(scored, path[-1]))),
        }
        record.update(_validation(settings, result.xi_star))
        record["wall_s"] = float(result.wall_s)
        record["score_wall_s"] = time.perf_counter() - t1
    record["settings_key"] = settings.key()
    return record


#: Impulse bands of the trade-off curve (quantiles of the grid's impulse spent).
TRADEOFF_BANDS = 8


def _tradeoff(settings: SweepSettings, xis, scores: Scores) -> list[list[float]]:
    """The grid's trade-off of impulse against validated error: in each of TRADEOFF_BANDS
    bands of impulse spent (quantiles over the grid), the point of lowest cost that the limits
    let fire as designed, validated like xi*. Rows [a, b, T_on, impulse N·m·s, cost, validated
    error or None (diverged)].
    """
    torqued = np.flatnonzero((scores.impulse > 0) & (scores.within == 1.0))
    if torqued.size == 0:
        return []
    edges = np.quantile(scores.impulse[torqued], np.linspace(0.0, 1.0, TRADEOFF_BANDS + 1))
    band = np.clip(np.searchsorted(edges, scores.impulse[torqued], side="right") - 1, 0,
                   TRADEOFF_BANDS - 1)
    rows = []
    for b in np.unique(band):
        members = torqued[band == b]
        k = int(members[np.argmin(scores.cost[members])])
        val = _validation(settings, xis[k])["val_rel_error"]
        rows.append([*xis[k].tolist(), float(scores.impulse[k]), float(scores.cost[k]), val])
    return rows


def _validation(settings: SweepSettings, xi) -> dict:
    """The validation keys of a record (the settings' duration and seeds are in settings.json)."""
    res = validated_error(settings.scenario, xi, settings.val_duration, settings.val_seeds)
    return {k: v for k, v in res.items() if k not in ("val_duration", "val_seeds")}


def _quartiles(values) -> dict | None:
    """{"median", "q25", "q75", "n"} of the finite values, None if there are none."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return None
    q25, med, q75 = np.quantile(v, [0.25, 0.5, 0.75])
    return {"median": float(med), "q25": float(q25), "q75": float(q75), "n": int(v.size)}


#: Resamples of the bootstrap interval of a median (median_interval); its seed is fixed so a
#: report is a pure function of its records.
BOOTSTRAP_RESAMPLES = 10_000


def median_interval(values, level: float = 0.95) -> list[float] | None:
    """The percentile-bootstrap interval of the median of the finite values (level 95 %):
    where the median over seeds would fall on another draw of as many seeds. None when fewer
    than 2 values.
    """
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size < 2:
        return None
    draws = np.random.default_rng(0).integers(0, v.size, (BOOTSTRAP_RESAMPLES, v.size))
    medians = np.median(v[draws], axis=1)
    tail = (1.0 - level) / 2.0
    return [float(np.quantile(medians, tail)), float(np.quantile(medians, 1.0 - tail))]


def win_rate(a: dict, b: dict, key: str = "reeval_cost") -> float | None:
    """Share of the seeds both agents ran on which agent a's `key` is lower (ties count half).

    a, b : {seed: record}. None when they share no seed.
    """
    common = sorted(set(a) & set(b))
    if not common:
        return None
    wins = [1.0 if a[s][key] < b[s][key] else 0.5 if a[s][key] == b[s][key] else 0.0
            for s in common]
    return float(np.mean(wins))


def summarize(records: list[dict]) -> dict:
    """The results of a sweep, from its task records (any order).

    Returns {"grid": the grid record or None, "reference_cost": its re-evaluated cost or None,
    "runs": the agent records (sorted by agent, then seed) with ``regret`` and
    ``regret_observed_best`` added (re-evaluated cost of xi* / of the observed best minus the
    grid optimum's; None without a grid; ``regret_recommended`` = ``regret``, a contract key),
    "agents": {agent: {"runs", "seeds", "best_cost", "reeval_cost",
    "reeval_cost_observed_best", "regret", "regret_observed_best", "val_rel_error", "wall_s"
    (each median/q25/q75/n), "val_diverged", "win_rate": {other agent: share of the shared
    seeds won on the re-evaluated cost of xi*}, "win_seeds": {other agent: how many seeds that
    share rests on}, "regret_median_ci95": the 95 % bootstrap interval of the median regret
    (None without a grid or with one seed)}}}. Under mission limits each agent adds
    "impulse_star" (quartiles of the N·m·s its xi* spent) and "within_limits" (the share of its
    runs whose xi* the limits let fire as designed on every evaluation seed).
    """
    grid = next((r for r in records if r["agent"] == GRID), None)
    ref = None if grid is None else grid["reeval_cost"]
    by_agent: dict[str, dict] = {}
    for r in records:
        if r["agent"] != GRID:
            by_agent.setdefault(r["agent"], {})[r["seed"]] = {
                **r,
                "regret": None if ref is None else r["reeval_cost"] - ref,
                "regret_observed_best": (None if ref is None
                                         else r["reeval_cost_observed_best"] - ref),
                "regret_recommended": None if ref is None else r["reeval_cost"] - ref,
            }
    agents, runs = {}, []
    for name, by_seed in by_agent.items():
        rows = [by_seed[s] for s in sorted(by_seed)]
        runs += rows

        def stat(key, rows=rows):
            return _quartiles([r[key] for r in rows])

        agents[name] = {
            "runs": len(rows), "seeds": sorted(by_seed),
            **{key: stat(key) for key in ("best_cost", "reeval_cost", "reeval_cost_observed_best",
                                          "regret", "regret_observed_best", "val_rel_error",
                                          "wall_s")},
            "regret_median_ci95": median_interval([r["regret"] for r in rows]),
            "val_diverged": int(sum(r["val_diverged"] for r in rows)),
            **({"impulse_star": stat("impulse_star"),
                "within_limits": float(np.mean([r["within_limits_star"] == 1.0 for r in rows]))}
               if all("within_limits_star" in r for r in rows) else {}),
            "win_rate": {other: win_rate(by_seed, by_agent[other]) for other in by_agent
                         if other != name},
            "win_seeds": {other: len(set(by_seed) & set(by_agent[other])) for other in by_agent
                          if other != name},
        }
    return {"grid": grid, "reference_cost": ref, "runs": runs, "agents": agents}


__all__ = ["AGENTS", "GRID", "SweepSettings", "Task", "dense_grid", "reevaluate", "run_task",
           "summarize", "sweep_tasks", "win_rate"]
