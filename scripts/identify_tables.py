"""identify() on the real rotor throws beside the classic estimator, and on families made with scipy.

rotor: for every throw of the data folder (``*.csv`` with its sidecar; ``truth.json`` holds each throw's
reference ``inertia``) and each configuration (the stem's prefix: Empty, A, cal_device_only,
cal_proof_body; the two calibration bodies scored together as "cal"):

* identify(rec): the reported estimate, and the equation error beside it;
* the classic estimator a newcomer writes in 40 lines: Savitzky-Golay smoothed rates and their
  derivatives (cubic, a window spanning one radian of rotation at the record's median rate, as
  the equation error's), least squares on Euler's equation with the rotor's h
  (``classic_estimate``), and the same at fixed 20, 40 and 80 ms windows;
* identify_joint over each body's throws (the stem without its log number).

Scores: the relative Frobenius error |J_hat - J|_F / |J|_F (blind to nothing: the reference's CAD
frame sits 1.5-2 deg off the gyro's, which shows in the off-diagonal terms), the same left once
the reference is turned by at most TRUTH_FRAME_DEG to fit each estimate (frame_free_frobenius:
what the reference's frame cannot explain), the worst relative
error of the principal moments (frame-free), whether each principal moment's 95 % interval holds
the reference's, and whether the scale is identified; per configuration, identify against the
classic estimator throw by throw (paired: how often it is the better, and the Wilcoxon
signed-rank test of the differences). Prints markdown tables; with --out writes
DIR/rotor_throws.json. The data live outside the repository (no licence to copy them in):
without the folder the script prints one line and exits 0.

families: Three families, each case over --seeds noise seeds:

* near-flat bodies tossed without torque, 1 s at 100 Hz: phone-like plates whose largest moment
  is 1-5 % short of the sum of the other two, in several aspect ratios, spun at 5-30 rad/s about
  a random direction, their axes turned at random, gyro noise 1e-3 or 5e-3 rad/s; the scale is
  not seen, so the principal ratios I2/I1, I3/I1 are scored;
* near-symmetric bodies tossed the same way (oblate and prolate, two moments 0.2 or 2 % apart;
  near-spherical, moments 1 % apart), spun at 5 or 15 rad/s, gyro noise 1e-3 rad/s; their
  principal ratios scored;
* a small satellite with five 2-s torque pulses (logged), 60 s at 10 Hz, gyro noise 1e-4 rad/s:
  the inertia's six entries are scored.

Per case: how many seeds have every scored quantity within 3 of its standard deviations and
within 0.5 % (of the largest moment, or of the entry's scale), and the share of 95 % intervals
that hold the truth. Beside it, the peer every estimator answers to: for the near-flat tosses,
the passes an efficient estimator is expected to reach, each seed's Cramér-Rao bound at its
truth (tests/records.py flat_ratio_bound, scipy alone) giving its chance to pass
(efficient_pass_probability). Prints a markdown table and, with --out, writes
DIR/families.json.

The records and their scores are the ones the test suite holds identify to (tests/records.py).

    PYTHONPATH=. .venv/bin/python scripts/identify_tables.py rotor [--data DIR] [--out DIR]
    PYTHONPATH=.:tests .venv/bin/python scripts/identify_tables.py families [--seeds 10] [--out DIR]
"""

import os

# run as a program, the tables are timed on one numba thread; imported (by the tests), the
# importer's environment is left alone: numba refuses a new thread count once its threads run
if __name__ == "__main__":
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy import optimize, stats  # noqa: E402
from scipy.signal import savgol_filter  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from inertia_gym.dynamics import skew  # noqa: E402
from inertia_gym.estimation.equation_error import omega_matrix  # noqa: E402
from inertia_gym.identification import identify  # noqa: E402
from inertia_gym.information import inertia_from_theta  # noqa: E402
from inertia_gym.joint_identification import identify_joint  # noqa: E402
from inertia_gym.recordings import read_recordings  # noqa: E402

# ../shared/data beside the repository (or beside the folder holding its worktrees)
DEFAULT_DATA = next((p / "shared" / "data" for p in Path(__file__).resolve().parents
                     if (p / "shared" / "data").is_dir()),
                    Path(__file__).resolve().parents[2] / "shared" / "data") / "rotor-throws"
