"""`inertia-gym validate`: long-horizon validation of an excitation xi (paper, Figures 2-3)."""

from __future__ import annotations

import argparse

import numpy as np

from inertia_gym.commands.common import (
    add_scenario_option,
    load_scenario,
    positive_float,
    positive_int,
    prepare_out_dir,
    write_json,
)
from inertia_gym.errors import ConfigError
from inertia_gym.excitation import check_xi
from inertia_gym.plots import plot_error_histories, plot_validation
from inertia_gym.validation import validate


def parse_xi(text: str):
    """'A,B,T_ON' -> array (3,), or 'none' -> None."""
    if text.strip().lower() == "none":
        return None
    parts = text.split(",")
    if len(parts) != 3:
        raise ConfigError(f"--xi must be A,B,T_ON or none, got {text!r}")
    try:
        return np.array([float(p) for p in parts])
    except ValueError as exc:
        raise ConfigError(f"--xi must be three numbers A,B,T_ON, got {text!r}") from exc


def add_parser(sub) -> None:
    """Register the sub-command."""
    p = sub.add_parser("validate", help="long-horizon validation of an excitation xi",
                       description=__doc__)
    p.add_argument("--xi", required=True, help="A,B,T_ON of eq. (18), or 'none' (no torque)")
    p.add_argument("--duration", type=positive_float, default=1000.0, help="seconds (1000)")
    p.add_argument("--seeds", type=positive_int, default=16, help="number of seeds 0..N-1 (16)")
    p.add_argument("--out", default="runs/validate", help="output folder (runs/validate)")
    p.add_argument("--no-bounds-check", action="store_true",
                   help="accept a, b outside the scenario's bounds (T_on must still be > 0)")
    add_scenario_option(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Validate, write result.json and the figures, print a one-line summary."""
    sc = load_scenario(args)
    xi = parse_xi(args.xi)
    if xi is not None:
        bounds = sc.xi_bounds.copy()
        if args.no_bounds_check:
            bounds[0, :2], bounds[1, :2] = -np.inf, np.inf
        xi = check_xi(xi, bounds)
    out = prepare_out_dir(args.out)
    result = validate(sc, xi, args.duration, range(args.seeds), refine_ml=True)
    summary = result.summary()
    write_json(out / "result.json", summary)
    plot_validation(result, out / "validation.png")
    plot_error_histories(result, out / "error_history.png")
    if summary["median_rel_error"] is None:
        print(f"validate xi={args.xi}: every run diverged ({summary['diverged']} of {args.seeds}); "
              f"no error to report ({summary['wall_s']:.1f} s) -> {out}")
        return 0
    print(
        f"validate xi={args.xi}: median error {summary['median_rel_error']:.4%}, "
        f"trace-normalised {summary['median_ratio_rel_error']:.4%}, "
        f"coverage {summary['ci95_coverage']:.0%}, diverged {summary['diverged']}, "
        f"scale identified: {summary['scale_identified']} ({summary['wall_s']:.1f} s) -> {out}"
    )
    if sc.limited:
        used = np.median(result.impulse)
        print(f"mission limits: median impulse spent {used:.4g} N·m·s over {args.duration:g} s, "
              f"largest true rate {float(np.max(result.rate_peak)):.4g} rad/s"
              + ("" if sc.rate_limit is None else f" (limit {sc.rate_limit:.4g})"))
    if summary.get("efficiency") is not None:
        print(f"batch ML refinement: median error {summary['refined_median_rel_error']:.4%}"
              f"{' (ratios)' if summary['refined_errors_are_ratios'] else ''}, coverage "
              f"{summary['refined_ci95_coverage']:.0%}, error / Cramér-Rao bound "
              f"{summary['efficiency']:.2f} (median over seeds)")
    if not summary["scale_identified"]:
        print("note: the torque applied did not fix the inertia's scale; only its ratios "
              "(ratio_rel_errors) are identified.")
    return 0
