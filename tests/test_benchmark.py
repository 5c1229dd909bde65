import csv
import json

import numpy as np
import pytest

from inertia_gym.agents.random_search import RandomAgent
from inertia_gym.benchmark import (
    GRID,
    SweepSettings,
    Task,
    dense_grid,
    reevaluate,
    run_task,
    summarize,
    sweep_tasks,
    win_rate,
)
from inertia_gym.benchmark_report import explanation, table_markdown, write_report
from inertia_gym.envs.excitation import xi_to_action
from inertia_gym.errors import ConfigError
from inertia_gym.optimization import evaluate_many, optimize, recommendation_checkpoints
from inertia_gym.plots import moving_mean
from inertia_gym.scenario import Scenario
from inertia_gym.validation import validate

TINY = dict(budget=10, eval_seeds=(10_000, 10_001), val_seeds=(0, 1), val_duration=150.0,
            grid_points=2)


@pytest.fixture(scope="module")
def tiny():
    return SweepSettings(scenario=Scenario(), **TINY)


def test_dense_grid_spans_the_bounds_of_xi(paper):
    g = dense_grid(paper, 3)
    lo, hi = paper.xi_bounds
    assert g.shape == (27, 3)
    assert np.all(g >= lo - 1e-12) and np.all(g <= hi + 1e-12)
    for axis in range(3):
        np.testing.assert_allclose(np.unique(g[:, axis]), np.linspace(lo[axis], hi[axis], 3))
    assert len({tuple(x) for x in g}) == 27


def test_reevaluate_is_the_mean_from_start_cost_in_any_chunking(paper):
    xis = dense_grid(paper, 2)[:5]
    seeds = [3, 4, 5]
    costs, errors = evaluate_many(paper, xis, seeds)
    got = reevaluate(paper, xis, seeds)
    np.testing.assert_allclose(got.cost, costs.mean(axis=1), rtol=1e-12)
    np.testing.assert_allclose(got.rel_error, np.median(errors, axis=1), rtol=1e-12)
    assert np.all(got.within == 1.0) and np.all(got.impulse >= 0) and got.impulse.max() > 0


def test_sweep_tasks_put_the_grid_first_and_give_each_agent_every_seed():
    tasks = sweep_tasks(["bo", "grid", "random", "bo"], 3)
    assert tasks[0] == Task(GRID, None)
    assert [t.name for t in tasks[1:]] == ["bo-seed0", "random-seed0", "bo-seed1",
                                          "random-seed1", "bo-seed2", "random-seed2"]
    with pytest.raises(ConfigError, match="agents"):
        sweep_tasks(["bo", "cmaes"], 2)
    with pytest.raises(ConfigError, match="agents"):
        sweep_tasks([], 2)
    with pytest.raises(ConfigError, match="seed"):
        Task("bo", None)


@pytest.mark.parametrize("field, value", [
    ("budget", 0), ("budget", 2.5), ("grid_points", 1), ("eval_seeds", ()),
    ("val_seeds", (-1,)), ("val_duration", 0.0), ("val_duration", float("nan")),
    ("cost", "fisher"),
])
def test_settings_reject_bad_values(field, value):
    with pytest.raises(ConfigError, match=field):
        SweepSettings(scenario=Scenario(), **{**TINY, field: value})


def test_settings_key_changes_with_anything_that_changes_a_result(tiny):
    assert SweepSettings.from_json(json.loads(json.dumps(tiny.to_json()))) == tiny
    assert SweepSettings(scenario=Scenario(), **TINY).key() == tiny.key()
    others = [SweepSettings(scenario=Scenario(), **{**TINY, "budget": 11}),
              SweepSettings(scenario=Scenario(), **TINY, carry_over=True),
              SweepSettings(scenario=Scenario(), **TINY, cost="info"),
              SweepSettings(scenario=Scenario(tau_max=4.0), **TINY)]
    assert len({tiny.key(), *(o.key() for o in others)}) == 5


