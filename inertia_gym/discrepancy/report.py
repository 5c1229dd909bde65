"""Diagnosis of one recording: fit, locate the mismatch (time, axis, frequency), check the
invariants, rank the catalogue, and write report.json, plots and a markdown summary.

diagnose() and the fits it takes are here; the analyses of a fit are in analysis.py, the plots
in report_plots.py and the summary's words in summary.py. This module gathers their public
names: the commands, the scripts and the tests import them from here.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.discrepancy.analysis import (
    BEYOND_CATALOGUE,
    DRAG_RATIO_TOLERANCE,
    NOISE_READ_HIGH,
    NOT_READ,
    RATIO_DRAWS_LOG2,
    SCALE_RCOND,
    _fit_summary,
    _noise_reads_high,
    _read_with_both,
    inertia_comparison,
    invariants,
    locate,
    mirrored_frame,
    normal_draws,
    principal_ratios,
    scale_identified,
    spectrum,
    trace_sigma,
)
from inertia_gym.discrepancy.effects import REGISTRY, jsonable
from inertia_gym.discrepancy.fit import (
    AMBIGUOUS_DELTA_BIC,
    MIN_ROWS,
    SIGNIFICANT_DELTA_BIC,
    UNEXPLAINED_RMS,
    Data,
    Fit,
    claim_margin,
    effective_share,
    finish,
    fit_all,
    fit_nominal,
    impulses,
    intervals,
    lattice_level,
    lattice_refits_counted,
    polished,
    predictive_selection,
    prepare,
    ranked,
    rounding_checked,
    rounding_floors,
    rounding_runs,
    search,
    select,
    sparse_terms,
)
from inertia_gym.discrepancy.plausibility import implausible
from inertia_gym.discrepancy.report_plots import write_plots
from inertia_gym.discrepancy.summary import (
    LISTED_NUMBERS,
    RATIO_SPREAD,
    ROTOR_READING,
    _beyond_words,
    _explanation_words,
    _invariants_words,
    _next_steps,
    _shape_words,
    markdown,
)
from inertia_gym.errors import RecordingError
from inertia_gym.estimation.uncertainty import SCALE_SIGMA_IDENTIFIED
from inertia_gym.executors import kernels_own_the_cores
from inertia_gym.prepare import Prepared, clips_at_the_ends, prepared
from inertia_gym.recordings import Recording, check_input_gaps, retimed
from inertia_gym.sensors import quantisation_note, stated_noise_note

__all__ = [
    "BEYOND_CATALOGUE",
    "DRAG_RATIO_TOLERANCE",
    "LISTED_NUMBERS",
    "NOISE_READ_HIGH",
    "NOT_READ",
    "RATIO_DRAWS_LOG2",
    "RATIO_SPREAD",
    "READINGS",
    "RECOUNT_BELOW",
    "ROTOR_READING",
    "SCALE_RCOND",
    "Diagnosis",
    "check_enough_rows",
    "diagnose",
    "inertia_comparison",
    "invariants",
    "locate",
    "markdown",
    "mirrored_frame",
    "normal_draws",
    "principal_ratios",
    "reading",
    "scale_identified",
    "spectrum",
    "trace_sigma",
    "write_plots",
    # the private helpers the tests read through this module
    "_beyond_words",
    "_explanation_words",
    "_fits",
    "_invariants_words",
    "_next_steps",
    "_read_with_both",
    "_shape_words",
]

#: The BICs are recounted with the independent rows when fewer than this share of them are.
RECOUNT_BELOW = 0.8


def _trimmed(rec: Recording, d: Data) -> list[dict]:
    """The spans left out at the record's ends as impulses: where, how long, how large."""
    out = []
    start, end = d.notes["trimmed"]
    if start:
        out.append({"where": "start", "t_start": float(rec.t[0]), "t_end": float(rec.t[start]),
                    "samples": int(start)})
    if end:
        out.append({"where": "end", "t_start": float(rec.t[-end - 1]), "t_end": float(rec.t[-1]),
                    "samples": int(end)})
    return out


def check_enough_rows(rec: Recording, d: Data) -> None:
    """Refuse in one line a recording whose samples make fewer than MIN_ROWS residual rows,
    saying where they went when the gyro clipped (clipped samples are left out).
    """
    if d.n_rows >= MIN_ROWS:
        return
    clipped = d.notes["saturated_samples"]
    if clipped:
        raise RecordingError(f"{rec.name}: the gyro clipped at its full scale in {clipped} of "
                             f"{rec.t.size} samples, which say only that the rate was beyond it; the "
                             f"rest make {d.n_rows} residual rows and diagnose needs at least "
                             f"{MIN_ROWS} (a gyro range above the body's rates, or a slower spin)")
    raise RecordingError(f"{rec.name}: {rec.t.size} samples make {d.n_rows} residual rows; "
                         f"diagnose needs at least {MIN_ROWS} (a longer recording)")


