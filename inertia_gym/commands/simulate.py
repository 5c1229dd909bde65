"""`inertia-gym simulate`: write a synthetic recording (CSV + sidecar with the effect's truth).

With --rotor-momentum H_MAX the recording also carries a known internal momentum (h columns).
"""

from __future__ import annotations

import argparse

from inertia_gym.commands.common import (
    add_scenario_option,
    load_scenario,
    nonnegative_int,
    positive_float,
)
from inertia_gym.discrepancy.synthetic import parse_effect, simulate_recording
from inertia_gym.recordings import write_recording


def add_parser(subparsers) -> None:
    """Register the sub-command."""
    p = subparsers.add_parser("simulate", help="write a synthetic recording with a catalogue effect",
                              description=__doc__)
    add_scenario_option(p)
    p.add_argument("--duration", type=positive_float, default=60.0, help="seconds (default 60)")
    p.add_argument("--effect", default=None,
                   help="NAME[:key=value,...] from the catalogue (random magnitudes unless given; "
                        "vectors as a;b;c), or none")
    p.add_argument("--seed", type=nonnegative_int, default=0,
                   help="seed of the noise, the initial rates and random effect magnitudes (default 0)")
    p.add_argument("--sample-dt", type=positive_float, default=None,
                   help="seconds between rows (default: the scenario's dt)")
    p.add_argument("--no-torque", action="store_true", help="torque-free (no commanded bursts)")
    p.add_argument("--rotor-momentum", type=positive_float, default=None, metavar="H_MAX",
                   help="kg·m²/s: add a rotor along a random body axis whose known momentum spins up "
                        "to H_MAX and back (0.5 (1 - cos(2 pi t / duration))), written as the h_x, h_y, "
                        "h_z columns (default: none)")
    p.add_argument("--out", required=True, metavar="REC.csv", help="output CSV (sidecar REC.json)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Simulate and write; refuses to overwrite an existing file."""
    name, overrides = parse_effect(args.effect)
    rec, sidecar = simulate_recording(load_scenario(args), args.duration, name, overrides,
                                      args.seed, not args.no_torque, args.sample_dt, args.rotor_momentum)
    write_recording(args.out, rec, sidecar)
    rotor = "" if args.rotor_momentum is None else f", rotor: h_max {args.rotor_momentum:g} kg·m²/s"
    print(f"wrote {args.out} ({rec.t.size} rows), effect: {name or 'none'}{rotor}")
    return 0
