"""What several recordings of one body say together: the summary that `diagnose` and `identify`
write beside their per-recording folders (DIR/summary.json and DIR/summary.md) when they are
given several recordings (a folder, or a phone export of several tosses).

Pure functions over the per-recording results as written (report.json, identify.json dicts).
The inertia's shape is compared as its principal moments over the largest (descending, the
first 1), which every recording fixes, with or without a known torque.
"""

from __future__ import annotations

import collections
import re

import numpy as np
from scipy import stats

from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.estimation.uncertainty import homogeneity

RATIO_LABELS = ("I1/I1", "I2/I1", "I3/I1")
#: deg: internal_momentum's axes, fitted on several recordings of one body, lie along one axis
#: (a rotor fixed in the body) where their median angle to their common axis is within this (the
#: rotor throws' fitted axes lie a median 2.25 deg from the logged rotor's, and 19 of 20 within 20)
ONE_AXIS_DEG = 20.0


def series_name(name: str) -> str:
    """The name a recording shares with the rest of its series: its own without its trailing
    number and the word that counts it ("Empty_LOG00179" -> "Empty_LOG", "EXPORT segment 3" ->
    "EXPORT", "EXPORT flight 2" -> "EXPORT", "REC rows 1-150" -> "REC", "throw 3" -> "throw").
    A heuristic: "racquet_v2" and "racquet_v3" are one series "racquet_v", and a name ending
    in a time stamp loses its last part.
    """
    return (re.sub(r"[\s_-]*(segment|flight|rows|piece)?[\s_-]*[\d-]+$", "", name)
            or re.sub(r"[\s_-]*[\d-]+$", "", name) or name)


def diagnoses_across(done: list[tuple[str, dict]], refused: list[tuple[str, str]]) -> dict:
    """summary.json of several diagnoses: done [(name, report.json dict)], refused [(name,
    one-line reason)].

    Keys: recordings, refused [{name, reason}], rows [{name, series, leading, explanation,
    valid, worst_before, worst_after, principal_ratios, beyond_catalogue, invariants_reading}],
    the keys of _diagnoses over them all, and groups: where the recordings fall into several series
    (series_name: a folder of several bodies' throws, say), [{name, names, the keys of
    _diagnoses}] per series, else [].
    """
    rows = [{"name": name, "series": series_name(name), "leading": leading_effect(r),
             "explanation": [e["name"] for e in r["explanation"]], "valid": bool(r["fit_after"]["valid"]),
             "worst_before": _worst(r["fit_before"]), "worst_after": _worst(r["fit_after"]),
             "principal_ratios": r["fit_after"]["principal_ratios"],
             "beyond_catalogue": bool(r["beyond_catalogue"]),
             "invariants_reading": _reading(r)} for name, r in done]
    return _across(done, refused, rows, _diagnoses)


def _across(done: list[tuple[str, dict]], refused: list[tuple[str, str]], rows: list[dict],
            aggregate) -> dict:
    """The summary of done [(name, result)] and refused [(name, reason)]: recordings, refused
    [{name, reason}], the keys of aggregate(done), groups (_groups) and rows.
    """
    return {"recordings": len(done) + len(refused),
            "refused": [{"name": name, "reason": reason} for name, reason in refused],
            **aggregate(done), "groups": _groups(done, aggregate), "rows": rows}


def leading_effect(report: dict) -> str:
    """The first effect of a report's explanation ("none" where none is selected)."""
    return report["explanation"][0]["name"] if report["explanation"] else "none"


def leading_cause(report: dict) -> str:
    """The physical cause (the catalogue's family: "drag" for viscous_damping and aero_drag) of a
    report's leading effect ("none" where none is selected).
    """
    if not report["explanation"]:
        return "none"
    name = report["explanation"][0]["name"]
    return REGISTRY[name].family if name in REGISTRY else name


def _reading(report: dict) -> str:
    """What a report's invariants say of the missing torque (report.invariants' `reading`), or
    "not applicable" where an input changes them.
    """
    inv = report.get("invariants") or {}
    return inv.get("reading", "not applicable") if inv.get("applicable") else "not applicable"


