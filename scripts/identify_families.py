"""identify() on families of records made with scipy alone (no inertia_gym code in the truth).

Two families, each case over --seeds noise seeds:

* near-flat bodies tossed without torque, 1 s at 100 Hz: phone-like plates whose largest moment
  is 1-5 % short of the sum of the other two, in several aspect ratios, spun at 5-30 rad/s about
  a random direction, their axes turned at random, gyro noise 1e-3 or 5e-3 rad/s; the scale is
  not seen, so the principal ratios I2/I1, I3/I1 are scored;
* a small satellite with five 2-s torque pulses (logged), 60 s at 10 Hz, gyro noise 1e-4 rad/s:
  the inertia's six entries are scored.

Per case: how many seeds have every scored quantity within 3 of its standard deviations and
within 0.5 % (of the largest moment, or of the entry's scale), and the share of 95 % intervals
that hold the truth. Prints a markdown table and, with --out, writes DIR/families.json.

    PYTHONPATH=.:tests .venv/bin/python scripts/identify_families.py [--seeds 10] [--out DIR]

The records and their scores are the ones the test suite holds identify to (tests/records.py).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from records import flat_record, satellite_record, score_entries, score_ratios

from inertia_gym.identification import identify

#: Near-flat shapes: (moment ratios before the flattening, flattening delta): I3 = (1 - delta)(I1 + I2).
FLAT_SHAPES = [((0.2, 0.8), 0.02), ((0.2, 0.8), 0.05), ((0.45, 0.55), 0.01), ((0.1, 0.9), 0.03)]
FLAT_RATES = (5.0, 15.0, 30.0)
FLAT_NOISE = (1e-3, 5e-3)
def cases():
    """(label, record maker(seed), scorer)."""
    for shape, delta in FLAT_SHAPES:
        for rate in FLAT_RATES:
            for sigma in FLAT_NOISE:
                label = f"flat {shape[0]}:{shape[1]} delta {delta} {rate:g} rad/s noise {sigma:g}"
                yield label, (lambda s, a=shape, b=delta, c=rate, d=sigma: flat_record(a, b, c, d, s)), \
                    score_ratios
    yield "satellite, five torque pulses", satellite_record, score_entries


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    rows = []
    print("| case | within 3 sigma and 0.5 % | 95 % intervals cover | reported by | wall s |")
    print("|---|---|---|---|---|")
    for label, make, scorer in cases():
        good, covered, estimators, t0 = 0, [], {}, time.perf_counter()
        for seed in range(args.seeds):
            rec, inertia = make(seed)
            result = identify(rec)
            ok, cov = scorer(result, inertia)
            good += ok
            covered.extend(cov.tolist())
            estimators[result.estimator] = estimators.get(result.estimator, 0) + 1
        wall = time.perf_counter() - t0
        rows.append({"case": label, "seeds": args.seeds, "within": good,
                     "coverage": float(np.mean(covered)), "estimators": estimators, "wall_s": wall})
        print(f"| {label} | {good}/{args.seeds} | {np.mean(covered):.2f} | "
              f"{', '.join(f'{k} {v}' for k, v in estimators.items())} | {wall:.1f} |", flush=True)
    within = sum(r["within"] >= 0.9 * r["seeds"] for r in rows)
    print(f"\n{within} of {len(rows)} cases within 3 sigma and 0.5 % on at least 90 % of their seeds; "
          f"coverage {np.mean([r['coverage'] for r in rows]):.3f} overall")
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        (Path(args.out) / "families.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
