"""The env under fork: gymnasium's vector modes and SB3's SubprocVecEnv (default start method),
after the parent has already run the compiled parallel loop."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import SubprocVecEnv

from inertia_gym.envs import ENV_ID


@pytest.fixture(scope="module", autouse=True)
def parallel_kernel_ran_in_parent():
    env = gym.make(ENV_ID, budget=2)
    env.reset(seed=0)
    env.step(env.action_space.sample())  # the parallel closed loop has run in this process


@pytest.mark.parametrize("mode", ["sync", "async", "vector_entry_point"])
def test_make_vec_steps_in_every_mode(mode):
    vec = gym.make_vec(ENV_ID, num_envs=4, vectorization_mode=mode, budget=2)
    try:
        vec.action_space.seed(0)
        obs, _ = vec.reset(seed=1)
        for expect_truncated in (False, True):
            obs, reward, terminated, truncated, info = vec.step(vec.action_space.sample())
            assert vec.observation_space.contains(obs) and obs.shape == (4, 16)
            assert np.all(np.isfinite(reward)) and len(set(reward)) == 4
            assert not terminated.any() and (truncated == expect_truncated).all()
            assert info["_cost"].all() and np.all(info["cost"] == -reward)
    finally:
        vec.close()


@pytest.mark.parametrize("start_method", [None, "fork"])
def test_ppo_trains_through_subproc_vec_env(start_method):
    # SB3's default start method (forkserver where available) starts fresh interpreters: the
    # "module:id" form makes gymnasium import inertia_gym (and so register the env) there.
    # "fork" children inherit the parent, which has run the parallel loop (fork-safe layer).
    vec = make_vec_env(f"inertia_gym:{ENV_ID}", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv,
                       env_kwargs={"budget": 8}, vec_env_kwargs={"start_method": start_method})
    try:
        model = PPO("MlpPolicy", vec, n_steps=4, batch_size=8, n_epochs=1, seed=0, device="cpu")
        model.set_logger(Logger(folder=None, output_formats=[]))  # not an SB3-<time> folder in /tmp
        model.learn(total_timesteps=8)
        assert model.num_timesteps == 8
    finally:
        vec.close()
