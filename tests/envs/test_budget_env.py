"""`InertiaGym/ExcitationBudget-v0`: the excitation env on the paper's body under an impulse budget."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from inertia_gym.envs import BUDGET_ENV_ID, BUDGET_ENV_KWARGS, ENV_ID, ExcitationEnv
from inertia_gym.scenario import Scenario

CORNER = np.ones(3, dtype=np.float32)  # a, b, T_on at their upper bounds


def test_registered_beside_the_unlimited_env_with_its_scenario_and_objective():
    env = gym.make(BUDGET_ENV_ID)
    inner = env.unwrapped
    assert env.spec.max_episode_steps == 100
    assert inner.scenario == Scenario.load("paper-budget")
    assert inner.scenario.impulse_budget == 13.0
    assert (inner.cost, inner.carry_over) == ("posterior", False)
    assert gym.make(ENV_ID).unwrapped.scenario.impulse_budget is None


def test_gymnasium_and_sb3_checkers_pass():
    gym_check_env(gym.make(BUDGET_ENV_ID).unwrapped, skip_render_check=True)
    sb3_check_env(ExcitationEnv(**BUDGET_ENV_KWARGS), warn=True)


def test_the_corner_spends_the_budget_and_info_says_so():
    env = gym.make(BUDGET_ENV_ID)
    env.reset(seed=0)
    _, reward, _, _, info = env.step(CORNER)
    assert info["impulse_budget"] == 13.0 and info["impulse"] == pytest.approx(13.0, rel=1e-12)
    assert info["budget_spent"] and info["rate_limit"] is None and info["rate_cuts"] == 0
    assert info["rate_peak"] >= np.linalg.norm(Scenario().omega0)
    assert reward == -info["cost"] == -info["posterior_cost"]
    # The same action without the budget spends about three times as much.
    free = gym.make(ENV_ID, cost="posterior", carry_over=False)
    free.reset(seed=0)
    free_info = free.step(CORNER)[4]
    assert free_info["impulse"] > 2.5 * 13.0 and not free_info["budget_spent"]
    assert free_info["impulse_budget"] is None


@pytest.mark.parametrize("mode", ["sync", "async", "vector_entry_point"])
def test_make_vec_runs_the_budget_in_every_mode(mode):
    vec = gym.make_vec(BUDGET_ENV_ID, num_envs=2, vectorization_mode=mode, budget=1)
    try:
        vec.reset(seed=3)
        _, reward, terminated, truncated, info = vec.step(np.tile(CORNER, (2, 1)))
        assert np.all(np.isfinite(reward)) and truncated.all() and not terminated.any()
        assert np.allclose(info["impulse"].astype(float), 13.0, rtol=1e-12)
        assert info["budget_spent"].all()
    finally:
        vec.close()
