"""The `inertia-gym` command. Each sub-command lives in inertia_gym/commands/<name>.py and
exposes ``add_parser(subparsers)`` (which sets ``func``); this module only dispatches.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import traceback
import warnings
from pathlib import Path

from inertia_gym.errors import InertiaGymError, InputWarning

COMMANDS = ("validate", "optimize", "benchmark", "simulate", "diagnose", "identify", "example")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="inertia-gym",
        description="Informative excitation design and inertia identification for tumbling bodies.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for name in COMMANDS:
        importlib.import_module(f"inertia_gym.commands.{name}").add_parser(sub)
    parser.subcommands = sub.choices  # name -> its parser, for errors in the sub-command's words
    return parser


#: Set to 1 to see the full traceback of an internal failure instead of its one-line summary.
DEBUG_VARIABLE = "INERTIA_GYM_DEBUG"


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit code: 2 for a usage or input error, 1 for an
    internal failure (one line on stderr; the traceback with INERTIA_GYM_DEBUG=1).
    """
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # a mistyped option: the sub-command's usage, which lists its options
        parser.subcommands[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
    shown = warnings.showwarning

    def one_line(message, category, filename, lineno, file=None, line=None):
        """A warning about the user's input as one line naming the command; others as Python shows them."""
        if issubclass(category, InputWarning):
            print(f"inertia-gym {args.command}: warning: {message}", file=sys.stderr)
        else:
            shown(message, category, filename, lineno, file, line)

    warnings.showwarning = one_line
    try:
        return int(args.func(args) or 0)
    except InertiaGymError as exc:
        print(f"inertia-gym {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # a failure the command did not foresee: one line, not a traceback
        if os.environ.get(DEBUG_VARIABLE) == "1":
            raise
        where = traceback.extract_tb(exc.__traceback__)[-1]
        print(f"inertia-gym {args.command}: internal error: {type(exc).__name__}: {exc} "
              f"(at {Path(where.filename).name}:{where.lineno}; rerun with {DEBUG_VARIABLE}=1 "
              "for the traceback, and please report it)", file=sys.stderr)
        return 1
    finally:
        warnings.showwarning = shown


if __name__ == "__main__":
    sys.exit(main())
