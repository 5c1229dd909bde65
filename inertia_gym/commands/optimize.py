"""`inertia-gym optimize`: Algorithm 1 (BO-EKF episodic excitation) or a baseline agent.

Writes DIR/result.json (docs/contracts.md: agent, budget, seed, xi_star, cost_star, costs,
wall_s; plus cost_kind, xis, rel_errors, xi_recommended) and DIR/optimize.png (Figure 1 style:
the cost of each evaluation and its running best).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from inertia_gym.commands.common import (  # noqa: E402
    add_scenario_option,
    load_scenario,
    nonnegative_int,
    positive_int,
    prepare_out_dir,
    write_json,
)
from inertia_gym.episode import COSTS  # noqa: E402
from inertia_gym.optimization import AGENTS, OptimizationResult, optimize  # noqa: E402


def add_parser(sub) -> None:
    """Register the sub-command."""
    p = sub.add_parser("optimize", help="Algorithm 1: optimise the excitation xi = (a, b, T_on)",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--agent", choices=AGENTS, default="bo", help="optimiser (bo)")
    p.add_argument("--budget", type=positive_int, default=100,
                   help="evaluation budget M, one excitation episode each (100)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of env and agent (0)")
    p.add_argument("--cost", choices=COSTS, default="info",
                   help="info: the paper's J; posterior: change of log det P_theta (info)")
    p.add_argument("--restart-each-episode", action="store_true",
                   help="start every evaluation from the scenario's start (a stationary "
                        "objective) instead of carrying the estimator over (Algorithm 1)")
    p.add_argument("--out", default="runs/optimize", help="output folder (runs/optimize)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_scenario_option(p)
    p.set_defaults(func=run)


def plot_costs(result: OptimizationResult, path: str | Path) -> Path:
    """Figure 1: cost of each evaluation (black) and the running best (green)."""
    path = Path(path)
    i = np.arange(1, len(result.costs) + 1)
    fig, ax = plt.subplots(figsize=(8, 4.5))
    ax.plot(i, result.costs, color="k", lw=1.0, marker=".", ms=3, label="J(xi^i)")
    ax.plot(i, np.minimum.accumulate(result.costs), color="g", lw=2.0, label="running best")
    ax.set_xlabel("function evaluation i")
    ax.set_ylabel("cost J" if result.cost_kind == "info" else "change of log det P_theta")
    xi = ", ".join(f"{x:.3g}" for x in result.xi_star)
    ax.set_title(f"{result.agent}, seed {result.seed}: xi* = ({xi}), "
                 f"J(xi*) = {result.cost_star:.3g}")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def run(args: argparse.Namespace) -> int:
    """Optimise, write result.json and the plot, print a one-line summary."""
    sc = load_scenario(args)
    out = prepare_out_dir(args.out)
    result = optimize(args.agent, sc, args.budget, args.seed, cost=args.cost,
                      progress=not args.no_progress,
                      carry_over=not args.restart_each_episode)
    data = result.to_json()
    data["carry_over"] = not args.restart_each_episode
    write_json(out / "result.json", data)
    plot_costs(result, out / "optimize.png")
    xi = ", ".join(f"{x:.4g}" for x in result.xi_star)
    rec = ", ".join(f"{x:.4g}" for x in result.xi_recommended)
    print(f"optimize {args.agent} M={args.budget} seed={args.seed} cost={args.cost}: "
          f"xi* = ({xi}) J = {result.cost_star:.4g} (evaluation "
          f"{int(np.argmin(result.costs)) + 1}); GP-recommended xi = ({rec}); "
          f"final inertia error {result.rel_errors[-1]:.3%} ({result.wall_s:.1f} s) -> {out}")
    return 0
