import json

import numpy as np
import pytest

from inertia_gym.agents.bo import posterior_best
from inertia_gym.cli import main
from inertia_gym.envs.excitation import xi_to_action
from inertia_gym.errors import ConfigError
from inertia_gym.optimization import (
    AGENTS,
    DEFAULT_CARRY_OVER,
    DEFAULT_COST,
    OptimizationResult,
    evaluate_many,
    evaluate_xi,
    optimize,
    validated_error,
)
from inertia_gym.scenario import Scenario
from inertia_gym.validation import validate

CONTRACT_KEYS = {"agent", "budget", "seed", "xi_star", "cost_star", "costs", "wall_s"}
ADDED_KEYS = {"cost_kind", "carry_over", "xis", "rel_errors", "recommendation", "xi_recommended",
              "xi_observed_best", "cost_observed_best"}


@pytest.fixture(scope="module")
def random_run():
    """Algorithm 1 as the paper runs it: carry-over, info cost."""
    return optimize("random", Scenario(), 6, seed=2, cost="info", carry_over=True)


def test_result_recommends_xi_and_keeps_the_observed_best(random_run):
    r = random_run
    assert isinstance(r, OptimizationResult) and r.agent == "random" and r.cost_kind == "info"
    assert r.carry_over is True
    assert r.costs.shape == (6,) and r.xis.shape == (6, 3) and r.rel_errors.shape == (6,)
    # Algorithm 1, line 24: the lowest observed cost, kept as the observed best.
    k = int(np.argmin(r.costs))
    np.testing.assert_array_equal(r.xi_observed_best, r.xis[k])
    assert r.cost_observed_best == r.costs[k] and r.wall_s > 0
    # xi*: the evaluated xi with the lowest GP posterior mean, cost* that posterior mean.
    actions = np.array([xi_to_action(Scenario(), x) for x in r.xis], dtype=float)
    index, mean = posterior_best(actions, r.costs, seed=2)
    assert r.star_index == index
    np.testing.assert_array_equal(r.xi_star, r.xis[index])
    assert r.cost_star == pytest.approx(mean, rel=1e-9)
    assert r.costs.min() - r.costs.std() < r.cost_star < r.costs.max() + r.costs.std()
    data = json.loads(json.dumps(r.to_json()))
    assert CONTRACT_KEYS | ADDED_KEYS <= set(data)
    assert data["costs"] == pytest.approx(list(r.costs))
    assert data["xi_recommended"] == data["xi_star"] and "GP posterior mean" in data["recommendation"]


def test_one_evaluation_recommends_itself():
    r = optimize("random", Scenario(), 1, seed=0)
    np.testing.assert_array_equal(r.xi_star, r.xis[0])
    assert r.cost_star == r.costs[0] == r.cost_observed_best


def test_default_objective_is_the_measured_one():
    assert (DEFAULT_COST, DEFAULT_CARRY_OVER) == ("posterior", False)
    r = optimize("random", Scenario(), 2, seed=0)
    assert r.cost_kind == "posterior" and r.carry_over is False
    # From the start every episode begins at the 104 %-off guess: one episode leaves ~20 %
    # (measured 0.198, 0.199), where carried over the estimate keeps improving (< 10 % below).
    assert r.rel_errors.min() > 0.1


def test_optimize_is_deterministic_under_seed(random_run):
    again = optimize("random", Scenario(), 6, seed=2, cost="info", carry_over=True)
    np.testing.assert_array_equal(again.costs, random_run.costs)
    np.testing.assert_array_equal(again.xi_star, random_run.xi_star)
    other = optimize("random", Scenario(), 6, seed=3, cost="info", carry_over=True)
    assert not np.allclose(other.costs, random_run.costs)


def test_validated_error_is_the_median_of_validate():
    sc = Scenario()
    xi = np.array([0.4, 4.0, 1.0])
    got = validated_error(sc, xi, 120.0, [0, 1, 2])
    ref = validate(sc, xi, 120.0, [0, 1, 2], record_torque=False)
    assert got["val_rel_errors"] == pytest.approx(list(ref.rel_errors), rel=1e-12)
    assert got["val_rel_error"] == pytest.approx(float(np.median(ref.rel_errors)), rel=1e-12)
    assert got["val_diverged"] == 0 and got["val_seeds"] == [0, 1, 2]
    assert got["val_duration"] == 120.0 and isinstance(got["val_scale_identified"], bool)
    assert validated_error(sc, None, 120.0, [0])["val_scale_identified"] is False


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


