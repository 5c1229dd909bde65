"""The `inertia-gym` command. Each sub-command lives in inertia_gym/commands/<name>.py and
exposes ``add_parser(subparsers)`` (which sets ``func``); this module only dispatches.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from inertia_gym.errors import InertiaGymError

COMMANDS = ("validate", "optimize", "benchmark", "simulate", "diagnose", "identify")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="inertia-gym",
        description="Informative excitation design and inertia identification for tumbling bodies.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(f"inertia_gym.commands.{name}").add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit code (2 for a usage or input error)."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except InertiaGymError as exc:
        print(f"inertia-gym {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
