"""`inertia-gym diagnose REC`: find where a recording departs from the rigid model and why."""

from __future__ import annotations

import argparse

from inertia_gym.across import diagnoses_across, diagnoses_markdown
from inertia_gym.commands.common import (
    add_recording_argument,
    check_physical_inertia,
    for_each_recording,
    write_json,
    write_summary,
)
from inertia_gym.discrepancy.report import diagnose, markdown, write_plots
from inertia_gym.html_page import render


def add_parser(subparsers) -> None:
    """Register the sub-command."""
    p = subparsers.add_parser("diagnose", help="diagnose a recording against the rigid-body model",
                              description=__doc__)
    add_recording_argument(p)
    p.add_argument("--out", default="diagnosis", metavar="DIR", help="output folder (default: diagnosis)")
    p.add_argument("--no-plots", action="store_true", help="report.json and summary only")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Diagnose each recording (each phyphox window on its own); one sub-folder per window, and
    for several, what they say together (summary.json, summary.md).
    """
    return for_each_recording(args, lambda rec, sub: _diagnose_one(rec, sub, args.no_plots),
                              _summarize)


def _summarize(folder, done, refused) -> None:
    summary = diagnoses_across(done, refused)
    write_summary(folder, summary, diagnoses_markdown(summary))


def _diagnose_one(rec, sub, no_plots: bool) -> dict:
    """Diagnose one recording into the folder sub (report.json, summary.md, summary.html with the
    plots inlined, plots); its report.
    """
    diagnosis = diagnose(rec)
    report = diagnosis.report
    check_physical_inertia(report["fit_after"]["inertia"], rec.name)
    plots = [] if no_plots else write_plots(sub, diagnosis)
    write_json(sub / "report.json", report)
    page = markdown(report, plots)
    (sub / "summary.md").write_text(page)
    (sub / "summary.html").write_text(render(page, sub, f"Diagnosis of {rec.name}"))
    print(f"{rec.name}: mismatch={report['mismatch_detected']} best={report['best_effect']} "
          f"-> {sub / 'report.json'}")
    return report
