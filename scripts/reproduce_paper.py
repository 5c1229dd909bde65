"""Reproduce the paper's simulation section: Algorithm 1 (M = 100), Figures 1-3, side by side.

1. optimize: BO with PI/kappa on the paper's scenario, M = 100, as Algorithm 1 runs it
   (carry-over, info cost; Figure 1: cost per evaluation and running best);
2. validate xi* over 1000 s on 16 seeds (Figure 2), for xi* by Algorithm 1's rule (lowest
   observed cost) and for the GP-recommended xi;
3. informative (xi*) against non-informative (no torque) input (Figure 3);
4. the paper's own xi* = (3.76, 3.87, 0.99), outside the default bounds of a, scored with the
   bounds widened;
then writes OUT/summary.md with the figures and our numbers next to the paper's.

    python scripts/reproduce_paper.py --out runs/reproduce_paper
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from inertia_gym.optimization import evaluate_many, optimize
from inertia_gym.plots import plot_costs, plot_informative_vs_not, plot_validation
from inertia_gym.scenario import Scenario
from inertia_gym.validation import validate

PAPER_XI = np.array([3.76, 3.87, 0.99])
PAPER_J = 14.0
EVAL_SEEDS = list(range(10_000, 10_008))


def fmt(x):
    return "(" + ", ".join(f"{v:.3g}" for v in x) + ")"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--budget", type=int, default=100)
    ap.add_argument("--val-seeds", type=int, default=16)
    ap.add_argument("--out", default="runs/reproduce_paper")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    sc = Scenario()
    res = optimize("bo", sc, args.budget, args.seed, cost="info", carry_over=True, progress=True)
    plot_costs(res, out / "figure1_bo_cost.png")
    seeds = range(args.val_seeds)
    val_star = validate(sc, res.xi_observed_best, 1000.0, seeds)
    val_rec = validate(sc, res.xi_star, 1000.0, seeds)
    val_none = validate(sc, None, 1000.0, seeds)
    plot_validation(val_star, out / "figure2_validation_xi_star.png")
    plot_validation(val_rec, out / "figure2_validation_xi_rec.png")
    plot_informative_vs_not(val_star, val_none, out / "figure3_informative_vs_none.png")
    wide = sc.replace(a_bounds=(0.0, 4.0))
    paper_val = validate(wide, PAPER_XI, 1000.0, seeds)
    from_start = {
        name: float(evaluate_many(wide, xi[None], EVAL_SEEDS)[0].mean())
        for name, xi in (("xi_star", res.xi_observed_best), ("xi_rec", res.xi_star),
                         ("paper_xi", PAPER_XI))
    }
    episode_windows = float(evaluate_many(wide.replace(window_set="episode"),
                                          res.xi_observed_best[None], EVAL_SEEDS)[0].mean())
    s_star, s_rec, s_none, s_paper = (v.summary() for v in (val_star, val_rec, val_none,
                                                             paper_val))
    numbers = {
        "optimize": res.to_json(),
        "argmin_evaluation": int(np.argmin(res.costs)) + 1,
        "from_start_mean_cost_8_seeds": from_start,
        "xi_star_cost_all_windows": episode_windows,
        "validation": {"xi_star": s_star, "xi_rec": s_rec, "none": s_none, "paper_xi": s_paper},
        "wall_s": time.perf_counter() - t0,
    }
    (out / "reproduce_paper.json").write_text(json.dumps(numbers, indent=1, default=float))
    lo, hi = sc.xi_bounds
    costs = res.costs
    md = f"""# Reproduction of Basu & Sanfelice, simulation section

