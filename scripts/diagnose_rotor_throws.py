"""Diagnose the real rotor throws with the rotor's momentum withheld, and with it given.

Each throw of ../shared/data/rotor-throws (never copied) is diagnosed twice:
- with its h_x, h_y, h_z columns withheld: the rotor's spin-up and brake are physics the rigid
  model leaves out, and diagnose should name `internal_momentum` (its varying form) with the
  axis of the rotor (truth.json `flywheel_axis`), and its fit should cut the residual;
- with the columns given: the rotor is in the model, and no `internal_momentum` should be
  claimed.

Usage: PYTHONPATH=. python scripts/diagnose_rotor_throws.py [--data DIR] [--out runs/rotor-diagnose]
       [--throws NAME,...]
Prints one row per throw and the totals; writes OUT/summary.json (and each report).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from inertia_gym.commands.common import write_json
from inertia_gym.discrepancy.report import diagnose
from inertia_gym.recordings import read_recordings


def axis_error_deg(fitted, truth) -> float:
    """Angle (deg) between two axes, sign ignored (a rotor's momentum may be fitted either way)."""
    a, b = np.asarray(fitted, float), np.asarray(truth, float)
    c = abs(a @ b) / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(min(c, 1.0))))


def momentum_claim(report: dict):
    """The internal_momentum entry of the explanation, or None."""
    return next((e for e in report["explanation"] if e["name"] == "internal_momentum"), None)


def main() -> None:
    ap = argparse.ArgumentParser()
    default = Path(__file__).resolve().parents[2] / "shared/data/rotor-throws"
    ap.add_argument("--data", default=str(default))
    ap.add_argument("--out", default="runs/rotor-diagnose")
    ap.add_argument("--throws", default="", help="comma-separated throw names (default all)")
    args = ap.parse_args()
    data, out = Path(args.data), Path(args.out)
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
        withheld, _ = diagnose(dataclasses.replace(rec, h=None))
        t1 = time.perf_counter()
        given, _ = diagnose(rec)
        t2 = time.perf_counter()
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
              "rms_fall_at_least_3": sum(f >= 3 for f in falls), "claimed_with_h_given": false_claims}
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "summary.json", {"throws": rows, "totals": totals})
    print(f"\ninternal_momentum named on {named}/{n} throws with h withheld "
          f"(leading on {totals['leading']}); "
          f"axis within 20 deg on {within}/{n} (median {totals['median_axis_error_deg']}); rms fell "
          f">= 3x on {totals['rms_fall_at_least_3']}/{n} (median x{totals['median_rms_fall']}); "
          f"claimed with h given on {false_claims}/{n}")


if __name__ == "__main__":
    main()
