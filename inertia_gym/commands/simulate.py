"""`inertia-gym simulate`: write a synthetic recording (CSV + sidecar with the effect's truth)."""

from __future__ import annotations

import argparse

from inertia_gym.commands.common import (
    add_scenario_option,
    load_scenario,
    nonnegative_int,
    positive_float,
)
from inertia_gym.discrepancy.recordings import write_recording
from inertia_gym.discrepancy.synthetic import parse_effect, simulate_recording


def add_parser(subparsers) -> None:
    """Register the sub-command."""
    p = subparsers.add_parser("simulate", help="write a synthetic recording with a catalogue effect")
    add_scenario_option(p)
    p.add_argument("--duration", type=positive_float, default=60.0, help="seconds (default 60)")
    p.add_argument("--effect", default=None,
                   help="NAME[:key=value,...] from the catalogue (random magnitudes unless given; "
                        "vectors as a;b;c), or none")
    p.add_argument("--seed", type=nonnegative_int, default=0)
    p.add_argument("--sample-dt", type=positive_float, default=None,
                   help="seconds between rows (default: the scenario's dt)")
    p.add_argument("--no-torque", action="store_true", help="torque-free (no commanded bursts)")
    p.add_argument("--out", required=True, metavar="REC.csv", help="output CSV (sidecar REC.json)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Simulate and write; refuses to overwrite an existing file."""
    name, overrides = parse_effect(args.effect)
    rec, sidecar = simulate_recording(load_scenario(args), args.duration, name, overrides,
                                      args.seed, not args.no_torque, args.sample_dt)
    write_recording(args.out, rec, sidecar)
    print(f"wrote {args.out} ({rec.t.size} rows), effect: {name or 'none'}")
    return 0