FIXED_WINDOWS_S = (0.02, 0.04, 0.08)
#: The most the reference's CAD frame may sit off the gyro's (deg): the data's README gives
#: 1.5-2 deg, so an error the reference turned this far explains is the reference's, not the
#: estimator's.
TRUTH_FRAME_DEG = 2.0


def classic_estimate(t, w, h, window_s: float | None = None) -> np.ndarray:
    """The 40-line estimator: SG-smoothed rates and derivatives (cubic) and least squares on
    J w_dot + w x (J w + h) + h_dot = 0; window_s None: one radian at the median rate."""
    dt = float(np.median(np.diff(t)))
    if window_s is None:
        window_s = 1.0 / float(np.median(np.linalg.norm(w, axis=1)))
    n = max(5, int(round(window_s / dt)) | 1)
    ws = savgol_filter(w, n, 3, axis=0)
    wd = savgol_filter(w, n, 3, deriv=1, delta=dt, axis=0)
    hs = savgol_filter(h, n, 3, axis=0)
    hd = savgol_filter(h, n, 3, deriv=1, delta=dt, axis=0)
    a = omega_matrix(wd) + skew(ws) @ omega_matrix(ws)
    b = -(hd + np.cross(ws, hs))
    k = n // 2
    theta = np.linalg.lstsq(a[k:-k].reshape(-1, 6), b[k:-k].reshape(-1), rcond=None)[0]
    return inertia_from_theta(theta)


def errors(inertia, truth) -> tuple[float, float]:
    """(relative Frobenius error, worst relative principal-moment error)."""
    moments, true = np.linalg.eigvalsh(inertia), np.linalg.eigvalsh(truth)
    return (float(np.linalg.norm(inertia - truth) / np.linalg.norm(truth)),
            float(np.max(np.abs(moments / true - 1))))


def frame_free_frobenius(inertia, truth, max_deg: float = TRUTH_FRAME_DEG) -> float:
    """The relative Frobenius error left once the reference is turned by the rotation, of at most
    max_deg, that fits the estimate best: min over R of |J_hat - R J R^T|_F / |J|_F, R's angle at
    most max_deg (the rotation vector max_deg u / sqrt(1 + |u|^2) over all u, from the identity
    and from a start off each axis)."""
    inertia, truth = np.asarray(inertia, float), np.asarray(truth, float)
    reach = np.deg2rad(max_deg)

    def error(u):
        turn = Rotation.from_rotvec(reach * u / np.sqrt(1.0 + u @ u)).as_matrix()
        return float(np.linalg.norm(inertia - turn @ truth @ turn.T) / np.linalg.norm(truth))

    starts = [np.zeros(3)] + [sign * e for e in np.eye(3) for sign in (1.0, -1.0)]
    return min(error(np.zeros(3)), *(optimize.minimize(error, u0, method="BFGS").fun for u0 in starts))


def configuration(stem: str) -> str:
    """The configuration a throw is scored in: Empty, A, or cal (both calibration bodies)."""
    return "cal" if stem.startswith("cal") else stem.split("_")[0]


def body(stem: str) -> str:
    """The body a throw is of: its stem without the log number."""
    return stem.rsplit("_", 1)[0]


def score(rec, truth) -> dict:
    """One throw: identify, its equation error and the classic estimates against the reference."""
    t0 = time.perf_counter()
    result = identify(rec)
    wall = time.perf_counter() - t0
    principal = result.estimate.principal()
    vals, half = principal.moments, principal.half
    row = {"throw": rec.name, "configuration": configuration(rec.name), "estimator": result.estimator,
           "scale_identified": bool(result.estimate.scale_identified), "wall_s": wall,
           "moments_covered": (np.abs(vals - np.linalg.eigvalsh(truth)) <= half).tolist(),
           "rms_over_noise": float(result.rms_over_noise), "inertia": result.estimate.inertia.tolist()}
    row["identify"] = errors(result.estimate.inertia, truth)
    row["equation_error"] = errors(result.reference.inertia, truth)
    row["frame_free"] = {"identify": frame_free_frobenius(result.estimate.inertia, truth)}
    classic = classic_estimate(rec.t, rec.w, rec.h)
    row["classic"] = errors(classic, truth)
    row["classic_inertia"] = classic.tolist()
    row["frame_free"]["classic"] = frame_free_frobenius(classic, truth)
    for window in FIXED_WINDOWS_S:
        key = f"classic_{int(window * 1e3)}ms"
        row[key] = errors(classic_estimate(rec.t, rec.w, rec.h, window), truth)
    return row


