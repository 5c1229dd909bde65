"""Stable-Baselines3 baselines (SAC, TD3, PPO) tuned to learn within a few hundred env steps.

Each env step is a whole excitation episode, so budgets are small (M ~ 100): learning starts
after 10 steps, small networks, one gradient step per env step, and a short discount horizon
(gamma = 0.5: an excitation mostly pays off in its own episode's cost). PPO uses short rollouts
(16 steps). Training stops after exactly `budget` env steps (a callback), whatever the rollout
length.
"""

from __future__ import annotations

import contextlib
import random

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.noise import NormalActionNoise
from tqdm.auto import tqdm

from inertia_gym.agents.base import Agent
from inertia_gym.errors import ConfigError


def sb3_settings(name: str, budget: int) -> dict:
    """Return constructor keyword arguments of SB3 algorithm `name` for a budget of steps."""
    start = min(10, max(1, budget // 4))
    if name == "sac":
        return dict(learning_rate=1e-3, buffer_size=max(budget, 1), learning_starts=start,
                    batch_size=32, gamma=0.5, train_freq=1, gradient_steps=1,
                    policy_kwargs={"net_arch": [64, 64]})
    if name == "td3":
        return dict(learning_rate=1e-3, buffer_size=max(budget, 1), learning_starts=start,
                    batch_size=32, gamma=0.5, train_freq=1, gradient_steps=1,
                    action_noise=NormalActionNoise(np.zeros(3), 0.3 * np.ones(3)),
                    policy_kwargs={"net_arch": [64, 64]})
    if name == "ppo":
        n_steps = min(16, max(2, budget))
        return dict(learning_rate=1e-3, n_steps=n_steps, batch_size=n_steps, n_epochs=10,
                    gamma=0.5, gae_lambda=0.9, ent_coef=0.0, policy_kwargs={"net_arch": [64, 64]})
    raise ConfigError(f"SB3 agent must be sac, td3 or ppo; got {name!r}")


@contextlib.contextmanager
def _restore_global_rngs():
    """SB3 seeds the global random, numpy and torch generators; put them back afterwards."""
    py_state, np_state = random.getstate(), np.random.get_state()
    with torch.random.fork_rng():
        try:
            yield
        finally:
            random.setstate(py_state)
            np.random.set_state(np_state)


class _StopAtBudget(BaseCallback):
    """Stop training once `budget` env steps were taken; optional tqdm progress bar."""

    def __init__(self, budget: int, name: str, progress: bool):
        super().__init__()
        self.budget = budget
        self.bar = tqdm(total=budget, desc=name, disable=not progress, leave=False)

    def _on_step(self) -> bool:
        self.bar.update(1)
        return self.num_timesteps < self.budget

    def _on_training_end(self) -> None:
        self.bar.close()


class SB3Agent(Agent):
    """SAC, TD3 or PPO learning a policy obs -> xi for exactly `budget` env steps.

    Fitted attribute ``model_``: the trained SB3 model.
    """

    _CLASSES = {"sac": SAC, "td3": TD3, "ppo": PPO}

    def __init__(self, name: str, seed: int, budget: int, **overrides):
        super().__init__(seed)
        self.name = name
        self.kwargs = {**sb3_settings(name, budget), **overrides}
        self.model_ = None

    def run(self, env: gym.Env, budget: int, progress: bool = False) -> None:
        """Train with ``learn(total_timesteps=budget)``; SB3 resets the env itself (seeded).

        Without a ``tensorboard_log`` override nothing is logged: SB3's default logger would make
        an empty SB3-<time> folder in the system's temporary folder on every learn().
        """
        with _restore_global_rngs():
            self.model_ = self._CLASSES[self.name]("MlpPolicy", env, seed=self.seed,
                                                   device="cpu", verbose=0, **self.kwargs)
            if self.kwargs.get("tensorboard_log") is None:
                self.model_.set_logger(Logger(folder=None, output_formats=[]))
            self.model_.learn(total_timesteps=budget,
                              callback=_StopAtBudget(budget, self.name, progress))
