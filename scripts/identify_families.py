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

    PYTHONPATH=. .venv/bin/python scripts/identify_families.py [--seeds 10] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from inertia_gym.identification import identify
from inertia_gym.recordings import Recording

#: Near-flat shapes: (moment ratios before the flattening, flattening delta): I3 = (1 - delta)(I1 + I2).
FLAT_SHAPES = [((0.2, 0.8), 0.02), ((0.2, 0.8), 0.05), ((0.45, 0.55), 0.01), ((0.1, 0.9), 0.03)]
FLAT_RATES = (5.0, 15.0, 30.0)
FLAT_NOISE = (1e-3, 5e-3)
SATELLITE = np.array([[0.060, 0.002, -0.001], [0.002, 0.075, 0.003], [-0.001, 0.003, 0.040]])


def _euler(inertia, torque=None):
    inv = np.linalg.inv(inertia)

    def rate(t, w):
        tau = np.zeros(3) if torque is None else torque(t)
        return inv @ (tau - np.cross(w, inertia @ w))

    return rate


def flat_record(shape, delta: float, rate: float, sigma: float,
                seed: int) -> tuple[Recording, np.ndarray]:
    """A 1-s, 100-Hz torque-free toss of a near-flat body: (record, true inertia (3, 3))."""
    rng = np.random.default_rng(seed)
    i1, i2 = shape
    moments = np.array([i1, i2, (1 - delta) * (i1 + i2)]) * 3e-4
    turn = Rotation.random(random_state=rng).as_matrix()
    inertia = turn @ np.diag(moments) @ turn.T
    direction = rng.normal(size=3)
    w0 = rate * direction / np.linalg.norm(direction)
    t = np.arange(101) * 0.01
    sol = solve_ivp(_euler(inertia), (0, t[-1]), w0, t_eval=t, rtol=1e-11, atol=1e-12, method="DOP853")
    w = sol.y.T + sigma * rng.normal(size=(t.size, 3))
    return Recording(t, w, meta={"gyro_sigma": sigma}, name=f"flat-{seed}"), inertia


def satellite_record(seed: int) -> tuple[Recording, np.ndarray]:
    """60 s at 10 Hz of a small satellite with five 2-s torque pulses, logged: (record, inertia)."""
    rng = np.random.default_rng(seed)
    t = np.arange(601) * 0.1
    starts = np.array([5.0, 16.0, 27.0, 38.0, 49.0])
    amplitudes = rng.uniform(-1e-3, 1e-3, size=(5, 3))

    def torque(time_s):
        k = np.flatnonzero((time_s >= starts) & (time_s < starts + 2.0))
        return amplitudes[k[0]] if k.size else np.zeros(3)

    w0 = rng.normal(0.0, 0.05, 3)
    sol = solve_ivp(_euler(SATELLITE, torque), (0, t[-1]), w0, t_eval=t, rtol=1e-11, atol=1e-13,
                    method="DOP853", max_step=0.05)
    tau = np.array([torque(x) for x in t])
    w = sol.y.T + 1e-4 * rng.normal(size=(t.size, 3))
    return Recording(t, w, tau=tau, meta={"gyro_sigma": 1e-4}, name=f"satellite-{seed}"), SATELLITE


def score_ratios(result, inertia) -> tuple[bool, np.ndarray]:
    """(within 3 sigma and 0.5 % on both ratios, covered (2,) by the 95 % intervals)."""
    summary = result.summary()
    ratios = np.array(summary["principal_ratios"])[1:]
    sd = np.sqrt(np.diag(np.array(summary["principal_ratios_cov"])))[1:]
    truth = np.sort(np.linalg.eigvalsh(inertia))[::-1]
    truth = (truth / truth[0])[1:]
    err = np.abs(ratios - truth)
    return bool(np.all(err <= 3 * sd) and np.all(err <= 0.005)), err <= 1.96 * sd


def score_entries(result, inertia) -> tuple[bool, np.ndarray]:
    """(within 3 sigma and 0.5 % of the largest moment on all six entries, covered (6,))."""
    est = result.estimate
    truth = inertia[np.triu_indices(3)]
    err = np.abs(est.theta - truth)
    scale = np.linalg.eigvalsh(inertia).max()
    return bool(np.all(err <= 3 * est.sigma) and np.all(err <= 0.005 * scale)), err <= 1.96 * est.sigma


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
