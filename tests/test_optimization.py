import json

import numpy as np
import pytest

from inertia_gym.cli import main
from inertia_gym.errors import ConfigError
from inertia_gym.optimization import (
    AGENTS,
    OptimizationResult,
    evaluate_many,
    evaluate_xi,
    optimize,
)
from inertia_gym.scenario import Scenario

CONTRACT_KEYS = {"agent", "budget", "seed", "xi_star", "cost_star", "costs", "wall_s"}


@pytest.fixture(scope="module")
def random_run():
    return optimize("random", Scenario(), 6, seed=2)


def test_result_holds_algorithm_1_line_24(random_run):
    r = random_run
    assert isinstance(r, OptimizationResult) and r.agent == "random" and r.cost_kind == "info"
    assert r.costs.shape == (6,) and r.xis.shape == (6, 3) and r.rel_errors.shape == (6,)
    k = int(np.argmin(r.costs))
    np.testing.assert_array_equal(r.xi_star, r.xis[k])
    assert r.cost_star == r.costs[k] and r.wall_s > 0
    assert any(np.allclose(r.xi_recommended, x) for x in r.xis)
    data = json.loads(json.dumps(r.to_json()))
    assert CONTRACT_KEYS | {"cost_kind", "xis"} <= set(data)
    assert data["costs"] == pytest.approx(list(r.costs))


def test_optimize_is_deterministic_under_seed(random_run):
    again = optimize("random", Scenario(), 6, seed=2)
    np.testing.assert_array_equal(again.costs, random_run.costs)
    other = optimize("random", Scenario(), 6, seed=3)
    assert not np.allclose(other.costs, random_run.costs)


def test_estimator_converges_along_algorithm_1(random_run):
    # The initial guess is 104% off; six episodes of any torque bring it within 10%.
    assert random_run.rel_errors.max() < 0.5 and random_run.rel_errors[-1] < 0.1


def test_posterior_cost_option():
    r = optimize("random", Scenario(), 3, seed=0, cost="posterior")
    assert r.cost_kind == "posterior" and r.costs[0] < -10  # the first episode shrinks P a lot


@pytest.mark.parametrize("kwargs, match", [
    ({"agent": "grid"}, "agent"), ({"budget": 0}, "budget"), ({"budget": 2.5}, "budget"),
    ({"seed": -1}, "seed"), ({"seed": None}, "seed"), ({"cost": "fisher"}, "cost"),
])
def test_optimize_rejects_bad_arguments(kwargs, match):
    args = {"agent": "random", "sc": Scenario(), "budget": 2, "seed": 0, **kwargs}
    with pytest.raises(ConfigError, match=match):
        optimize(**args)


def test_evaluate_xi_batches_with_common_random_numbers():
    sc = Scenario()
    lo, hi = sc.xi_bounds
    xis = np.stack([hi, lo + 0.5 * (hi - lo)])
    costs, errors = evaluate_many(sc, xis, [5, 6, 7])
    assert costs.shape == errors.shape == (2, 3)
    np.testing.assert_allclose(evaluate_many(sc, xis[1:], [5, 6, 7])[0][0], costs[1])
    assert evaluate_xi(sc, xis[0], [5, 6, 7]) == pytest.approx(costs[0].mean())
    with pytest.raises(ConfigError, match="outside the bounds"):
        evaluate_xi(sc, hi * 2, [0])
    with pytest.raises(ConfigError, match="seeds"):
        evaluate_xi(sc, hi, [])
    with pytest.raises(ConfigError, match="seed"):
        evaluate_xi(sc, hi, [-3])


def test_cli_optimize_writes_contract_and_plot(tmp_path, capsys):
    out = tmp_path / "opt"
    assert main(["optimize", "--agent", "random", "--budget", "3", "--seed", "1",
                 "--out", str(out), "--no-progress", "--cost", "posterior"]) == 0
    data = json.loads((out / "result.json").read_text())
    assert CONTRACT_KEYS <= set(data) and len(data["costs"]) == 3 and data["seed"] == 1
    assert data["cost_kind"] == "posterior" and data["carry_over"] is True
    assert (out / "optimize.png").stat().st_size > 10_000
    assert "xi* =" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--budget", "0"], ["--seed", "-2"], ["--agent", "dqn"],
                                  ["--cost", "fisher"]])
def test_cli_optimize_rejects_bad_options(argv, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["optimize", "--out", str(tmp_path), *argv])
    assert exc.value.code == 2


def test_agents_tuple_is_the_contract():
    assert AGENTS == ("bo", "random", "sac", "td3", "ppo")


@pytest.mark.slow
def test_bo_exploits_algorithm_1_objective_better_than_random():
    """Fixed seeds, M = 50: BO's mean cost over its last 20 evaluations is lower than random
    search's on every seed (measured gaps 0.51, 0.81, 2.35, 1.35)."""
    sc = Scenario()
    gaps = []
    for seed in range(4):
        bo = optimize("bo", sc, 50, seed)
        rs = optimize("random", sc, 50, seed)
        gaps.append(rs.costs[-20:].mean() - bo.costs[-20:].mean())
    assert min(gaps) > 0.25 and np.mean(gaps) > 0.8
