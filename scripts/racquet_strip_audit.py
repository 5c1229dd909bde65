"""diagnose on racquet tosses from an independent simulator (scripts/racquet_strip_sim.py): tosses
of the development set's kind that the project's own simulator did not make, with an air drag of
no form in the catalogue.

The audit's 48 tosses (racquet_strip_sim.PLAN: 30 intermediate-axis flips at 6-30 rad/s, 5
spins about the handle, 5 about the largest axis, all with the air's drag, a constant gyro bias
on seeds ending in 3 or 8; 8 flips without air or bias, the controls) are written to --out and
diagnosed one after the other. Per toss one JSON line: the explanation's leading effect, the
worst-axis rms / noise before and after, the principal ratios after against the simulator's
truth, whether the ratios' 95 % intervals hold the fit's own ratios and the truth, the wall
time. Then per kind: leaders, the drag family's share (viscous_damping, aero_drag), median and
smallest fall of the rms, ratio errors, and on the controls what was named (nothing, if right).

Usage: PYTHONPATH=. python scripts/racquet_strip_audit.py [--out DIR] [--kinds flips,clean]
(about 2 minutes for all 48 on this 2-core machine).
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from racquet_strip_sim import PLAN, simulate_toss, write_toss  # noqa: E402

from inertia_gym.discrepancy.report import diagnose  # noqa: E402
from inertia_gym.recordings import read_recordings  # noqa: E402

DRAG_FAMILY = ("viscous_damping", "aero_drag")


def audited(path: Path, truth: dict) -> dict:
    """One toss's row: diagnose's reading of the recording at path against the simulator's truth."""
    rec = list(read_recordings(path))[0]
    start = time.perf_counter()
    report, _ = diagnose(rec)
    wall = time.perf_counter() - start
    before, after = report["fit_before"], report["fit_after"]
    ratios, ci = np.array(after["principal_ratios"]), after["principal_ratios_ci95"]
    true = np.array(truth["ratios"])
    ci = np.array(ci) if ci is not None else None
    return {"toss": path.stem, "kind": path.parent.name,
            "explanation": [e["name"] for e in report["explanation"]],
            "valid": bool(after["valid"]), "before": max(before["rms_over_noise"]),
            "after": max(after["rms_over_noise"]), "ratios": ratios.tolist(),
            "ratio_error": float(np.abs(ratios[1:] - true[1:]).max()),
            "holds_own": None if ci is None else _inside(ratios, ci),
            "holds_truth": None if ci is None else _inside(true[1:], ci[1:]),
            "beyond_catalogue": report["beyond_catalogue"], "wall_s": round(wall, 2)}


def _inside(values, intervals) -> bool:
    """Whether every value (k,) lies in its interval (k, 2)."""
    return bool(np.all((intervals[:, 0] <= values) & (values <= intervals[:, 1])))


def summary(rows: list[dict]) -> dict:
    """Per kind: counts of leaders, the drag family's share, the rms's fall, the ratios' errors and
    intervals, wall times."""
    out = {}
    for kind in dict.fromkeys(r["kind"] for r in rows):
        some = [r for r in rows if r["kind"] == kind]
        leads = collections.Counter(r["explanation"][0] if r["explanation"] else "none" for r in some)
        falls = [r["before"] / r["after"] for r in some if r["valid"] and r["after"] > 0]
        out[kind] = {"tosses": len(some), "valid": sum(r["valid"] for r in some), "leaders": dict(leads),
                     "drag_family_leads": sum(leads[n] for n in DRAG_FAMILY),
                     "rms_before_median": float(np.median([r["before"] for r in some])),
                     "rms_after_median": float(np.median([r["after"] for r in some])),
                     "fall_median": float(np.median(falls)), "fall_min": float(np.min(falls)),
                     "ratio_error_median": float(np.median([r["ratio_error"] for r in some])),
                     "ratio_error_max": float(np.max([r["ratio_error"] for r in some])),
                     "intervals_hold_own": sum(bool(r["holds_own"]) for r in some),
                     "intervals_hold_truth": sum(bool(r["holds_truth"]) for r in some),
                     "beyond_catalogue": sum(r["beyond_catalogue"] for r in some),
                     "wall_median_s": float(np.median([r["wall_s"] for r in some])),
                     "wall_max_s": float(np.max([r["wall_s"] for r in some]))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=None,
                    help="folder for the recordings and audit.json (default: a temporary one)")
    ap.add_argument("--kinds", default=",".join(p[0] for p in PLAN),
                    help="which of the plan's kinds to run (flips, handle, largest, clean)")
    args = ap.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix="racquet_strip_"))
    kinds = args.kinds.split(",")
    rows = []
    for folder, kind, with_air, seeds in PLAN:
        if folder not in kinds:
            continue
        for seed in seeds:
            recording, truth = simulate_toss(seed, kind, with_air, bias=with_air and seed % 5 == 3)
            rows.append(audited(write_toss(out / folder, f"{kind}_{seed}", recording), truth))
            print(json.dumps(rows[-1]), flush=True)
    result = {"rows": rows, "summary": summary(rows)}
    (out / "audit.json").write_text(json.dumps(result, indent=1))
    for kind, line in result["summary"].items():
        print(json.dumps({kind: line}))
    print(f"written: {out / 'audit.json'}")


if __name__ == "__main__":
    main()