def _diagnoses(done: list[tuple[str, dict]]) -> dict:
    """diagnosed, leading_effects {effect: count} (the first effect of each explanation; "none"
    where none is selected), leading_causes {family: {count, effects {effect: count}}} (the
    physical cause of each leading effect, the catalogue's family: two effects that model one
    cause at different fidelity, a thrown body's air as linear drag on one toss and as the air
    of its flight on another, count as one), most_common_lead {name, count, share} (share of the
    diagnosed),
    valid_fits, beyond_catalogue (count), gyro_frame_mirrored (count of reports whose gyro
    reads as a left-handed frame), invariants_readings
    {reading: count} (what the drifts of |H| and of the energy say of the missing torque,
    model-free but for the inertia),
    worst_rms_over_noise {before_median, after_median, fall} (each recording's worst axis;
    fall = before / after of the medians), principal_ratios
    (the body's shape from the fits after, shape_combined(); each fit's covariance taken as
    diagonal, from its 95 % intervals), pooled_delta_bic and momentum_axes (their functions).
    """
    reports = [r for _, r in done]
    fits = [f for r in reports if (f := r["fit_after"])["valid"] and f["principal_ratios_ci95"]]
    ratios = shape_combined([f["principal_ratios"] for f in fits],
                            [np.diag(((np.ptp(f["principal_ratios_ci95"], axis=1)) / (2 * 1.96)) ** 2)
                             for f in fits])
    leads = collections.Counter(leading_effect(r) for r in reports)
    causes: dict = {}
    for report in reports:
        cause = causes.setdefault(leading_cause(report), {"count": 0, "effects": collections.Counter()})
        cause["count"] += 1
        cause["effects"][leading_effect(report)] += 1
    causes = {family: {"count": c["count"], "effects": dict(c["effects"].most_common())}
              for family, c in sorted(causes.items(), key=lambda item: -item[1]["count"])}
    top = leads.most_common(1)[0] if reports else ("none", 0)
    before = [w for r in reports if (w := _worst(r["fit_before"])) is not None]
    after = [w for r in reports if (w := _worst(r["fit_after"])) is not None]
    median_before = float(np.median(before)) if before else None
    median_after = float(np.median(after)) if after else None
    return {
        "diagnosed": len(reports), "leading_effects": dict(leads.most_common()),
        "leading_causes": causes,
        "pooled_delta_bic": pooled_delta_bic(reports), "momentum_axes": momentum_axes(reports),
        "most_common_lead": {"name": top[0], "count": top[1],
                             "share": top[1] / len(reports) if reports else None},
        "valid_fits": sum(bool(r["fit_after"]["valid"]) for r in reports),
        "beyond_catalogue": sum(bool(r["beyond_catalogue"]) for r in reports),
        "gyro_frame_mirrored": sum(bool(r["gyro_frame_mirrored"]) for r in reports),
        "invariants_readings": dict(collections.Counter(_reading(r) for r in reports).most_common()),
        "worst_rms_over_noise": {"before_median": median_before, "after_median": median_after,
                                 "fall": median_before / median_after if median_before and median_after
                                 else None},
        "principal_ratios": ratios,
    }


def pooled_delta_bic(reports: list[dict]) -> dict:
    """{effect: the sum of its single-effect delta BICs over the reports}, largest first, for the
    effects with a valid single fit in every one (a report's `effects`): the BIC by which the
    effect present in every recording, its parameters each recording's own, beats none, since
    independent recordings' BICs add. The effect that leads one recording may explain little in
    the others; this is what they say together. On a recording whose gyro's rounding alone gives
    an effect a gain (its `noise.rounding_floor`, recounted with `independent_row_share` as the
    report's margins are), that gain is taken off first: summed over recordings it would read as
    physics. {} for fewer than two reports.
    """
    if len(reports) < 2:
        return {}
    sums: dict = collections.defaultdict(float)
    counts: collections.Counter = collections.Counter()
    for report in reports:
        noise = report.get("noise") or {}
        floors, share = noise.get("rounding_floor") or {}, noise.get("independent_row_share", 1.0)
        for effect in report["effects"]:
            if effect["delta_bic"] is not None:
                sums[effect["name"]] += effect["delta_bic"] - share * floors.get(effect["name"], 0.0)
                counts[effect["name"]] += 1
    return dict(sorted(((name, total) for name, total in sums.items() if counts[name] == len(reports)),
                       key=lambda item: -item[1]))


