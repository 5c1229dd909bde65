"""identify() on the 20 real rotor throws (tudelft/inertiaEstimation) against their reference.

For every ``*.csv`` in the data folder (each with its sidecar JSON; ``truth.json`` holds per
throw stem the reference ``inertia`` and, for the Empty throws, the source authors' own
estimate ``authors_estimate_inertia``) runs ``identify(rec)`` and scores:

* error: the relative Frobenius error |J_hat - J|_F / |J|_F against the reference;
* authors: the same error of the source authors' estimate (– where truth.json has none);
* CRLB: identify's Cramér-Rao bound (white noise at the sidecar's sigma, relative Frobenius);
* 1-sigma: the reported standard deviations weighted like the Frobenius norm,
  sqrt(sum_i w_i sigma_i^2) / |J|_F with w = (1, 2, 2, 1, 2, 1) (off-diagonals count twice);
* principal: the relative error of the principal moments |lambda_hat - lambda| / |lambda|
  (sorted eigenvalues): frame-independent, so blind to the reference's own CAD-vs-gyro frame
  misalignment (~1.5-2 degrees) that shows in the off-diagonal terms;
* coverage: whether each of the 6 reference parameters lies in its reported 95 % interval, and
  whether each of the 3 reference principal moments lies in its reported 95 % interval;
* rms/noise, the estimator (output error, or filter error where identify found model error),
  the model-error disturbance torque's estimated intensities (white q N²·m²·s, random-walk
  q_rw N²·m²/s), the rotor log's estimated lag behind the gyro, identify's wall time.

Prints a markdown table, the median and worst error and the coverage over 6 x 20 parameters,
and the same split by configuration (the 10 Empty throws against the 10 calibration throws).
Then each body's throws together, as `inertia-gym identify` on the folder summarizes them
(across.identifications_across, one series per body): the combined principal moments (the
ratios with --withhold-h) against the reference's, and whether their 95 % intervals cover it.
``--withhold-h`` drops the rotor momentum (the h columns): torque-free motion then fixes the
inertia only up to scale, so identify reports it normalised (to trace 1 kg·m², no nominal in the
sidecars); the error is then that of the ratios after rescaling the estimate to the reference's
trace (coverage is not meaningful and is reported against the same rescaled reference).

The data live outside the repository (no licence to copy them in): without the folder the
script prints one line and exits 0.

    .venv/bin/python scripts/identify_rotor_throws.py [--data ../shared/data/rotor-throws]
        [--out DIR] [--withhold-h] [--fit-drag]
"""

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from inertia_gym.across import identifications_across  # noqa: E402
from inertia_gym.discrepancy.recordings import read_recordings  # noqa: E402
from inertia_gym.estimation.ml import FROBENIUS_WEIGHTS  # noqa: E402
from inertia_gym.identification import identify  # noqa: E402

# ../shared/data beside the repository (or beside the folder holding its worktrees)
DEFAULT_DATA = next((p / "shared" / "data" for p in Path(__file__).resolve().parents
                     if (p / "shared" / "data").is_dir()),
                    Path(__file__).resolve().parents[2] / "shared" / "data") / "rotor-throws"
TRIU = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))  # theta order


def rel_frobenius(estimate, truth) -> float:
    """|estimate - truth|_F / |truth|_F."""
    return float(np.linalg.norm(estimate - truth) / np.linalg.norm(truth))


