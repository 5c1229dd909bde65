"""diagnose on the real development recordings (never copied into the repository).

racquet: every kept free-flight window of the phyphox racquet tosses. Writes per toss
report.json, summary.md and plots under OUT, prints one line per toss, then what the tosses say
together (OUT/summary.json and summary.md, as `inertia-gym diagnose` writes for several
recordings, with the per-toss rows under "tosses"). --without-segments reads each export as
phyphox writes it, without its authors' meta/segments.csv (its "Raw Data.csv" copied to a
temporary folder, deleted after): the tosses are then the free flights found from the gyro.

rotor: each rotor throw three times. With its h_x, h_y, h_z columns withheld, the rotor's spin-up and
brake are physics the rigid model leaves out: diagnose should name `internal_momentum` (its
varying form) with the rotor's axis (truth.json `flywheel_axis`) and cut the residual. With the
columns given, the rotor is in the model and no `internal_momentum` should be claimed. Withheld
again with the sidecar's body saying {"rotor": false}, a momentum it fits is read as an
unmodelled torque, not a rotor (its explanation entries' `reading`). Prints
one row per throw and the totals; writes OUT/summary.json and each report.

Usage: PYTHONPATH=. python scripts/diagnose_real.py racquet [--data DIR] [--out DIR] [--without-segments]
       PYTHONPATH=. python scripts/diagnose_real.py rotor [--data DIR] [--out DIR] [--throws NAME,...]
Without the data the script prints one line and exits 0.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from inertia_gym.across import diagnoses_across, diagnoses_markdown
from inertia_gym.commands.common import write_json
from inertia_gym.discrepancy.report import diagnose, markdown, write_plots
from inertia_gym.recordings import read_recordings

#: The development data beside the repository.
DATA = Path(__file__).resolve().parents[2] / "shared/data"


def _round(values):
    return None if values is None else np.round(values, 2).tolist()


def racquet(args) -> None:
    """Every kept free-flight window of the racquet tosses, and what they say together."""
    out = Path(args.out or ("runs/racquet-found" if args.without_segments else "runs/racquet"))
    data = Path(args.data or DATA / "phyphox-racquet")
    raws = sorted(data.glob("round*/*/Raw Data.csv"))
    if not raws:
        print(f"no racquet recordings under {data}: nothing to do")
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
        diagnosis = diagnose(rec)
        report = diagnosis.report
        plots = write_plots(sub, diagnosis)
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


def axis_error_deg(fitted, truth) -> float:
    """Angle (deg) between two axes, sign ignored (a rotor's momentum may be fitted either way)."""
    a, b = np.asarray(fitted, float), np.asarray(truth, float)
    c = abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(min(c, 1.0))))


def momentum_claim(report: dict):
    """The internal_momentum entry of the explanation, or None."""
    return next((e for e in report["explanation"] if e["name"] == "internal_momentum"), None)