def momentum_axes(reports: list[dict]) -> dict | None:
    """Where internal_momentum is in the explanation of two reports or more: whether its fitted
    axes (the varying form's `axis`, the constant form's `h` direction; a line, either sign)
    lie along one axis, as a rotor fixed in the body would: {recordings, axis (3,) their common
    axis (the principal eigenvector of the sum of a a^T), median_angle_deg and max_angle_deg
    (each axis's angle to it), one_axis (median within ONE_AXIS_DEG)}; None otherwise.
    """
    axes = []
    for report in reports:
        for effect in report["explanation"]:
            if effect["name"] == "internal_momentum":
                vector = np.asarray(effect["params"].get("axis", effect["params"].get("h")), float)
                if vector.shape == (3,) and np.linalg.norm(vector) > 0:
                    axes.append(vector / np.linalg.norm(vector))
    if len(axes) < 2:
        return None
    stacked = np.array(axes)
    common = np.linalg.eigh(stacked.T @ stacked)[1][:, -1]
    angles = np.degrees(np.arccos(np.clip(np.abs(stacked @ common), 0.0, 1.0)))
    median = float(np.median(angles))
    return {"recordings": len(axes), "axis": common.tolist(), "median_angle_deg": median,
            "max_angle_deg": float(angles.max()), "one_axis": median <= ONE_AXIS_DEG}


def identifications_across(done: list[tuple[str, dict]], refused: list[tuple[str, str]]) -> dict:
    """summary.json of several identifications: done [(name, identify.json dict)], refused.

    Keys: recordings, refused [{name, reason}], rows [{name, series, principal_ratios,
    principal_ratios_ci95, principal_moments, scale_identified, rms_over_noise}], the keys of
    _identifications over them all, and groups as diagnoses_across's.
    """
    rows = [{"name": name, "series": series_name(name), "principal_ratios": s["principal_ratios"],
             "principal_ratios_ci95": s["principal_ratios_ci95"],
             "principal_moments": sorted(s["principal_moments"], reverse=True),
             "scale_identified": bool(s["scale_identified"]), "rms_over_noise": s["rms_over_noise"]}
            for name, s in done]
    return _across(done, refused, rows, _identifications)


def _identifications(done: list[tuple[str, dict]]) -> dict:
    """identified, principal_ratios (the body's shape from them all: shape_combined()) and
    principal_moments (kg·m², descending, combined() the same way, where every recording
    identified the scale; else None).
    """
    summaries = [s for _, s in done]
    ratios = shape_combined([s["principal_ratios"] for s in summaries],
                            [s["principal_ratios_cov"] for s in summaries])
    moments = None
    if summaries and all(s["scale_identified"] for s in summaries):  # descending, as the ratios
        moments = combined([np.array(s["principal_moments"][::-1]) for s in summaries],
                           [np.array(s["principal_moments_cov"])[::-1, ::-1] for s in summaries])
    return {"identified": len(summaries), "principal_ratios": ratios, "principal_moments": moments}


def _groups(done: list[tuple[str, dict]], summarize) -> list[dict]:
    """[{name, names, **summarize(its recordings)}] per series (series_name) where there are
    several, in the order they first appear; [] for one.
    """
    series: dict[str, list] = {}
    for name, result in done:
        series.setdefault(series_name(name), []).append((name, result))
    if len(series) < 2:
        return []
    return [{"name": key, "names": [n for n, _ in members], **summarize(members)}
            for key, members in series.items()]


def shape_combined(ratios: list, covs: list) -> dict | None:
    """combined() of principal-moment ratios [(3,)] (descending, the first 1) with their
    covariances [(3, 3)]: the first, the largest over itself, is 1 exactly and left out of the
    test; the result's vectors have it back in front.
    """
    result = combined([np.asarray(r, float)[1:] for r in ratios],
                      [np.asarray(c, float)[1:, 1:] for c in covs])
    if result is None:
        return None
    return {**result, **{k: [1.0, *result[k]] for k in ("estimate", "median", "min", "max")},
            "ci95": None if result["ci95"] is None else [[1.0, 1.0], *result["ci95"]]}


