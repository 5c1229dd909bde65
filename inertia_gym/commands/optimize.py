"""`inertia-gym optimize`: optimise the excitation xi = (a, b, T_on) with an agent, validate it.

Writes DIR/result.json (docs/contracts.md: agent, budget, seed, xi_star, cost_star, costs,
wall_s; plus cost_kind, carry_over, xis, rel_errors, recommendation, xi_recommended,
xi_observed_best, cost_observed_best and the validation of xi*: val_rel_error, val_rel_errors,
val_diverged, val_scale_identified, val_duration, val_seeds) and DIR/optimize.png (Figure 1
style: the cost of each evaluation, its running best and moving mean, xi* marked).

xi* is the xi the agent recommends (the evaluated xi with the lowest GP posterior mean cost);
cost_star its predicted cost. By default every evaluation is one episode from the scenario's
start scored by the posterior cost (the mode that identified the inertia best, docs/benchmark.md);
`--carry-over --cost info` is the paper's Algorithm 1.
"""

from __future__ import annotations

import argparse

from inertia_gym.commands.common import (
    add_objective_options,
    add_scenario_option,
    load_scenario,
    nonnegative_int,
    positive_float,
    positive_int,
    prepare_out_dir,
    write_json,
)
from inertia_gym.optimization import AGENTS, optimize, validated_error
from inertia_gym.plots import plot_costs


def add_parser(sub) -> None:
    """Register the sub-command."""
    p = sub.add_parser("optimize", help="optimise the excitation xi = (a, b, T_on), validate xi*",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--agent", choices=AGENTS, default="bo", help="optimiser (bo)")
    p.add_argument("--budget", type=positive_int, default=100,
                   help="evaluation budget M, one excitation episode each (100)")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of env and agent (0)")
    add_objective_options(p)
    p.add_argument("--val-seeds", type=nonnegative_int, default=4,
                   help="seeds 0..N-1 of the long-horizon validation of xi* (4; 0: none)")
    p.add_argument("--val-duration", type=positive_float, default=1000.0,
                   help="seconds of the validation of xi* (1000)")
    p.add_argument("--out", default="runs/optimize", help="output folder (runs/optimize)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_scenario_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Optimise, validate xi*, write result.json and the plot, print a summary."""
    sc = load_scenario(args)
    out = prepare_out_dir(args.out)
    result = optimize(args.agent, sc, args.budget, args.seed, cost=args.cost,
                      progress=not args.no_progress, carry_over=args.carry_over)
    data = result.to_json()
    if args.val_seeds:
        data.update(validated_error(sc, result.xi_star, args.val_duration, range(args.val_seeds)))
    write_json(out / "result.json", data)
    plot_costs(result, out / "optimize.png")
    mode = "carry-over" if args.carry_over else "from-start"
    xi = ", ".join(f"{x:.4g}" for x in result.xi_star)
    best = ", ".join(f"{x:.4g}" for x in result.xi_observed_best)
    print(f"optimize {args.agent} M={args.budget} seed={args.seed} cost={args.cost} {mode} "
          f"({result.wall_s:.1f} s):\n"
          f"  xi* = ({xi}) (evaluation {result.star_index + 1}, recommended: lowest GP posterior "
          f"mean; predicted cost {result.cost_star:.4g})\n"
          f"  observed best: ({best}) cost {result.cost_observed_best:.4g}")
    if result.within_limits is not None:
        k = result.star_index
        budget = "" if sc.impulse_budget is None else f" of the {sc.impulse_budget:.4g} allowed"
        print(f"  mission limits: xi* asked for {result.impulse_demands[k]:.4g} N·m·s per "
              f"episode{budget} ({'within the limits' if result.within_limits[k] else 'cut by them'}); "
              f"{int(result.within_limits.sum())} of {len(result.within_limits)} evaluations "
              "fired as designed")
    if args.val_seeds:
        err = data["val_rel_error"]
        text = "every run diverged" if err is None else (
            f"median inertia error {err:.3%}, scale "
            f"{'identified' if data['val_scale_identified'] else 'NOT identified'}")
        print(f"  validation of xi* over {args.val_duration:g} s, {args.val_seeds} seeds: {text}"
              f" ({data['val_diverged']} diverged)")
    print(f"  -> {out}")
    return 0
