"""The native vector env against B single envs and SyncVectorEnv, seeded the same way.

Every run of the batch draws from its own Generator in the same order as a single env, and the
compiled loop advances each run with the same code whether the batch has 1 or B runs, so the
results are compared for exact equality (not to a tolerance).
"""

import dataclasses
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import DictInfoToList, RecordEpisodeStatistics

from inertia_gym.envs import ENV_ID, ExcitationEnv, ExcitationVectorEnv, excitation
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario

B = 3


def random_actions(steps, seed=0):
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1, 1, (B, 3)).astype(np.float32) for _ in range(steps)]


def rollout(venv, seed, actions):
    out = [venv.reset(seed=seed)]
    out += [venv.step(a) for a in actions]
    venv.close()
    return out


def assert_same_rollouts(a, b):
    assert len(a) == len(b)
    for k, (x, y) in enumerate(zip(a, b)):
        assert data_equivalence(x, y, exact=True), f"step {k} differs:\n{x}\n{y}"


@pytest.mark.parametrize("kwargs", [
    {"budget": 2},  # truncation at the budget, then autoreset, twice
    {"cost": "posterior", "carry_over": False, "budget": 5},
    {"budget": 10, "max_episode_steps": 2},  # the TimeLimit of gym.make, in the vector env
])
def test_matches_sync_vector_env_exactly(kwargs):
    actions = random_actions(5)
    native = gym.make_vec(ENV_ID, num_envs=B, vectorization_mode="vector_entry_point", **kwargs)
    sync = gym.make_vec(ENV_ID, num_envs=B, vectorization_mode="sync", **kwargs)
    assert isinstance(native.unwrapped, ExcitationVectorEnv)
    a, b = rollout(native, 7, actions), rollout(sync, 7, actions)
    assert_same_rollouts(a, b)
    ends = np.array([terminated | truncated for _, _, terminated, truncated, _ in a[1:]])
    assert ends.any(), "the rollout must cross an autoreset"


def test_matches_single_envs_seeded_the_same():
    actions = random_actions(2, seed=1)
    for action in actions:
        action[2] = action[0]
    venv = ExcitationVectorEnv(num_envs=B, scenario={"tau_max": 3.0})
    seeds = [11, 4, 11]  # a repeated seed (and actions) gives the same run
    obs, info = venv.reset(seed=seeds)
    singles = [ExcitationEnv(scenario={"tau_max": 3.0}) for _ in range(B)]
    for i, env in enumerate(singles):
        single_obs, single_info = env.reset(seed=seeds[i])
        np.testing.assert_array_equal(obs[i], single_obs)
        assert single_info["rel_error"] == info["rel_error"][i]
    for action in actions:
        obs, reward, terminated, truncated, info = venv.step(action)
        for i, env in enumerate(singles):
            s_obs, s_reward, s_term, s_trunc, s_info = env.step(action[i])
            np.testing.assert_array_equal(obs[i], s_obs)
            assert (reward[i], terminated[i], truncated[i]) == (s_reward, s_term, s_trunc)
            for key, value in s_info.items():
                np.testing.assert_array_equal(info[key][i], value, err_msg=key)
                assert info[f"_{key}"][i]
    np.testing.assert_array_equal(obs[0], obs[2])
    assert not np.array_equal(obs[0], obs[1])


def doom_first_episode(monkeypatch, doomed):
    """Make the first episode of each Generator in `doomed` diverge, in every env."""
    real, seen = excitation.run_episode, set()

    def diverging(sc, state, xi, rngs, cost):
        new_state, results = real(sc, state, xi, rngs, cost=cost)
        hit = np.array([any(r is d for d in doomed) and id(r) not in seen for r in rngs])
        seen.update(id(r) for r in rngs)
        results = [dataclasses.replace(res, diverged=True, cost=np.inf) if h else res
                   for res, h in zip(results, hit)]
        return dataclasses.replace(new_state, diverged=new_state.diverged | hit), results

    monkeypatch.setattr(excitation, "run_episode", diverging)


def test_divergence_terminates_one_env_and_autoresets_it_next_step(monkeypatch):
    actions = random_actions(3, seed=2)
    native = ExcitationVectorEnv(num_envs=B, budget=5)
    sync = gym.make_vec(ENV_ID, num_envs=B, vectorization_mode="sync", budget=5)
    a, b = [native.reset(seed=0)], [sync.reset(seed=0)]
    doom_first_episode(monkeypatch, [native.np_random[1], sync.envs[1].unwrapped.np_random])
    a += [native.step(x) for x in actions]
    b += [sync.step(x) for x in actions]
    assert_same_rollouts(a, b)
    obs, reward, terminated, truncated, info = a[1]
    assert terminated.tolist() == [False, True, False] and not truncated.any()
    assert np.all(obs[1] == 0) and reward[1] == -excitation.divergence_cost(Scenario(), "info")
    obs, reward, terminated, truncated, info = a[2]  # env 1 reset, its action ignored
    assert reward[1] == 0 and not terminated[1] and info["_cost"].tolist() == [True, False, True]
    assert info["_time"].all() and info["time"][1] == 0 and obs[1, -1] == 0
    assert a[3][4]["_cost"].all() and a[3][0][1, -1] == pytest.approx(1 / 5)


