import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import inertia_gym  # noqa: F401  (registers the env)
from inertia_gym.envs import ENV_ID
from inertia_gym.envs.excitation import (
    OBS_SIZE,
    ExcitationEnv,
    ResetNeededError,
    action_to_xi,
    xi_to_action,
)
from inertia_gym.errors import ConfigError, InertiaGymError
from inertia_gym.scenario import Scenario

ACTION = np.array([0.5, 1.0, 1.0], dtype=np.float32)


def rollout(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, reward, *_ = env.step(a)
        out.append(np.append(obs, reward))
    return out


def test_registered_with_time_limit_at_budget():
    env = gym.make(ENV_ID)
    assert env.spec.max_episode_steps == 100
    env = gym.make(ENV_ID, budget=3, max_episode_steps=3)
    env.reset(seed=0)
    flags = [env.step(ACTION)[3] for _ in range(3)]
    assert flags == [False, False, True]


def test_gymnasium_and_sb3_checkers_pass():
    gym_check_env(gym.make(ENV_ID).unwrapped, skip_render_check=True)
    sb3_check_env(ExcitationEnv(), warn=True)


def test_spaces_and_info():
    env = gym.make(ENV_ID)
    assert env.action_space == gym.spaces.Box(-1, 1, (3,), np.float32)
    obs, info = env.reset(seed=3)
    assert obs.shape == (OBS_SIZE,) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    assert info["rel_error"] > 0.5  # the paper's initial guess is far from the truth
    obs, reward, terminated, truncated, info = env.step(ACTION)
    assert env.observation_space.contains(obs)
    assert reward == pytest.approx(-info["cost"]) and info["cost"] == info["info_cost"]
    assert info["theta_hat"].shape == (6,) and info["p_theta_eigvals"].shape == (6,)
    assert np.all(np.diff(info["p_theta_eigvals"]) >= 0)
    np.testing.assert_allclose(info["xi"], action_to_xi(Scenario(), ACTION))
    assert 40 < info["duration"] < 90 and info["time"] == info["duration"]
    assert 0 < info["rel_error"] < 0.5 and not terminated and not truncated
    assert obs[-1] == pytest.approx(0.01)  # progress 1/100


def test_posterior_cost_option():
    env = gym.make(ENV_ID, cost="posterior")
    env.reset(seed=0)
    _, reward, *_, info = env.step(ACTION)
    assert reward == pytest.approx(-info["posterior_cost"]) and info["posterior_cost"] < 0


def test_deterministic_under_seed_and_seed_matters():
    env = gym.make(ENV_ID)
    actions = [ACTION, -ACTION, np.zeros(3, np.float32)]
    a = rollout(env, 11, actions)
    b = rollout(env, 11, actions)
    c = rollout(env, 12, actions)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert not np.allclose(a[-1], c[-1])


def test_estimator_state_carries_over():
    env = gym.make(ENV_ID)
    env.reset(seed=5)
    first = env.step(ACTION)[4]
    second = env.step(ACTION)[4]
    assert second["time"] == pytest.approx(first["duration"] + second["duration"])
    assert second["rel_error"] < first["rel_error"]
    restart = gym.make(ENV_ID, carry_over=False)
    restart.reset(seed=5)
    restart.step(ACTION)
    fresh = restart.step(ACTION)[4]
    assert fresh["rel_error"] > second["rel_error"]


def test_make_vec_and_pickle():
    venv = gym.make_vec(ENV_ID, num_envs=2)
    obs, _ = venv.reset(seed=[1, 2])
    obs, rewards, *_ = venv.step(np.stack([ACTION, ACTION]))
    assert obs.shape == (2, OBS_SIZE) and np.all(np.isfinite(rewards))
    assert rewards[0] != rewards[1]
    env = ExcitationEnv()
    env.reset(seed=4)
    env.step(ACTION)
    clone = pickle.loads(pickle.dumps(env))
    np.testing.assert_array_equal(env.step(ACTION)[0], clone.step(ACTION)[0])


@pytest.mark.parametrize("action, match", [
    ([np.nan, 0, 0], "finite"),
    ([0, np.inf, 0], "finite"),
    ([1.5, 0, 0], r"\[-1, 1\]"),
    ([0, -1.01, 0], r"\[-1, 1\]"),
    ([0, 0], "shape"),
])
def test_invalid_actions_raise(action, match):
    env = gym.make(ENV_ID)
    env.reset(seed=0)
    with pytest.raises(ConfigError, match=match):
        env.step(np.array(action, dtype=np.float32))


def test_step_before_reset_raises():
    with pytest.raises(ResetNeededError, match="reset"):
        ExcitationEnv().step(ACTION)
    with pytest.raises(gym.error.ResetNeeded):
        gym.make(ENV_ID).step(ACTION)
    assert issubclass(ResetNeededError, InertiaGymError)


@pytest.mark.parametrize("seed", [-1, 1.5, "7", True, np.float64(2.0)])
def test_invalid_seeds_raise(seed):
    with pytest.raises(ConfigError, match="seed"):
        ExcitationEnv().reset(seed=seed)


@pytest.mark.parametrize("kwargs, match", [
    ({"cost": "fisher"}, "cost"), ({"budget": 0}, "budget"), ({"scenario": 3.0}, "Scenario"),
    ({"scenario": {"tau_mx": 1.0}}, "unknown scenario field"), ({"scenario": "absent.toml"}, "exist"),
])
def test_invalid_constructor_arguments(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        ExcitationEnv(**kwargs)


def test_action_rescaling_round_trip():
    sc = Scenario()
    lo, hi = sc.xi_bounds
    np.testing.assert_allclose(action_to_xi(sc, -np.ones(3)), lo)
    np.testing.assert_allclose(action_to_xi(sc, np.ones(3)), hi)
    xi = lo + np.array([0.2, 0.7, 0.4]) * (hi - lo)
    np.testing.assert_allclose(action_to_xi(sc, xi_to_action(sc, xi)), xi, rtol=1e-6)


def test_observation_is_scale_free():
    """A body 100x lighter with 100x smaller torques tumbles the same: same observations."""
    paper, s = Scenario(), 0.01
    small = paper.replace(
        inertia_true=(np.array(paper.inertia_true) * s).tolist(),
        inertia_guess=(np.array(paper.inertia_guess) * s).tolist(),
        P0_theta=(np.array(paper.P0_theta) * s**2).tolist(), Q_theta=paper.Q_theta * s**2,
        tau_max=paper.tau_max * s,
    )
    a = rollout(ExcitationEnv(paper), 0, [ACTION])
    b = rollout(ExcitationEnv(small), 0, [ACTION])
    np.testing.assert_allclose(a[0], b[0], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(a[1][:OBS_SIZE - 7], b[1][:OBS_SIZE - 7], rtol=1e-3, atol=1e-3)


def test_divergence_terminates_with_finite_cost(monkeypatch):
    import dataclasses

    from inertia_gym.envs import excitation

    real = excitation.run_episode

    def diverging(sc, state, xi, rngs, cost):
        new_state, (res,) = real(sc, state, xi, rngs, cost=cost)
        new_state = dataclasses.replace(new_state, diverged=np.array([True]))
        return new_state, [dataclasses.replace(res, diverged=True, cost=np.inf)]

    monkeypatch.setattr(excitation, "run_episode", diverging)
    env = ExcitationEnv()
    env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(ACTION)
    assert terminated and not truncated and info["diverged"]
    assert reward == -excitation.divergence_cost(env.scenario, "info") == np.log(1e-8)
    assert np.all(obs == 0)
    with pytest.raises(ResetNeededError):
        env.step(ACTION)


def test_scenario_may_be_a_mapping_or_a_file(tmp_path):
    assert ExcitationEnv(scenario={"tau_max": 2.0}).scenario == Scenario(tau_max=2.0)
    path = tmp_path / "sc.toml"
    path.write_text("tau_max = 3.0\n")
    assert ExcitationEnv(scenario=str(path)).scenario == Scenario(tau_max=3.0)
    assert ExcitationEnv(scenario=path).scenario == Scenario(tau_max=3.0)


def test_budget_truncates_the_episode():
    env = ExcitationEnv(budget=2)
    env.reset(seed=0)
    flags = [env.step(ACTION)[2:4] for _ in range(2)]
    assert flags == [(False, False), (False, True)]
