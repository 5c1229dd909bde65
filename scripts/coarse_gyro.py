"""diagnose on a gyro read coarser than its motion and noise move it (README, "A gyro read coarser
than its motion and noise move it"): a slow tumble read in steps of 0.01 rad/s, with no effect
and with one concealed, each record diagnosed once; the explanation, its gains and the worst
axis's rms over the noise after it.

Usage: PYTHONPATH=. python scripts/coarse_gyro.py [--out OUT.json]
Cases (600 s at 10 Hz, no torque, no gyro_sigma given): no effect at noise 5e-4 rad/s (seeds
0-5) and 2.5e-3 (seeds 0-3); internal_momentum, constant_body_torque and gyro_scale at 5e-4
(seeds 0-2). About 20 s a record on this 2-core machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np
from slow_tumble_pairs import slow_tumble

from inertia_gym.discrepancy.report import diagnose

#: (effect or None, noise rad/s, seeds)
CASES = ((None, 5e-4, range(6)), (None, 2.5e-3, range(4)), ("internal_momentum", 5e-4, range(3)),
         ("constant_body_torque", 5e-4, range(3)), ("gyro_scale", 5e-4, range(3)))


def slow_tumble_read_coarsely(seed: int, effect: str | None, duration: float = 600.0, noise: float = 5e-4,
                              step: float = 0.01):
    """slow_tumble_pairs.slow_tumble's body (rates drawn with seed 100 + seed) sampled at 10 Hz
    for `duration` s, its gyro (noise 5e-4 rad/s: runs of 5-18 equal samples) read in steps of
    0.01 rad/s (0: in full) and no gyro_sigma given: the rounding error a function of the rate."""
    rec, _ = slow_tumble(effect, seed, 100 + seed, duration=duration, noise=noise)
    return dataclasses.replace(rec, w=np.round(rec.w / step) * step if step else rec.w)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=None, help="write the rows to this JSON file")
    args = ap.parse_args()
    rows = []
    for effect, noise, seeds in CASES:
        for seed in seeds:
            t0 = time.perf_counter()
            report, _ = diagnose(slow_tumble_read_coarsely(seed, effect, noise=noise))
            row = {"effect": effect, "noise": noise, "seed": seed,
                   "explanation": [(e["name"], round(e["delta_bic"], 1)) for e in report["explanation"]],
                   "worst_axis_after": max(report["fit_after"]["rms_over_noise"]),
                   "rounding_floor": report["noise"]["rounding_floor"] is not None,
                   "wall_s": time.perf_counter() - t0}
            rows.append(row)
            print(f"{effect or 'none':22s} noise {noise:.1e} seed {seed}: "
                  f"{', '.join(f'{n} ({g})' for n, g in row['explanation']) or 'nothing named':60s} "
                  f"worst axis {row['worst_axis_after']:.2f}x  {row['wall_s']:.1f} s", flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
