"""`inertia-gym identify REC`: the inertia of the body in a recording, with 95 % intervals."""

from __future__ import annotations

import argparse

import numpy as np

from inertia_gym.across import identifications_across, identifications_markdown
from inertia_gym.commands.common import (
    add_recording_argument,
    check_physical_inertia,
    for_each_recording,
    write_json,
    write_summary,
)
from inertia_gym.identification import METHODS, identify, markdown
from inertia_gym.plots import plot_identification


def add_parser(subparsers) -> None:
    """Register the sub-command."""
    p = subparsers.add_parser("identify", help="identify the inertia of the body in a recording",
                              description=__doc__)
    add_recording_argument(p)
    p.add_argument("--method", choices=METHODS, default="ml",
                   help="ml: maximum likelihood over the whole record (default); ekf/ukf: the "
                        "paper's filter run once over the record")
    p.add_argument("--out", default="identify", metavar="DIR", help="output folder (identify)")
    p.add_argument("--no-plots", action="store_true", help="identify.json and summary.md only")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Identify each recording (each phyphox window on its own); one sub-folder per window, and
    for several, the inertia they give together (summary.json, summary.md).
    """
    return for_each_recording(args, lambda rec, sub: _identify_one(rec, sub, args.method, args.no_plots),
                              _summarize)


def _summarize(folder, done, refused) -> None:
    summary = identifications_across(done, refused)
    write_summary(folder, summary, identifications_markdown(summary))


def _identify_one(rec, sub, method: str, no_plots: bool) -> dict:
    """Identify one recording into the folder sub (identify.json, summary.md, plots); its summary."""
    result = identify(rec, method)
    summary = result.summary()
    check_physical_inertia(summary["inertia"], rec.name)
    plots = [] if no_plots else plot_identification(result, sub)
    write_json(sub / "identify.json", summary)
    (sub / "summary.md").write_text(markdown(summary, [p.name for p in plots]))
    moments = np.array(summary["principal_moments"])
    print(f"{rec.name}: principal moments {np.array2string(moments, precision=4)} "
          f"{'kg·m²' if summary['scale_identified'] else '(normalised: scale not identified)'}"
          f", rms/noise {summary['rms_over_noise']:.2f} -> {sub / 'identify.json'}")
    return summary
