"""Must-show 2: the project's BO loop against a stock BoTorch loop, same objective, one process.

Stock loop: the same GP (SingleTaskGP, Normalize, Standardize), the same acquisition (LogPI with
kappa, eq. 23) and the same Sobol design, but the GP is refitted from scratch at every iteration
and optimize_acqf uses the BoTorch tutorials' settings (num_restarts=10, raw_samples=512, default
options). Project loop: inertia_gym.agents.bo.BOAgent with its defaults (warm-started hyperparameters,
refit every 10 evaluations, 2 restarts / 256 raw samples, no retries), on one torch thread as
optimize() runs it. The stock loop runs twice: with torch's default thread count (as a user
would run it) and on one thread (isolating the algorithmic gains). All go through the same env
with the same seed.

Objective: the stationary variant (every evaluation starts from the scenario's start), where the
best observed cost is a meaningful score; under Algorithm 1's carry-over the first evaluation is
the best observed cost of both loops (see bo_vs_random.py), so it cannot tell them apart. Each
loop's GP-recommended xi is also re-evaluated on 8 fresh seeds.

    python scripts/bench_bo.py --seeds 4 --budget 100 --out runs/bench_bo
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from botorch.acquisition.analytic import LogProbabilityOfImprovement
from botorch.fit import fit_gpytorch_mll
from botorch.models import SingleTaskGP
from botorch.models.transforms import Normalize, Standardize
from botorch.optim import optimize_acqf
from gpytorch.mlls import ExactMarginalLogLikelihood

from inertia_gym.agents.base import AskTellAgent
from inertia_gym.agents.bo import BOAgent, posterior_best
from inertia_gym.envs.excitation import xi_to_action
from inertia_gym.optimization import EvaluationLog, evaluate_xi, make_env, torch_threads
from inertia_gym.scenario import Scenario

UNIT = torch.tensor([[0.0] * 3, [1.0] * 3], dtype=torch.double)
EVAL_SEEDS = list(range(10_000, 10_008))


class StockBO(AskTellAgent):
    name = "stock-bo"

    def __init__(self, seed, n_init=8, kappa=0.01):
        super().__init__(seed)
        self.n_init, self.kappa = n_init, kappa
        engine = torch.quasirandom.SobolEngine(3, scramble=True, seed=self.seed)
        self._design = engine.draw(n_init, dtype=torch.double).numpy()
        self.x_, self.y_ = [], []

    def ask(self):
        n = len(self.x_)
        if n < self.n_init:
            return 2.0 * self._design[n] - 1.0
        x = torch.tensor(np.array(self.x_), dtype=torch.double)
        y = torch.tensor(np.array(self.y_)[:, None], dtype=torch.double)
        with torch.random.fork_rng():
            torch.manual_seed(self.seed * 100_003 + n)
            model = SingleTaskGP(x, y, input_transform=Normalize(d=3),
                                 outcome_transform=Standardize(m=1))
            fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
            acq = LogProbabilityOfImprovement(
                model, best_f=float(y.min()) - self.kappa * float(y.std()), maximize=False)
            cand, _ = optimize_acqf(acq, bounds=UNIT, q=1, num_restarts=10, raw_samples=512)
        return 2.0 * cand.detach().numpy().reshape(3) - 1.0

    def tell(self, action, cost):
        self.x_.append((np.asarray(action, dtype=float) + 1.0) / 2.0)
        self.y_.append(float(cost))


def run_loop(agent, sc, budget):
    env = EvaluationLog(make_env(sc, budget, cost="info", carry_over=False))
    t0 = time.perf_counter()
    agent.run(env, budget)
    wall = time.perf_counter() - t0
    costs = np.array(env.costs)
    actions = np.array([xi_to_action(sc, x) for x in env.xis], dtype=float)
    rec = np.asarray(env.xis[posterior_best(actions, costs, agent.seed)[0]])
    return {"wall_s": wall, "best_cost": float(costs.min()),
            "xi_best": env.xis[int(np.argmin(costs))].tolist(), "xi_rec": rec.tolist(),
            "reeval_rec": evaluate_xi(sc, rec, EVAL_SEEDS), "costs": costs.tolist()}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--out", default="runs/bench_bo")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sc = Scenario()
    rows = []
    with torch_threads(1):
        run_loop(BOAgent(0), sc, 10)  # warm-up: imports, numba, torch kernels
    for seed in range(args.seeds):
        # The project loop as optimize() runs it (torch on one thread); the stock loop as a
        # user runs it (torch's default thread count) and, to isolate the algorithmic part,
        # on one thread too.
        with torch_threads(1):
            ours = run_loop(BOAgent(seed), sc, args.budget)
            stock1 = run_loop(StockBO(seed), sc, args.budget)
        stock = run_loop(StockBO(seed), sc, args.budget)
        rows.append({"seed": seed, "project": ours, "stock": stock, "stock_1thread": stock1})
        print(f"seed {seed}: project {ours['wall_s']:.1f} s best {ours['best_cost']:.3f} "
              f"re-eval {ours['reeval_rec']:.3f} | stock {stock['wall_s']:.1f} s best "
              f"{stock['best_cost']:.3f} re-eval {stock['reeval_rec']:.3f} | stock 1 thread "
              f"{stock1['wall_s']:.1f} s best {stock1['best_cost']:.3f} re-eval "
              f"{stock1['reeval_rec']:.3f}", flush=True)
    summary = {"budget": args.budget, "seeds": args.seeds,
               "torch_default_threads": torch.get_num_threads()}
    for key in ("project", "stock", "stock_1thread"):
        summary[key] = {
            "total_wall_s": sum(r[key]["wall_s"] for r in rows),
            "best_cost": [r[key]["best_cost"] for r in rows],
            "mean_best_cost": float(np.mean([r[key]["best_cost"] for r in rows])),
            "reeval_rec": [r[key]["reeval_rec"] for r in rows],
            "mean_reeval_rec": float(np.mean([r[key]["reeval_rec"] for r in rows])),
        }
    for key in ("stock", "stock_1thread"):
        summary[f"speedup_vs_{key}"] = (summary[key]["total_wall_s"]
                                        / summary["project"]["total_wall_s"])
    print(json.dumps(summary, indent=1))
    (out / "bench_bo.json").write_text(json.dumps({"summary": summary, "runs": rows}, indent=1))


if __name__ == "__main__":
    main()
