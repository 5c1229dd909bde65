"""`inertia-gym identify REC [--joint]`: the inertia of the body in a recording, with 95 % intervals;
with --joint, one inertia from every recording of a folder (or file of segments) of one body.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from inertia_gym.across import identifications_across, identifications_markdown
from inertia_gym.commands.common import (
    add_recording_argument,
    check_physical_inertia,
    for_each_recording,
    write_json,
    write_summary,
)
from inertia_gym.errors import ConfigError
from inertia_gym.identification import METHODS, identify_prepared
from inertia_gym.identify_report import joint_markdown, markdown
from inertia_gym.joint_identification import identify_joint
from inertia_gym.plots import plot_identification
from inertia_gym.prepare import prepared


def add_parser(subparsers) -> None:
    """Register the sub-command."""
    p = subparsers.add_parser("identify", help="identify the inertia of the body in a recording",
                              description=__doc__)
    add_recording_argument(p)
    p.add_argument("--method", choices=METHODS, default="ml",
                   help="ml: maximum likelihood over the whole record (default); ekf/ukf: the "
                        "paper's filter run once over the record")
    p.add_argument("--out", default="identify", metavar="DIR", help="output folder (default: identify)")
    p.add_argument("--no-plots", action="store_true", help="identify.json and summary.md only")
    p.add_argument("--joint", action="store_true",
                   help="the recordings are of one body: also fit one inertia to them all (DIR/joint.json, "
                        "DIR/joint.md), each keeping its own initial state and noise level")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Identify each recording (each phyphox window on its own); one sub-folder per window, and
    for several, the inertia they give together (summary.json, summary.md); with --joint, also
    one inertia fitted to them all (joint.json, joint.md).
    """
    if args.joint and args.method != "ml":
        raise ConfigError("--joint fits by maximum likelihood and the equation error: use it with "
                          "--method ml")
    preps, results = [], []

    def one(rec, sub):
        return _identify_one(rec, sub, args.method, args.no_plots, results, preps)

    code = for_each_recording(args, one, _summarize)
    if args.joint:
        recordings = [p.rec for p in preps]
        joint = identify_joint(recordings, results, preps)
        summary = joint.summary()
        folder = Path(args.out)
        write_json(folder / "joint.json", summary)
        (folder / "joint.md").write_text(joint_markdown(summary))
        moments = np.array(summary["principal_moments"])
        print(f"joint ({len(recordings)} recordings, {summary['estimator']}): principal moments "
              f"{_moments(moments)}, agreement p = {summary['agreement_p']:.3g} "
              f"-> {folder / 'joint.json'}")
    return code


def _summarize(folder, done, refused) -> None:
    summary = identifications_across(done, refused)
    write_summary(folder, summary, identifications_markdown(summary))


def _moments(moments) -> str:
    """Principal moments in words, four significant figures each."""
    return "[" + ", ".join(f"{m:.4g}" for m in moments) + "]"


def _identify_one(rec, sub, method: str, no_plots: bool, results: list | None = None,
                  preps: list | None = None) -> dict:
    """Identify one recording into the folder sub (identify.json, summary.md, plots); its summary.
    results, preps: where the Identification and the prepared record are kept (a joint fit
    reuses both: the record is prepared once).
    """
    started = time.perf_counter()
    prep = prepared(rec)
    result = identify_prepared(prep, method, started=started)
    if results is not None:
        results.append(result)
        preps.append(prep)
    summary = result.summary()
    check_physical_inertia(summary["inertia"], rec.name)
    plots = [] if no_plots else plot_identification(result, sub)
    write_json(sub / "identify.json", summary)
    (sub / "summary.md").write_text(markdown(summary, [p.name for p in plots]))
    moments = np.array(summary["principal_moments"])
    print(f"{rec.name}: principal moments {_moments(moments)} "
          f"{'kg·m²' if summary['scale_identified'] else '(normalised: scale not identified)'}"
          f", rms/noise {summary['rms_over_noise']:.2f} -> {sub / 'identify.json'}")
    return summary