def test_agent_task_scores_its_xi_by_the_definitions(tiny):
    rec = run_task(tiny, Task("random", 1))
    again = optimize("random", tiny.scenario, tiny.budget, 1, cost=tiny.cost,
                     carry_over=tiny.carry_over)
    assert rec["costs"] == pytest.approx(list(again.costs), rel=1e-12)
    assert rec["xi_star"] == pytest.approx(list(again.xi_star))
    assert rec["cost_star"] == pytest.approx(again.cost_star, rel=1e-9)
    assert rec["xi_observed_best"] == pytest.approx(rec["xis"][int(np.argmin(rec["costs"]))])
    assert rec["best_cost"] == pytest.approx(min(rec["costs"]))
    costs, _ = evaluate_many(tiny.scenario, np.array([rec["xi_star"], rec["xi_observed_best"]]),
                             tiny.eval_seeds, tiny.cost)
    assert rec["reeval_cost"] == pytest.approx(costs[0].mean(), rel=1e-12)
    assert rec["reeval_cost_observed_best"] == pytest.approx(costs[1].mean(), rel=1e-12)
    assert rec["xi_recommended"] == rec["xi_star"]
    assert rec["reeval_cost_recommended"] == rec["reeval_cost"]
    # The learning curve: the recommendation after the first i evaluations, re-evaluated.
    curve = rec["recommended_curve"]
    assert curve["evaluations"][-1] == tiny.budget and curve["reeval_cost"][-1] == rec["reeval_cost"]
    i = curve["evaluations"][0]
    agent = RandomAgent(1)
    first, _ = agent.recommend([xi_to_action(tiny.scenario, x) for x in rec["xis"][:i]],
                               rec["costs"][:i])
    c, _ = evaluate_many(tiny.scenario, np.array([rec["xis"][first]]), tiny.eval_seeds, tiny.cost)
    assert curve["reeval_cost"][0] == pytest.approx(c[0].mean(), rel=1e-12)
    val = validate(tiny.scenario, np.array(rec["xi_star"]), tiny.val_duration, tiny.val_seeds,
                   record_torque=False)
    assert rec["val_rel_error"] == pytest.approx(float(np.median(val.rel_errors)), rel=1e-12)
    assert rec["val_diverged"] == 0 and rec["settings_key"] == tiny.key()
    assert json.loads(json.dumps(rec)) == rec  # plain JSON types only


def test_grid_task_keeps_the_best_grid_point(tiny):
    rec = run_task(tiny, Task(GRID, None))
    xis = dense_grid(tiny.scenario, tiny.grid_points)
    costs, _ = evaluate_many(tiny.scenario, xis, tiny.eval_seeds, tiny.cost)
    best = int(np.argmin(costs.mean(axis=1)))
    assert rec["n_points"] == 8
    assert rec["xi_star"] == pytest.approx(list(xis[best]))
    assert rec["reeval_cost"] == pytest.approx(costs.mean(axis=1)[best], rel=1e-12)
    assert [t[3] for t in rec["top"]] == sorted(t[3] for t in rec["top"])


def test_under_a_budget_the_grid_and_the_agents_pick_designs_within_it(tmp_path):
    """The grid's optimum fires as designed on every seed, its trade-off curve spans the grid's
    impulse, and the report adds the limit columns and the trade-off plot."""
    settings = SweepSettings(scenario=Scenario.load("paper-budget"),
                             **{**TINY, "grid_points": 3, "val_duration": 100.0})
    grid = run_task(settings, Task(GRID, None))
    scores = reevaluate(settings.scenario, dense_grid(settings.scenario, 3), settings.eval_seeds,
                        settings.cost)
    within = scores.within == 1.0
    assert 0 < within.sum() < len(within)  # the budget cuts some grid points and not others
    assert grid["reeval_cost"] == pytest.approx(scores.cost[within].min(), rel=1e-12)
    assert grid["within_limits_star"] == 1.0 and 0 < grid["impulse_star"] <= 13.0
    assert len(grid["grid"]) == 27
    impulses = [row[3] for row in grid["tradeoff"]]
    assert impulses == sorted(impulses) and len(impulses) >= 3
    rec = run_task(settings, Task("random", 0))
    assert 0 <= rec["within_limits_star"] <= 1 and 0 < rec["impulse_star"] <= 13.0 + 1e-9
    report = write_report(tmp_path, settings, ["random"], 1, [grid, rec])
    summary = (tmp_path / "summary.md").read_text()
    assert "xi* within the limits" in summary and "13 N·m·s" in summary
    assert "bootstrap intervals of the median regret" not in summary  # one seed: no interval
    assert (tmp_path / "tradeoff.png").stat().st_size > 10_000
    row = next(csv.DictReader((tmp_path / "benchmark.csv").open()))
    assert float(row["impulse_star"]) == pytest.approx(rec["impulse_star"])
    assert report["summary"]["agents"]["random"]["within_limits"] in (0.0, 1.0)


def test_median_interval_brackets_the_median_and_narrows_with_more_seeds():
    """The bootstrap interval of a median over seeds: it holds the sample median, it is the same
    on every call (fixed resampling seed), and over 40 draws of normal samples it covers the true
    median 0 on about 95 % (at least 34 of 40 asked) and narrows about as 1/sqrt(n)."""
    from inertia_gym.benchmark import median_interval

    rng = np.random.default_rng(3)
    widths, covered = {16: [], 64: []}, 0
    for _ in range(40):
        for n in widths:
            v = rng.standard_normal(n)
            lo, hi = median_interval(v)
            assert lo <= np.median(v) <= hi and median_interval(v) == [lo, hi]
            widths[n].append(hi - lo)
            covered += n == 16 and lo <= 0.0 <= hi
    assert covered >= 34
    assert 1.4 < np.median(widths[16]) / np.median(widths[64]) < 2.8
    assert median_interval([1.0]) is None and median_interval([None, 2.0]) is None