def _fitted_nominal(d: Data) -> tuple[Data, Fit]:
    """The nominal fit of d, and d with the noise level of a coarsely read gyro read again on it
    (fit.lattice_level; the fit scored with that level).
    """
    nominal = fit_nominal(d)
    level = lattice_level(d, nominal)
    return (d, nominal) if level is d else (level, finish(nominal.layout, nominal.x, level, nominal.k))


@dataclasses.dataclass(frozen=True)
class _Fits:
    """What diagnose fitted to one record: data (the prepared Data, impulses trimmed), nominal
    (the rigid fit), singles (the single-effect fits, ranked), skipped (the effects not fitted,
    each with why), chosen (the explanation).
    """

    data: Data
    nominal: Fit
    singles: list
    skipped: dict
    chosen: object


def _fits(prep: Prepared) -> _Fits:
    """Nominal, single-effect and compound fits of a prepared recording, its impulses trimmed.

    Impulses at the ends are located on the nominal fit's residual and, once the explanation
    has taken the smooth misfit away, again on the compound fit's (where a small impulse stands
    out): the first search's, then, where that shows none, the selected one's; a second trim
    repeats the fits on the trimmed record. On a coarsely rounded record
    (rounding_floors), the explanation's effects are then checked against the rounding
    (rounding_checked), which raises the floors of those it checks alone.
    """
    rec = prep.rec
    d = prepare(prep)
    check_enough_rows(rec, d)
    d, nominal = _fitted_nominal(d)
    if not np.isfinite(nominal.bic):
        raise RecordingError(f"{rec.name}: the rigid-body model could not be integrated over this "
                             "recording (its residual is not finite); check the units of t and w")
    trim = impulses(d, nominal)
    floors: dict = {}  # what each effect gains from a coarse gyro's rounding alone, where
    # one gains significantly (rounding_floors)
    for attempt in range(2):
        if any(trim):
            d, nominal = _fitted_nominal(prepare(prep, trim))
        fits, skipped = fit_all(d, nominal)
        if not floors and any(nominal.bic - f.bic > SIGNIFICANT_DELTA_BIC for f in fits):
            floors = rounding_floors(d, nominal, [f.name for f in fits])  # every candidate's: each
            # is screened on top of the others, significant alone or not
        d = dataclasses.replace(d, rounding_floor=floors)
        first = search(d, nominal, fits)
        more = _impulses_left(d, first, attempt)
        if not any(more):  # select's other searches run only on the record as it stays
            chosen = select(d, nominal, fits, first=first)
            more = _impulses_left(d, chosen, attempt)
        if not any(more):
            break
        trim = (trim[0] + more[0], trim[1] + more[1])
    # what even the explanation leaves unexplained is correlated on real recordings: the BICs are
    # recounted with the rows that are independent, and the selection made again on them
    share = effective_share(d, chosen.fit or nominal)
    if share < RECOUNT_BELOW:
        d = dataclasses.replace(d, effective_share=share)
        nominal = finish(nominal.layout, nominal.x, d, nominal.k)
        fits = ranked([finish(f.layout, f.x, d, f.k) for f in fits])
        chosen = select(d, nominal, fits)
    chosen = predictive_selection(chosen, d, nominal, fits)  # what it adds after its leader must predict
    if floors and chosen.fit is not None:  # each effect it claims against the rounding, over more draws
        chosen, alone = rounding_checked(d, nominal, chosen, fits)
        d = dataclasses.replace(d, rounding_floor={n: max(f, alone.get(n, 0.0)) for n, f in floors.items()})
    if chosen.fit is not None:  # the fit the report reads its inertia and intervals from (the
        # selection's delta BICs, chosen.added, are kept as selected)
        chosen = dataclasses.replace(chosen, chain=chosen.chain[:-1] + tuple(polished([chosen.fit], d)))
    return _Fits(d, nominal, fits, skipped, chosen)


def _impulses_left(d: Data, expl, attempt: int) -> tuple[int, int]:
    """Samples (start, end) of the impulses the explanation expl's fit shows at d's ends on the
    first attempt (fit.impulses); none on the second, or where expl has no fit.
    """
    return impulses(d, expl.fit) if expl.fit is not None and attempt == 0 else (0, 0)


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """What :func:`diagnose` finds in one recording.

    report: the JSON-ready document written to report.json (docs/contracts.md keys, and more).
    The series its plots draw, on the residual rows (times t_rows, s): residual_before and
    residual_after (rows, 3) rad/s, of the nominal rigid fit and of the explanation's fit;
    frequency (Hz) and power (frequency, 3), the nominal residual's spectrum; invariants, the
    momentum and energy check with its series over data.t. data: the prepared rows the fits read;
    nominal and best: the rigid fit and the explanation's (best is nominal when nothing is added).
    """

    report: dict
    t_rows: np.ndarray
    residual_before: np.ndarray
    residual_after: np.ndarray
    frequency: np.ndarray
    power: np.ndarray
    invariants: dict
    data: Data
    nominal: Fit
    best: Fit


