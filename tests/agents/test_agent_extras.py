"""Agents whose packages come with an extra: without the extra, building one fails in one line
that names the missing package and the extra to install; the random agent needs none."""

import sys

import pytest

from inertia_gym import optimization
from inertia_gym.agents import make_agent
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario


def _uninstalled(monkeypatch, *packages):
    """As if the packages were not installed: None in sys.modules makes their import fail, for
    the package and every submodule an earlier test imported."""
    for name in list(sys.modules):
        if name.split(".")[0] in packages:
            monkeypatch.setitem(sys.modules, name, None)
    for package in packages:
        monkeypatch.setitem(sys.modules, package, None)
    for module in ("inertia_gym.agents.bo", "inertia_gym.agents.sb3", "inertia_gym.agents.random_search"):
        monkeypatch.delitem(sys.modules, module, raising=False)


@pytest.mark.parametrize(("agent", "package", "extra"),
                         [("bo", "botorch", "optimize"), ("ppo", "stable_baselines3", "rl")])
def test_an_agent_without_its_extra_names_the_extra_in_one_line(monkeypatch, agent, package, extra):
    _uninstalled(monkeypatch, package)
    with pytest.raises(ConfigError) as caught:
        make_agent(agent, seed=0, budget=4)
    message = str(caught.value)
    assert f"the {agent} agent needs {package}" in message
    assert f"pip install -e '.[{extra}]'" in message and "torch==2.13.0" in message
    assert "\n" not in message


def test_the_random_agent_needs_no_extra(monkeypatch):
    _uninstalled(monkeypatch, "botorch", "gpytorch", "stable_baselines3")
    agent = make_agent("random", seed=0, budget=4)
    assert agent.ask().shape == (3,)


def test_optimize_without_the_optimize_extra_stops_before_its_first_episode(monkeypatch):
    """Every agent's recommended xi is a GP's, so optimize needs the extra even with random search:
    it says so at once, not after the run."""
    _uninstalled(monkeypatch, "botorch")
    built = []
    monkeypatch.setattr(optimization, "make_env", lambda *a, **k: built.append(a))
    with pytest.raises(ConfigError, match=r"pip install -e '\.\[optimize\]'"):
        optimization.optimize("random", Scenario(), budget=3, seed=0)
    assert not built  # no env was built: the run had not started
