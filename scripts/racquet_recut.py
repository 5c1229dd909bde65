"""diagnose and identify on the real racquet tosses re-cut: tosses we were not given, of the kind.

Each kept free-flight window of ``../shared/data/phyphox-racquet`` (its ``meta/segments.csv``) is
cut again with its start and end moved by CUTS seconds (widened to hold part of the throw and the
catch, narrowed, shifted), and every cut is diagnosed and identified as a user's own toss would
be. Per cut it prints one JSON line: diagnose's leading explanation, its worst-axis rms / noise
before and after, the principal-moment ratios after, identify's ratios and rms / noise, or the
one-line refusal of either. Then the counts: valid fits, refusals, other failures (a traceback
of any kind is a defect), the leading explanation per round, the median fall of the rms, and the
spread of identify's ratios per toss.

Usage: PYTHONPATH=. python scripts/racquet_recut.py [--data ../shared/data/phyphox-racquet]
The data live outside the repository: without the folder the script prints one line and exits 0.
"""

from __future__ import annotations

import argparse
import collections
import json
import warnings
from pathlib import Path

import numpy as np

from inertia_gym.across import leading_effect
from inertia_gym.discrepancy.report import diagnose
from inertia_gym.errors import EstimatorDivergedError, RecordingError
from inertia_gym.identification import identify
from inertia_gym.recordings import Recording, read_recordings

#: (start, end) shifts of each window, s: widened, narrowed, start later, end earlier, as given.
CUTS = ((-0.05, 0.05), (0.05, -0.05), (0.1, 0.0), (0.0, -0.1), (0.0, 0.0))


def _ratios(inertia) -> list[float]:
    """Principal moments 2 and 3 over the largest, rounded (identify's inertia (3, 3))."""
    moments = np.sort(np.linalg.eigvalsh(np.asarray(inertia, float)))[::-1]
    return np.round(moments[1:] / moments[0], 3).tolist()


def recut(t, w, window, name: str) -> dict:
    """diagnose and identify on one cut (t (n,) s, w (n, 3) rad/s, window (start, end) s)."""
    keep = (t >= window[0]) & (t <= window[1])
    rec = Recording(t[keep], w[keep], name=name)
    row = {"cut": name}
    try:
        report, _ = diagnose(rec)
        after = report["fit_after"]
        row |= {"lead": leading_effect(report),
                "before": round(max(report["fit_before"]["rms_over_noise"]), 1),
                "after": round(max(after["rms_over_noise"]), 1) if after["valid"] else None,
                "ratios": np.round(after["principal_ratios"][1:], 3).tolist() if after["valid"] else None}
    except RecordingError as err:
        row["diagnose_refused"] = str(err)
    try:
        res = identify(rec)
        row |= {"identify_ratios": _ratios(res.estimate.inertia),
                "identify_rms": round(res.rms_over_noise, 1), "identify_converged": res.converged}
    except (RecordingError, EstimatorDivergedError) as err:
        row["identify_refused"] = str(err)
    return row


def summarize(rows: list[dict], failures: list[str]) -> dict:
    """The counts over all cuts: rows as recut() gives them (a cut whose diagnosis names no
    effect leads with "none"), failures the one-line tracebacks of the cuts that raised."""
    fitted = [r for r in rows if r.get("after") is not None]
    leads = collections.Counter((r["cut"].split()[0], r["lead"]) for r in fitted)
    fall = [r["before"] / r["after"] for r in fitted]
    spread = collections.defaultdict(list)
    for r in rows:
        if "identify_ratios" in r:
            spread[r["cut"].rsplit(" ", 2)[0]].append(r["identify_ratios"])
    return {
        "cuts": len(rows) + len(failures), "diagnose_valid": len(fitted),
        "diagnose_refused": sum("diagnose_refused" in r for r in rows),
        "identify_results": sum("identify_ratios" in r for r in rows),
        "identify_refused": sum("identify_refused" in r for r in rows),
        "other_failures": len(failures),
        "leading": {f"{k[0]} {k[1]}": v for k, v in sorted(leads.items())},
        "rms_fall_median": round(float(np.median(fall)), 1) if fall else None,
        "rms_fall_below_3x": int(np.sum(np.array(fall) < 3.0)),
        "identify_ratio_spread_max": round(max(float(np.ptp(np.array(v), axis=0).max())
                                               for v in spread.values()), 3) if spread else None}


def main() -> None:
    ap = argparse.ArgumentParser()
    data = Path(__file__).resolve().parents[2] / "shared/data/phyphox-racquet"
    ap.add_argument("--data", default=str(data))
    args = ap.parse_args()
    raws = sorted(Path(args.data).glob("round*/*/Raw Data.csv"))
    if not raws:
        print(f"no racquet recordings under {args.data}: nothing to do")
        return
    warnings.simplefilter("error")  # a warning reaching the user is a defect: count it as one
    rows, failures = [], []
    for raw in raws:
        table = np.loadtxt(raw, delimiter=",", skiprows=1)
        for seg in read_recordings(raw.parent):
            start, end = seg.meta["window"]
            for shift in CUTS:
                name = (f"{raw.parent.parent.name} segment {seg.meta['segment']} "
                        f"{shift[0]:+.2f} {shift[1]:+.2f}")
                try:
                    rows.append(recut(table[:, 0], table[:, 1:4], (start + shift[0], end + shift[1]), name))
                except Exception as exc:  # noqa: BLE001 -- counted and printed: the defects sought
                    failures.append(f"{name}: {type(exc).__name__}: {exc}")
                    print(failures[-1])
                    continue
                print(json.dumps(rows[-1]), flush=True)
    print(json.dumps(summarize(rows, failures)))


if __name__ == "__main__":
    main()
