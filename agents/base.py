"""The one small interface every agent implements, and the factory by name."""

from __future__ import annotations

import abc

import gymnasium as gym
import numpy as np
from tqdm.auto import tqdm

from inertia_gym.errors import ConfigError


class Agent(abc.ABC):
    """Chooses actions u in [-1, 1]^3 (the env's normalised xi) for a budget of env steps.

    Subclasses set ``name`` and implement :meth:`run`; the seed is their only source of
    randomness.
    """

    name: str = "agent"

    def __init__(self, seed: int):
        self.seed = int(seed)

    @abc.abstractmethod
    def run(self, env: gym.Env, budget: int, progress: bool = False) -> None:
        """Take exactly `budget` steps in `env`.

        The env is reset with ``seed`` first, and again after a terminated or truncated run.
        """


class AskTellAgent(Agent):
    """An agent that proposes one action at a time and is told its cost (BO, random search).

    Subclasses implement :meth:`ask` -> u (3,) in [-1, 1] and :meth:`tell` (u, cost); the
    observations of the env are not used (Algorithm 1 treats J(xi) as a black box).
    """

    @abc.abstractmethod
    def ask(self) -> np.ndarray:
        """Next action u, shape (3,), in [-1, 1]."""

    @abc.abstractmethod
    def tell(self, action: np.ndarray, cost: float) -> None:
        """Record that `action` (3,) cost `cost` (lower is better)."""

    def run(self, env: gym.Env, budget: int, progress: bool = False) -> None:
        """Ask, step, tell, `budget` times."""
        env.reset(seed=self.seed)
        for _ in tqdm(range(budget), desc=self.name, disable=not progress, leave=False):
            action = self.ask()
            _, reward, terminated, truncated, _ = env.step(action.astype(np.float32))
            self.tell(action, -float(reward))
            if terminated or truncated:
                env.reset()


def make_agent(name: str, seed: int, budget: int, **options) -> Agent:
    """Build the agent `name` ("bo", "random", "sac", "td3", "ppo") for a budget of steps."""
    if name == "bo":
        from agents.bo import BOAgent

        return BOAgent(seed, **options)
    if name == "random":
        from agents.random_search import RandomAgent

        return RandomAgent(seed, **options)
    if name in ("sac", "td3", "ppo"):
        from agents.sb3 import SB3Agent

        return SB3Agent(name, seed, budget, **options)
    raise ConfigError(f"agent must be one of bo, random, sac, td3, ppo; got {name!r}")
