"""`inertia-gym benchmark`: agents compared across seeds at equal budgets, resumable.

Every (agent, seed) run is saved to DIR/runs/<agent>-seed<S>.json the moment it finishes, so
an interrupted sweep (Ctrl-C, a killed job, a lost node) resumes when the same command is run
again: finished runs are read back, not redone. DIR/settings.json pins what the runs were made
under; rerunning with other settings (budget, cost, scenario, ...) into the same DIR is refused
rather than mixing results. Adding agents or seeds to a finished sweep runs only the new ones.

Outputs: DIR/benchmark.json (settings, per-agent table, per-run records with xi* (the
recommended xi), the observed best, the cost curve, wall time and the validated inertia error of
xi*), DIR/benchmark.csv (one row per run), DIR/summary.md (the table, what it means, the plots),
DIR/cost_curves.png, DIR/regret.png and DIR/validated_error.png. Default objective: from-start
episodes with the posterior cost; the paper's Algorithm 1 is `--carry-over --cost info`.
"""

from __future__ import annotations

import argparse
import sys
import time

from inertia_gym.benchmark import AGENTS, SweepSettings, sweep_tasks
from inertia_gym.benchmark_report import table_markdown, write_report
from inertia_gym.benchmark_store import RUNS_DIR, run_sweep, saved_runs
from inertia_gym.commands.common import (
    add_objective_options,
    add_scenario_option,
    load_scenario,
    positive_float,
    positive_int,
    prepare_out_dir,
)
from inertia_gym.errors import ConfigError
from inertia_gym.executors import BACKENDS

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
    add_objective_options(p)
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
        carry_over=args.carry_over,
        eval_seeds=tuple(range(10_000, 10_000 + args.eval_seeds)),
        val_seeds=tuple(range(args.val_seeds)), val_duration=args.val_duration,
        grid_points=args.grid_points,
    )


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
        print(f"\nbenchmark interrupted: {saved_runs(out)} of {len(tasks)} runs are saved in "
              f"{out / RUNS_DIR}; run the same command again to resume.", file=sys.stderr)
        return 130
    report = write_report(out, settings, agents, args.seeds, records)
    print(table_markdown(report["summary"]))
    print(f"benchmark: {len(tasks)} runs ({time.perf_counter() - t0:.1f} s this call) -> {out}")
    return 0
