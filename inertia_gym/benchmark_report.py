"""The report of a benchmark sweep: benchmark.json, benchmark.csv, summary.md and the figures.

Every number comes from :func:`inertia_gym.benchmark.summarize`; every figure from
:mod:`inertia_gym.plots`. summary.md says in words what each column means, what the grid row is
and on how many seeds each win rate rests.
"""

from __future__ import annotations

import csv
from pathlib import Path

from inertia_gym.benchmark import SweepSettings, summarize
from inertia_gym.commands.common import write_json
from inertia_gym.plots import plot_cost_curves, plot_regret, plot_tradeoff, plot_validated_error

CSV_FIELDS = ("agent", "seed", "best_cost", "cost_star", "reeval_cost",
              "reeval_cost_observed_best", "regret", "regret_observed_best", "val_rel_error",
              "val_diverged", "a", "b", "t_on", "wall_s", "impulse_star", "within_limits_star")


def _fmt(stat: dict | None, pct: bool = False) -> str:
    if stat is None:
        return "–"
    f = (lambda x: f"{x:.3%}") if pct else (lambda x: f"{x:.3g}")
    return f"{f(stat['median'])} [{f(stat['q25'])}, {f(stat['q75'])}]"


def table_markdown(summary: dict) -> str:
    """The per-agent table (median [25 %, 75 %]) and the win-rate matrix, as markdown."""
    agents = list(summary["agents"])
    limited = bool(agents) and all("within_limits" in summary["agents"][a] for a in agents)
    extra = " impulse of xi* N·m·s | xi* within the limits |" if limited else ""
    lines = [
        "| agent | runs | best observed cost | re-evaluated cost of xi* | regret of xi* | "
        "regret of the observed best | validated error of xi* | wall s |" + extra,
        "|---|---|---|---|---|---|---|---|" + ("---|---|" if limited else ""),
    ]
    for name in agents:
        s = summary["agents"][name]
        cells = (f" {_fmt(s['impulse_star'])} | {s['within_limits']:.0%} |" if limited else "")
        lines.append(f"| {name} | {s['runs']} | {_fmt(s['best_cost'])} | {_fmt(s['reeval_cost'])} | "
                     f"{_fmt(s['regret'])} | {_fmt(s['regret_observed_best'])} | "
                     f"{_fmt(s['val_rel_error'], pct=True)} | {_fmt(s['wall_s'])} |" + cells)
    grid = summary["grid"]
    if grid is not None:
        err = "diverged" if grid["val_rel_error"] is None else f"{grid['val_rel_error']:.3%}"
        cells = (f" {grid['impulse_star']:.3g} | {grid['within_limits_star']:.0%} |"
                 if limited and "impulse_star" in grid else (" – | – |" if limited else ""))
        lines.append(f"| grid ({grid['n_points']} xi) | 1 | – | {grid['reeval_cost']:.3g} | "
                     f"0 (the reference) | – | {err} | {grid['wall_s']:.3g} |" + cells)
    intervals = [f"{a} [{summary['agents'][a]['regret_median_ci95'][0]:.3g}, "
                 f"{summary['agents'][a]['regret_median_ci95'][1]:.3g}]"
                 for a in agents if summary["agents"][a].get("regret_median_ci95") is not None]
    if intervals:
        lines += ["", "95 % bootstrap intervals of the median regret of xi*: " + "; ".join(intervals)
                  + "."]
    if len(agents) > 1:
        lines += ["", "Win rate (row beats column on the re-evaluated cost of xi*, on the seeds "
                      "both ran; ties count half; in brackets the number of those seeds):", "",
                  "| | " + " | ".join(agents) + " |", "|---" * (len(agents) + 1) + "|"]
        for a in agents:
            wr, n = summary["agents"][a]["win_rate"], summary["agents"][a]["win_seeds"]
            cells = ["–" if b == a or wr.get(b) is None else f"{wr[b]:.2f} ({n[b]})"
                     for b in agents]
            lines.append(f"| {a} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def explanation(settings: SweepSettings, summary: dict) -> str:
    """The paragraphs of summary.md that define the table's columns, the grid row and win rates."""
    n_eval, n_val = len(settings.eval_seeds), len(settings.val_seeds)
    rule = next((r["recommendation"] for r in summary["runs"] if "recommendation" in r),
                "the evaluated xi with the lowest GP posterior mean cost")
    seeds = sorted({n for s in summary["agents"].values() for n in s["win_seeds"].values()})
    text = [
        "## How to read the table", "",
        f"* **xi\\*** is the xi each run recommends: {rule}. The **observed best** is the "
        "evaluation with the lowest observed cost (Algorithm 1, line 24), shown for comparison: "
        "it is one noisy draw, and under carry-over it is usually the first episode.",
        f"* **re-evaluated cost**: the mean cost of one episode from the scenario's start over "
        f"{n_eval} fresh seeds, the same seeds for every agent (common random numbers).",
        "* **regret** = re-evaluated cost of the run's xi minus that of the grid optimum; 0 means "
        "as good as the best grid point, a negative regret a better xi between the grid's "
        "points. Lower is better; it is in the cost's units.",
        f"* **validated error**: median over {n_val} seeds of ||J_hat − J||_F / ||J||_F after "
        f"a {settings.val_duration:g}-s validation of xi* (bursts every ~90–100 s): whether "
        "applying xi* identifies the inertia, which is what the cost stands in for.",
    ]
    if summary["grid"] is not None:
        grid = summary["grid"]
        text.append(
            f"* **the grid row** is not an agent but the reference: every one of the "
            f"{grid['n_points']} points of a regular grid over the bounds of xi re-evaluated the "
            f"same way ({grid['n_points'] * n_eval} episodes), the best kept. Its regret is 0 by "
            "definition; its validated error says whether the cost's optimum identifies the "
            "inertia (with the info cost from the start it does not: J is lowest with no "
            "torque, which leaves the inertia's scale unidentified).")
    if seeds:
        counts = ", ".join(str(n) for n in seeds)
        text.append(
            f"* **win rates** rest on {counts} seed(s) per pair of agents (in brackets): with n "
            f"seeds a rate moves in steps of 1/(2n) and one seed changes it by up to 1/n "
            f"({1 / min(seeds):.2g} here). Read them with the quartiles above, not as a ranking.")
    if settings.scenario.limited:
        sc = settings.scenario
        limits = ", ".join(x for x in (
            f"an impulse budget of {sc.impulse_budget:g} N·m·s per episode"
            if sc.impulse_budget is not None else "",
            f"a rate limit of {sc.rate_limit:g} rad/s" if sc.rate_limit is not None else "") if x)
        text.append(
            f"* **mission limits**: {limits}. The loop cuts the bursts where a limit binds, so "
            r"every episode stays within them; **xi\* within the limits** is the share of runs "
            "whose xi* the limits let fire as designed (the impulse its law asks for within the "
            "budget, no burst cut by the rate monitor) on every evaluation seed, and **impulse "
            r"of xi\*** what it spends per episode. xi* and the grid optimum are picked among "
            "such designs. **tradeoff.png** plots the validated error against the impulse spent: "
            "the grid's best point in each band of impulse, and each run's xi*.")
    text.append(
        "* **cost_curves.png**: left, the re-evaluated cost of the xi a run would have "
        "recommended after i evaluations (the learning curve: what the agent knows, not one "
        "noisy episode); right, the running best of the observed cost (Figure 1 of the paper).")
    return "\n".join(text) + "\n"


def write_report(out: Path, settings: SweepSettings, agents: list[str], n_seeds: int,
                 records: list[dict]) -> dict:
    """Write benchmark.json, benchmark.csv, summary.md and the plots into `out`; return the
    JSON dict (settings, agents, seeds, summary, runs).
    """
    out = Path(out)
    summary = summarize(records)
    runs = summary["runs"]
    report = {"settings": settings.to_json(), "agents": agents, "seeds": n_seeds,
              "summary": {k: v for k, v in summary.items() if k != "runs"}, "runs": runs}
    write_json(out / "benchmark.json", report)
    with open(out / "benchmark.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS, extrasaction="ignore")
        writer.writeheader()
        for r in runs:
            writer.writerow({**r, **dict(zip(("a", "b", "t_on"), r["xi_star"]))})
    plots = [plot_cost_curves(runs, summary, settings, out / "cost_curves.png"),
             plot_regret(runs, summary, out / "regret.png"),
             plot_validated_error(runs, summary, out / "validated_error.png"),
             plot_tradeoff(runs, summary, out / "tradeoff.png")]
    objective = ("Algorithm 1: the estimator carries over between evaluations"
                 if settings.carry_over else "every evaluation is one episode from the "
                                             "scenario's start (stationary)")
    text = [f"# Benchmark: {', '.join(agents)}", "",
            f"{n_seeds} seeds per agent, budget M = {settings.budget}, cost `{settings.cost}`, "
            f"objective: {objective}. Medians over seeds with [25 %, 75 %] quantiles.", "",
            table_markdown(summary)]
    if summary["grid"] is None:
        text.append("No grid reference in this sweep: add `grid` to --agents to state regrets.\n")
    text.append(explanation(settings, summary))
    text += [f"![{p.stem}]({p.name})\n" for p in plots if p is not None]
    (out / "summary.md").write_text("\n".join(text))
    return report


__all__ = ["CSV_FIELDS", "explanation", "table_markdown", "write_report"]
