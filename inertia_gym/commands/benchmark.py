"""`inertia-gym benchmark`: agents compared across seeds at equal budgets, resumable.

Every (agent, seed) run is saved to DIR/runs/<agent>-seed<S>.json the moment it finishes, so
an interrupted sweep (Ctrl-C, a killed job, a lost node) resumes when the same command is run
again: finished runs are read back, not redone. DIR/settings.json pins what the runs were made
under; rerunning with other settings (budget, cost, scenario, ...) into the same DIR is refused
rather than mixing results. Adding agents or seeds to a finished sweep runs only the new ones.

Outputs: DIR/benchmark.json (settings, per-agent table, per-run records with the best cost, the
cost curve, xi*, wall time and the validated inertia error of xi*), DIR/benchmark.csv (one row
per run), DIR/summary.md (the table and the plots), DIR/cost_curves.png, DIR/regret.png and
DIR/validated_error.png. Scores are defined in inertia_gym/benchmark.py.
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from tqdm.auto import tqdm  # noqa: E402

from inertia_gym.benchmark import (  # noqa: E402
    AGENTS,
    SweepSettings,
    Task,
    run_task,
    summarize,
    sweep_tasks,
)
from inertia_gym.commands.common import (  # noqa: E402
    add_scenario_option,
    load_scenario,
    positive_float,
    positive_int,
    prepare_out_dir,
    write_json,
)
from inertia_gym.episode import COSTS  # noqa: E402
from inertia_gym.errors import ConfigError  # noqa: E402
from inertia_gym.executors import BACKENDS, map_unordered  # noqa: E402

SETTINGS_FILE = "settings.json"
RUNS_DIR = "runs"
DEFAULT_AGENTS = ",".join(AGENTS)


def parse_agents(text: str) -> list[str]:
    """'bo,random,grid' -> ['bo', 'random', 'grid'] (checked by sweep_tasks)."""
    return [a.strip().lower() for a in text.split(",") if a.strip()]


def add_parser(sub) -> None:
    """Register the sub-command."""
    p = sub.add_parser("benchmark", help="compare agents across seeds at equal budgets",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--agents", default=DEFAULT_AGENTS,
                   help=f"comma-separated, from {', '.join(AGENTS)} ({DEFAULT_AGENTS}); "
                        "grid is the dense-grid reference that regrets are measured against")
    p.add_argument("--seeds", type=positive_int, default=16, help="seeds 0..N-1 per agent (16)")
    p.add_argument("--budget", type=positive_int, default=100, help="evaluations M per run (100)")
    p.add_argument("--cost", choices=COSTS, default="info", help="info (the paper's J) or posterior")
    p.add_argument("--restart-each-episode", action="store_true",
                   help="every evaluation starts from the scenario's start (a stationary "
                        "objective) instead of Algorithm 1's carry-over")
    p.add_argument("--backend", choices=BACKENDS, default="local",
                   help="local (default): a process pool here; ray: a Ray cluster")
    p.add_argument("--workers", type=positive_int, default=None,
                   help="parallel runs (default: one per core here, or what the cluster takes)")
    p.add_argument("--ray-address", default=None,
                   help="existing Ray cluster: 'auto', HOST:PORT or ray://HOST:PORT (default: "
                        "start a local cluster for this sweep)")
    p.add_argument("--grid-points", type=positive_int, default=9,
                   help="points per axis of the dense-grid reference (9: 729 xi)")
    p.add_argument("--eval-seeds", type=positive_int, default=8,
                   help="fresh seeds of the from-start re-evaluation of each xi* (8)")
    p.add_argument("--val-seeds", type=positive_int, default=4,
                   help="seeds of the long-horizon validation of each xi* (4)")
    p.add_argument("--val-duration", type=positive_float, default=1000.0,
                   help="seconds of the long-horizon validation (1000)")
    p.add_argument("--out", default="runs/benchmark", help="output folder (runs/benchmark)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_scenario_option(p)
    p.set_defaults(func=run)


def settings_from_args(args: argparse.Namespace) -> SweepSettings:
    """The sweep settings selected on the command line."""
    return SweepSettings(
        scenario=load_scenario(args), budget=args.budget, cost=args.cost,
        carry_over=not args.restart_each_episode,
        eval_seeds=tuple(range(10_000, 10_000 + args.eval_seeds)),
        val_seeds=tuple(range(args.val_seeds)), val_duration=args.val_duration,
        grid_points=args.grid_points,
    )


# --- the store: one JSON file per finished run ---------------------------------------------

def _settings_diff(saved: dict, new: dict) -> list[str]:
    keys = sorted(set(saved) | set(new))
    diff = [k for k in keys if k != "scenario" and saved.get(k) != new.get(k)]
    old_sc, new_sc = saved.get("scenario") or {}, new.get("scenario") or {}
    diff += [f"scenario.{k}" for k in sorted(set(old_sc) | set(new_sc))
             if old_sc.get(k) != new_sc.get(k)]
    return diff


def open_sweep(out: Path, settings: SweepSettings) -> dict[str, dict]:
    """Pin `settings` to the folder `out`; return the runs already saved there, by task name.

    Raises ConfigError if `out` holds a sweep made under other settings. A run file that cannot
    be read (e.g. truncated by a crash) is reported on stderr and redone.
    """
    path = out / SETTINGS_FILE
    new = settings.to_json()
    if path.exists():
        try:
            saved = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path} is not valid JSON ({exc}); choose another --out") from exc
        if not isinstance(saved, dict):
            raise ConfigError(f"{path} does not hold benchmark settings; choose another --out")
        diff = _settings_diff(saved, new)
        if diff:
            raise ConfigError(f"{out} holds a sweep made with other settings ({', '.join(diff)}); "
                              f"choose another --out, or remove {out} to start over")
    else:
        write_json(path, new)
    runs = out / RUNS_DIR
    runs.mkdir(exist_ok=True)
    done = {}
    for f in sorted(runs.glob("*.json")):
        try:
            record = json.loads(f.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            print(f"benchmark: {f} is unreadable ({exc}); that run is done again", file=sys.stderr)
            continue
        if record.get("settings_key") == settings.key():
            done[f.stem] = record
    return done


def run_sweep(out: Path, settings: SweepSettings, tasks: list[Task], *, backend: str = "local",
              workers: int | None = None, ray_address: str | None = None,
              progress: bool = True) -> list[dict]:
    """Run the tasks not yet saved in `out`, saving each as it finishes; return all records.

    Records come back in the order of `tasks`, whatever order they finished in.
    """
    done = open_sweep(out, settings)
    todo = [t for t in tasks if t.name not in done]
    if len(todo) < len(tasks):
        print(f"benchmark: resuming, {len(tasks) - len(todo)} of {len(tasks)} runs already saved "
              f"in {out / RUNS_DIR}", file=sys.stderr)
    bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), desc="benchmark",
               unit="run", disable=not progress)
    try:
        fn = functools.partial(run_task, settings)
        for task, record in map_unordered(fn, todo, backend=backend, workers=workers,
                                          ray_address=ray_address):
            write_json(out / RUNS_DIR / f"{task.name}.json", record)
            done[task.name] = record
            bar.set_postfix_str(task.name)
            bar.update(1)
    finally:
        bar.close()
    return [done[t.name] for t in tasks]


# --- the report ----------------------------------------------------------------------------

def _fmt(stat: dict | None, pct: bool = False) -> str:
    if stat is None:
        return "–"
    f = (lambda x: f"{x:.3%}") if pct else (lambda x: f"{x:.3g}")
    return f"{f(stat['median'])} [{f(stat['q25'])}, {f(stat['q75'])}]"


def table_markdown(summary: dict) -> str:
    """The per-agent table (median [IQR]) and the win-rate matrix, as markdown."""
    agents = list(summary["agents"])
    lines = [
        "| agent | runs | best observed cost | re-evaluated cost of xi* | regret of xi* | "
        "regret of GP-recommended xi | validated error of xi* | wall s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in agents:
        s = summary["agents"][name]
        lines.append(f"| {name} | {s['runs']} | {_fmt(s['best_cost'])} | {_fmt(s['reeval_cost'])} | "
                     f"{_fmt(s['regret'])} | {_fmt(s['regret_recommended'])} | "
                     f"{_fmt(s['val_rel_error'], pct=True)} | {_fmt(s['wall_s'])} |")
    grid = summary["grid"]
    if grid is not None:
        err = "diverged" if grid["val_rel_error"] is None else f"{grid['val_rel_error']:.3%}"
        lines.append(f"| grid ({grid['n_points']} xi) | 1 | – | {grid['reeval_cost']:.3g} | 0 | 0 | "
                     f"{err} | {grid['wall_s']:.3g} |")
    if len(agents) > 1:
        lines += ["", "Win rate (row beats column on the re-evaluated cost of xi*, same seeds; "
                      "ties count half):", "",
                  "| | " + " | ".join(agents) + " |", "|---" * (len(agents) + 1) + "|"]
        for a in agents:
            wr = summary["agents"][a]["win_rate"]
            cells = ["–" if b == a or wr.get(b) is None else f"{wr[b]:.2f}" for b in agents]
            lines.append(f"| {a} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot_cost_curves(runs: list[dict], summary: dict, settings: SweepSettings, path: Path) -> Path:
    """Running best of the observed cost per agent: median over seeds with the IQR as a band."""
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for k, name in enumerate(summary["agents"]):
        curves = np.array([np.minimum.accumulate(r["costs"]) for r in runs if r["agent"] == name])
        i = np.arange(1, curves.shape[1] + 1)
        ax.plot(i, np.median(curves, 0), color=f"C{k}", lw=2, label=name)
        ax.fill_between(i, np.quantile(curves, 0.25, 0), np.quantile(curves, 0.75, 0),
                        color=f"C{k}", alpha=0.2)
    if summary["reference_cost"] is not None and not settings.carry_over:
        ax.axhline(summary["reference_cost"], color="k", ls=":",
                   label=f"grid optimum (mean of {len(settings.eval_seeds)} episodes; the "
                         "curves are single noisy draws)")
    ax.set_xlabel("evaluation i")
    ax.set_ylabel("running best of the observed cost")
    ax.set_title("cost curves (median, band: 25-75 %)"
                 + (", Algorithm 1 carry-over" if settings.carry_over else ", from-start episodes"))
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _per_agent_strip(ax, runs, agents, key, **scatter):
    data = [[r[key] for r in runs if r["agent"] == a and r[key] is not None] for a in agents]
    for k, values in enumerate(data):
        if values:
            x = k + np.linspace(-0.15, 0.15, len(values))
            ax.scatter(x, values, color=f"C{k}", s=14, alpha=0.7, **scatter)
            ax.hlines(np.median(values), k - 0.3, k + 0.3, color=f"C{k}", lw=2)
    ax.set_xticks(range(len(agents)), agents)


def plot_regret(runs: list[dict], summary: dict, path: Path) -> Path | None:
    """Regret of xi* and of the GP-recommended xi per agent (dots: seeds; bar: median)."""
    if summary["reference_cost"] is None:
        return None
    agents = list(summary["agents"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True)
    for ax, key, title in ((axes[0], "regret", "xi* (lowest observed cost)"),
                           (axes[1], "regret_recommended", "GP-recommended xi")):
        _per_agent_strip(ax, runs, agents, key)
        ax.axhline(0.0, color="k", ls=":", lw=1)
        ax.set_title(title)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0].set_ylabel("regret: re-evaluated cost − grid optimum")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_validated_error(runs: list[dict], summary: dict, path: Path) -> Path:
    """Validated relative inertia error of xi* per agent (dots: seeds; bar: median)."""
    agents = list(summary["agents"])
    fig, ax = plt.subplots(figsize=(8, 4.5))
    _per_agent_strip(ax, runs, agents, "val_rel_error")
    grid = summary["grid"]
    if grid is not None and grid["val_rel_error"] is not None:
        ax.axhline(grid["val_rel_error"], color="k", ls=":", label="grid optimum's xi")
        ax.legend()
    ax.set_yscale("log")
    ax.set_ylabel("||J_hat − J||_F / ||J||_F after validation")
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


CSV_FIELDS = ("agent", "seed", "best_cost", "reeval_cost", "reeval_cost_recommended", "regret",
              "regret_recommended", "val_rel_error", "val_diverged", "a", "b", "t_on", "wall_s")


def write_report(out: Path, settings: SweepSettings, agents: list[str], n_seeds: int,
                 records: list[dict]) -> dict:
    """Write benchmark.json, benchmark.csv, summary.md and the plots; return the JSON dict."""
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
             plot_validated_error(runs, summary, out / "validated_error.png")]
    objective = ("Algorithm 1 (the estimator carries over between evaluations)"
                 if settings.carry_over else "from-start episodes (stationary)")
    text = [f"# Benchmark: {', '.join(agents)}", "",
            f"{n_seeds} seeds, budget M = {settings.budget}, cost `{settings.cost}`, objective: "
            f"{objective}. Re-evaluation on {len(settings.eval_seeds)} fresh seeds from the "
            f"scenario's start; validation over {settings.val_duration:g} s on "
            f"{len(settings.val_seeds)} seeds. Medians with [25 %, 75 %] quantiles.", "",
            table_markdown(summary)]
    if summary["grid"] is None:
        text.append("No grid reference in this sweep: add `grid` to --agents to state regrets.\n")
    text += [f"![{p.stem}]({p.name})\n" for p in plots if p is not None]
    (out / "summary.md").write_text("\n".join(text))
    return report


def run(args: argparse.Namespace) -> int:
    """Run (or resume) the sweep, write the report, print the table."""
    agents = parse_agents(args.agents)
    tasks = sweep_tasks(agents, args.seeds)
    if args.ray_address is not None and args.backend != "ray":
        raise ConfigError("a Ray address needs backend 'ray' (--backend ray)")
    settings = settings_from_args(args)
    out = prepare_out_dir(args.out)
    t0 = time.perf_counter()
    try:
        records = run_sweep(out, settings, tasks, backend=args.backend, workers=args.workers,
                            ray_address=args.ray_address, progress=not args.no_progress)
    except KeyboardInterrupt:
        saved = len(list((out / RUNS_DIR).glob("*.json")))
        print(f"\nbenchmark interrupted: {saved} of {len(tasks)} runs are saved in {out / RUNS_DIR}; "
              "run the same command again to resume.", file=sys.stderr)
        return 130
    report = write_report(out, settings, agents, args.seeds, records)
    print(table_markdown(report["summary"]))
    print(f"benchmark: {len(tasks)} runs ({time.perf_counter() - t0:.1f} s this call) -> {out}")
    return 0