def group_stats(rows, key: str) -> dict:
    frob = np.array([r[key][0] for r in rows])
    moments = np.array([r[key][1] for r in rows])
    return {"median": float(np.median(frob)), "worst": float(frob.max()),
            "moments_worst": float(moments.max()), "moments_median": float(np.median(moments))}


def paired(rows, key: str, other: str = "classic") -> dict:
    """key's errors against other's, throw by throw, for the relative Frobenius error and the
    worst principal moment: on how many throws key's is the smaller, and the two-sided Wilcoxon
    signed-rank p of the differences (small: one estimator is the better on such throws beyond
    their scatter; large: a difference of medians or worsts is within it).
    """
    out = {}
    for i, measure in enumerate(("frobenius", "moments")):
        a = np.array([r[key][i] for r in rows])
        b = np.array([r[other][i] for r in rows])
        p = float(stats.wilcoxon(a, b).pvalue) if np.any(a != b) else 1.0
        out[measure] = {"better": int(np.sum(a < b)), "throws": len(rows), "p": p}
    return out


def rotor(args) -> None:
    """identify, the classic estimator and the joint fits on the rotor throws: the tables."""
    data = Path(args.data)
    if not (data / "truth.json").exists():
        print(f"no rotor-throw data at {data} (truth.json missing): nothing to do")
        return
    truth = json.loads((data / "truth.json").read_text())
    files = sorted(p for p in data.glob("*.csv") if p.stem in truth)
    identify(read_recordings(files[0])[0])  # compile the kernels outside the timed runs
    recordings = {p.stem: read_recordings(p)[0] for p in files}
    rows = [score(rec, np.asarray(truth[name]["inertia"], float)) for name, rec in recordings.items()]
    configs = sorted({r["configuration"] for r in rows})
    keys = ["identify", "equation_error", "classic"]
    keys += [f"classic_{int(w * 1e3)}ms" for w in FIXED_WINDOWS_S]
    print("| configuration | estimator | median Frobenius % | worst Frobenius % | median worst-moment % "
          "| worst moment % |")
    print("|---|---|---|---|---|---|")
    split = {}
    for config in configs:
        members = [r for r in rows if r["configuration"] == config]
        split[config] = {key: group_stats(members, key) for key in keys}
        split[config]["throws"] = len(members)
        split[config]["scale_identified"] = sum(r["scale_identified"] for r in members)
        split[config]["moments_covered"] = int(sum(sum(r["moments_covered"]) for r in members))
        for key in keys:
            g = split[config][key]
            print(f"| {config} ({len(members)}) | {key} | {100 * g['median']:.2f} | {100 * g['worst']:.2f} "
                  f"| {100 * g['moments_median']:.2f} | {100 * g['moments_worst']:.2f} |")
    print("\n| configuration | identify better than classic: Frobenius | Wilcoxon p | worst moment "
          "| Wilcoxon p |")
    print("|---|---|---|---|---|")
    for config in configs:
        pair = paired([r for r in rows if r["configuration"] == config], "identify")
        split[config]["paired"] = pair
        f, m = pair["frobenius"], pair["moments"]
        print(f"| {config} | {f['better']} of {f['throws']} | {f['p']:.2g} | {m['better']} of {m['throws']} "
              f"| {m['p']:.2g} |")
    print(f"\n| configuration | Frobenius % beyond a reference turned up to {TRUTH_FRAME_DEG:g} deg: "
          "identify, median / worst | classic, median / worst | identify better | Wilcoxon p |")
    print("|---|---|---|---|---|")
    for config in configs:
        members = [r for r in rows if r["configuration"] == config]
        free = {key: np.array([r["frame_free"][key] for r in members]) for key in ("identify", "classic")}
        ours, theirs = free["identify"], free["classic"]
        p = float(stats.wilcoxon(ours, theirs).pvalue) if np.any(ours != theirs) else 1.0
        split[config]["frame_free"] = {key: {"median": float(np.median(v)), "worst": float(v.max())}
                                       for key, v in free.items()}
        split[config]["frame_free"].update(better=int(np.sum(ours < theirs)), p=p)
        print(f"| {config} | {100 * np.median(ours):.2f} / {100 * ours.max():.2f} "
              f"| {100 * np.median(theirs):.2f} / {100 * theirs.max():.2f} "
              f"| {int(np.sum(ours < theirs))} of {len(members)} | {p:.2g} |")
    covered = sum(sum(r["moments_covered"]) for r in rows)
    print(f"\n- scale identified on {sum(r['scale_identified'] for r in rows)} of {len(rows)}; principal "
          f"moments' 95 % intervals hold the reference's on {covered} of {3 * len(rows)} "
          f"({100 * covered / (3 * len(rows)):.1f} %); reported: "
          f"{sum(r['estimator'] == 'equation error' for r in rows)} equation error, "
          f"{sum(r['estimator'] == 'output error' for r in rows)} output error")
    print(f"- identify's wall time: median {np.median([r['wall_s'] for r in rows]):.2f} s, "
          f"max {max(r['wall_s'] for r in rows):.2f} s")
    joints = {}
    print("\n| body | joint principal moments, error % | 95 % half-width % | covered | agreement p "
          "| classic's mean, error % | wall s |")
    print("|---|---|---|---|---|---|---|")
    for config in sorted({body(r["throw"]) for r in rows}):
        names = [r["throw"] for r in rows if body(r["throw"]) == config]
        t0 = time.perf_counter()
        joint = identify_joint([recordings[n] for n in names])
        wall = time.perf_counter() - t0
        true = np.mean([np.linalg.eigvalsh(np.asarray(truth[n]["inertia"], float)) for n in names], axis=0)
        principal = joint.estimate.principal()
        vals, half = principal.moments, principal.half
        classic = np.mean([np.linalg.eigvalsh(np.asarray(r["classic_inertia"])) for r in rows
                           if body(r["throw"]) == config], axis=0)
        joints[config] = {"throws": len(names), "estimator": joint.estimator,
                          "moment_errors": (vals / true - 1).tolist(), "half_widths": (half / true).tolist(),
                          "covered": (np.abs(vals - true) <= half).tolist(),
                          "agreement_p": joint.agreement_p,
                          "classic_mean_errors": (classic / true - 1).tolist(), "wall_s": wall}
        j = joints[config]
        print(f"| {config} ({len(names)}) | {', '.join(f'{100 * e:+.2f}' for e in j['moment_errors'])} "
              f"| {', '.join(f'{100 * e:.2f}' for e in j['half_widths'])} | {sum(j['covered'])}/3 "
              f"| {j['agreement_p']:.3g} | {', '.join(f'{100 * e:+.2f}' for e in j['classic_mean_errors'])} "
              f"| {wall:.1f} |")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        report = {"data": str(data), "split": split, "joint": joints, "moments_covered": covered,
                  "rows": rows}
        (out / "rotor_throws.json").write_text(json.dumps(report, indent=1))


