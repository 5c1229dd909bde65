"""Concealed-effect harness on the project's own simulator: every catalogue effect alone, pairs of
effects, and clean controls, over fixed seeds with random magnitudes. The diagnosis sees only
the recording; the truth is read back from the sidecar afterwards.

Usage: PYTHONPATH=. python scripts/confusion_matrix.py [--seeds 3] [--controls 40]
           [--pair-seeds 2] [--duration 40] [--workers N] [--effects a,b] [--pairs a+b,c+d]
           [--out harness.json]

Prints the confusion matrix and the figures of issue 11's must-show 1: single effects top-1
correct, pairs with both effects named in the explanation, false alarms on the controls, share
of correct cases with the fitted parameters within 20 % of the truth, share of recordings with
post-fit rms <= 1.2x the noise on every axis; and the wall time. A recording of
momentum_misalignment carries a logged rotor (the effect needs a changing h).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from inertia_gym.discrepancy.effects import EFFECTS, REGISTRY
from inertia_gym.discrepancy.report import diagnose
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.executors import HELPERS_VARIABLE
from inertia_gym.scenario import Scenario

#: Pairs of effects from different families, each of a kind a real recording can hold together.
DEFAULT_PAIRS = ("gyro_bias+constant_body_torque", "gyro_scale+internal_momentum",
                 "gyro_bias+actuator_misalignment", "internal_momentum+viscous_damping",
                 "actuator_delay+gyro_bias", "inertia_offset+gyro_bias",
                 "flexible_mode+constant_body_torque", "inertia_change+gyro_bias")
#: The logged rotor's peak momentum on recordings of effects that need a changing h, as a share
#: of the body's initial angular momentum |J omega0|.
ROTOR_SHARE = 0.3


@dataclass(frozen=True)
class Case:
    """One recording: its concealed effects (() for a control) and seed."""
    effects: tuple[str, ...]
    seed: int

    @property
    def label(self) -> str:
        return "+".join(self.effects) or "none"


def param_error(name, truth: dict, fitted: dict, nominal=None, rotor_axis=None) -> float:
    """Relative error of the effect's parameters (norm of difference / norm of truth); for
    inertia_offset, of the fitted inertia relative to the offset from the nominal; for
    momentum_misalignment, of the logged rotor axis' rotated direction relative to its true
    displacement (a rotation about the rotor's own axis changes nothing, so is not identifiable).
    """
    if name == "momentum_misalignment":
        axis = np.asarray(rotor_axis, float)
        true_dir = Rotation.from_rotvec(truth["rotvec"]).apply(axis)
        fit_dir = Rotation.from_rotvec(fitted["rotvec"]).apply(axis)
        return float(np.linalg.norm(fit_dir - true_dir) / np.linalg.norm(true_dir - axis))
    if name == "inertia_offset":
        j_true, j_fit = np.asarray(truth["inertia"]), np.asarray(fitted["inertia"])
        return float(np.linalg.norm(j_fit - j_true) / np.linalg.norm(j_true - np.asarray(nominal)))
    if name == "inertia_change":
        keys = ["delta_inertia"]
    elif name == "gravity_gradient":
        keys = ["orbit_rate"]
    else:
        keys = list(truth)
    fitted = dict(fitted)
    if name == "flexible_mode":  # the model depends on coupling coupling^T: its sign is arbitrary
        c_true, c_fit = np.asarray(truth["coupling"]), np.asarray(fitted["coupling"])
        if np.linalg.norm(c_true + c_fit) < np.linalg.norm(c_true - c_fit):
            fitted["coupling"] = (-c_fit).tolist()
    a = np.concatenate([np.ravel(truth[k]) for k in keys])
    b = np.concatenate([np.ravel(fitted[k]) for k in keys])
    return float(np.linalg.norm(a - b) / np.linalg.norm(a))


def run_case(case: Case, duration: float, tau_max: float) -> dict:
    """Simulate, conceal, diagnose and score one case (a process-pool task)."""
    sc = Scenario(tau_max=tau_max)
    needs_rotor = any(REGISTRY[name].needs_momentum for name in case.effects)
    h_max = ROTOR_SHARE * float(np.linalg.norm(sc.inertia_true_array @ np.asarray(sc.omega0)))
    rec, side = simulate_recording(sc, duration, list(case.effects) or None, seed=case.seed,
                                   rotor_h_max=h_max if needs_rotor else None)
    blind = type(rec)(rec.t, rec.w, rec.q, rec.tau,
                      {k: v for k, v in rec.meta.items() if k not in ("effect", "effects", "rotor")},
                      rec.name, h=rec.h)
    t0 = time.perf_counter()
    report = diagnose(blind).report
    wall = time.perf_counter() - t0
    explained = [e["name"] for e in report.get("explanation", [])]
    top = report["best_effect"] or "none"
    row = {"label": case.label, "seed": case.seed, "top": top, "explanation": explained,
           "wall_s": wall, "rms_over_noise": max(report["fit_after"]["rms_over_noise"] or [np.inf])}
    if len(case.effects) == 1 and top == case.effects[0]:
        fitted = next(e for e in report["effects"] if e["name"] == top)["params"]
        row["param_error"] = param_error(top, side["effect"]["params"], fitted,
                                         side.get("inertia_nominal"), side.get("rotor", {}).get("axis"))
    return row


def cases(effects, pairs, seeds: int, controls: int, pair_seeds: int) -> list[Case]:
    """Controls, single effects and pairs, each with its own seeds (1000 + i)."""
    out = [Case((), 1000 + i) for i in range(controls)]
    out += [Case((name,), 1000 + i) for name in effects for i in range(seeds)]
    out += [Case(tuple(p.split("+")), 1000 + i) for p in pairs for i in range(pair_seeds)]
    return out


def figures(rows: list[dict]) -> dict:
    """The must-show figures of a harness run's rows."""
    controls = [r for r in rows if r["label"] == "none"]
    singles = [r for r in rows if r["label"] != "none" and "+" not in r["label"]]
    pairs = [r for r in rows if "+" in r["label"]]
    correct = [r for r in singles if r["top"] == r["label"]]
    perr = np.array([r["param_error"] for r in correct])
    ratios = np.array([r["rms_over_noise"] for r in rows])
    return {
        "singles_correct": len(correct), "singles": len(singles),
        "pairs_both_named": sum(set(r["label"].split("+")) <= set(r["explanation"]) for r in pairs),
        "pairs": len(pairs),
        "false_alarms": sum(r["top"] != "none" for r in controls), "controls": len(controls),
        "params_within_20pc": int(np.sum(perr <= 0.2)), "param_error_median": float(np.median(perr))
        if perr.size else None,
        "rms_within_1p2": int(np.sum(ratios <= 1.2)), "recordings": len(rows),
        "rms_over_noise_median": float(np.median(ratios)),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=3, help="seeds per single effect")
    ap.add_argument("--controls", type=int, default=40, help="clean recordings")
    ap.add_argument("--pair-seeds", type=int, default=2, help="seeds per pair")
    ap.add_argument("--duration", type=float, default=40.0, help="s per recording")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--effects", default=None, help="comma-separated subset of the catalogue")
    ap.add_argument("--pairs", default=",".join(DEFAULT_PAIRS),
                    help="comma-separated pairs a+b ('' for none)")
    ap.add_argument("--tau-max", type=float, default=50.0,
                    help="N·m of the torque bursts (the paper's 5 N·m hides actuator effects "
                         "below the gyro noise at a 10 rad/s spin)")
    ap.add_argument("--out", default=None, help="write the rows and figures to this JSON file")
    args = ap.parse_args()
    effects = list(EFFECTS) if not args.effects else args.effects.split(",")
    unknown = [n for p in filter(None, args.pairs.split(",")) for n in p.split("+")] + effects
    unknown = sorted(set(unknown) - set(EFFECTS))
    if unknown:
        raise SystemExit(f"unknown effects {unknown}; the catalogue: {', '.join(EFFECTS)}")
    todo = cases(effects, list(filter(None, args.pairs.split(","))), args.seeds, args.controls,
                 args.pair_seeds)
    t0 = time.perf_counter()
    rows = []
    os.environ[HELPERS_VARIABLE] = "0"  # the workers fill the cores: no helpers of their own
    with ProcessPoolExecutor(args.workers) as pool:
        futures = [pool.submit(run_case, c, args.duration, args.tau_max) for c in todo]
        for future in futures:
            row = future.result()
            rows.append(row)
            print(f"{row['label']} seed {row['seed']}: top {row['top']}, explanation "
                  f"{row['explanation']}, rms/noise {row['rms_over_noise']:.2f}, {row['wall_s']:.1f} s",
                  flush=True)
    wall = time.perf_counter() - t0
    order = ["none"] + list(EFFECTS)
    single_rows = [r for r in rows if "+" not in r["label"]]
    cols = sorted({r["top"] for r in single_rows}, key=order.index)
    print(f"\n{'truth / top-ranked':24s}" + "".join(f"{c[:9]:>10s}" for c in cols))
    for lab in dict.fromkeys(r["label"] for r in single_rows):
        tops = [r["top"] for r in single_rows if r["label"] == lab]
        print(f"{lab:24s}" + "".join(f"{tops.count(c):10d}" for c in cols))
    f = figures(rows)
    print(f"\n{f['recordings']} recordings of {args.duration:.0f} s, tau_max {args.tau_max} N·m, "
          f"{args.workers} workers, wall {wall:.0f} s")
    print(f"single effects top-1 correct: {f['singles_correct']}/{f['singles']}")
    print(f"pairs with both effects named: {f['pairs_both_named']}/{f['pairs']}")
    print(f"false alarms on clean controls: {f['false_alarms']}/{f['controls']}")
    print(f"parameters within 20 % (correct singles): {f['params_within_20pc']}/{f['singles_correct']}"
          f" (median error {f['param_error_median']:.1%})" if f["param_error_median"] is not None else "")
    print(f"post-fit rms <= 1.2x noise on every axis: {f['rms_within_1p2']}/{f['recordings']} "
          f"(median {f['rms_over_noise_median']:.3f})")
    print(f"diagnosis wall per recording: median {np.median([r['wall_s'] for r in rows]):.1f} s, "
          f"max {max(r['wall_s'] for r in rows):.1f} s")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        with open(args.out, "w") as fh:
            json.dump({"figures": f, "wall_s": wall, "rows": rows, "args": vars(args)}, fh, indent=1)


if __name__ == "__main__":
    main()
