"""Native vector env of `InertiaGym/Excitation-v0`: B envs stepped by one call of the batched loop.

``gym.make_vec("InertiaGym/Excitation-v0", num_envs=B, vectorization_mode="vector_entry_point")``
(the default mode of ``make_vec`` for this id) builds :class:`ExcitationVectorEnv`. It is a thin
shell over the same functions as the single env (:func:`~inertia_gym.envs.excitation.start_runs`,
:func:`~inertia_gym.envs.excitation.step_runs`, ...), which run the episodes of all B envs in
one call of the compiled closed loop (parallel over runs).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from inertia_gym.envs.excitation import (
    OBS_HIGH,
    OBS_LOW,
    ResetNeededError,
    as_scenario,
    check_cost,
    check_count,
    check_seed,
    observations,
    start_runs,
    step_info,
    step_runs,
)
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario


class ExcitationVectorEnv(VectorEnv):
    """B independent copies of :class:`~inertia_gym.envs.excitation.ExcitationEnv`, batched.

    **Spaces.** ``single_action_space`` and ``single_observation_space`` are those of the single
    env; ``action_space`` (B, 3) and ``observation_space`` (B, 16) are their batches.

    **Step.** ``step(actions)`` with actions (B, 3) runs one excitation episode for every env
    that is not being reset, all in one call of the compiled batched loop; rewards (B,) float64,
    terminated / truncated (B,) bool and infos, a dict of arrays with a ``_key`` mask per key
    (gymnasium's vector-info layout), with the same keys and values as the single env's info.
    A sub-env terminates only when its estimator diverges and is truncated once it has taken
    ``budget`` steps, or ``max_episode_steps`` (as ``TimeLimit`` does for ``gym.make``).

    **Autoreset.** ``AutoresetMode.NEXT_STEP`` (gymnasium's default, as ``SyncVectorEnv``): a
    sub-env that ended on step t is reset on step t+1, where its action is ignored and it returns
    its reset observation, reward 0, terminated = truncated = False and its reset info.

    **Seeding.** Each sub-env owns a Generator. ``reset(seed=s)`` seeds sub-env i with s + i,
    ``reset(seed=[s0, s1, ...])`` with s_i (None keeps its current Generator, or draws a fresh
    one on the first reset); autoresets continue each sub-env's Generator.
    ``reset(options={"reset_mask": mask})`` resets (and seeds) only the sub-envs in mask. Seeded the same way,
    sub-env i runs exactly as a single env: ``make_vec`` in "sync" mode gives the same results.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, scenario: Scenario | Mapping | str | Path | None = None,
                 cost: str = "info", budget: int = 100, carry_over: bool = True,
                 max_episode_steps: int | None = None):
        """Build B = num_envs envs; the other arguments as for ExcitationEnv.

        max_episode_steps: truncate every sub-env after this many steps (None: only the
        budget truncates); ``make_vec`` passes the registered limit (100).
        """
        self.num_envs = check_count("num_envs", num_envs)
        self.scenario = as_scenario(scenario)
        self.cost = check_cost(cost)
        self.budget = check_count("budget", budget)
        self.carry_over = bool(carry_over)
        self.max_episode_steps = (None if max_episode_steps is None
                                  else check_count("max_episode_steps", max_episode_steps))
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        self.single_observation_space = spaces.Box(OBS_LOW, OBS_HIGH, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._seeds: list[int | None] = [None] * self.num_envs
        self._state = None
        self._steps = np.zeros(self.num_envs, dtype=np.int64)
        self._time = np.zeros(self.num_envs)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)

    @property
    def np_random(self) -> tuple[np.random.Generator, ...]:
        """The Generators of the sub-envs (set by reset)."""
        return tuple(self._rngs)

    @property
    def np_random_seed(self) -> tuple[int | None, ...]:
        """The seeds of the sub-envs' Generators (as drawn by gymnasium's seeding)."""
        return tuple(self._seeds)

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict | None = None):
        """Reset the sub-envs to the scenario's start; returns (obs (B, 16), infos).

        options may hold ``reset_mask``, a (B,) bool array: only those sub-envs are reset (and
        seeded); the others keep their run, and the infos hold only the reset ones.
        """
        mask = self._reset_mask(options)
        envs = np.flatnonzero(mask)
        seeds = self._sub_seeds(seed)
        for i in envs:
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i], self._seeds[i] = seeding.np_random(seeds[i])
        fresh, reset_infos = start_runs(self.scenario, [self._rngs[i] for i in envs])
        self._state = fresh if mask.all() else self._state.with_rows(envs, fresh)
        self._steps[envs] = 0
        self._time[envs] = 0.0
        self._autoreset[envs] = False
        infos: list[dict] = [{}] * self.num_envs
        for i, info in zip(envs, reset_infos):
            infos[i] = info
        return observations(self.scenario, self._state, self._steps, self.budget), \
            self._batch_infos(infos)

    def step(self, actions):
        """One episode for every sub-env not being autoreset; the batched Gymnasium 5-tuple."""
        if self._state is None:
            raise ResetNeededError("call reset() before step()")
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs, 3):
            raise ConfigError(f"actions must have shape ({self.num_envs}, 3), got {actions.shape}")
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict] = [{}] * self.num_envs
        stepping = np.flatnonzero(~self._autoreset)
        resetting = np.flatnonzero(self._autoreset)
        if stepping.size:
            step = step_runs(self.scenario, self._state.select(stepping), actions[stepping],
                             [self._rngs[i] for i in stepping], cost=self.cost, carry_over=self.carry_over)
            results, xis, costs = step.results, step.xi, step.costs
            self._state = self._state.with_rows(stepping, step.state)
            self._steps[stepping] += 1
            self._time[stepping] += [res.duration for res in results]
            for i, res, xi, cost in zip(stepping, results, xis, costs):
                rewards[i] = -cost
                terminated[i] = res.diverged
                truncated[i] = not res.diverged and self._steps[i] >= self.budget
                infos[i] = step_info(self.scenario, res, xi, float(cost), float(self._time[i]))
        if self.max_episode_steps is not None:
            truncated[stepping] |= self._steps[stepping] >= self.max_episode_steps
        if resetting.size:
            fresh, reset_infos = start_runs(self.scenario, [self._rngs[i] for i in resetting])
            self._state = self._state.with_rows(resetting, fresh)
            self._steps[resetting] = 0
            self._time[resetting] = 0.0
            for i, info in zip(resetting, reset_infos):
                infos[i] = info
        self._autoreset = terminated | truncated
        obs = observations(self.scenario, self._state, self._steps, self.budget)
        return obs, rewards, terminated, truncated, self._batch_infos(infos)

    def _reset_mask(self, options: dict | None) -> np.ndarray:
        """The (B,) bool mask of the sub-envs to reset: options["reset_mask"], or all."""
        if not options or "reset_mask" not in options:
            return np.ones(self.num_envs, dtype=bool)
        if self._state is None:
            raise ResetNeededError("the first reset() resets every sub-env: no reset_mask")
        mask = options["reset_mask"]
        if not (isinstance(mask, np.ndarray) and mask.dtype == np.bool_
                and mask.shape == (self.num_envs,) and mask.any()):
            raise ConfigError(f"options['reset_mask'] must be a ({self.num_envs},) bool array "
                              f"with a True entry, got {mask!r}")
        return mask

    def _sub_seeds(self, seed) -> list[int | None]:
        """Per-sub-env seeds from None, an int s (s + i) or a sequence of B ints / None."""
        if not isinstance(seed, (list, tuple, np.ndarray)):
            base = check_seed(seed)
            return [None if base is None else base + i for i in range(self.num_envs)]
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ConfigError(f"seed must be None, an integer or {self.num_envs} seeds, got "
                              f"{len(seeds)}")
        return [check_seed(s) for s in seeds]

    def _batch_infos(self, infos: list[dict]) -> dict[str, Any]:
        """Per-sub-env info dicts in gymnasium's vector layout (arrays and `_key` masks)."""
        batched: dict[str, Any] = {}
        for i, info in enumerate(infos):
            batched = self._add_info(batched, info, i)
        return batched