def test_reset_mask_resets_only_those_envs_as_sync_does():
    actions = random_actions(2, seed=3)
    mask = np.array([True, False, True])
    outcomes = []
    for mode in ("vector_entry_point", "sync"):
        venv = gym.make_vec(ENV_ID, num_envs=B, vectorization_mode=mode)
        rollout = [venv.reset(seed=1), venv.step(actions[0]),
                   venv.reset(seed=20, options={"reset_mask": mask.copy()}), venv.step(actions[1])]
        outcomes.append(rollout)
    assert_same_rollouts(*outcomes)
    obs, info = outcomes[0][2]
    assert info["_time"].tolist() == mask.tolist() and obs[1, -1] == pytest.approx(0.01)
    assert np.all(obs[mask, -1] == 0)


def test_make_vec_defaults_to_the_native_env_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        venv = gym.make_vec(ENV_ID, num_envs=2)
    assert isinstance(venv, ExcitationVectorEnv) and venv.max_episode_steps == 100
    assert venv.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert venv.spec.kwargs["vectorization_mode"] == "vector_entry_point"
    single = gym.make(ENV_ID)
    assert venv.single_observation_space == single.observation_space
    assert venv.single_action_space == single.action_space
    assert venv.action_space.shape == (2, 3) and venv.observation_space.shape == (2, 16)


def test_gymnasium_vector_wrappers_run_over_it():
    venv = DictInfoToList(RecordEpisodeStatistics(ExcitationVectorEnv(num_envs=2, budget=2)))
    venv.action_space.seed(0)
    obs, infos = venv.reset(seed=3)
    assert venv.observation_space.contains(obs) and len(infos) == 2
    returns = []
    for _ in range(2):
        obs, reward, terminated, truncated, infos = venv.step(venv.action_space.sample())
        returns.append(reward)
        assert venv.observation_space.contains(obs)
    assert truncated.all() and not terminated.any()
    episode = infos[0]["episode"]
    assert episode["l"] == 2 and episode["r"] == pytest.approx(returns[0][0] + returns[1][0])


def test_seeding_rules():
    venv = ExcitationVectorEnv(num_envs=2)
    first, _ = venv.reset(seed=5)
    same, _ = venv.reset(seed=[5, 6])
    np.testing.assert_array_equal(first, same)
    venv.reset(seed=None)  # keeps the Generators: continues their streams
    generators = venv.np_random
    venv.reset(seed=[None, 9])
    assert venv.np_random[0] is generators[0] and venv.np_random[1] is not generators[1]
    assert venv.np_random_seed[1] == 9


@pytest.mark.parametrize("seed, match", [(-1, "seed"), (1.5, "seed"), ([1, 2, 3], "2 seeds"),
                                         ([1, "x"], "seed")])
def test_invalid_seeds_raise(seed, match):
    with pytest.raises(ConfigError, match=match):
        ExcitationVectorEnv(num_envs=2).reset(seed=seed)


@pytest.mark.parametrize("kwargs, match", [
    ({"num_envs": 0}, "num_envs"), ({"cost": "fisher"}, "cost"), ({"budget": 0}, "budget"),
    ({"max_episode_steps": 0}, "max_episode_steps"), ({"scenario": 3.0}, "Scenario"),
])
def test_invalid_constructor_arguments(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        ExcitationVectorEnv(**kwargs)


@pytest.mark.parametrize("mask", [np.array([1, 0]), np.array([False, False]), np.array([True]),
                                  [True, False]])
def test_invalid_reset_masks_raise(mask):
    venv = ExcitationVectorEnv(num_envs=2)
    with pytest.raises(gym.error.ResetNeeded):
        venv.reset(options={"reset_mask": np.array([True, False])})
    venv.reset(seed=0)
    with pytest.raises(ConfigError, match="reset_mask"):
        venv.reset(options={"reset_mask": mask})


def test_invalid_actions_raise_and_leave_the_envs_unchanged():
    venv = ExcitationVectorEnv(num_envs=2)
    with pytest.raises(gym.error.ResetNeeded):
        venv.step(np.zeros((2, 3)))
    venv.reset(seed=0)
    with pytest.raises(ConfigError, match=r"shape \(2, 3\)"):
        venv.step(np.zeros(3))
    with pytest.raises(ConfigError, match="finite"):
        venv.step(np.array([[0, 0, 0], [np.nan, 0, 0]]))
    obs, *_ = venv.step(np.zeros((2, 3)))
    reference = ExcitationVectorEnv(num_envs=2)
    reference.reset(seed=0)
    np.testing.assert_array_equal(obs, reference.step(np.zeros((2, 3)))[0])
