"""Options and helpers shared by the sub-commands."""

from __future__ import annotations

import argparse
import json
import re
import sys
import warnings
from pathlib import Path

import numpy as np

from inertia_gym.errors import ConfigError, InertiaGymError, RecordingError
from inertia_gym.estimation.inertia_param import REALIZABLE_TOLERANCE
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
                             f"paper's J. Default: {DEFAULT_COST}")
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
    """The positional REC of the commands that read a recording, with --columns and the units."""
    from inertia_gym.recordings import RATE_UNITS, TIME_UNITS

    parser.add_argument("rec", metavar="REC",
                        help="project CSV/Parquet (+ sidecar JSON), a phyphox export (its "
                             "folder or 'Raw Data.csv', or the .zip or .xlsx phyphox writes), "
                             "or a folder holding recordings at any depth")
    parser.add_argument("--columns", metavar="MAP", default=None,
                        help="the file's own column names, e.g. t=time,wx=gx,wy=gy,wz=gz "
                             "(format name=file name, comma separated)")
    parser.add_argument("--time-unit", choices=tuple(TIME_UNITS), default=None,
                        help="unit of the time column, converted to s (default: s, and time "
                             "evidently in ms or us is refused)")
    parser.add_argument("--rate-unit", choices=tuple(RATE_UNITS), default=None,
                        help="unit of the gyro columns, converted to rad/s (default: rad/s, and "
                             "rates evidently in deg/s are refused)")


def parse_column_map(text: str | None) -> dict[str, str] | None:
    """--columns 't=time,wx=gx' -> {'t': 'time', 'wx': 'gx'} (None for None); ConfigError on
    a pair without '=', an empty name or a format name given twice.
    """
    if text is None:
        return None
    mapping: dict[str, str] = {}
    for pair in text.split(","):
        target, sep, source = (part.strip() for part in pair.partition("="))
        if not sep or not target or not source:
            raise ConfigError(f"--columns: expected NAME=COLUMN pairs separated by commas, got {pair!r}")
        if target in mapping:
            raise ConfigError(f"--columns: {target!r} is mapped twice")
        mapping[target] = source
    return mapping


#: What several recordings say together, beside their sub-folders (a recording of that name
#: gets a folder with "_" appended).
SUMMARY_FILES = ("summary.json", "summary.md")


def for_each_recording(args: argparse.Namespace, work, summarize=None) -> int:
    """Run work(recording, its output folder) -> its result on every recording (segment) of
    args.rec (read with args.columns, args.time_unit, args.rate_unit); the folder is args.out
    itself for a single recording, else one sub-folder per recording named after it, and then
    summarize(args.out, [(name, result)], [(name, one-line reason)]) writes what they say
    together. Returns 0.

    A single recording's refusal (an InertiaGymError: the recording refused, the fit diverged) is
    raised as it is. Of several (a folder of recordings, a file of segments), a refused one does
    not stop the rest, nor does a file of the folder that cannot be read: its one-line reason
    goes to stderr and to refused.txt in its folder, and once all are done (and summarized) a
    RecordingError says how many were refused (exit 2).
    """
    from inertia_gym.recordings import recording_sources

    path = Path(args.rec)
    many = path.is_dir() and not (path / "Raw Data.csv").exists()  # not one phyphox export
    sources = recording_sources(path) if many else [(None, path)]
    pending = list(_read_each(sources, (parse_column_map(args.columns), args.time_unit, args.rate_unit)))
    folder = prepare_out_dir(args.out)
    if len(pending) == 1:
        rec = pending[0][1]
        if isinstance(rec, InertiaGymError):
            raise rec
        work(rec, folder)
        return 0
    done, refused = [], []
    for label, rec in pending:
        safe = re.sub(r"[^\w.-]+", "_", label)
        sub = prepare_out_dir(folder / (f"{safe}_" if safe in SUMMARY_FILES else safe))
        try:
            if isinstance(rec, InertiaGymError):  # the file could not be read
                raise rec
            done.append((label, work(rec, sub)))
        except InertiaGymError as exc:
            refused.append((label, str(exc)))
            (sub / "refused.txt").write_text(f"{exc}\n")
            print(f"{label}: refused: {exc}", file=sys.stderr)
    if summarize is not None:
        summarize(folder, done, refused)
    if refused:
        written = len(pending) - len(refused)
        raise RecordingError(f"{len(refused)} of {len(pending)} recordings refused (reasons above and in "
                             f"each one's refused.txt under {folder}); the other {written} are written")
    return 0


def write_summary(folder: Path, summary: dict, text: str) -> None:
    """Write what several recordings say together: folder/SUMMARY_FILES."""
    json_path, md_path = (folder / name for name in SUMMARY_FILES)
    write_json(json_path, summary)
    md_path.write_text(text)
    print(f"across {summary['recordings']} recordings -> {md_path}")


def _read_each(sources, units):
    """(name, recording) of every recording of sources ((name or None, path) pairs, read with
    units = (columns, time_unit, rate_unit)); (name, the InertiaGymError) for a source that
    cannot be read (name: its path where None).
    """
    from inertia_gym.recordings import read_source

    for name, source in sources:
        try:
            recs = read_source(source, name, *units)
        except InertiaGymError as exc:
            yield (name or str(source)), exc
            continue
        for rec in recs:
            yield rec.name, rec


def check_physical_inertia(inertia, what: str) -> None:
    """Refuse (RecordingError) a result inertia (3, 3) kg·m² that no body can have: not finite,
    not symmetric positive definite, or principal moments breaking the triangle inequality
    (each at most the sum of the others, to REALIZABLE_TOLERANCE). what names it in the message.
    """
    j = np.asarray(inertia, dtype=float)
    fix = ("the recording does not determine a rigid body's inertia: too short or too little motion, "
           "or check the units (--time-unit, --rate-unit) and the column mapping (--columns)")
    if j.shape != (3, 3) or not np.all(np.isfinite(j)):
        raise RecordingError(f"{what}: the fitted inertia is not a finite 3x3 matrix; {fix}")
    moments = np.linalg.eigvalsh(0.5 * (j + j.T))
    if moments[0] <= 0 or moments[2] > (moments[0] + moments[1]) * (1 + REALIZABLE_TOLERANCE):
        raise RecordingError(f"{what}: the fitted inertia has principal moments "
                             f"{np.array2string(moments, precision=4)}, which no body has; {fix}")


def prepare_out_dir(path: str | Path) -> Path:
    """Create the output folder (parents too) and return it."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    return out


def write_json(path: Path, data: dict) -> None:
    """Write JSON atomically (temporary file, then rename), numpy values converted; NaN and
    infinity are refused (ValueError) rather than written as invalid JSON.
    """
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_to_builtin, allow_nan=False) + "\n")
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