def score(rec, truth_entry, withhold_h: bool, fit_drag: bool = False) -> tuple[dict, dict]:
    """One throw's identify.json summary and its row of the table."""
    if withhold_h:
        rec = dataclasses.replace(rec, h=None)
    truth = np.asarray(truth_entry["inertia"], dtype=float)
    ident = identify(rec, fit_drag=fit_drag)
    est = ident.estimate
    j_hat = est.inertia
    raw_error = rel_frobenius(j_hat, truth)
    reference = truth
    if not est.scale_identified and withhold_h:
        # Ratios only: compare the shape, at the reference's trace.
        factor = float(np.trace(truth) / np.trace(j_hat))
        j_hat = j_hat * factor
        theta, sigma, ci = est.theta * factor, est.sigma * factor, est.ci95() * factor
    else:
        theta, sigma, ci = est.theta, est.sigma, est.ci95()
    theta_true = reference[TRIU]
    covered = (theta_true >= ci[:, 0]) & (theta_true <= ci[:, 1])
    moments, half, _, _ = dataclasses.replace(est, theta=theta, theta_cov=est.theta_cov * (
        (theta[0] / est.theta[0]) ** 2)).principal()
    moments_true = np.linalg.eigvalsh(reference)
    principal_error = float(np.linalg.norm(moments - moments_true) / np.linalg.norm(moments_true))
    rel_sigma = float(np.sqrt(np.sum(FROBENIUS_WEIGHTS * sigma ** 2))
                      / np.sqrt(np.sum(FROBENIUS_WEIGHTS * theta_true ** 2)))
    authors = truth_entry.get("authors_estimate_inertia")
    return ident.summary(), {
        "throw": rec.name,
        "n_samples": int(rec.t.size),
        "duration_s": float(rec.t[-1] - rec.t[0]),
        "rel_error": rel_frobenius(j_hat, reference),
        "rel_error_unscaled": raw_error,
        "principal_rel_error": principal_error,
        "principal_covered": (np.abs(moments - moments_true) <= half).tolist(),
        "authors_rel_error": None if authors is None else rel_frobenius(np.asarray(authors, float),
                                                                         truth),
        "crlb": float(ident.crlb),
        "rel_sigma": rel_sigma,
        "covered": covered.tolist(),
        "z": ((theta - theta_true) / np.maximum(sigma, 1e-300)).tolist(),
        "rms_over_noise": float(ident.rms_over_noise),
        "noise_kind": ident.noise.kind,
        "hac_lags": int(ident.noise.hac_lags),
        "interval_inflation": float(ident.noise.inflation),
        "disturbance_q": float(ident.noise.disturbance_q),
        "disturbance_q_rw": float(ident.noise.disturbance_q_rw),
        "estimator": ident.noise.estimator,
        "momentum_log_delay_s": float(ident.noise.log_delay),
        "configuration": truth_entry.get("configuration", ""),
        "scale_identified": bool(est.scale_identified),
        "converged": bool(ident.converged),
        "wall_s": float(ident.wall_s),
        "inertia_hat": j_hat.tolist(),
        "inertia_true": truth.tolist(),
        "notes": list(ident.notes),
    }


def body_together(group: dict, truth: dict) -> dict:
    """One body's throws combined (a group of across.identifications_across) against the
    reference: its principal moments, descending (its ratios where the scale is not identified),
    the relative error and 95 % half-width of each, and whether the interval covers it."""
    moments = np.mean([np.sort(np.linalg.eigvalsh(np.asarray(truth[n]["inertia"], float)))[::-1]
                       for n in group["names"]], axis=0)
    scaled = group["principal_moments"] is not None
    result = group["principal_moments"] if scaled else group["principal_ratios"]
    reference = moments if scaled else moments / moments[0]
    keep = slice(0, 3) if scaled else slice(1, 3)  # the largest over itself is 1: nothing to score
    estimate, reference = np.array(result["estimate"])[keep], reference[keep]
    ci = np.array(result["ci95"] or np.full((3, 2), np.nan))[keep]
    return {"series": group["name"], "throws": len(group["names"]), "source": result["source"],
            "quantity": "principal moments (kg·m²)" if scaled else "principal ratios I2/I1, I3/I1",
            "estimate": estimate.tolist(), "reference": reference.tolist(),
            "rel_error": ((estimate - reference) / reference).tolist(),
            "rel_half_width": ((ci[:, 1] - ci[:, 0]) / 2 / reference).tolist(),
            "covered": [bool(lo <= r <= hi) for r, (lo, hi) in zip(reference, ci)]}


def pct(x) -> str:
    return "–" if x is None else f"{100 * x:.2f}"


def table(rows) -> str:
    lines = ["| throw | error % | principal-moment error % | authors' error % | CRLB % "
             "| reported 1-sigma % | rms/noise | estimator | q N²m²s | q_rw N²m²/s | log lag ms "
             "| theta in 95 % CI | moments in 95 % CI | wall s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['throw']} | {pct(r['rel_error'])} | {pct(r['principal_rel_error'])} "
                     f"| {pct(r['authors_rel_error'])} | {pct(r['crlb'])} | {pct(r['rel_sigma'])} "
                     f"| {r['rms_over_noise']:.2f} | {r['estimator']} | {r['disturbance_q']:.2g} "
                     f"| {r['disturbance_q_rw']:.2g} | {1e3 * r['momentum_log_delay_s']:.2f} "
                     f"| {sum(r['covered'])}/6 | {sum(r['principal_covered'])}/3 "
                     f"| {r['wall_s']:.3f} |")
    return "\n".join(lines)