def test_cli_optimize_writes_contract_validation_and_plot(tmp_path, capsys):
    out = tmp_path / "opt"
    assert main(["optimize", "--agent", "random", "--budget", "3", "--seed", "1",
                 "--out", str(out), "--no-progress", "--val-seeds", "2",
                 "--val-duration", "100"]) == 0
    data = json.loads((out / "result.json").read_text())
    assert CONTRACT_KEYS | ADDED_KEYS <= set(data) and len(data["costs"]) == 3
    assert data["seed"] == 1 and data["cost_kind"] == "posterior" and data["carry_over"] is False
    val = validated_error(Scenario(), np.array(data["xi_star"]), 100.0, [0, 1])
    assert data["val_rel_error"] == pytest.approx(val["val_rel_error"], rel=1e-12)
    assert (out / "optimize.png").stat().st_size > 10_000
    printed = capsys.readouterr().out
    assert "xi* =" in printed and "validation of xi* over 100 s, 2 seeds: median inertia error" \
        in printed
    assert "impulses" not in data and "mission limits" not in printed  # none set


def test_cli_optimize_and_validate_report_the_mission_limits(tmp_path, capsys):
    out = tmp_path / "opt"
    assert main(["optimize", "--scenario", "paper-budget", "--agent", "random", "--budget", "4",
                 "--seed", "0", "--out", str(out), "--no-progress", "--val-seeds", "0"]) == 0
    data = json.loads((out / "result.json").read_text())
    sc = Scenario.load("paper-budget")
    assert len(data["impulses"]) == len(data["within_limits"]) == 4
    assert all(i <= sc.impulse_budget * (1 + 1e-12) for i in data["impulses"])
    assert data["within_limits"] == [d <= sc.impulse_budget for d in data["impulse_demands"]]
    star = data["xis"].index(data["xi_star"])
    assert data["within_limits"][star] or not any(data["within_limits"])
    assert "N·m·s per episode of the 13 allowed" in capsys.readouterr().out
    assert main(["validate", "--scenario", "paper-budget", "--xi", "0,3,1", "--seeds", "1",
                 "--duration", "100", "--out", str(tmp_path / "val")]) == 0
    result = json.loads((tmp_path / "val" / "result.json").read_text())
    assert 0 < result["impulse_used"][0] <= sc.impulse_budget and result["rate_peak"][0] > 10
    assert "mission limits: median impulse spent" in capsys.readouterr().out


def test_cli_optimize_runs_algorithm_1_on_request(tmp_path):
    out = tmp_path / "alg1"
    assert main(["optimize", "--agent", "random", "--budget", "2", "--carry-over", "--cost",
                 "info", "--val-seeds", "0", "--out", str(out), "--no-progress"]) == 0
    data = json.loads((out / "result.json").read_text())
    assert data["carry_over"] is True and data["cost_kind"] == "info"
    assert "val_rel_error" not in data


@pytest.mark.parametrize("argv", [["--budget", "0"], ["--seed", "-2"], ["--agent", "dqn"],
                                  ["--cost", "fisher"], ["--val-seeds", "-1"],
                                  ["--carry-over", "--restart-each-episode"]])
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
        bo = optimize("bo", sc, 50, seed, cost="info", carry_over=True)
        rs = optimize("random", sc, 50, seed, cost="info", carry_over=True)
        gaps.append(rs.costs[-20:].mean() - bo.costs[-20:].mean())
    assert min(gaps) > 0.25 and np.mean(gaps) > 0.8


def test_bo_recommendation_is_not_the_lucky_draw():
    """Fixed seed where they differ (measured: evaluation 12 recommended, 13 observed best)."""
    sc = Scenario()
    r = optimize("bo", sc, 16, seed=2)
    actions = np.array([xi_to_action(sc, x) for x in r.xis], dtype=float)
    index, mean = posterior_best(actions, r.costs, seed=2)
    assert index != int(np.argmin(r.costs))
    np.testing.assert_array_equal(r.xi_star, r.xis[index])
    assert r.cost_star == pytest.approx(mean, rel=1e-9) and r.cost_star > r.cost_observed_best
    np.testing.assert_array_equal(r.xi_observed_best, r.xis[int(np.argmin(r.costs))])