Command: `python scripts/reproduce_paper.py --seed {args.seed} --budget {args.budget} --out {out}`
(wall time {numbers['wall_s']:.0f} s). Scenario: the paper's (docs/paper-errata.md choices);
bounds of xi = (a, b, T_on): {fmt(lo)} to {fmt(hi)} (the paper's formula a <= tau_max/|w0|).

| quantity | paper | here | why they differ |
|---|---|---|---|
| xi* (Algorithm 1, lowest observed J) | (3.76, 3.87, 0.99) | {fmt(res.xi_observed_best)} (evaluation {numbers['argmin_evaluation']} of {args.budget}) | a = 3.76 violates the paper's own bound a <= tau_max/|w0| = {hi[0]:.3f}; the first episode, run with the worst inertia guess, has by far the lowest J (below) |
| GP-recommended xi (lowest posterior mean) | - | {fmt(res.xi_star)} | what BO learned; median xi of its last {args.budget // 2} evaluations: {fmt(np.median(res.xis[args.budget // 2:], axis=0))} |
| J(xi*) | 14 | {res.cost_observed_best:.3g} (median J over evaluations {np.median(costs):.3g}, last 10: {costs[-10:].mean():.3g}) | J's absolute level depends on unreported choices (eps, eps_lambda, beta, which windows enter eq. 24); with every window of the episode J(xi*) = {episode_windows:.3g} from the start |
| median inertia error, 1000 s, xi* | converges (Fig. 2) | {s_star['median_rel_error']:.3%} over {args.val_seeds} seeds, {s_star['diverged']} diverged | - |
| median inertia error, 1000 s, GP-recommended xi | - | {s_rec['median_rel_error']:.3%} | - |
| median inertia error, 1000 s, paper's xi* (a bound widened to 4) | converges | {s_paper['median_rel_error']:.3%} | - |
| median inertia error, 1000 s, no torque | does not converge (Fig. 3) | {s_none['median_rel_error']:.3%}, scale identified: {s_none['scale_identified']}; trace-normalised error {s_none['median_ratio_rel_error']:.3%} | torque-free motion fixes the ratios of J, never its scale |
| J of one episode from the start (8 fresh seeds) | - | xi*: {from_start['xi_star']:.3g}; GP-rec: {from_start['xi_rec']:.3g}; paper's xi*: {from_start['paper_xi']:.3g} | - |

## Figures

- Figure 1 (cost per evaluation, running best): ![fig1](figure1_bo_cost.png)
- Figure 2 (w_hat, J_hat with 95% band, torque; xi*): ![fig2](figure2_validation_xi_star.png)
  and for the GP-recommended xi: ![fig2b](figure2_validation_xi_rec.png)
- Figure 3 (inertia error, informative vs no torque): ![fig3](figure3_informative_vs_none.png)

## Differences explained

1. **Bounds.** The paper's bound for a gives [0, {hi[0]:.3f}] for w0 = (0.5, 10, 0.45), yet it
   reports a = 3.76. We keep the formula (it is configuration: `a_bounds`) and score the paper's
   xi* with a widened to [0, 4].
2. **Which episode has the lowest J.** J is built from w_dot_hat = J_hat^-1(tau - w x J_hat w):
   while J_hat is still the poor initial guess, w_dot_hat is large and so is the Gram, so the
   first episode of a run reports far more "information" than any later one (its J is
   {costs[0]:.3g}; evaluations 11-{args.budget} have median {np.median(costs[10:]):.3g}). The
   running best of Figure 1 is therefore set at evaluation {numbers['argmin_evaluation']}, and
   Algorithm 1's xi* is the first design point, not BO's choice. The GP-recommended xi is what
   BO learned. From the scenario's start the lowest J of all lies at the corner a = b = 0,
   T_on = 1 s, i.e. no torque with the longest window (scripts/bo_vs_random.py, grid), an
   excitation that cannot identify the inertia's scale: J rewards the estimator's error, the
   caveat docs/paper-errata.md names.
3. **J's level (14 vs ~{np.median(costs):.2g}).** J = -log(alpha + eps_lambda) with alpha the
   soft-min of lambda_min; the paper's J = 14 means alpha ~ 1e-6, ours ~ exp(-J). The paper does
   not report eps, eps_lambda, beta, nor whether coast-only windows enter S; these set J's level
   (not its minimiser along b and T_on).
4. **Validation.** Median inertia error after 1000 s over {args.val_seeds} seeds: the paper's
   xi* {s_paper['median_rel_error']:.2%}, Algorithm 1's xi* here {s_star['median_rel_error']:.2%},
   the GP-recommended xi {s_rec['median_rel_error']:.2%}, no torque
   {s_none['median_rel_error']:.2%}. Bursts with b > 0 fix the scale, longer and stronger bursts
   (larger b, T_on) fix it better; no torque leaves the scale unidentified (Figure 3), as the
   paper says.
"""
    (out / "summary.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
