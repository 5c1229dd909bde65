"""identify's intervals on a gyro read on a coarse lattice (README, "A gyro read on a lattice
coarse beside its noise"): coarse_gyro.py's 600-s 10-Hz tumbles (no torque, no sidecar, noise
5e-4 rad/s) read in steps of 20x, 5x and 2x the noise, seeds 0-5, each identified once (ML);
per record the principal ratios' errors in their sigmas (z), the widening the lattice's replays
gave (identification._lattice_replayed) and the wall time; then per step how many ratios lie
within 1.96 sigma.

Usage: PYTHONPATH=. python scripts/identify_coarse_gyro.py [--out OUT.json]
About 5 s a replayed record on this 2-core machine (0.6 s without replays).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import time

import numpy as np
from coarse_gyro import slow_tumble_read_coarsely

from inertia_gym.identification import identify

NOISE = 5e-4
STEPS = (20 * NOISE, 5 * NOISE, 2 * NOISE)
SEEDS = range(6)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=None, help="write the rows to this JSON file")
    args = ap.parse_args()
    rows = []
    for step in STEPS:
        for seed in SEEDS:
            rec = slow_tumble_read_coarsely(seed, None, noise=NOISE, step=step)
            truth = np.sort(np.linalg.eigvalsh(rec.inertia_nominal))[::-1]
            rec = dataclasses.replace(rec, meta={k: v for k, v in rec.meta.items() if k != "inertia_nominal"})
            started = time.perf_counter()
            res = identify(rec)
            wall = time.perf_counter() - started
            summary = res.summary()
            ratios, cov = np.asarray(summary["principal_ratios"]), np.asarray(summary["principal_ratios_cov"])
            z = ((ratios - truth / truth[0])[1:] / np.sqrt(np.diag(cov)[1:])).tolist()
            said = [n for n in res.notes if "replays of the fit" in n]
            widening = re.search(r"entries ([\d.]+)-([\d.]+)x", said[0]).groups() if said else None
            rows.append({"step": step, "seed": seed, "z": z, "widening": widening, "wall_s": wall})
            print(f"step {step:.4g} seed {seed}: z {np.round(z, 2).tolist()}  widened "
                  f"{'-'.join(widening) if widening else 'no'}  {wall:.1f} s", flush=True)
    for step in STEPS:
        z = np.array([r["z"] for r in rows if r["step"] == step])
        print(f"step {step:.4g} ({step / NOISE:.0f}x the noise): {int(np.sum(np.abs(z) < 1.96))} of {z.size} "
              f"ratios within 1.96 sigma, largest |z| {np.abs(z).max():.2f}")
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(rows, fh, indent=1)


if __name__ == "__main__":
    main()
