"""`identify` on Basilisk recordings (scripts/basilisk_harness.py identify runs it; the tests use it):
the cases, one case's scores and their summary. See the script for what is scored.
"""

from __future__ import annotations

import dataclasses
import time

import basilisk_cases as harness
import numpy as np
from basilisk_sim import TRUTH_KEY, SpacecraftCase, simulate

from inertia_gym import identify

#: Per body class: tumble rate rad/s, gyro sigma rad/s, sample_dt s, duration s, burst
#: acceleration rad/s² (burst torque = it x the largest hub moment).
PROFILES = {
    "device": dict(rate=2.0, gyro_sigma=2e-3, sample_dt=0.01, duration=20.0, accel=0.05),
    "cubesat": dict(rate=0.1, gyro_sigma=1e-3, sample_dt=0.1, duration=300.0, accel=0.002),
    "smallsat": dict(rate=0.3, gyro_sigma=2e-4, sample_dt=0.1, duration=60.0, accel=0.01),
    "bus": dict(rate=0.05, gyro_sigma=5e-5, sample_dt=0.2, duration=600.0, accel=0.001),
    "stage": dict(rate=0.02, gyro_sigma=2e-5, sample_dt=0.5, duration=1200.0, accel=2e-4),
}
KINDS = ("bursts", "bursts_gyro_only", "gyro_bias_gyro_only", "wheels", "free", "slosh", "panel")
#: The gyro bias of the kind gyro_bias_gyro_only, in units of the tumble rate.
BIAS_SHARE = np.array([0.01, -0.006, 0.004])
#: The user's nominal: the hub inertia with each row and column scaled by these factors.
NOMINAL_FACTORS = np.array([1.3, 0.9, 1.1])
PARAMS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def make_case(kind: str, body: str, seed: int) -> SpacecraftCase:
    """One Basilisk case of a kind (KINDS) for a body class (PROFILES)."""
    prof = PROFILES[body]
    bursts = kind in ("bursts", "bursts_gyro_only", "gyro_bias_gyro_only", "slosh", "panel")
    case = harness.base(f"{kind}_{body}_{seed}", body, seed, bursts)
    _, inertia = harness.hub(body)
    speed = prof["rate"] / harness.RATE
    extra = {}
    if kind == "bursts_gyro_only":
        extra["quat_sigma"] = None
    elif kind == "gyro_bias_gyro_only":
        extra.update(quat_sigma=None, gyro_bias=tuple((BIAS_SHARE * prof["rate"]).tolist()))
    elif kind == "wheels":
        # wheel momentum 0.3 x the body's, motors accelerating the body at 0.2 x the bursts' rate
        extra["wheels"] = harness.wheels(body, 0.3 * speed, True, seed,
                                         motor=0.2 * prof["accel"] / harness.WHEEL_SPIN_SHARE)
    elif kind == "slosh":  # frequencies in proportion to the rate, as in the harness at RATE
        extra["slosh"] = (harness.slosh(body, 0.1, 0.3 * speed, 0.05, seed),)
    elif kind == "panel":
        extra["panels"] = (harness.panel(body, 0.04, 0.5 * speed, 0.02),)
    largest = float(np.linalg.eigvalsh(inertia).max())
    return dataclasses.replace(
        case, omega0=tuple((speed * np.asarray(case.omega0)).tolist()),
        burst_torque=prof["accel"] * largest if bursts else 0.0, gyro_sigma=prof["gyro_sigma"],
        sample_dt=prof["sample_dt"], duration=prof["duration"], integration_dt=0.01, **extra)


def theta_of(inertia: np.ndarray) -> np.ndarray:
    """(6,) the inertia's entries in the order xx, xy, xz, yy, yz, zz."""
    return np.array([inertia[i, j] for i, j in PARAMS])


def run_case(kind: str, body: str, seed: int) -> dict:
    """Simulate, identify with the wrong nominal, score against Basilisk's inertia."""
    case = make_case(kind, body, seed)
    run = simulate(case)
    truth = np.asarray(run.sidecar[TRUTH_KEY]["inertia_equilibrium"], float)
    meta = {k: v for k, v in run.recording.meta.items() if k != TRUTH_KEY}
    hub = np.asarray(case.hub_inertia, float)
    meta["inertia_nominal"] = (hub * np.outer(NOMINAL_FACTORS, NOMINAL_FACTORS)).tolist()
    rec = dataclasses.replace(run.recording, meta=meta)
    t0 = time.perf_counter()
    result = identify(rec)
    wall = time.perf_counter() - t0
    est = result.estimate
    carries_scale = rec.sees_scale
    reference = truth if carries_scale else truth * np.trace(est.inertia) / np.trace(truth)
    z = (est.theta - theta_of(reference)) / np.sqrt(np.clip(np.diag(est.theta_cov), 1e-300, None))
    return {"case": case.name, "kind": kind, "body": body, "seed": seed, "samples": int(rec.t.size),
            "carries_scale": bool(carries_scale), "scale_identified": bool(est.scale_identified),
            "error": float(np.linalg.norm(est.inertia - reference) / np.linalg.norm(reference)),
            "z": z.tolist(), "rms_over_noise": float(result.rms_over_noise), "noise": result.noise.kind,
            "wall_s": wall}


def summarise(rows: list[dict]) -> dict:
    """Median error, coverage of the 6 parameters' 95 % intervals, rms z, scale flags."""
    z = np.array([r["z"] for r in rows])
    return {"cases": len(rows), "median_error": float(np.median([r["error"] for r in rows])),
            "max_error": float(np.max([r["error"] for r in rows])),
            "covered": int((np.abs(z) < 1.959964).sum()), "parameters": int(z.size),
            "rms_z": float(np.sqrt(np.mean(z ** 2))),
            "scale_identified": sum(r["scale_identified"] for r in rows),
            "carries_scale": sum(r["carries_scale"] for r in rows),
            "median_rms_over_noise": float(np.median([r["rms_over_noise"] for r in rows]))}


def markdown(summary: dict) -> str:
    lines = ["| kind | body | cases | median error | worst | 95 % coverage | rms z | scale identified |"
             " rms/noise |", "|---|---|---|---|---|---|---|---|---|"]
    for key, s in summary.items():
        kind, body = key.split("/")
        scale = f"{s['scale_identified']}/{s['carries_scale']}" if s["carries_scale"] else "— (ratios)"
        lines.append(f"| {kind} | {body} | {s['cases']} | {100 * s['median_error']:.3g} % | "
                     f"{100 * s['max_error']:.3g} % | {s['covered']}/{s['parameters']} | "
                     f"{s['rms_z']:.2f} | {scale} | {s['median_rms_over_noise']:.2f} |")
    return "\n".join(lines) + "\n"