#: Near-flat shapes: (moment ratios before the flattening, flattening delta): I3 = (1 - delta)(I1 + I2).
FLAT_SHAPES = [((0.2, 0.8), 0.02), ((0.2, 0.8), 0.05), ((0.45, 0.55), 0.01), ((0.1, 0.9), 0.03)]
FLAT_RATES = (5.0, 15.0, 30.0)
FLAT_NOISE = (1e-3, 5e-3)
#: Near-symmetric bodies: (name, principal moments relative to the phone's scale): oblate (a disc,
#: its two least moments 0.2 % or 2 % apart), prolate (a rod, its two largest) and a body near a
#: sphere (moments 1 % apart).
SYMMETRIC_SHAPES = [("oblate", (1.0, 1.002, 1.8)), ("oblate", (1.0, 1.02, 1.8)),
                    ("prolate", (0.3, 1.0, 1.002)), ("prolate", (0.3, 1.0, 1.02)),
                    ("near-spherical", (1.0, 1.01, 1.02))]
SYMMETRIC_RATES = (5.0, 15.0)
SYMMETRIC_NOISE = 1e-3


@dataclasses.dataclass(frozen=True)
class FamilyCase:
    """One case of the families: its label, make(seed) -> (record, true inertia), score(result,
    inertia) -> (passes, covered), and bound(seed) -> an efficient estimator's chance to pass that
    seed (None where no bound is worked out).
    """

    label: str
    make: Callable
    score: Callable
    bound: Callable | None