def rotor(args) -> None:
    """Each rotor throw with its momentum withheld and given, and the totals."""
    data, out = Path(args.data or DATA / "rotor-throws"), Path(args.out or "runs/rotor-diagnose")
    if not (data / "truth.json").exists():
        print(f"no rotor-throw data at {data} (truth.json missing): nothing to do")
        return
    truth = json.loads((data / "truth.json").read_text())
    wanted = set(filter(None, args.throws.split(",")))
    rows = []
    for csv in sorted(data.glob("*.csv")):
        if wanted and csv.stem not in wanted:
            continue
        (rec,) = read_recordings(csv)
        axis = truth[csv.stem]["flywheel_axis"]
        t0 = time.perf_counter()
        withheld = diagnose(dataclasses.replace(rec, h=None)).report
        t1 = time.perf_counter()
        given = diagnose(rec).report
        t2 = time.perf_counter()
        denied = diagnose(dataclasses.replace(rec, h=None, meta=rec.meta | {"body": {"rotor": False}})).report
        (out / csv.stem).mkdir(parents=True, exist_ok=True)
        write_json(out / csv.stem / "withheld.json", withheld)
        write_json(out / csv.stem / "given.json", given)
        claim = momentum_claim(withheld)
        before = np.sqrt(np.mean(np.square(withheld["fit_before"]["rms"])))
        after = np.sqrt(np.mean(np.square(withheld["fit_after"]["rms"])))
        row = {"throw": csv.stem,
               "explanation_withheld": [e["name"] for e in withheld["explanation"]],
               "named": claim is not None,
               "leading": [e["name"] for e in withheld["explanation"]][:1] == ["internal_momentum"],
               "axis_error_deg": axis_error_deg(claim["params"]["axis"], axis)
               if claim is not None and "axis" in claim["params"] else None,
               "rms_before": float(before), "rms_after": float(after), "rms_fall": float(before / after),
               "explanation_given": [e["name"] for e in given["explanation"]],
               "claimed_with_h_given": momentum_claim(given) is not None,
               "reading_withheld": claim["reading"] if claim is not None else None,
               "reading_rotor_denied": [e["reading"] for e in denied["explanation"]
                                        if e["name"] == "internal_momentum"],
               "wall_s": [round(t1 - t0, 2), round(t2 - t1, 2)]}
        rows.append(row)
        angle = row["axis_error_deg"]
        print(f"{row['throw']:26s} withheld -> {','.join(row['explanation_withheld']) or 'none':48s} "
              f"axis {angle if angle is None else round(angle, 1)} "
              f"deg, rms x{row['rms_fall']:.1f}; given -> {','.join(row['explanation_given']) or 'none'} "
              f"({row['wall_s'][0]}+{row['wall_s'][1]} s)", flush=True)
    n = len(rows)
    named = sum(r["named"] for r in rows)
    axes = [r["axis_error_deg"] for r in rows if r["axis_error_deg"] is not None]
    within = sum(a <= 20.0 for a in axes)
    falls = [r["rms_fall"] for r in rows]
    false_claims = sum(r["claimed_with_h_given"] for r in rows)
    totals = {"throws": n, "internal_momentum_named": named, "leading": sum(r["leading"] for r in rows),
              "axis_within_20_deg": within, "median_axis_error_deg": float(np.median(axes)) if axes else None,
              "median_rms_fall": float(np.median(falls)) if falls else None,
              "rms_fall_at_least_3": sum(f >= 3 for f in falls), "claimed_with_h_given": false_claims,
              "worded_conditionally": sum(r["reading_withheld"] == "if_carried" for r in rows),
              "rotor_denied_read_as_torque": sum(bool(r["reading_rotor_denied"]) and all(
                  x == "unmodelled" for x in r["reading_rotor_denied"]) for r in rows)}
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "summary.json", {"throws": rows, "totals": totals})
    print(f"\ninternal_momentum named on {named}/{n} throws with h withheld "
          f"(leading on {totals['leading']}); "
          f"axis within 20 deg on {within}/{n} (median {totals['median_axis_error_deg']}); rms fell "
          f">= 3x on {totals['rms_fall_at_least_3']}/{n} (median x{totals['median_rms_fall']}); "
          f"claimed with h given on {false_claims}/{n}; worded 'if the body carries a rotor' on "
          f"{totals['worded_conditionally']}/{n}; with the sidecar's body saying no rotor, read as an "
          f"unmodelled torque on {totals['rotor_denied_read_as_torque']}/{n}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="data_set", required=True)
    one = sub.add_parser("racquet", help="the phyphox racquet tosses")
    one.add_argument("--data", default=None, help="default ../shared/data/phyphox-racquet")
    one.add_argument("--out", default=None, help="default runs/racquet, or runs/racquet-found "
                     "with --without-segments")
    one.add_argument("--without-segments", action="store_true",
                     help="ignore meta/segments.csv: diagnose the free flights found from the gyro")
    two = sub.add_parser("rotor", help="the rotor throws, h withheld and given")
    two.add_argument("--data", default=None, help="default ../shared/data/rotor-throws")
    two.add_argument("--out", default=None, help="default runs/rotor-diagnose")
    two.add_argument("--throws", default="", help="comma-separated throw names (default all)")
    args = ap.parse_args()
    (racquet if args.data_set == "racquet" else rotor)(args)


if __name__ == "__main__":
    main()
