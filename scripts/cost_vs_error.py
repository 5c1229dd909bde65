"""Must-show 3: does an episode's cost predict the final inertia error? Both cost options.

A. From the scenario's start: K Sobol xi, each run for one episode on S seeds (common random
   numbers); Spearman rank correlation of the episode's cost (info J, posterior change of
   log det P_theta) with (i) the relative inertia error at the episode's end, per (xi, seed)
   and over xi means, and (ii) the median error after a 1000 s validation of xi.
B. Along Algorithm 1 (carry-over): random xi for M episodes on a few seeds; Spearman of each
   episode's cost with the error at its end, episodes 11..M (after the start transient).

    python scripts/cost_vs_error.py --xis 64 --seeds 8 --out runs/cost_vs_error
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
from inertia_gym.envs import ENV_ID
from inertia_gym.optimization import evaluate_many
from inertia_gym.plots import plot_cost_vs_error
from inertia_gym.scenario import Scenario
from inertia_gym.validation import validate


def rho(x, y):
    return float(spearmanr(np.ravel(x), np.ravel(y)).statistic)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--xis", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--val-seeds", type=int, default=4)
    ap.add_argument("--runs", type=int, default=4, help="Algorithm 1 runs for part B")
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--out", default="runs/cost_vs_error")
    args = ap.parse_args()
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

if __name__ == "__main__":
    main()
