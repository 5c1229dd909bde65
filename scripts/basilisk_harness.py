"""Concealed-effect harness on an independent simulator: Basilisk (PyPI `bsk`, AVS Lab).

Each case is a spacecraft simulated by Basilisk (tests/basilisk_sim.py; the cases are in
tests/basilisk_cases.py): a hub with
slosh particles, hinged panels, reaction wheels, commanded torque bursts, a hidden constant
torque, and a gyro with noise, bias or scale error. The recording (CSV + sidecar, written to
OUT/recordings) carries what a user would log and the hub-only nominal inertia; the concealed
truth sits under the sidecar key `basilisk_truth`, which `diagnose` does not read. `diagnose`
runs on the file read back from disk, and the case is scored against the table ACCEPTED.

Usage: PYTHONPATH=.:tests python scripts/basilisk_harness.py [--out runs/basilisk] [--duration 60]
           [--subset smoke] [--cases NAME,...] [--stamp-scatter 0.1]
Writes OUT/basilisk_harness.json and OUT/basilisk_harness.md; prints the table and the totals.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from basilisk_cases import SMOKE, cases, run_case


def markdown(rows: list[dict], totals: dict) -> str:
    """The table: one row per case, then the totals."""
    lines = ["| case | concealed | nominal off by | named by diagnose | rms / noise after (worst axis) "
             "| mismatch detected | correct |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        worst = max(r["rms_over_noise_after"] or [float("nan")])
        lines.append(f"| {r['case']} | {', '.join(r['components']) or '— (control)'} | "
                     f"{100 * r['nominal_error']:.1f} % | {', '.join(r['named']) or '—'} | {worst:.2f} | "
                     f"{'yes' if r['mismatch_detected'] else 'no'} | {'yes' if r['correct'] else 'no'} |")
    lines += ["", f"Concealed-effect cases correct: {totals['cases_correct']}/{totals['cases']}; "
              f"controls clean: {totals['controls_clean']}/{totals['controls']}; "
              f"wall {totals['wall_s']:.0f} s."]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="runs/basilisk", help="output folder (must not hold earlier recordings)")
    ap.add_argument("--duration", type=float, default=60.0, help="s per recording")
    ap.add_argument("--subset", choices=["all", "smoke"], default="all")
    ap.add_argument("--cases", default="", help="comma-separated case names (default: the subset)")
    ap.add_argument("--stamp-scatter", type=float, default=0.0,
                    help="log time stamps off the sampling instants by up to this share of the interval")
    ap.add_argument("--gyro-step", type=float, default=0.0,
                    help="round the gyro rates to a lattice of this many times its noise level (0: in full)")
    args = ap.parse_args()
    if not 0.0 <= args.stamp_scatter < 0.5:
        raise SystemExit(f"--stamp-scatter must be in [0, 0.5), got {args.stamp_scatter}")
    if args.gyro_step < 0:
        raise SystemExit(f"--gyro-step must be >= 0, got {args.gyro_step}")
    todo = cases(args.duration)
    wanted = set(filter(None, args.cases.split(","))) or (set(SMOKE) if args.subset == "smoke" else None)
    if wanted:
        unknown = wanted - {c.name for c in todo}
        if unknown:
            raise SystemExit(f"--cases: unknown {sorted(unknown)}")
        todo = [c for c in todo if c.name in wanted]
    out = Path(args.out)
    t0 = time.perf_counter()
    rows = []
    for case in todo:
        row = run_case(case, out / "recordings", args.stamp_scatter, args.gyro_step)
        rows.append(row)
        print(f"{row['case']:34s} {','.join(row['components']) or 'control':28s} -> "
              f"{','.join(row['named']) or 'none':40s} {'ok' if row['correct'] else 'WRONG'} "
              f"({row['simulate_s']:.1f}+{row['diagnose_s']:.1f} s)", flush=True)
    controls = [r for r in rows if not r["components"]]
    concealed = [r for r in rows if r["components"]]
    totals = {"cases": len(concealed), "cases_correct": sum(r["correct"] for r in concealed),
              "controls": len(controls), "controls_clean": sum(r["correct"] for r in controls),
              "wall_s": time.perf_counter() - t0, "duration_s": args.duration,
              "stamp_scatter": args.stamp_scatter, "gyro_step": args.gyro_step}
    (out / "basilisk_harness.json").write_text(json.dumps({"totals": totals, "rows": rows}, indent=1) + "\n")
    table = markdown(rows, totals)
    (out / "basilisk_harness.md").write_text(table)
    print(table)


if __name__ == "__main__":
    main()