def _rec(agent, seed, reeval, best=1.0, val=0.01):
    return {"agent": agent, "seed": seed, "reeval_cost": reeval,
            "reeval_cost_observed_best": reeval + 0.5, "best_cost": best, "val_rel_error": val,
            "val_diverged": 0, "wall_s": 1.0}


def test_win_rate_counts_ties_half_and_only_shared_seeds():
    a = {0: _rec("a", 0, 1.0), 1: _rec("a", 1, 2.0), 2: _rec("a", 2, 3.0), 5: _rec("a", 5, 0.0)}
    b = {0: _rec("b", 0, 1.5), 1: _rec("b", 1, 2.0), 2: _rec("b", 2, 2.0)}
    assert win_rate(a, b) == pytest.approx((1 + 0.5 + 0) / 3)
    assert win_rate(b, a) == pytest.approx((0 + 0.5 + 1) / 3)
    assert win_rate(a, {}) is None


def test_summary_states_regret_against_the_grid_optimum():
    grid = {"agent": GRID, "seed": None, "reeval_cost": 0.25, "n_points": 8}
    recs = [_rec("bo", s, c) for s, c in enumerate([1.0, 2.0, 3.0, 4.0])]
    recs += [_rec("random", s, c) for s, c in enumerate([2.0, 3.0, 4.0, 5.0])]
    s = summarize([grid, *recs])
    assert s["reference_cost"] == 0.25 and s["grid"] is grid
    regret = s["agents"]["bo"]["regret"]
    expected = np.array([1.0, 2.0, 3.0, 4.0]) - 0.25
    assert regret["median"] == pytest.approx(np.median(expected))
    assert regret["q25"] == pytest.approx(np.quantile(expected, 0.25))
    assert regret["q75"] == pytest.approx(np.quantile(expected, 0.75))
    assert s["agents"]["bo"]["regret_observed_best"]["median"] == pytest.approx(
        np.median(expected) + 0.5)
    assert s["agents"]["bo"]["win_rate"]["random"] == 1.0
    assert s["agents"]["bo"]["win_seeds"] == {"random": 4}
    assert s["agents"]["random"]["win_rate"]["bo"] == 0.0
    no_grid = summarize(recs)
    assert no_grid["reference_cost"] is None and no_grid["agents"]["bo"]["regret"] is None


def test_report_explains_regret_the_grid_row_and_the_seeds_behind_win_rates(tiny):
    grid = {"agent": GRID, "seed": None, "reeval_cost": 0.25, "n_points": 8,
            "val_rel_error": 0.15, "wall_s": 3.0}
    recs = [_rec("bo", s, c) for s, c in enumerate([1.0, 2.0, 3.0])]
    recs += [_rec("random", s, c) for s, c in enumerate([2.0, 3.0])]
    s = summarize([grid, *recs])
    table = table_markdown(s)
    assert "| grid (8 xi) | 1 | – | 0.25 | 0 (the reference) |" in table
    assert "| bo | – | 1.00 (2) |" in table and "| random | 0.00 (2) | – |" in table
    lo, hi = s["agents"]["bo"]["regret_median_ci95"]
    assert lo <= s["agents"]["bo"]["regret"]["median"] <= hi
    assert f"median regret of xi*: bo [{lo:.3g}, {hi:.3g}]" in table
    text = explanation(tiny, s)
    assert "**regret** = re-evaluated cost" in text and "**the grid row**" in text
    assert f"{8 * len(tiny.eval_seeds)} episodes" in text
    assert "win rates** rest on 2 seed(s)" in text and "(0.5 here)" in text
    assert "grid row" not in explanation(tiny, summarize(recs))


def test_moving_mean_is_the_mean_of_the_last_window_costs():
    rng = np.random.default_rng(0)
    costs = rng.normal(size=(3, 25))
    got = moving_mean(costs, window=10)
    for i in range(25):
        np.testing.assert_allclose(got[:, i], costs[:, max(0, i - 9):i + 1].mean(axis=1),
                                   rtol=1e-12)


@pytest.mark.parametrize("budget, expected", [(1, [1]), (2, [2]), (5, [2, 3, 4, 5]),
                                              (100, [2, 3, 6, 11, 19, 33, 57, 100])])
def test_recommendation_checkpoints_end_at_the_budget(budget, expected):
    assert recommendation_checkpoints(budget).tolist() == expected
