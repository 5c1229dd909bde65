"""The one small interface every agent implements, and the factory by name."""

from __future__ import annotations

import abc
import importlib

import gymnasium as gym
import numpy as np
from tqdm.auto import tqdm

from inertia_gym.errors import ConfigError, install_hint


def candidates(within, n: int) -> np.ndarray:
    """Indices of the n evaluations a recommendation picks from: those within the scenario's
    limits (within (n,) bool) when there are any, else all (also for within None).
    """
    allowed = np.flatnonzero(np.asarray(within, dtype=bool)) if within is not None else np.arange(0)
    return allowed if allowed.size else np.arange(n)


class Agent(abc.ABC):
    """Chooses actions u in [-1, 1]^3 (the env's normalised xi) for a budget of env steps.

    Subclasses set ``name`` and implement :meth:`run`; the seed is their only source of
    randomness.
    """

    name: str = "agent"
    #: How :meth:`recommend` picks the xi a user should use, in words (reports print it).
    recommendation_rule: str = ("the evaluated xi with the lowest GP posterior mean cost "
                                "(a GP fitted to all M evaluations)")

    def __init__(self, seed: int):
        self.seed = int(seed)

    def recommend(self, actions, costs, within=None) -> tuple[int, float]:
        """The evaluation whose xi a user should use: (its index, its predicted cost).

        actions (M, 3) in [-1, 1] and costs (M,) are the run's evaluations in order. The rule,
        the same for every agent so that agents are compared on one footing: the evaluated
        point with the lowest posterior mean of a GP fitted to all M costs (seeded by the
        agent's seed), with that posterior mean as its predicted cost, in the costs' units.
        Unlike the lowest observed cost (Algorithm 1, line 24) it does not chase one lucky
        noisy draw. With M = 1 the only evaluation and its cost.
        within (M,) bool, optional: the evaluations whose bursts the scenario's limits let fire
        as designed; the pick is among them when there are any (a design the limits cut is not
        the design that flew).
        """
        costs = np.asarray(costs, dtype=float)
        if len(costs) == 1:
            return 0, float(costs[0])
        return extra_module("optimize", "the recommendation (a GP fitted to the costs)").posterior_best(
            actions, costs, self.seed, within)

    @abc.abstractmethod
    def run(self, env: gym.Env, budget: int, progress: bool = False) -> None:
        """Take exactly `budget` steps in `env`.

        The env is reset with ``seed`` first, and again after a terminated or truncated run.
        """


class AskTellAgent(Agent):
    """An agent that proposes one action at a time and is told its cost (BO, random search).

    Subclasses implement :meth:`ask` -> u (3,) in [-1, 1] and :meth:`tell` (u, cost); the
    observations of the env are not used (Algorithm 1 treats J(xi) as a black box). An agent
    that also learns from a step's info (BO's model of the impulse an xi demands) overrides
    :meth:`observe`.
    """

    @abc.abstractmethod
    def ask(self) -> np.ndarray:
        """Next action u, shape (3,), in [-1, 1]."""

    @abc.abstractmethod
    def tell(self, action: np.ndarray, cost: float) -> None:
        """Record that `action` (3,) cost `cost` (lower is better)."""

    def observe(self, action: np.ndarray, info: dict) -> None:
        """Called with each step's info before :meth:`tell`; nothing by default."""

    def run(self, env: gym.Env, budget: int, progress: bool = False) -> None:
        """Ask, step, observe, tell, `budget` times."""
        env.reset(seed=self.seed)
        for _ in tqdm(range(budget), desc=self.name, disable=not progress, leave=False):
            action = self.ask()
            _, reward, terminated, truncated, info = env.step(action.astype(np.float32))
            self.observe(action, info)
            self.tell(action, -float(reward))
            if terminated or truncated:
                env.reset()


def extra_module(extra: str, needed_by: str):
    """The module of an extra (inertia_gym.agents.bo for "optimize", .sb3 for "rl"), imported;
    where a package of the extra is missing, a one-line ConfigError saying what needs it and
    which extra to install.
    """
    try:
        module = importlib.import_module(f"inertia_gym.agents.{'bo' if extra == 'optimize' else 'sb3'}")
    except ModuleNotFoundError as missing:
        raise ConfigError(f"{needed_by} needs {missing.name}, which is not installed: "
                          f"{install_hint(extra)}") from missing
    return module


def _bo(seed, budget, **options):
    return extra_module("optimize", "the bo agent").BOAgent(seed, **options)


def _random(seed, budget, **options):
    from inertia_gym.agents.random_search import RandomAgent

    return RandomAgent(seed, **options)


def _sb3(algorithm):
    def build(seed, budget, **options):
        return extra_module("rl", f"the {algorithm} agent").SB3Agent(algorithm, seed, budget, **options)
    return build


#: The agents by name: each entry builds one from (seed, budget, **options). Its module is
#: imported only when the agent is built (torch and SB3 load only for the agents that need them).
AGENTS = {"bo": _bo, "random": _random, "sac": _sb3("sac"), "td3": _sb3("td3"), "ppo": _sb3("ppo")}


def make_agent(name: str, seed: int, budget: int, **options) -> Agent:
    """Build the agent `name` (a key of AGENTS: "bo", "random", "sac", "td3", "ppo")."""
    if name not in AGENTS:
        raise ConfigError(f"agent must be one of {', '.join(AGENTS)}; got {name!r}")
    return AGENTS[name](seed, budget, **options)