def group_stats(rows) -> dict:
    """Median and worst error, and coverage, of a group of rows."""
    errors = np.array([r["rel_error"] for r in rows])
    covered = np.array([r["covered"] for r in rows])
    moments = np.array([r["principal_covered"] for r in rows])
    return {"throws": len(rows), "median_rel_error": float(np.median(errors)),
            "worst_rel_error": float(errors.max()), "covered": int(covered.sum()),
            "parameters": int(covered.size), "moments_covered": int(moments.sum()),
            "moments": int(moments.size)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(DEFAULT_DATA),
                        help="folder with the throws' CSV + JSON and truth.json")
    parser.add_argument("--out", default=None, help="write DIR/rotor_throws.json")
    parser.add_argument("--withhold-h", action="store_true",
                        help="drop the rotor momentum columns (scale then not identified)")
    parser.add_argument("--fit-drag", action="store_true",
                        help="also fit a body-axis aerodynamic damping (identify(fit_drag=True))")
    args = parser.parse_args()
    data = Path(args.data)
    if not (data / "truth.json").exists():
        print(f"no rotor-throw data at {data} (truth.json missing): nothing to do")
        return
    truth = json.loads((data / "truth.json").read_text())
    files = sorted(p for p in data.glob("*.csv") if p.stem in truth)
    # Compile the numba kernels outside the per-throw wall times.
    identify(read_recordings(files[0])[0])
    t0 = time.perf_counter()
    rows, summaries = [], []
    for path in files:
        rec = read_recordings(path)[0]
        summary, row = score(dataclasses.replace(rec, name=path.stem), truth[path.stem],
                             args.withhold_h, args.fit_drag)
        rows.append(row)
        summaries.append((path.stem, summary))
    total = time.perf_counter() - t0
    errors = np.array([r["rel_error"] for r in rows])
    principal = np.array([r["principal_rel_error"] for r in rows])
    covered = np.array([r["covered"] for r in rows])
    moments_covered = np.array([r["principal_covered"] for r in rows])
    worst = rows[int(np.argmax(errors))]["throw"]
    authors = [r["authors_rel_error"] for r in rows if r["authors_rel_error"] is not None]
    print(("h withheld: ratios only (estimate rescaled to the reference's trace)\n\n"
           if args.withhold_h else "") + table(rows))
    print()
    print(f"- median error {100 * np.median(errors):.2f} %, worst {100 * errors.max():.2f} % "
          f"({worst}); authors' median {100 * np.median(authors):.2f} % over {len(authors)} throws")
    print(f"- principal moments: median error {100 * np.median(principal):.2f} %, worst "
          f"{100 * principal.max():.2f} %")
    print(f"- 95 % intervals cover {int(covered.sum())} of {covered.size} parameters "
          f"({100 * covered.mean():.0f} %); per parameter (xx, xy, xz, yy, yz, zz): "
          f"{covered.sum(axis=0).tolist()} of {len(rows)}; principal moments: "
          f"{int(moments_covered.sum())} of {moments_covered.size}")
    groups = {"Empty (the device on the base plate)": [r for r in rows if r["configuration"] == "Empty"],
              "calibration (device only, proof body)":
                  [r for r in rows if r["configuration"] != "Empty"]}
    split = {name: group_stats(members) for name, members in groups.items() if members}
    for name, g in split.items():
        print(f"- {name}: {g['throws']} throws, median error {100 * g['median_rel_error']:.2f} %, "
              f"worst {100 * g['worst_rel_error']:.2f} %; intervals cover {g['covered']} of "
              f"{g['parameters']} parameters and {g['moments_covered']} of {g['moments']} moments")
    bodies = [body_together(group, truth) for group in identifications_across(summaries, [])["groups"]]
    for b in bodies:
        off, widths = (np.round(100 * np.array(b[k]), 2).tolist() for k in ("rel_error", "rel_half_width"))
        print(f"- {b['series']} ({b['throws']} throws together, {b['source']}): {b['quantity']} "
              f"{np.round(b['estimate'], 7).tolist()} against the reference's "
              f"{np.round(b['reference'], 7).tolist()}: errors {off} %, 95 % half-widths {widths} %, "
              f"{sum(b['covered'])} of {len(b['covered'])} covered")
    print(f"- {len(rows)} throws identified in {total:.1f} s")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        report = {"data": str(data), "withhold_h": args.withhold_h,
                  "median_rel_error": float(np.median(errors)), "worst_rel_error": float(errors.max()),
                  "median_principal_rel_error": float(np.median(principal)),
                  "worst_principal_rel_error": float(principal.max()),
                  "covered": int(covered.sum()), "parameters": int(covered.size),
                  "moments_covered": int(moments_covered.sum()), "split": split, "bodies": bodies,
                  "wall_s_total": total, "rows": rows}
        (out / "rotor_throws.json").write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