def family_cases():
    """The FamilyCases: the records and scores the tests hold identify to."""
    from records import (  # tests/records.py
        efficient_pass_probability,
        flat_ratio_bound,
        flat_record,
        satellite_record,
        score_entries,
        score_ratios,
        toss_ratio_bound,
        toss_record,
    )

    for shape, delta in FLAT_SHAPES:
        for rate in FLAT_RATES:
            for sigma in FLAT_NOISE:
                label = f"flat {shape[0]}:{shape[1]} delta {delta} {rate:g} rad/s noise {sigma:g}"
                args = (shape, delta, rate, sigma)
                yield FamilyCase(label, lambda s, a=args: flat_record(*a, s), score_ratios,
                                 lambda s, a=args: efficient_pass_probability(flat_ratio_bound(*a, s)))
    for name, shape in SYMMETRIC_SHAPES:
        moments = 3e-4 * np.array(shape)
        for rate in SYMMETRIC_RATES:
            label = f"{name} {':'.join(f'{m:g}' for m in shape)} {rate:g} rad/s noise {SYMMETRIC_NOISE:g}"
            args = (moments, rate, SYMMETRIC_NOISE)
            yield FamilyCase(label, lambda s, a=args: toss_record(*a, s), score_ratios,
                             lambda s, a=args: efficient_pass_probability(toss_ratio_bound(*a, s)))
    yield FamilyCase("satellite, five torque pulses", satellite_record, score_entries, None)


def families(args) -> None:
    """identify on the scipy-made families: one table row per case, the totals."""
    rows = []
    print("| case | within 3 sigma and 0.5 % | an efficient estimator's expected passes | "
          "95 % intervals cover | reported by | wall s |")
    print("|---|---|---|---|---|---|")
    for case in family_cases():
        label, bound = case.label, case.bound
        good, covered, estimators, wall = 0, [], {}, 0.0
        for seed in range(args.seeds):
            rec, inertia = case.make(seed)
            t0 = time.perf_counter()
            result = identify(rec)
            wall += time.perf_counter() - t0
            ok, cov = case.score(result, inertia)
            good += ok
            covered.extend(cov.tolist())
            estimators[result.estimator] = estimators.get(result.estimator, 0) + 1
        expected = None if bound is None else sum(bound(seed) for seed in range(args.seeds))
        rows.append({"case": label, "seeds": args.seeds, "within": good, "efficient_expected": expected,
                     "coverage": float(np.mean(covered)), "estimators": estimators, "wall_s": wall})
        shown = "–" if expected is None else f"{expected:.1f}"
        print(f"| {label} | {good}/{args.seeds} | {shown} | {np.mean(covered):.2f} | "
              f"{', '.join(f'{k} {v}' for k, v in estimators.items())} | {wall:.1f} |", flush=True)
    within = sum(r["within"] >= 0.9 * r["seeds"] for r in rows)
    bounded = [r for r in rows if r["efficient_expected"] is not None]
    reachable = sum(r["efficient_expected"] >= 0.9 * r["seeds"] for r in bounded)
    print(f"\n{within} of {len(rows)} cases within 3 sigma and 0.5 % on at least 90 % of their seeds; "
          f"coverage {np.mean([r['coverage'] for r in rows]):.3f} overall. An efficient estimator is "
          f"expected to pass on at least 90 % of the seeds in {reachable} of the {len(bounded)} "
          "tossed cases")
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        (Path(args.out) / "families.json").write_text(json.dumps(rows, indent=1))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="table", required=True)
    one = sub.add_parser("rotor", help="the real rotor throws beside the classic estimator")
    one.add_argument("--data", default=str(DEFAULT_DATA),
                     help="folder with the throws' CSV + JSON and truth.json")
    one.add_argument("--out", default=None, help="write DIR/rotor_throws.json")
    two = sub.add_parser("families", help="near-flat and near-symmetric tosses and a small satellite made "
                         "with scipy alone")
    two.add_argument("--seeds", type=int, default=10)
    two.add_argument("--out", default=None, help="write DIR/families.json")
    args = parser.parse_args()
    (rotor if args.table == "rotor" else families)(args)


if __name__ == "__main__":
    main()
