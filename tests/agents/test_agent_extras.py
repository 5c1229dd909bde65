"""Agents whose packages come with an extra: without the extra, building one fails in one line
that names the missing package and the extra to install; the random agent needs none."""

import sys

import pytest

from inertia_gym import optimization
from inertia_gym.agents import make_agent
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario


@pytest.mark.parametrize(("agent", "package", "extra"),
                         [("bo", "botorch", "optimize"), ("ppo", "stable_baselines3", "rl")])
def test_an_agent_without_its_extra_names_the_extra_in_one_line(monkeypatch, agent, package, extra):
    monkeypatch.setitem(sys.modules, package, None)  # None in sys.modules: the import fails
    monkeypatch.delitem(sys.modules, f"inertia_gym.agents.{'bo' if extra == 'optimize' else 'sb3'}",
                        raising=False)
    with pytest.raises(ConfigError) as caught:
        make_agent(agent, seed=0, budget=4)
    message = str(caught.value)
    assert f"the {agent} agent needs {package}" in message
    assert f"pip install 'inertia-gym[{extra}]'" in message
    assert "\n" not in message


def test_the_random_agent_needs_no_extra(monkeypatch):
    for package in ("torch", "botorch", "gpytorch", "stable_baselines3"):
        monkeypatch.setitem(sys.modules, package, None)
    monkeypatch.delitem(sys.modules, "inertia_gym.agents.random_search", raising=False)
    agent = make_agent("random", seed=0, budget=4)
    assert agent.ask().shape == (3,)


def test_optimize_without_the_optimize_extra_stops_before_its_first_episode(monkeypatch):
    """Every agent's recommended xi is a GP's, so optimize needs the extra even with random search:
    it says so at once, not after the run."""
    monkeypatch.setitem(sys.modules, "botorch", None)
    monkeypatch.delitem(sys.modules, "inertia_gym.agents.bo", raising=False)
    built = []
    monkeypatch.setattr(optimization, "make_env", lambda *a, **k: built.append(a))
    with pytest.raises(ConfigError, match=r"pip install 'inertia-gym\[optimize\]'"):
        optimization.optimize("random", Scenario(), budget=3, seed=0)
    assert not built  # no env was built: the run had not started
