"""BO against random search at equal budget, judged on fresh seeds and a dense grid.

Per objective mode ("restart": every evaluation one episode from the scenario's start, the
default; "carry": Algorithm 1's carry-over), one benchmark sweep of bo, random and the grid
reference through the library (inertia_gym.benchmark_store.run_sweep: resumable, one file per
run; inertia_gym.benchmark_report.write_report: benchmark.json, summary.md, plots) into
OUT/<mode>/. On top of the benchmark's scores, every evaluated xi of every run is re-evaluated
from the start on the benchmark's fresh seeds, giving the number of evaluations an agent needs
before it has evaluated a xi within 5 % of the grid optimum's cost.

    python scripts/bo_vs_random.py --seeds 16 --budget 100 --out runs/bo_vs_random
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from inertia_gym.benchmark import SweepSettings, reevaluate, sweep_tasks
from inertia_gym.benchmark_report import write_report
from inertia_gym.benchmark_store import run_sweep
from inertia_gym.optimization import DEFAULT_COST
from inertia_gym.scenario import Scenario

AGENTS = ["bo", "random", "grid"]


def evals_to_within(true_costs, target) -> int | None:
    """First evaluation (1-based) whose running best re-evaluated cost reaches `target`."""
    hit = np.nonzero(np.minimum.accumulate(true_costs) <= target)[0]
    return int(hit[0]) + 1 if hit.size else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--grid", type=int, default=9, help="grid points per axis")
    ap.add_argument("--cost", default=DEFAULT_COST)
    ap.add_argument("--modes", default="restart,carry")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--out", default="runs/bo_vs_random")
    args = ap.parse_args()
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
            true_costs, _ = reevaluate(sc, r["xis"], settings.eval_seeds, settings.cost)
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


if __name__ == "__main__":
    main()
