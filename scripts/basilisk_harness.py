"""Basilisk (PyPI `bsk`, AVS Lab), an independent simulator, against diagnose and identify.

Each case is a spacecraft simulated by Basilisk (tests/basilisk_sim.py; the cases are in
tests/basilisk_cases.py and tests/basilisk_identify.py).

diagnose: the concealed-effect harness. A hub with slosh particles, hinged panels, reaction
wheels, commanded torque bursts, a hidden constant torque, and a gyro with noise, bias or scale
error. The recording (CSV + sidecar, written to OUT/recordings) carries what a user would log
and the hub-only nominal inertia; the concealed truth sits under the sidecar key
`basilisk_truth`, which `diagnose` does not read. `diagnose` runs on the file read back from
disk, and the case is scored against the table ACCEPTED. Writes OUT/basilisk_harness.json and
OUT/basilisk_harness.md; prints the table and the totals.

identify: five body classes from a 1e-4 kg·m² device to a 1e4 kg·m² upper stage, each with its
own tumble rate, gyro noise, sampling and length, and seven kinds of experiment (commanded
torque bursts with attitude, the same gyro-only, the same with a gyro bias, logged reaction
wheels, a free tumble, and bursts on a vehicle whose slosh particle or hinged panel the model
leaves out); the sidecar's nominal is the hub inertia deliberately wrong. Per case the relative
Frobenius error against Basilisk's rigid-equivalent inertia, the z-score of each of the 6
inertia parameters against its reported standard deviation, and whether the scale was
identified. Writes OUT/identify_basilisk.json and prints the summary tables.

Usage: PYTHONPATH=.:tests python scripts/basilisk_harness.py diagnose [--out runs/basilisk]
           [--duration 60] [--subset smoke] [--cases NAME,...] [--stamp-scatter 0.1] [--gyro-step 20]
       PYTHONPATH=.:tests python scripts/basilisk_harness.py identify [--seeds 4]
           [--out runs/identify-basilisk] [--kinds bursts,...] [--bodies device,...]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from basilisk_cases import SMOKE
from basilisk_cases import cases as diagnose_cases
from basilisk_cases import run_case as cases_run_case
from basilisk_identify import KINDS, PROFILES, summarise
from basilisk_identify import markdown as identify_markdown
from basilisk_identify import run_case as identify_case


def diagnose_markdown(rows: list[dict], totals: dict) -> str:
    """The table: one row per case, then the totals."""
    lines = ["| case | concealed | nominal off by | named by diagnose | of which not in the truth "
             "| rms / noise after (worst axis) | mismatch detected | correct |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        worst = max(r["rms_over_noise_after"] or [float("nan")])
        lines.append(f"| {r['case']} | {', '.join(r['components']) or '— (control)'} | "
                     f"{100 * r['nominal_error']:.1f} % | {', '.join(r['named']) or '—'} | "
                     f"{', '.join(r['outside_truth']) or '—'} | {worst:.2f} | "
                     f"{'yes' if r['mismatch_detected'] else 'no'} | {'yes' if r['correct'] else 'no'} |")
    lines += ["", f"Concealed-effect cases correct: {totals['cases_correct']}/{totals['cases']}; "
              f"controls clean: {totals['controls_clean']}/{totals['controls']}; "
              f"wall {totals['wall_s']:.0f} s."]
    return "\n".join(lines) + "\n"


def diagnose_harness(args) -> None:
    """The concealed-effect cases diagnosed and scored; the table and totals written."""
    if not 0.0 <= args.stamp_scatter < 0.5:
        raise SystemExit(f"--stamp-scatter must be in [0, 0.5), got {args.stamp_scatter}")
    if args.gyro_step < 0:
        raise SystemExit(f"--gyro-step must be >= 0, got {args.gyro_step}")
    todo = diagnose_cases(args.duration)
    wanted = set(filter(None, args.cases.split(","))) or (set(SMOKE) if args.subset == "smoke" else None)
    if wanted:
        unknown = wanted - {c.name for c in todo}
        if unknown:
            raise SystemExit(f"--cases: unknown {sorted(unknown)}")
        todo = [c for c in todo if c.name in wanted]
    out = Path(args.out or "runs/basilisk")
    t0 = time.perf_counter()
    rows = []
    for case in todo:
        row = cases_run_case(case, out / "recordings", args.stamp_scatter, args.gyro_step)
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
    table = diagnose_markdown(rows, totals)
    (out / "basilisk_harness.md").write_text(table)
    print(table)


def identify_study(args) -> None:
    """identify on each kind and body class over the seeds; the summary written and printed."""
    kinds, bodies = args.kinds.split(","), args.bodies.split(",")
    unknown = sorted(set(kinds) - set(KINDS)) + sorted(set(bodies) - set(PROFILES))
    if unknown:
        raise SystemExit(f"unknown kinds or bodies: {unknown}")
    t0 = time.perf_counter()
    rows, summary = [], {}
    for kind in kinds:
        for body in bodies:
            group = [identify_case(kind, body, seed) for seed in range(args.seeds)]
            rows += group
            summary[f"{kind}/{body}"] = summarise(group)
            print(json.dumps({f"{kind}/{body}": summary[f"{kind}/{body}"]}), flush=True)
    overall = {kind: summarise([r for r in rows if r["kind"] == kind]) for kind in kinds}
    out = Path(args.out or "runs/identify-basilisk")
    out.mkdir(parents=True, exist_ok=True)
    (out / "identify_basilisk.json").write_text(json.dumps(
        {"rows": rows, "summary": summary, "by_kind": overall, "wall_s": time.perf_counter() - t0},
        indent=1) + "\n")
    print(identify_markdown(summary))
    print(identify_markdown({f"{k}/all": s for k, s in overall.items()}))
    print(f"wall {time.perf_counter() - t0:.0f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="study", required=True)
    one = sub.add_parser("diagnose", help="the concealed-effect harness")
    one.add_argument("--out", default=None, help="output folder, default runs/basilisk (must not hold "
                     "earlier recordings)")
    one.add_argument("--duration", type=float, default=60.0, help="s per recording")
    one.add_argument("--subset", choices=["all", "smoke"], default="all")
    one.add_argument("--cases", default="", help="comma-separated case names (default: the subset)")
    one.add_argument("--stamp-scatter", type=float, default=0.0,
                     help="log time stamps off the sampling instants by up to this share of the interval")
    one.add_argument("--gyro-step", type=float, default=0.0,
                     help="round the gyro rates to a lattice of this many times its noise level (0: in full)")
    two = sub.add_parser("identify", help="identify's errors and interval coverage")
    two.add_argument("--seeds", type=int, default=4, help="cases per kind and body class")
    two.add_argument("--out", default=None, help="output folder, default runs/identify-basilisk")
    two.add_argument("--kinds", default=",".join(KINDS))
    two.add_argument("--bodies", default=",".join(PROFILES))
    args = ap.parse_args()
    (diagnose_harness if args.study == "diagnose" else identify_study)(args)


if __name__ == "__main__":
    main()