def combined(values: list[np.ndarray], covs: list[np.ndarray]) -> dict | None:
    """One vector from several estimates of it, values [(k,)] with covariances [(k, k)] (n of
    them); None for none.

    Each component by random effects: every recording's estimate is the truth plus its own
    error (its variance from its covariance) plus an error of its own that its interval does
    not count (a model that leaves something out, or a body that changed), of a variance tau^2
    shared by all (DerSimonian-Laird: zero where they agree within their own intervals). The
    estimate is the mean weighted by 1 / (v_i + tau^2), its 95 % interval Hartung-Knapp's
    (Student's t over n - 1, the weighted scatter about the estimate, never narrower than the
    weights alone allow). Recordings with honest intervals then get their weighted mean; with
    errors their intervals leave out, weights that even out, and an interval set by the scatter
    (weighting by understated intervals alone, or widening them all by one factor, covered the
    truth on only 58-70 % of such cases, simulated).
    One recording: its own estimate and interval. Where a variance is not positive and finite:
    the plain mean and the scatter's interval (Student's t over n - 1; none from one recording).
    Keys: estimate, ci95 ((k, 2) or None), source ("intervals": tau = 0 in every component;
    "random effects"; "scatter"), between_sd ((k,) tau, or None), and the test of one vector for
    all, with the full covariances: chi2 (None where one is singular), dof = k (n - 1), p;
    n, median, min, max.
    """
    if not values:
        return None
    x = np.array(values, float)
    n, k = x.shape
    out = {"n": n, **_spread(x), "chi2": None, "dof": k * (n - 1), "p": None, "between_sd": None}
    var = np.array([np.diag(np.asarray(c, float)) for c in covs])
    if not (np.all(np.isfinite(var)) and np.all(var > 0)):
        mean = x.mean(axis=0)
        if n < 2:
            return {**out, "estimate": mean.tolist(), "ci95": None, "source": "scatter"}
        half = stats.t.ppf(0.975, n - 1) * x.std(axis=0, ddof=1) / np.sqrt(n)
        return {**out, "estimate": mean.tolist(), "ci95": _interval(mean, half), "source": "scatter"}
    out.update(_one_vector_test(x, covs))
    if n < 2:
        return {**out, "estimate": x[0].tolist(), "ci95": _interval(x[0], 1.96 * np.sqrt(var[0])),
                "source": "intervals"}
    w = 1.0 / var
    fixed = np.sum(w * x, 0) / np.sum(w, 0)
    q = np.sum(w * (x - fixed) ** 2, 0)
    tau2 = np.maximum(0.0, (q - (n - 1)) / (np.sum(w, 0) - np.sum(w ** 2, 0) / np.sum(w, 0)))
    ws = 1.0 / (var + tau2)
    mean = np.sum(ws * x, 0) / np.sum(ws, 0)
    scatter = np.sum(ws * (x - mean) ** 2, 0) / (n - 1)
    half = stats.t.ppf(0.975, n - 1) * np.sqrt(np.maximum(scatter, 1.0) / np.sum(ws, 0))
    if not (np.all(np.isfinite(half)) and np.all(np.isfinite(tau2))):  # variances near underflow
        return combined(values, [np.full((k, k), np.nan)] * n)
    return {**out, "estimate": mean.tolist(), "ci95": _interval(mean, half),
            "source": "random effects" if np.any(tau2 > 0) else "intervals",
            "between_sd": np.sqrt(tau2).tolist()}


def _one_vector_test(x: np.ndarray, covs) -> dict:
    """uncertainty.homogeneity of the estimates x (n, k) with their covariances, its chi2 and p
    over k (n - 1) degrees of freedom; {} where a covariance is not positive definite.
    """
    try:
        for c in covs:
            np.linalg.cholesky(np.asarray(c, float))  # positive definite, or no test
    except np.linalg.LinAlgError:
        return {}
    test = homogeneity(list(x), covs)
    return {"chi2": test.statistic, "p": test.p_value} if np.isfinite(test.statistic) else {}


def _interval(mean: np.ndarray, half: np.ndarray) -> list:
    """(k, 2) [lo, hi] of mean +- half."""
    return np.stack([mean - half, mean + half], 1).tolist()


def _worst(fit: dict) -> float | None:
    """A fit summary's worst-axis rms over the noise (None for no valid fit)."""
    return max(fit["rms_over_noise"]) if fit.get("rms_over_noise") else None


def _spread(x: np.ndarray) -> dict:
    """Median, min and max of each column of x (n, k)."""
    return {"median": np.median(x, 0).tolist(), "min": x.min(0).tolist(), "max": x.max(0).tolist()}