@kernels_own_the_cores
def diagnose(rec: Recording) -> Diagnosis:
    """The full diagnosis of one recording (:class:`Diagnosis`): its report and the series of its
    plots.
    """
    check_input_gaps(rec)
    rec = retimed(rec)
    found = _fits(prepared(rec))
    d, nominal, fits, skipped, chosen = found.data, found.nominal, found.singles, found.skipped, found.chosen
    ranked = []
    for f in fits:
        delta = float(nominal.bic - f.bic)
        finite = bool(np.isfinite(delta))  # no valid fit: no delta
        ranked.append({"name": f.name, "form": f.forms[0] or None,
                       "params": jsonable(f.params) if finite else {},
                       "delta_bic": delta if finite else None,
                       "significant": finite and delta > claim_margin(d, f.name)})
    sig = [e for e in ranked if e["significant"]]
    best = chosen.fit or nominal
    ambiguous = []
    if sig:
        top = sig[0]
        for e in sig[1:]:
            if top["delta_bic"] - e["delta_bic"] < AMBIGUOUS_DELTA_BIC:
                ambiguous.append({"effects": [top["name"], e["name"]],
                                  "reason": f"delta BIC differs by {top['delta_bic'] - e['delta_bic']:.1f}"
                                            f" < {AMBIGUOUS_DELTA_BIC}"})
        for other, reason in _live_ambiguities(top["name"], top["form"] or "", skipped):
            ambiguous.append({"effects": [top["name"], other], "reason": reason})
    offset = next((f for f in fits if f.name == "inertia_offset"), None)  # J fitted vs the nominal
    scale_seen, scale_sigma = scale_identified(d, best, offset)
    # the inertia is compared with the nominal in absolute terms only where the scale is firm
    scale_firm = scale_seen and scale_sigma is not None and scale_sigma <= SCALE_SIGMA_IDENTIFIED
    t_row = d.t_row
    # a rounding error stays near one value while the rate dwells within a step: over a window its
    # mean square reaches q^2 / 4, not the q^2 / 12 of the level (sensors.stated_gyro_level)
    rounding = np.sqrt(d.sigma ** 2 + d.notes["quantisation_step"] ** 2 / 6.0)
    locations = locate(nominal.r, t_row, rounding * d.row_scale[:, None])
    before = _fit_summary(nominal, d)
    after = before if best is nominal else _fit_summary(best, d)
    unexplained = not after["valid"] or max(after["rms_over_noise"]) > UNEXPLAINED_RMS
    f, p = spectrum(nominal.r, float(np.median(np.diff(t_row))) if t_row.size > 1 else 1.0)
    frame = mirrored_frame(rec, d, best) if bool(sig) or unexplained else None
    inv = invariants(d, best)
    if best is not nominal and (unexplained or not all(REGISTRY[n].keeps_invariants for n in best.names)):
        inv = _read_with_both(inv, invariants(d, nominal))  # its inertia alone is not sure
    explanation = _explanation(chosen, d, scale_firm, skipped, rec)
    refused = [{"name": n, "why": why, "delta_bic": gain} for n, (why, gain) in chosen.refused.items()]
    report = {
        "recording": rec.name, "samples": int(rec.t.size), "duration_s": float(rec.t[-1] - rec.t[0]),
        "mismatch_detected": bool(sig) or bool(locations) or unexplained,
        "locations": locations, "effects": ranked, "best_effect": sig[0]["name"] if sig else None,
        "explanation": explanation, "left_out": chosen.dropped,
        "ambiguous": ambiguous, "skipped_effects": skipped,
        "fit_before": before,
        "fit_inertia_fitted": before if offset is None else _fit_summary(offset, d), "fit_after": after,
        "inertia_vs_nominal": None if offset is None else {
            "delta_bic": float(nominal.bic - offset.bic) if np.isfinite(offset.bic) else None,
            **inertia_comparison(d.inertia0, offset.inertia, scale_firm)},
        "gyro_sigma": d.sigma.tolist(), "gyro_sigma_source": d.sigma_source,
        "noise": {"rows": "block means" if d.block > 1 else "samples", "samples_per_row": d.block,
                  "sigma": d.sigma.tolist(), "source": d.sigma_source,
                  "independent_row_share": d.effective_share, "read_high": _noise_reads_high(best, d),
                  "sidecar_disagrees": None if d.sigma_source != "sidecar"
                  else stated_noise_note(d.w[d.row >= 0], d.sigma, np.sqrt(np.mean(best.r ** 2, axis=0))),
                  "quantisation": None if d.sigma_source != "sidecar"
                  else quantisation_note(float(rec.meta["gyro_sigma"]), d.notes["quantisation_step"]),
                  "rounding_runs": rounding_runs(d).tolist(), "rounding_floor": d.rounding_floor or None,
                  "lattice_refits": lattice_refits_counted(best, d)},
        "segments": d.segments, "trimmed": _trimmed(rec, d),
        "split_at_gaps": rec.meta.get("split_at_gaps"),
        "retimed": rec.meta.get("retimed"),
        "free_flight_window": None if "window_source" not in rec.meta else {
            "t_start": rec.meta["window"][0], "t_end": rec.meta["window"][1],
            "source": rec.meta["window_source"]},
        "saturated_samples": d.notes["saturated_samples"],
        "clipped_at_ends": clips_at_the_ends(rec),
        "saturation_rad_s": d.notes.get("saturation_rad_s"),
        "scale_identified": scale_seen,
        "scale_sigma": scale_sigma if scale_sigma is None or np.isfinite(scale_sigma) else None,
        "scale_seen_by_inputs": d.excited,
        "inertia_nominal_given": d.inertia0 is not None, "inertia_trace_assumed": d.trace0,
        "spectrum_peak_hz": [float(f[1:][np.argmax(p[1:, i])]) if len(f) > 1 else 0.0 for i in range(3)],
        "invariants": {k: v for k, v in inv.items() if k != "series"},
        "unexplained_residual": unexplained,
        "refused_implausible": refused,
        "unpredictive": [{"name": n, "held_out_ratio": r} for n, r in chosen.unpredictive.items()],
        "beyond_catalogue": (not after["valid"] or max(after["rms_over_noise"]) > BEYOND_CATALOGUE
                             or any(e["implausible"] for e in explanation) or bool(refused)
                             or bool(chosen.unpredictive)),
        "sparse_terms": sparse_terms(d, best) if unexplained else [],
        "gyro_frame_mirrored": frame,
    }
    return Diagnosis(report, t_row, nominal.r, best.r, f, p, inv, d, nominal, best)


