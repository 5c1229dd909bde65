"""Diagnose every kept free-flight window of the phyphox racquet tosses (data never copied
into the repository).

Usage: PYTHONPATH=. python scripts/diagnose_racquet.py [--data ../shared/data/phyphox-racquet]
       [--out DIR] [--without-segments]
Writes per toss report.json, summary.md and plots under OUT, prints one line per toss, then what
the tosses say together (OUT/summary.json and summary.md, as `inertia-gym diagnose` writes for
several recordings, with the per-toss rows below under "tosses"). --without-segments reads each
export as phyphox writes it, without its authors' meta/segments.csv (its "Raw Data.csv" copied to
a temporary folder, deleted after): the tosses are then the free flights found from the gyro.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np

from inertia_gym.across import diagnoses_across, diagnoses_markdown
from inertia_gym.commands.common import write_json
from inertia_gym.discrepancy.report import diagnose, markdown, write_plots
from inertia_gym.recordings import read_recordings


def _round(values):
    return None if values is None else np.round(values, 2).tolist()


def main() -> None:
    ap = argparse.ArgumentParser()
    data = Path(__file__).resolve().parents[2] / "shared/data/phyphox-racquet"
    ap.add_argument("--data", default=str(data))
    ap.add_argument("--out", default=None, help="default runs/racquet, or runs/racquet-found "
                    "with --without-segments")
    ap.add_argument("--without-segments", action="store_true",
                    help="ignore meta/segments.csv: diagnose the free flights found from the gyro")
    args = ap.parse_args()
    out = Path(args.out or ("runs/racquet-found" if args.without_segments else "runs/racquet"))
    raws = sorted(Path(args.data).glob("round*/*/Raw Data.csv"))
    if not raws:
        print(f"no racquet recordings under {args.data}: nothing to do")
        return
    rows, reports = [], []
    with tempfile.TemporaryDirectory() as scratch:
        for raw in raws:
            source = raw.parent
            if args.without_segments:  # the export as phyphox writes it: no segments file
                source = Path(scratch) / raw.parent.parent.name / raw.parent.name
                source.mkdir(parents=True)
                shutil.copy(raw, source / raw.name)
            rows += _diagnose_each(read_recordings(source), raw.parent.parent.name, out, reports)
    summary = diagnoses_across(reports, [])
    write_json(out / "summary.json", {**summary, "tosses": rows})
    text = diagnoses_markdown(summary)
    (out / "summary.md").write_text(text)
    print("\n".join(line for line in text.splitlines() if line.startswith("- ")))


def _diagnose_each(recs, round_name: str, out: Path, reports: list) -> list[dict]:
    """Diagnose each recording of one export, write its outputs under out, one row per toss;
    each (toss, report) appended to reports."""
    rows = []
    for rec in recs:
        sub = out / re.sub(r"[^\w.-]+", "_", f"{round_name}_{rec.name}")
        sub.mkdir(parents=True, exist_ok=True)
        report, arrays = diagnose(rec)
        plots = write_plots(sub, report, arrays)
        write_json(sub / "report.json", report)
        (sub / "summary.md").write_text(markdown(report, plots))
        reports.append((sub.name, report))
        top = [f"{e['name']}({e['delta_bic']:.0f})" for e in report["effects"][:3]
               if e["delta_bic"] is not None]
        inertia = np.array(report["fit_after"]["inertia"])
        eig = np.sort(np.linalg.eigvalsh(inertia))[::-1]
        rows.append({"toss": sub.name, "window": rec.meta.get("window"),
                     "best": report["best_effect"], "top3": top,
                     "explanation": [e["name"] for e in report["explanation"]],
                     "before": _round(report["fit_before"]["rms_over_noise"]),
                     "after": _round(report["fit_after"]["rms_over_noise"]),
                     "max_abs_rate": float(np.abs(rec.w).max()),
                     "principal_ratios": np.round(eig / eig[0], 3).tolist(),
                     "invariants": report["invariants"].get("verdict"),
                     "locations": len(report["locations"]),
                     "sigma": np.round(report["gyro_sigma"], 4).tolist()})
        print(json.dumps(rows[-1]), flush=True)
    return rows


if __name__ == "__main__":
    main()
