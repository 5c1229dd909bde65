"""`inertia-gym example NAME [--out DIR]`: copy a shipped example recording (CSV + sidecar) into
a folder, to try `identify` and `diagnose` without data of your own (inertia_gym.examples).
"""

from __future__ import annotations

import argparse

from inertia_gym import examples


def add_parser(subparsers) -> None:
    """Register the sub-command."""
    p = subparsers.add_parser("example", help="copy a shipped example recording into a folder",
                              description=__doc__)
    p.add_argument("name", choices=examples.names(), help="which example")
    p.add_argument("--out", default="examples", metavar="DIR",
                   help="folder to copy it into (default: examples)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Copy the example; print where it went."""
    target = examples.write(args.name, args.out)
    print(f"{args.name}: {target} (sidecar {target.with_suffix('.json').name})")
    return 0
