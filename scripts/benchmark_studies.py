"""Studies of the excitation design's benchmark, one per sub-command.

bo-vs-random: BO against random search at equal budget, judged on fresh seeds and a dense grid.

Per objective mode ("restart": every evaluation one episode from the scenario's start, the
default; "carry": Algorithm 1's carry-over), one benchmark sweep of bo, random and the grid
reference through the library (inertia_gym.benchmark_store.run_sweep: resumable, one file per
run; inertia_gym.benchmark_report.write_report: benchmark.json, summary.md, plots) into
OUT/<mode>/. On top of the benchmark's scores, every evaluated xi of every run is re-evaluated
from the start on the benchmark's fresh seeds, giving the number of evaluations an agent needs
before it has evaluated a xi within 5 % of the grid optimum's cost.

cost-vs-error: does an episode's cost predict the final inertia error? Both cost options.

A. From the scenario's start: K Sobol xi, each run for one episode on S seeds (common random
   numbers); Spearman rank correlation of the episode's cost (info J, posterior change of
   log det P_theta) with (i) the relative inertia error at the episode's end, per (xi, seed)
   and over xi means, and (ii) the median error after a 1000 s validation of xi.
B. Along Algorithm 1 (carry-over): random xi for M episodes on a few seeds; Spearman of each
   episode's cost with the error at its end, episodes 11..M (after the start transient).

    python scripts/benchmark_studies.py bo-vs-random --seeds 16 --budget 100 --out runs/bo_vs_random
    python scripts/benchmark_studies.py cost-vs-error --xis 64 --seeds 8 --out runs/cost_vs_error
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from scipy.stats import spearmanr

import inertia_gym  # noqa: F401
from inertia_gym.benchmark import SweepSettings, reevaluate, sweep_tasks
from inertia_gym.benchmark_report import write_report
from inertia_gym.benchmark_store import run_sweep
from inertia_gym.envs import ENV_ID
from inertia_gym.optimization import DEFAULT_COST, evaluate_many
from inertia_gym.plots import plot_cost_vs_error
from inertia_gym.scenario import Scenario
from inertia_gym.validation import validate

AGENTS = ["bo", "random", "grid"]


def evals_to_within(true_costs, target) -> int | None:
    """First evaluation (1-based) whose running best re-evaluated cost reaches `target`."""
    hit = np.nonzero(np.minimum.accumulate(true_costs) <= target)[0]
    return int(hit[0]) + 1 if hit.size else None


def bo_vs_random(args) -> None:
    """BO, random search and the grid reference per objective mode, re-evaluated on fresh seeds."""
    sc = Scenario()
    overall = {}
    for mode in args.modes.split(","):
        out = Path(args.out) / mode
        out.mkdir(parents=True, exist_ok=True)
        settings = SweepSettings(scenario=sc, budget=args.budget, cost=args.cost,
                                 carry_over=(mode == "carry"), grid_points=args.grid)
        records = run_sweep(out, settings, sweep_tasks(AGENTS, args.seeds), workers=args.workers)
        report = write_report(out, settings, AGENTS, args.seeds, records)
        ref = report["summary"]["reference_cost"]
        target = ref + 0.05 * abs(ref)
        true_runs = []
        for r in report["runs"]:
            true_costs = reevaluate(sc, r["xis"], settings.eval_seeds, settings.cost).cost
            true_runs.append({**r, "costs": true_costs.tolist(),
                              "evals_to_5pct": evals_to_within(true_costs, target)})
        summary = {}
        for agent in ("bo", "random"):
            rows = [r for r in true_runs if r["agent"] == agent]
            evals = [r["evals_to_5pct"] or args.budget + 1 for r in rows]
            summary[agent] = {
                "median_evals_to_5pct (budget+1 = never)": float(np.median(evals)),
                "runs_reaching_5pct": sum(r["evals_to_5pct"] is not None for r in rows),
                "first_eval_is_observed_best": sum(int(np.argmin(r["costs"])) == 0
                                                   for r in report["runs"]
                                                   if r["agent"] == agent),
                **{k: report["summary"]["agents"][agent][k]
                   for k in ("reeval_cost", "regret", "regret_observed_best", "val_rel_error")},
            }
        summary["bo_win_rate"] = report["summary"]["agents"]["bo"]["win_rate"]["random"]
        overall[mode] = {"grid_cost": ref, "target_5pct": target, **summary}
        print(mode, json.dumps(overall[mode], indent=1), flush=True)
    (Path(args.out) / "bo_vs_random.json").write_text(json.dumps(overall, indent=1))


def rho(x, y):
    return float(spearmanr(np.ravel(x), np.ravel(y)).statistic)


def cost_vs_error(args) -> None:
    """The rank correlation of each episode cost with the inertia error, both cost options."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sc = Scenario()
    lo, hi = sc.xi_bounds
    u = torch.quasirandom.SobolEngine(3, scramble=True, seed=0).draw(args.xis).double().numpy()
    xis = lo + u * (hi - lo)
    seeds = list(range(20_000, 20_000 + args.seeds))
    costs, errs = {}, None
    for kind in ("info", "posterior"):
        c, e = [], []
        for i in range(0, len(xis), 32):
            ci, ei = evaluate_many(sc, xis[i:i + 32], seeds, cost=kind)
            c.append(ci)
            e.append(ei)
        costs[kind], errs = np.concatenate(c), np.concatenate(e)
    val_err = np.array([np.median(validate(sc, x, 1000.0, range(args.val_seeds),
                                           record_torque=False).rel_errors) for x in xis])
    report = {"A_from_start": {"n_xi": args.xis, "seeds": seeds}}
    for kind in ("info", "posterior"):
        report["A_from_start"][kind] = {
            "rho_episode_error_pooled": rho(costs[kind], errs),
            "rho_episode_error_xi_means": rho(costs[kind].mean(1), np.median(errs, 1)),
            "rho_validated_error_1000s": rho(costs[kind].mean(1), val_err),
        }
    # B: along Algorithm 1 with random xi.
    rows = {"info": [], "posterior": [], "err": []}
    for seed in range(args.runs):
        env = gym.make(ENV_ID, scenario=sc, budget=args.budget, max_episode_steps=args.budget,
                       carry_over=True)
        env.reset(seed=seed)
        rng = np.random.default_rng([seed, 99])
        for i in range(args.budget):
            *_, info = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
            if i >= 10:
                rows["info"].append(info["info_cost"])
                rows["posterior"].append(info["posterior_cost"])
                rows["err"].append(info["rel_error"])
    report["B_algorithm_1"] = {
        "episodes": len(rows["err"]),
        "info": {"rho_episode_error": rho(rows["info"], rows["err"])},
        "posterior": {"rho_episode_error": rho(rows["posterior"], rows["err"])},
    }
    print(json.dumps(report, indent=1))
    (out / "cost_vs_error.json").write_text(json.dumps(report, indent=1))
    plot_cost_vs_error({k: costs[k].mean(1) for k in ("info", "posterior")}, val_err,
                       np.median(errs, 1), report["A_from_start"], out / "cost_vs_error.png")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="study", required=True)
    one = sub.add_parser("bo-vs-random", help="BO against random search at equal budget")
    one.add_argument("--seeds", type=int, default=16)
    one.add_argument("--budget", type=int, default=100)
    one.add_argument("--grid", type=int, default=9, help="grid points per axis")
    one.add_argument("--cost", default=DEFAULT_COST)
    one.add_argument("--modes", default="restart,carry")
    one.add_argument("--workers", type=int, default=None)
    one.add_argument("--out", default="runs/bo_vs_random")
    two = sub.add_parser("cost-vs-error", help="does an episode's cost predict the final error?")
    two.add_argument("--xis", type=int, default=64)
    two.add_argument("--seeds", type=int, default=8)
    two.add_argument("--val-seeds", type=int, default=4)
    two.add_argument("--runs", type=int, default=4, help="Algorithm 1 runs for part B")
    two.add_argument("--budget", type=int, default=100)
    two.add_argument("--out", default="runs/cost_vs_error")
    args = ap.parse_args()
    (bo_vs_random if args.study == "bo-vs-random" else cost_vs_error)(args)


if __name__ == "__main__":
    main()