def diagnoses_markdown(summary: dict) -> str:
    """summary.md of diagnoses_across's summary."""
    def cells(row):
        ratios = row["principal_ratios"]
        return [row["name"], row["leading"], " + ".join(row["explanation"]) or "-", _num(row["worst_before"]),
                _num(row["worst_after"]), ", ".join(f"{r:.3f}" for r in ratios[1:]) if ratios else "-"]

    return _markdown("Diagnosis", summary, _diagnoses_lines, "diagnosed",
                     ("recording", "leading effect", "explanation", "worst rms/noise before", "after",
                      "I2/I1, I3/I1"), cells)


def _markdown(title: str, summary: dict, lines_of, count: str, header, cells) -> str:
    """summary.md of an across summary: its lines (lines_of), each series' (counted by the key
    count), and a table of the rows (header, and cells(row) -> the row's cells).
    """
    lines = [f"# {title} across {_count(summary['recordings'])}", ""]
    lines += _refused_lines(summary) + lines_of(summary) + _series_note(summary)
    for group in summary["groups"]:
        lines += ["", f"## Series {group['name']} ({_count(group[count])})", ""] + lines_of(group)
    if summary["rows"]:
        lines += ["", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(cells(row)) + " |" for row in summary["rows"]]
    return "\n".join(lines) + "\n"


def _diagnoses_lines(result: dict) -> list[str]:
    """Lines on a _diagnoses() result (of all recordings or of one series)."""
    n = result["diagnosed"]
    if not n:
        return []
    leads = ", ".join(f"`{name}` on {count} ({count / n:.0%})"
                      for name, count in result["leading_effects"].items())
    worst = result["worst_rms_over_noise"]
    causes = "; ".join(
        f"{family} on {c['count']} ({c['count'] / n:.0%}"
        + (": " + ", ".join(f"`{name}` {count}" for name, count in c["effects"].items())
           if family != "none" else "") + ")"
        for family, c in result["leading_causes"].items())
    lines = [f"- Leading effect of the explanation, of {n} diagnosed: {leads}.",
             f"- Its physical cause (the catalogue's family of each leading effect): {causes}.",
             f"- A valid fit on {result['valid_fits']} of {n}; beyond the catalogue (the explanation "
             f"leaves a large misfit) on {result['beyond_catalogue']}.",
             "- The missing torque as the drifts of |H| and of the energy read it (the invariants): "
             + ", ".join(f"{name} on {count}" for name, count in result["invariants_readings"].items())
             + "."]
    if result["gyro_frame_mirrored"]:
        lines.append(f"- **The gyro's frame reads left-handed** on {result['gyro_frame_mirrored']} of {n} "
                     "(two columns swapped or one axis's sign flipped fit a rigid body better than any "
                     "explanation): check the order and signs of the gyro's axes before reading the effects.")
    if worst["fall"] is not None:
        lines.append(f"- Worst-axis rms over the noise, median: {worst['before_median']:.3g} before, "
                     f"{worst['after_median']:.3g} after ({worst['fall']:.3g}x lower).")
    return lines + _pooled_lines(result) + _shape_lines(result["principal_ratios"], "the explained fits")


def _pooled_lines(result: dict) -> list[str]:
    """Lines on a _diagnoses() result's pooled_delta_bic and momentum_axes."""
    lines = []
    pooled = list(result.get("pooled_delta_bic", {}).items())
    if pooled and pooled[0][1] > 0:
        lines.append("- Pooled over the recordings (each effect in every one, its parameters each one's "
                     "own; the single-effect delta BICs summed): "
                     + ", ".join(f"`{name}` {total:.0f}" for name, total in pooled[:3])
                     + f"; together they are best read as `{pooled[0][0]}`.")
    elif pooled:
        lines.append("- Pooled over the recordings, no effect improves the BIC.")
    axes = result.get("momentum_axes")
    if axes:
        where = (f"- `internal_momentum` is in the explanation of {axes['recordings']}: its axes lie a "
                 f"median {axes['median_angle_deg']:.0f} deg from their common axis (at most "
                 f"{axes['max_angle_deg']:.0f} deg)")
        held, diagnosed = axes["recordings"], result["diagnosed"]
        if not axes["one_axis"]:
            lines.append(where + f", over {ONE_AXIS_DEG:g} deg: not one rotor fixed in the body; read it as "
                         "a torque about a body axis with a time course of its own (air on a thrown "
                         "body, say), the ambiguity its reports name.")
        elif 2 * held < diagnosed:  # a rotor of the body would act in most of them
            lines.append(where + f", as one rotor fixed in the body would; but only {held} of {diagnosed} "
                         "recordings hold it, and a rotor would act in the others too: read it as what "
                         "those fits trade for what the catalogue lacks, the ambiguity their reports name.")
        else:
            lines.append(where + ", as one rotor fixed in the body would.")
    return lines


