"""identify's and diagnose's intervals on a gyro read on a coarse lattice (README, "A gyro read on
a lattice coarse beside its noise" and "Its intervals, counting the rounding"): coarse_gyro.py's
600-s 10-Hz tumbles (no torque, no sidecar, no nominal, noise 5e-4 rad/s) read in steps of 20x,
5x and 2x the noise, seeds 0-5. Per record: identify's (ML) principal ratios' errors in their
sigmas (z) and the widening its lattice replays gave (identification._lattice_replayed); with
--diagnose also diagnose's, in the half-widths of its 95 % intervals (fit.lattice_spread), and
the explanation. Then per step how many ratios each holds.

Usage: PYTHONPATH=.:scripts python scripts/coarse_gyro_intervals.py [--diagnose] [--out OUT.json]
About 5 s a replayed identify on this 2-core machine (0.6 s without replays); a diagnosis 3-25 s.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import time

import numpy as np
from coarse_gyro import slow_tumble_read_coarsely

from inertia_gym.discrepancy.report import diagnose
from inertia_gym.identification import identify

NOISE = 5e-4
STEPS = (20 * NOISE, 5 * NOISE, 2 * NOISE)
SEEDS = range(6)


def _identified(rec, truth) -> dict:
    started = time.perf_counter()
    res = identify(rec)
    wall = time.perf_counter() - started
    summary = res.summary()
    ratios, cov = np.asarray(summary["principal_ratios"]), np.asarray(summary["principal_ratios_cov"])
    said = [n for n in res.notes if "replays of the fit" in n]
    widening = re.search(r"entries ([\d.]+)-([\d.]+)x", said[0]).groups() if said else None
    return {"z": ((ratios - truth)[1:] / np.sqrt(np.diag(cov)[1:])).tolist(), "widening": widening,
            "wall_s": wall}


def _diagnosed(rec, truth) -> dict:
    started = time.perf_counter()
    report, _ = diagnose(rec)
    wall = time.perf_counter() - started
    after = report["fit_after"]
    ratios, ci = np.asarray(after["principal_ratios"]), np.asarray(after["principal_ratios_ci95"])
    half = (ci[1:, 1] - ci[1:, 0]) / 2
    return {"off_over_half": ((ratios - truth)[1:] / half).tolist(),
            "held": bool(np.all((ci[1:, 0] <= truth[1:]) & (truth[1:] <= ci[1:, 1]))),
            "explanation": [e["name"] for e in report["explanation"]], "wall_s": wall}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--diagnose", action="store_true", help="also diagnose each record")
    ap.add_argument("--out", default=None, help="write the rows to this JSON file")
    args = ap.parse_args()
    rows = []
    for step in STEPS:
        for seed in SEEDS:
            rec = slow_tumble_read_coarsely(seed, None, noise=NOISE, step=step)
            truth = np.sort(np.linalg.eigvalsh(rec.inertia_nominal))[::-1]
            truth = truth / truth[0]
            rec = dataclasses.replace(rec, meta={k: v for k, v in rec.meta.items() if k != "inertia_nominal"})
            row = {"step": step, "seed": seed, "identify": _identified(rec, truth)}
            if args.diagnose:
                row["diagnose"] = _diagnosed(rec, truth)
            rows.append(row)
            ident = row["identify"]
            line = (f"step {step:.4g} seed {seed}: identify z {np.round(ident['z'], 2).tolist()} widened "
                    f"{'-'.join(ident['widening']) if ident['widening'] else 'no'} {ident['wall_s']:.1f} s")
            if args.diagnose:
                diag = row["diagnose"]
                line += (f" | diagnose off/half {np.round(diag['off_over_half'], 2).tolist()} "
                         f"{diag['explanation']} {diag['wall_s']:.1f} s")
            print(line, flush=True)
    for step in STEPS:
        at = [r for r in rows if r["step"] == step]
        z = np.array([r["identify"]["z"] for r in at])
        line = (f"step {step:.4g} ({step / NOISE:.0f}x the noise): identify {int(np.sum(np.abs(z) < 1.96))} "
                f"of {z.size} ratios within 1.96 sigma, largest |z| {np.abs(z).max():.2f}")
        if args.diagnose:
            off = np.abs(np.array([r["diagnose"]["off_over_half"] for r in at]))
            line += (f"; diagnose {int(np.sum(off <= 1.0))} of {off.size} inside, "
                     f"largest {off.max():.2f} half-widths")
        print(line)
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
