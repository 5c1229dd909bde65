"""Options and helpers shared by the sub-commands."""

from __future__ import annotations

import argparse
import json
import re
import sys
import warnings
from pathlib import Path

import numpy as np

from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario, ScenarioWarning, shipped_scenarios


def add_scenario_option(parser: argparse.ArgumentParser) -> None:
    """--scenario FILE|NAME: TOML or JSON overriding fields of the paper's scenario, or the name
    of a shipped example.
    """
    parser.add_argument(
        "--scenario", metavar="FILE|NAME", default=None,
        help="TOML or JSON file overriding any scenario field, or a shipped scenario "
             f"({', '.join(shipped_scenarios())}); default: the paper's scenario",
    )


def add_objective_options(parser: argparse.ArgumentParser) -> None:
    """--cost and --carry-over / --restart-each-episode: what one evaluation of xi is.

    Defaults: the measured ones of inertia_gym.optimization (DEFAULT_COST, DEFAULT_CARRY_OVER);
    ``--carry-over --cost info`` is the paper's Algorithm 1. Sets args.cost and args.carry_over.
    """
    from inertia_gym.episode import COSTS
    from inertia_gym.optimization import DEFAULT_CARRY_OVER, DEFAULT_COST

    parser.add_argument("--cost", choices=COSTS, default=DEFAULT_COST,
                        help=f"posterior: change of log det P_theta over the episode; info: the "
                             f"paper's J ({DEFAULT_COST})")
    objective = parser.add_mutually_exclusive_group()
    default = "carry-over" if DEFAULT_CARRY_OVER else "restart-each-episode"
    objective.add_argument("--carry-over", dest="carry_over", action="store_true",
                           help="the estimator carries over from one evaluation to the next, "
                                "as in the paper's Algorithm 1 (with --cost info: Algorithm 1 "
                                f"itself) (default: {default})")
    objective.add_argument("--restart-each-episode", dest="carry_over", action="store_false",
                           help="every evaluation is one episode from the scenario's start: a "
                                f"stationary objective (default: {default})")
    parser.set_defaults(carry_over=DEFAULT_CARRY_OVER)


def load_scenario(args: argparse.Namespace) -> Scenario:
    """The scenario selected by --scenario; its implausibilities (ScenarioWarning) are printed
    on stderr as one line each, "warning: ...".
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ScenarioWarning)
        sc = Scenario.load(args.scenario)
    command = getattr(args, "command", None) or "scenario"
    for w in caught:
        if issubclass(w.category, ScenarioWarning):
            print(f"inertia-gym {command}: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return sc


def add_recording_argument(parser: argparse.ArgumentParser) -> None:
    """The positional REC of the commands that read a recording."""
    parser.add_argument("rec", metavar="REC",
                        help="project CSV/Parquet (+ sidecar JSON) or a phyphox export "
                             "folder/'Raw Data.csv'")


def recording_folders(rec_path: str, out: str | Path):
    """Read every recording (segment) of rec_path; yield (recording, its output folder): out
    itself for a single recording, else one sub-folder per segment named after it.
    """
    from inertia_gym.discrepancy.recordings import read_recordings

    recs = read_recordings(rec_path)
    folder = prepare_out_dir(out)
    for rec in recs:
        yield rec, folder if len(recs) == 1 else prepare_out_dir(folder / re.sub(r"[^\w.-]+", "_", rec.name))


def prepare_out_dir(path: str | Path) -> Path:
    """Create the output folder (parents too) and return it."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    return out


def write_json(path: Path, data: dict) -> None:
    """Write JSON atomically (temporary file, then rename), numpy values converted."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_to_builtin) + "\n")
    tmp.replace(path)


def _to_builtin(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"not JSON serialisable: {type(obj)}")


def positive_int(text: str) -> int:
    """Argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from exc
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def nonnegative_int(text: str) -> int:
    """Argparse type: an integer >= 0 (seeds)."""
    try:
        value = int(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from exc
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    return value


def positive_float(text: str) -> float:
    """Argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from exc
    if not np.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text}")
    return value