def identifications_markdown(summary: dict) -> str:
    """summary.md of identifications_across's summary."""
    def cells(row):
        ratios = [f"{r:.4g} [{lo:.4g}, {hi:.4g}]" for r, (lo, hi) in
                  zip(row["principal_ratios"][1:], row["principal_ratios_ci95"][1:])]
        return [row["name"], *ratios, str(row["scale_identified"]), f"{row['rms_over_noise']:.3g}"]

    return _markdown("Inertia", summary, _identifications_lines, "identified",
                     ("recording", "I2/I1", "I3/I1", "scale identified", "rms/noise"), cells)


def _identifications_lines(result: dict) -> list[str]:
    """Lines on an _identifications() result (of all recordings or of one series)."""
    lines = _shape_lines(result["principal_ratios"], "the rigid fits")
    moments = result["principal_moments"]
    if moments is not None:
        lines += [f"- Principal moments (kg·m², the scale identified on every recording): "
                  f"{_values(('I1', 'I2', 'I3'), moments)} (95 %).", "- " + source_words(moments)]
    return lines


def _shape_lines(ratios: dict | None, fits: str) -> list[str]:
    """Lines on the body's shape from a shape_combined() result (none for None)."""
    if ratios is None:
        return []
    shape = {**ratios, "estimate": ratios["estimate"][1:], "ci95": ratios["ci95"] and ratios["ci95"][1:]}
    values = _values(RATIO_LABELS[1:], shape)
    spread = "; ".join(f"{label} {lo:.4g} to {hi:.4g}" for label, lo, hi in
                       zip(RATIO_LABELS[1:], ratios["min"][1:], ratios["max"][1:]))
    return [f"- Principal moments over the largest, from {fits} of {_count(ratios['n'])}: {values}"
            f" (95 %; each recording's own: {spread}).", "- " + source_words(ratios)]


def _values(labels, result: dict) -> str:
    """"label = estimate [lo, hi]; ..." of a combined() result (no interval where it has none)."""
    ci = result["ci95"] or [None] * len(labels)
    return "; ".join(f"{label} = {m:.4g}" + ("" if c is None else f" [{c[0]:.4g}, {c[1]:.4g}]")
                     for label, m, c in zip(labels, result["estimate"], ci))


def source_words(result: dict) -> str:
    """Where a combined() interval comes from, in words."""
    if result["source"] == "scatter":
        if result["n"] < 2:
            return "One recording whose intervals cannot be used: no interval."
        return ("A recording's intervals cannot be used (a variance is not positive): the interval is "
                "the scatter between the recordings.")
    if result["n"] < 2:
        return "One recording: its own interval."
    test = ("" if result["chi2"] is None else
            f" The test of one vector for all, with the covariances' correlations: chi-square "
            f"{result['chi2']:.3g} on {result['dof']} degrees of freedom, p = {result['p']:.2g}.")
    if result["source"] == "intervals":
        return ("The recordings scatter no more than their own intervals allow, one component at a "
                "time (a between-recording spread of zero): the estimate is their weighted mean." + test)
    return ("The recordings scatter more than their own intervals allow: each recording's interval "
            "understates its error (its model leaves something out, or the body changed between "
            "recordings) by about " + ", ".join(f"{b:.3g}" for b in result["between_sd"])
            + " (standard deviation), which the estimate's weights and interval include (random "
            "effects)." + test)


def _series_note(summary: dict) -> list[str]:
    """A line saying the recordings fall into several series, each summarized below."""
    if not summary["groups"]:
        return []
    return [f"- The recordings fall into {len(summary['groups'])} series (named alike up to their "
            "number): if these are different bodies, read each series below, not what all of them "
            "give together."]


def _refused_lines(summary: dict) -> list[str]:
    if not summary["refused"]:
        return []
    return [f"- Refused: {len(summary['refused'])} ("
            + "; ".join(f"{r['name']}: {r['reason']}" for r in summary["refused"]) + ")."]


def _count(n: int) -> str:
    return f"{n} recording{'' if n == 1 else 's'}"


def _num(value) -> str:
    return "-" if value is None else f"{value:.3g}"