def _live_ambiguities(name: str, form: str, skipped: dict) -> list[tuple[str, str]]:
    """The effect's known ambiguities in that form (EffectModel.confounded) but those with an
    effect the recording cannot test (in skipped: an inertia offset trades against a torque
    scale only where a torque is commanded).
    """
    return [(other, why) for other, why in REGISTRY[name].confounded(form) if other not in skipped]


#: An explanation entry's ``reading``: the named physics (the body may carry what it needs, or it
#: needs nothing), the named physics if the body carries the part (the sidecar does not say), or
#: only what the fitted terms do (the sidecar says the body has none of the parts).
READINGS = ("physics", "if_carried", "unmodelled")


def reading(name: str, rec: Recording) -> str:
    """How the report words effect `name` on `rec`'s body (:data:`READINGS`)."""
    parts = REGISTRY[name].hardware
    carried = rec.carries(parts) if parts else True
    return {True: "physics", None: "if_carried", False: "unmodelled"}[carried]


def _explanation(chosen, d: Data, scale_seen: bool, skipped: dict, rec: Recording) -> list[dict]:
    """The selected effects in order: name, params, 95 % intervals, the delta BIC each added
    (an inertia_offset's comparison with the nominal at the nominal's trace unless scale_seen:
    the record fixes the scale firmly),
    the ambiguities the recording leaves open (_live_ambiguities; skipped: the effects it cannot
    test), and how it reads on rec's body (:func:`reading`).
    """
    if chosen.fit is None:
        return []
    fit = chosen.fit
    named, ci = fit.effect_params, intervals(fit, d)
    out = []
    for name, added in chosen.added:
        model = REGISTRY[name]
        form = fit.forms[fit.names.index(name)]
        entry = {"name": name, "form": form or None,
                 "family": model.family, "params": jsonable(named[name]),
                 "ci95": {k: {"lo": np.asarray(v["lo"]).tolist(), "hi": np.asarray(v["hi"]).tolist()}
                          for k, v in ci[name].items()},
                 "delta_bic": added, "reading": reading(name, rec),
                 "implausible": implausible(name, named[name], d, SIGNIFICANT_DELTA_BIC),
                 "confounded_with": [{"with": other, "reason": why}
                                     for other, why in _live_ambiguities(name, form, skipped)]}
        if name == "inertia_offset":
            entry["inertia_vs_nominal"] = inertia_comparison(d.inertia0, named[name]["inertia"],
                                                             scale_seen)
        out.append(entry)
    return out
