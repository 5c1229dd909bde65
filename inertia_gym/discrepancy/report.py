"""Diagnosis of one recording: fit, locate the mismatch (time, axis, frequency), check the
invariants, rank the catalogue, and write report.json, plots and a markdown summary.
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
from scipy import signal, stats

from inertia_gym.discrepancy.effects import REGISTRY, jsonable
from inertia_gym.discrepancy.fit import (
    AMBIGUOUS_DELTA_BIC,
    LATTICE_REPLAYS,
    MIN_ROWS,
    SIGNIFICANT_DELTA_BIC,
    UNEXPLAINED_RMS,
    Data,
    Fit,
    claim_margin,
    covariance,
    effective_share,
    finish,
    fit_all,
    fit_model,
    fit_nominal,
    impulses,
    information,
    intervals,
    lattice_level,
    lattice_refits_counted,
    model_inertia,
    polished,
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
from inertia_gym.errors import RecordingError
from inertia_gym.estimation.inertia_param import nearest_realizable
from inertia_gym.estimation.uncertainty import SCALE_SIGMA_IDENTIFIED
from inertia_gym.executors import kernels_own_the_cores
from inertia_gym.prepare import CLIP_ADVICE, Prepared, clips_at_the_ends, prepared
from inertia_gym.recordings import (
    Recording,
    check_input_gaps,
    retimed,
    retimed_note,
    window_note,
)
from inertia_gym.sensors import quantisation_note, stated_noise_note

#: The BICs are recounted with the independent rows when fewer than this share of them are.
RECOUNT_BELOW = 0.8
#: A principal-moment ratio whose 95 % interval is wider than this says little of the body's shape.
RATIO_SPREAD = 0.1
#: Residual rms / noise (worst axis) above which the explanation is reported as short of the
#: recording: physics the catalogue lacks is at work, and the effects named are at best part of
#: what is missing. The own and Basilisk harnesses end at most at 3.6 and the racquet tosses the
#: catalogue explains (round 2) at 2.3-4.3 (coloured noise); racquet round 1 stays at 18.7-104
#: whatever is added, and the real rotor throws, their rotor named, at 19.7-169 (a 4-kHz gyro
#: whose noise is far below what the model leaves).
BEYOND_CATALOGUE = 5.0
#: Residual rms / noise (every axis, the fitted parameters' degrees of freedom restored) below
#: which a noise level read from the data is reported as reading high: a fit cannot leave much
#: less than the noise, but motion fast for the sampling passes for noise in the differences
#: (a 1-s toss at 15 rad/s sampled at 25-33 Hz read 1.3-3.3x its noise; its fit 0.25-0.68x).
NOISE_READ_HIGH = 0.8
#: Draws of a fit's parameters behind the ratios' intervals: 2**RATIO_DRAWS_LOG2 points of a
#: scrambled Sobol sequence (seeded) mapped to normal quantiles. Their 2.5/97.5 percentiles come
#: within 2 % of the exact interval where the ratios are linear in the parameters; 400
#: pseudo-random draws, as before, missed it by up to 12 % (a racquet flip with drag: half-width
#: 3.45e-4 against 3.92e-4; tests/discrepancy/test_fit.py).
RATIO_DRAWS_LOG2 = 9
#: The least eigenvalue a fit's information (scaled to a unit diagonal) counts with, as a share
#: of its largest (trace_sigma).
SCALE_RCOND = 1e-12


def locate(r, t_mid, sigma, alpha: float = 1e-3) -> list[dict]:
    """Windows where the rate residual rows r (K, 3) rad/s at times t_mid (K,) exceed their noise
    sigma ((3,) or (K, 3)): windowed chi-square test per axis, Bonferroni over windows and axes;
    adjacent windows merged.
    """
    k = r.shape[0]
    size = max(5, k // 25)
    starts = np.arange(0, k - size + 1, size)
    crit = stats.chi2.ppf(1 - alpha / (3 * max(len(starts), 1)), size)
    sigma = np.broadcast_to(sigma, r.shape)
    out = []
    for s in starts:
        chi = np.sum((r[s:s + size] / sigma[s:s + size]) ** 2, 0)
        axes = [a for a, c in zip("xyz", chi) if c > crit]
        if not axes:
            continue
        stat = float(np.max(chi) / size)
        t0, t1 = float(t_mid[s]), float(t_mid[min(s + size, k - 1)])
        if out and abs(out[-1]["t_end"] - t0) < 1e-9:
            out[-1]["t_end"] = t1
            out[-1]["axes"] = sorted(set(out[-1]["axes"]) | set(axes))
            out[-1]["statistic"] = max(out[-1]["statistic"], stat)
        else:
            out.append({"t_start": t0, "t_end": t1, "axes": axes, "statistic": stat})
    return out


def spectrum(r, dt_row: float):
    """Welch spectrum of the rate residual rows: frequencies (f,) Hz, power (f, 3) (rad/s)²/Hz."""
    f, p = signal.welch(r, fs=1.0 / dt_row, axis=0, nperseg=min(256, r.shape[0]), detrend=False)
    return f, p


#: a ratio of the energy's relative drift to |H|'s within this factor of the references reads as a
#: drag (the references are means over the record of ratios that move with the rotation)
DRAG_RATIO_TOLERANCE = 1.15
#: the reading where the drifts cannot be read as a torque's
NOT_READ = "not read (no rotation, or a known momentum against it)"


def invariants(d: Data, fit: Fit) -> dict:
    """Drift of |H| = |J w + h| and of the rotational energy E = w.J w / 2 (fitted J, known
    internal momentum h) over the recording, when torque-free; and what the drift says of the
    torque missing from the model.

    An external torque changes |H|; an internal effect (dissipation) changes E but keeps |H|.
    Drift is the fitted linear change over the recording relative to the mean, with a z-score.
    Where both fall, their ratio (dE/E) / (d|H|/|H|) tells the torque's direction: a torque tau
    gives w.tau / E against (H.tau) / |H|^2 at each instant, so one against the angular
    momentum (tau = -k H; where h = 0 a drag -k J w, every motion slowed alike) gives w.H / E (2
    where h = 0) and one against the rates (tau = -c w) |w|^2 |H|^2 / (E H.w) (at least 2 where
    h = 0); both references are taken from the record's means as the observed ratio is
    (`against_momentum_ratio`, `against_rates_ratio`, _torque_reading), and `reading` names
    the nearer where the ratio lies within DRAG_RATIO_TOLERANCE of them, says which the torque
    drains beyond a drag where it lies outside (energy: dissipation inside the body besides), or
    says it adds to the rotation where E or |H| grows.
    """
    if d.has_torque or d.has_momentum:
        return {"applicable": False, "reason": "commanded torque or a changing known momentum acts"}
    w = d.w
    jw = w @ fit.inertia.T
    big_h = jw + (0.0 if d.h is None else d.h)
    energy = 0.5 * np.sum(w * jw, 1)
    series = {"momentum": np.linalg.norm(big_h, axis=1), "energy": energy}
    out: dict = {"applicable": True}
    t = d.t - d.t[0]
    for key, y in series.items():
        a = np.vstack([t, np.ones_like(t)]).T
        coef, res, *_ = np.linalg.lstsq(a, y, rcond=None)
        resid = y - a @ coef
        # noise of y is serially correlated; use the std of differences as a conservative scale
        se = np.std(np.diff(resid)) / np.sqrt(2) / (np.std(t) * np.sqrt(len(t)))
        rel = float(coef[0] * t[-1] / np.mean(y))
        out[key] = {"relative_drift": rel, "z": float(coef[0] / se) if se > 0 else 0.0}
    dm, de = abs(out["momentum"]["z"]) > 5, abs(out["energy"]["z"]) > 5
    out["verdict"] = ("external (|H| drifts)" if dm else "internal (energy drifts, |H| kept)" if de
                      else "no drift")
    out |= _torque_reading(out, w, big_h, energy, dm, de)
    out["series"] = {k: v for k, v in series.items()}
    return out


def _torque_reading(inv: dict, w, big_h, energy, drifts_h: bool, drifts_e: bool) -> dict:
    """invariants()' reading of the missing torque from the drifts (see there): the observed
    ratio, the two references and the words' key.

    The references are taken as the observed ratio is, from the record's means: for tau = -k H,
    (mean w.H / mean E) over (mean |H| / mean |H|); for tau = -c w, (mean |w|^2 / mean E) over
    (mean H.w/|H| / mean |H|). Where a known momentum makes mean H.w <= 0 neither drag need
    drain both, and the reading is not made.
    """
    norm_h = np.linalg.norm(big_h, axis=1)
    h_dot_w = np.sum(big_h * w, 1)
    mean_e, mean_hw = float(np.mean(energy)), float(np.mean(h_dot_w))
    readable = mean_e > 0 and mean_hw > 0
    along_h = mean_hw / mean_e if readable else None
    along_w = ((float(np.mean(np.sum(w * w, 1))) / mean_e) / (
        float(np.mean(h_dot_w / np.maximum(norm_h, 1e-300))) / float(np.mean(norm_h)))
        if readable else None)
    out = {"energy_per_momentum": None, "against_momentum_ratio": along_h, "against_rates_ratio": along_w}
    if not drifts_h:
        return out | {"reading": "internal" if drifts_e else "none"}
    if not readable:
        return out | {"reading": NOT_READ}
    e_rel, h_rel = inv["energy"]["relative_drift"], inv["momentum"]["relative_drift"]
    ratio = e_rel / h_rel
    if h_rel > 0 or (drifts_e and e_rel > 0):
        reading = "adds to the rotation"
    elif not drifts_e:
        reading = "drains |H|, energy kept"
    elif ratio > DRAG_RATIO_TOLERANCE * max(along_h, along_w):
        reading = "drains the energy beyond a drag"
    elif ratio < min(along_h, along_w) / DRAG_RATIO_TOLERANCE:
        reading = "drains |H| beyond a drag"
    elif abs(np.log(ratio / along_h)) <= abs(np.log(ratio / along_w)):
        reading = "against the angular momentum"
    else:
        reading = "against the rates"
    return out | {"energy_per_momentum": ratio, "reading": reading}


def _read_with_both(explained: dict, rigid: dict) -> dict:
    """The invariants read with the explanation's inertia, their reading kept only where the
    rigid fit's inertia reads the same (a fit that leaves more than noise may have moved the
    inertia, and |J w| and w.J w / 2 move with it); else `reading` is "uncertain" and
    `readings` gives both.
    """
    if not explained.get("applicable") or explained["reading"] == rigid["reading"]:
        return explained
    return {**explained, "reading": "uncertain",
            "readings": {"rigid fit": rigid["reading"], "explanation": explained["reading"]}}


def principal_ratios(fit: Fit, d: Data) -> tuple[list, list | None]:
    """The fit's principal moments over the largest (3,), descending, and their 95 % intervals
    ((3, 2) [lo, hi], None where the fit's covariance is not finite or so wide that a draw from
    it is no inertia at all, its moments overflowing): the inertia's shape, which gyro-only data
    fix without its scale. The intervals come from quasi-random draws (RATIO_DRAWS_LOG2) of the
    parameters from covariance() (the fit's own, widened by its misfit and its residual's
    correlation), each turned into the model's
    inertia, so an effect that trades with the inertia widens them; each draw kept to the bodies
    that exist as the fits are (nearest_realizable: each moment at most the sum of the other
    two), and the interval stretched to hold the fit's own ratios where the draws' percentiles
    miss them. A wide covariance read as it fell had given I2/I1 down to 1e-9 (no body) and an
    estimate outside its own interval (an independent audit's slow racquet flip: 0.787 against
    [1.5e-9, 0.562]).
    """
    def ratios(inertia):
        if not np.all(np.isfinite(inertia)):
            return np.full(3, np.nan)
        moments = np.sort(np.linalg.eigvalsh(nearest_realizable(inertia)))[::-1]
        return moments / moments[0]

    point = ratios(fit.inertia)
    cov, idx = covariance(fit, d)
    if not np.all(np.isfinite(cov)):
        return point.tolist(), None
    values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    draws = normal_draws(RATIO_DRAWS_LOG2, values.size)
    xs = np.repeat(fit.x[None], len(draws), axis=0)
    xs[:, idx] += (draws * np.sqrt(np.maximum(values, 0.0))) @ vectors.T
    with np.errstate(over="ignore", invalid="ignore"):  # a draw far out overflows: said below
        drawn = np.array([ratios(model_inertia(fit.layout, x, d)) for x in xs])
    if not np.all(np.isfinite(drawn)):
        return point.tolist(), None
    lo, hi = np.percentile(drawn, [2.5, 97.5], axis=0)
    return point.tolist(), np.stack([np.minimum(lo, point), np.maximum(hi, point)], axis=1).tolist()


def trace_sigma(fit: Fit, d: Data) -> float:
    """Relative standard deviation of the trace of the fit's model inertia: the delta method
    (central differences along each free entry) over the fit's information, widened by its
    misfit; inf where the information does not see the trace. How well a torque or a known
    momentum fixes the scale: a momentum far smaller than the body's own, J w, leaves it free
    in all but name.

    Not from covariance(): its pseudo-inverse gives no variance at all along a direction the
    information barely sees (a trace that has drifted where the momentum no longer acts), so the
    information is first scaled to a unit diagonal and no eigenvalue counts for less than
    SCALE_RCOND of its largest: a direction the data do not see gives the trace a variance as
    large as the gradient's reach into it (a mere rounding error's reach, none worth naming).
    """
    info, idx, widen = information(fit, d)
    steps = 1e-6 * np.maximum(np.abs(fit.x[idx]), 1.0)
    grad = np.zeros(idx.size)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for i, (j, h) in enumerate(zip(idx, steps)):
            up, down = fit.x.copy(), fit.x.copy()
            up[j] += h
            down[j] -= h
            log_traces = np.log([np.trace(model_inertia(fit.layout, x, d)) for x in (up, down)])
            grad[i] = (log_traces[0] - log_traces[1]) / (2 * h)
    diag = np.diag(info)
    if not (np.all(np.isfinite(grad)) and np.all(np.isfinite(info))) or np.any((diag <= 0) & (grad != 0)):
        return float("inf")
    seen = diag > 0
    unit = 1.0 / np.sqrt(diag[seen])
    values, vectors = np.linalg.eigh(info[np.ix_(seen, seen)] * unit[:, None] * unit[None, :])
    along = vectors.T @ (grad[seen] * unit)
    sigma = float(np.sqrt(widen * np.sum(along ** 2 / np.maximum(values, SCALE_RCOND * values.max()))))
    return sigma if np.isfinite(sigma) else float("inf")


def scale_identified(d: Data, best: Fit, offset: Fit | None) -> tuple[bool, float | None]:
    """(whether the record fixes the inertia's scale, the relative sigma of the fitted trace or
    None): identify's rule.

    The scale is fixed wherever a commanded torque or a known momentum that is not zero acts
    (d.excited, Recording.sees_scale); how well is the sigma, read from the fit that holds the
    explanation's effects with the inertia free (:func:`_inertia_free_fit`), so that a nominal
    in the sidecar changes neither answer. None where no such fit is finite.
    """
    if not d.excited:
        return False, None
    fit = _inertia_free_fit(d, best, offset)
    if fit is None or not np.isfinite(fit.bic):
        return True, None
    return True, trace_sigma(fit, d)


def _inertia_free_fit(d: Data, best: Fit, offset: Fit | None) -> Fit | None:
    """The fit in which the data set the inertia: best itself where its inertia is fitted (no
    nominal, or an effect that sets the inertia), the nominal's inertia_offset fit where best is
    the nominal model, else best's effects fitted again with inertia_offset added.
    """
    if d.inertia0 is None or any(m.sets_inertia for m in best.layout.models):
        return best
    if not best.names:
        return offset
    form = REGISTRY["inertia_offset"].forms(d)[0]
    return fit_model(best.names + ("inertia_offset",), best.forms + (form,), d, best)


def normal_draws(log2_count: int, dim: int) -> np.ndarray:
    """(2**log2_count, dim) standard normal draws from a scrambled Sobol sequence (seed 0): the
    same for every call, and far evener in every direction than as many pseudo-random draws.
    """
    u = stats.qmc.Sobol(dim, scramble=True, seed=0).random_base2(log2_count)
    return stats.norm.ppf(np.clip(u, 1e-12, 1.0 - 1e-12))


def _fit_summary(fit: Fit, d: Data) -> dict:
    rms = np.sqrt(np.mean(fit.r ** 2, 0))
    if not np.all(np.isfinite(rms)):  # no positive-definite inertia fits: JSON has no Infinity
        return {"rms": None, "rms_over_noise": None, "nis_mean": None, "inertia": fit.inertia.tolist(),
                "principal_ratios": None, "principal_ratios_ci95": None, "valid": False}
    ratios, ci = principal_ratios(fit, d)
    return {"rms": rms.tolist(), "rms_over_noise": (rms / d.sigma).tolist(),
            "nis_mean": float(np.mean((fit.r / d.sigma) ** 2)), "inertia": fit.inertia.tolist(),
            "principal_ratios": ratios, "principal_ratios_ci95": ci, "valid": True}


def _noise_reads_high(fit: Fit, d: Data) -> bool:
    """A noise level read from the data (no sidecar gyro_sigma) that the fit's own residual says
    is too high: under NOISE_READ_HIGH of it on every axis, with the degrees of freedom of the
    fitted parameters and the segments' rates restored (rms x sqrt(N / (N - k)), N residuals).
    """
    if d.sigma_source == "sidecar" or not np.all(np.isfinite(fit.r)):
        return False
    n = fit.r.size
    free = fit.k + 3 * d.segments
    if free >= n:
        return False
    rms = np.sqrt(np.mean(fit.r ** 2, 0) * n / (n - free))
    return bool(np.all(rms < NOISE_READ_HIGH * d.sigma))


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


@kernels_own_the_cores
def diagnose(rec: Recording) -> tuple[dict, dict]:
    """The full diagnosis of one recording as a JSON-ready dict (docs/contracts.md keys, and more)
    and the arrays its plots need.
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
        "beyond_catalogue": (not after["valid"] or max(after["rms_over_noise"]) > BEYOND_CATALOGUE
                             or any(e["implausible"] for e in explanation) or bool(refused)),
        "sparse_terms": sparse_terms(d, best) if unexplained else [],
        "gyro_frame_mirrored": frame,
    }
    arrays = {"t_mid": t_row, "r_before": nominal.r, "r_after": best.r, "f": f, "p": p,
              "inv": inv, "d": d, "best": best, "nominal": nominal}
    return report, arrays


def mirrored_frame(rec: Recording, d: Data, best: Fit) -> dict | None:
    """Where a gyro-only record (no torque, momentum or attitude) reads as a rigid body in a
    left-handed frame (two gyro columns swapped, or one axis's sign flipped: for gyro-only data
    the same up to a rotation the inertia's axes absorb): the rigid fit of d with its x and y
    columns swapped, where it is within UNEXPLAINED_RMS of the noise and its BIC beats the
    explanation's (best) by SIGNIFICANT_DELTA_BIC, as {"rms_over_noise" (3,), "delta_bic",
    "principal_ratios"}; else None. A flat plate's clean tumble with two columns swapped has no
    right-handed body (its mirror is a rod's limit), so without this test its misfit would be
    read as effects (a gyro scale, an inertia change).
    """
    if rec.q is not None or rec.sees_scale or rec.has_momentum:
        return None
    swap = [1, 0, 2]
    mirrored = fit_nominal(dataclasses.replace(d, w=d.w[:, swap], sigma=d.sigma[swap], inertia0=None,
                                               cache={}))
    rms = np.sqrt(np.mean(mirrored.r ** 2, axis=0)) / d.sigma[swap]
    gain = float(best.bic - mirrored.bic)
    if not (np.all(np.isfinite(rms)) and rms.max() <= UNEXPLAINED_RMS and gain > SIGNIFICANT_DELTA_BIC):
        return None
    moments = np.sort(np.linalg.eigvalsh(mirrored.inertia))[::-1]
    return {"rms_over_noise": rms.tolist(), "delta_bic": gain,
            "principal_ratios": (moments / moments[0]).tolist()}


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


def inertia_comparison(nominal, fitted, scale_seen: bool) -> dict:
    """Principal moments of the fitted vs the nominal inertia (3, 3) kg·m²: % change per moment
    (the nominal's in ascending order, each fitted axis matched to the nominal axis nearest in
    direction), and the angle (deg) between matched principal axes.

    scale_seen False (no torque, or one that fixes the scale only loosely): the fitted inertia is
    first scaled to the nominal's trace, so the percentages compare shapes only.
    """
    nominal, fitted = np.asarray(nominal, float), np.asarray(fitted, float)
    if not scale_seen:
        fitted = fitted * np.trace(nominal) / np.trace(fitted)
    m0, v0 = np.linalg.eigh(nominal)
    m1, v1 = np.linalg.eigh(fitted)
    # match each nominal axis with the fitted axis nearest in direction (moments may reorder)
    dots = np.abs(v0.T @ v1)
    order = max(itertools.permutations(range(3)), key=lambda o: sum(dots[i, o[i]] for i in range(3)))
    m1, v1 = m1[list(order)], v1[:, list(order)]
    angles = np.degrees(np.arccos(np.clip(np.abs(np.sum(v0 * v1, axis=0)), 0.0, 1.0)))
    return {"principal_moments_nominal": m0.tolist(), "principal_moments": m1.tolist(),
            "percent_change": (100.0 * (m1 / m0 - 1.0)).tolist(),
            "axis_rotation_deg": angles.tolist(), "scale_compared": bool(scale_seen)}


def write_plots(out: Path, report: dict, arrays: dict, stem: str = "") -> list[str]:
    """residuals.png (located windows shaded), overlay.png, spectrum.png, invariants.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    t = arrays["t_mid"]
    fig, axs = plt.subplots(3, 1, sharex=True, figsize=(9, 6))
    added = " + ".join(e["name"] for e in report["explanation"]) or "nothing"
    for i, ax in enumerate(axs):
        ax.plot(t, arrays["r_before"][:, i], lw=0.7, label="nominal")
        ax.plot(t, arrays["r_after"][:, i], lw=0.7, label=f"+ {added}")
        for loc in report["locations"]:
            if "xyz"[i] in loc["axes"]:
                ax.axvspan(loc["t_start"], loc["t_end"], color="red", alpha=0.15)
        ax.set_ylabel(f"r_{'xyz'[i]} (rad/s)")
    axs[0].legend(loc="upper right", fontsize=8)
    axs[-1].set_xlabel("t (s)")
    fig.suptitle("interval-prediction residuals (shaded: located mismatch)")
    files.append(_save(fig, out / f"{stem}residuals.png"))
    d = arrays["d"]
    fig, axs = plt.subplots(3, 1, sharex=True, figsize=(9, 6))
    for i, ax in enumerate(axs):
        ax.plot(t, np.cumsum(arrays["r_before"][:, i]), label="nominal, accumulated miss")
        ax.plot(t, np.cumsum(arrays["r_after"][:, i]), label="after fit, accumulated miss")
        ax.set_ylabel(f"{'xyz'[i]} (rad/s)")
    axs[0].legend(fontsize=8)
    axs[-1].set_xlabel("t (s)")
    fig.suptitle("before / after: accumulated interval residual (a random walk when explained)")
    files.append(_save(fig, out / f"{stem}overlay.png"))
    fig, ax = plt.subplots(figsize=(7, 4))
    for i in range(3):
        ax.semilogy(arrays["f"], arrays["p"][:, i] + 1e-30, label="xyz"[i])
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD of nominal residual")
    ax.legend()
    files.append(_save(fig, out / f"{stem}spectrum.png"))
    inv = arrays["inv"]
    if inv.get("applicable"):
        fig, axs = plt.subplots(2, 1, sharex=True, figsize=(8, 5))
        for ax, key in zip(axs, ("momentum", "energy")):
            y = inv["series"][key]
            ax.plot(d.t, y / np.mean(y), lw=0.7)
            ax.set_ylabel(f"{key} / mean")
        axs[-1].set_xlabel("t (s)")
        fig.suptitle(f"invariants (fitted J): {inv['verdict']}")
        files.append(_save(fig, out / f"{stem}invariants.png"))
    return files


def _save(fig, path: Path) -> str:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path.name


def _fmt(values) -> str:
    return "no valid fit" if values is None else str(np.round(values, 2).tolist())


def _significant(values, digits: int = 4):
    """Nested lists of floats: values (any shape) rounded to `digits` significant digits, so that
    a 5e-4 kg·m² body's parameters and a 2e-5 rad/s noise level stay readable (fixed decimals
    printed them as 0.0).
    """
    rounded = np.vectorize(lambda v: float(f"{v:.{digits}g}"), otypes=[float])
    return rounded(np.asarray(values, float)).tolist()


#: Parameters with more numbers than this are told by their count and range (a momentum
#: profile's knots), not number by number.
LISTED_NUMBERS = 6


@dataclasses.dataclass(frozen=True)
class _Fitted:
    """One fitted parameter: value, its 95 % bounds lo and hi (arrays), held (the fit held it,
    lo = hi: knot times, a chart's centre: no interval) and counted (read by its count and
    range, more than LISTED_NUMBERS numbers, rather than listed).
    """

    value: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    held: bool
    counted: bool


def _fitted(value, ci: dict) -> _Fitted:
    """One fitted parameter's _Fitted from its value and 95 % bounds ci ({"lo", "hi"})."""
    value, lo, hi = (np.asarray(a, float) for a in (value, ci["lo"], ci["hi"]))
    return _Fitted(value, lo, hi, bool(np.all(lo == hi)), value.size > LISTED_NUMBERS)


def _param_words(name: str, value, ci: dict) -> str:
    """One fitted parameter in words: its value and 95 % interval (_fitted: a held value without
    one, a long one by its count, range and widest interval).
    """
    f = _fitted(value, ci)
    if f.counted:
        text = f"{name}: {f.value.size} values from {f.value.min():.4g} to {f.value.max():.4g}"
        return text + ("" if f.held else f" (95 % half-widths up to {np.max(f.hi - f.lo) / 2:.4g})")
    text = f"{name} = {_significant(f.value)}"
    return text + ("" if f.held else f" [{_significant(f.lo)}, {_significant(f.hi)}]")


#: A slow mode and a momentum read together as one rotor (_rotor_reading): the most their axes
#: may differ (deg), and the least share of the record the mode's period spans.
ROTOR_READING = (10.0, 0.5)


def _rotor_reading(expl: list[dict], duration: float | None) -> str | None:
    """The sentence that reads a flexible mode and an internal momentum of the explanation as one
    rotor, or None: where the mode's period spans at least ROTOR_READING[1] of the record
    (duration s; None: no reading) and its coupling lies within ROTOR_READING[0] deg of the
    momentum's axis (its varying form's) or direction. A mode's swing enters the body's
    equation as a momentum along its coupling, so the two together draw a momentum that rises
    and falls along that axis (a rotor spun up and braked over a 20-s record as
    0.5 (1 - cos 2 pi t / 20 s) is read so).
    """
    named = {e["name"]: e for e in expl}
    mode, momentum = named.get("flexible_mode"), named.get("internal_momentum")
    if mode is None or momentum is None or not duration:
        return None
    period = 2.0 * np.pi / float(mode["params"]["omega_n"])
    along = np.asarray(momentum["params"]["axis" if momentum["form"] == "varying" else "h"], float)
    coupling = np.asarray(mode["params"]["coupling"], float)
    norms = np.linalg.norm(along) * np.linalg.norm(coupling)
    if not norms > 0 or period < ROTOR_READING[1] * duration:
        return None
    angle = float(np.degrees(np.arccos(min(1.0, abs(along @ coupling) / norms))))
    if angle > ROTOR_READING[0]:
        return None
    axis = np.round(coupling / np.linalg.norm(coupling), 3).tolist()
    return (f"flexible_mode (period {period:.3g} s, {period / duration:.2g} of the record) and "
            f"internal_momentum lie along one body axis {axis} ({angle:.1f} deg apart): a mode's swing "
            "is a momentum along its coupling, so together they are a momentum that rises and falls "
            "along that axis, a rotor spinning up and down where the body has one.")


def _flight_reading(expl: list[dict]) -> str | None:
    """The sentence that reads aero_drag's flight form in the explanation as a throw, or None: the
    plate's normal, the launch speed and how far above the horizontal it was thrown.
    """
    flight = next((e for e in expl if e["name"] == "aero_drag" and e["form"] == "flight"), None)
    if flight is None:
        return None
    p = flight["params"]
    v0, down = np.asarray(p["launch_velocity"], float), np.asarray(p["gravity_direction"], float)
    speed = float(np.linalg.norm(v0))
    climb = float(np.degrees(np.arcsin(np.clip(-(v0 @ down) / speed, -1.0, 1.0)))) if speed > 0 else 0.0
    return (f"aero_drag's flight form reads the body as a flat plate of normal "
            f"{np.round(p['normal'], 3).tolist()} (body axes) thrown at {speed:.3g} m/s, {climb:.0f} deg "
            "above the horizontal, through still air: the air's torque follows the throw's speed "
            "and the plate's attitude to it.")


def _explanation_words(report: dict) -> str:
    """The compound explanation and what was left out, in sentences."""
    expl = report["explanation"]
    if not expl:
        text = "**Explanation:** no effect improves the fit significantly; the nominal model stands."
    else:
        parts = []
        for e in expl:
            params = ", ".join(_param_words(k, v, e["ci95"][k]) for k, v in e["params"].items())
            parts.append(f"{_label(e)} (adds delta BIC {e['delta_bic']:.1f}; {params})")
        text = ("**Explanation:** the nominal model leaves out " + "; then ".join(parts)
                + ". Brackets are 95 % intervals.")
        for e in expl:
            cmp = e.get("inertia_vs_nominal")
            if cmp is not None:
                text += (f"\n\nThe inertia differs from the nominal: principal moments change by "
                         f"{np.round(cmp['percent_change'], 1).tolist()} % (ascending), principal "
                         f"axes turn by {np.round(cmp['axis_rotation_deg'], 1).tolist()} deg"
                         + ("" if cmp["scale_compared"] else
                            " (no torque or known momentum: shapes compared at the nominal's "
                            "trace)") + ".")
            for c in e["confounded_with"]:
                text += f"\n\n{e['name']} is confounded with {c['with']}: {c['reason']}."
        rotor = _rotor_reading(expl, report.get("duration_s"))  # (a hand-made report may lack it)
        text += f"\n\n{rotor}" if rotor else ""
        flight = _flight_reading(expl)
        text += f"\n\n{flight}" if flight else ""
    cmp = report.get("inertia_vs_nominal")
    if cmp is not None and cmp["delta_bic"] is not None:
        text += (f"\n\nThe user's model as given (`fit_before`, the base of every effect but "
                 f"inertia_offset) against the same model with the inertia fitted "
                 f"(`fit_inertia_fitted`): delta BIC {cmp['delta_bic']:.1f}; principal moments "
                 f"{np.round(cmp['percent_change'], 2).tolist()} % from the nominal's "
                 f"(ascending), matched axes turned by {np.round(cmp['axis_rotation_deg'], 2).tolist()} deg.")
    if _scale_loose(report):
        text += ("\n\nThe commanded torque or the known internal momentum fixes the inertia's scale only "
                 "loosely (relative sigma of the fitted trace "
                 + (f"{report['scale_sigma']:.2g}" if report["scale_sigma"] is not None else "unbounded")
                 + f", over {SCALE_SIGMA_IDENTIFIED:g}): the principal-moment ratios are firmer than the "
                 "absolute values, and every fitted torque (N·m), momentum (kg·m²/s) and damping "
                 "coefficient carries the trace's uncertainty.")
    if not report["scale_identified"]:
        text += ("\n\nNo commanded torque or known internal momentum: the data fix the inertia only up "
                 "to a common factor, "
                 + ("so the fitted torques, momenta and damping are in units of the sidecar's "
                    "nominal inertia and scale with it if it is wrong."
                    if report.get("inertia_nominal_given") else
                    "and with no nominal inertia in the sidecar its trace was set to "
                    f"{report['inertia_trace_assumed']:g} kg·m²: every fitted torque (N·m), "
                    "momentum (kg·m²/s) and damping coefficient scales with the unknown true "
                    "trace; multiply them by (true trace) / "
                    f"{report['inertia_trace_assumed']:g}."))
    elif not report.get("inertia_nominal_given"):  # fixed, up to an actuator's scale
        text += ("\n\nThe inertia's scale is fixed by the commanded torque and the known internal "
                 "momentum as logged: a torque c times the commanded one (an actuator scale) or a "
                 "momentum c times the logged one makes the true inertia c times the fitted one, and "
                 "with no nominal inertia in the sidecar the data cannot tell the two apart.")
    # only what the data supported alone: an effect no fit favours is in the table of every effect
    significant = {e["name"] for e in report.get("effects", []) if e["significant"]}
    left_out = {name: why for name, why in report["left_out"].items() if name in significant}
    if left_out:
        text += "\n\nLeft out of the explanation: " + "; ".join(
            f"{name} ({why})" for name, why in left_out.items()) + "."
    return text


def _ratios_words(fit: dict) -> str:
    ci = fit["principal_ratios_ci95"] or [[None, None]] * 3
    return ", ".join(f"{r:.3g}" + ("" if lo is None or hi - lo < 5e-4 else f" [{lo:.3g}, {hi:.3g}]")
                     for r, (lo, hi) in zip(fit["principal_ratios"], ci))


def _shape_words(report: dict) -> list[str]:
    """The inertia's shape before and after the explanation, with a warning where a ratio's 95 %
    interval is wider than RATIO_SPREAD: after the explanation and over twice the rigid fit's
    (the explanation's effects trade with the inertia), or already for the rigid fit (the record
    fixes the shape poorly).
    """
    before, after = report["fit_before"], report["fit_after"]
    if not (before.get("valid") and after.get("valid")):  # a fit not followed, or no ratios written
        return []
    words = [f"- principal-moment ratios (95 % intervals): rigid fit {_ratios_words(before)}; "
             f"with the explanation {_ratios_words(after)}"]
    if before["principal_ratios_ci95"] is None or after["principal_ratios_ci95"] is None:
        return words
    rigid = np.ptp(np.array(before["principal_ratios_ci95"]), axis=1)
    width = np.ptp(np.array(after["principal_ratios_ci95"]), axis=1)
    if report["explanation"] and np.any((width > RATIO_SPREAD) & (width > 2.0 * rigid)):
        momentum = any(e["name"] == "internal_momentum" for e in report["explanation"])
        words.append("- **the explanation leaves the inertia's shape poorly determined** (a ratio's "
                     f"95 % interval is wider than {RATIO_SPREAD:g} and than twice the rigid fit's): "
                     "its effects trade with the inertia"
                     + (" (about a near-steady spin, a momentum along the spin axis changes the "
                        "nutation as the moments do)" if momentum else "")
                     + "; do not read the body's shape from this fit")
    elif np.any(rigid > RATIO_SPREAD):
        words.append(f"- the record fixes the inertia's shape poorly: a ratio's 95 % interval is wider "
                     f"than {RATIO_SPREAD:g} already for the rigid fit")
    return words


def _noise_words(report: dict) -> list[str]:
    """A warning where the noise level read from the data reads high (_noise_reads_high), or the
    sidecar's level disagrees with the samples' (sensors.stated_noise_note); after the line that
    the samples' quantisation was added to the sidecar's level, where it was, the one that
    the gyro's rounding raised the margin of the effects (fit.rounding_floors), where it did, and
    the one that the intervals count the rounding (fit.lattice_spread), where they do.
    """
    noise = report.get("noise", {})  # (a report written before the keys existed has neither)
    said = [f"- {noise['quantisation']}"] if noise.get("quantisation") else []
    if noise.get("rounding_floor"):
        runs = [f"{r:.1f}" for r in noise["rounding_runs"] if r > 0]
        top = sorted(noise["rounding_floor"].items(), key=lambda kv: -kv[1])[:3]
        said.append("- **the gyro reads the rate coarser than its motion and noise move it** (its "
                    f"samples repeat in runs of {', '.join(runs)} on average): the rounding error "
                    "follows the rate, and fits gain from tracing it. Each effect must beat, besides "
                    "the margin, the most its fit gains on the rounded nominal model alone ("
                    + ", ".join(f"`{name}` {gain:.0f}" for name, gain in top)
                    + (", ..." if len(noise["rounding_floor"]) > 3 else "")
                    + "; `noise.rounding_floor`): smaller effects than the rounding hides are not "
                    "claimed")
    if noise.get("lattice_refits"):
        said.append("- the intervals (the principal-moment ratios', the effects' parameters') count the "
                    "rounding: the spread of the fit's refits on its own prediction read on the gyro's "
                    f"lattice ({noise['lattice_refits']} of {LATTICE_REPLAYS} replays, shifted at random, "
                    "the noise beneath the step added) is added to their covariance")
    if noise.get("sidecar_disagrees"):
        return said + ["- **the sidecar's noise level disagrees with the data's**: "
                       f"{noise['sidecar_disagrees']}"]
    if not noise.get("read_high"):
        return said
    return said + ["- **the noise level read from the data reads high**: the best fit leaves "
            f"{_fmt(report['fit_after']['rms_over_noise'])} of it, under {NOISE_READ_HIGH:g} on every "
            "axis: motion fast for the sampling passed for noise (give the gyro's `gyro_sigma` in a "
            "sidecar); every rms / noise here reads that much low, and the noise-based flags "
            "(beyond the catalogue, unexplained) are that much lenient. The selection does not depend "
            "on it"]


def _frame_words(report: dict) -> list[str]:
    """The line on a gyro frame that reads left-handed (mirrored_frame), or none."""
    frame = report["gyro_frame_mirrored"]
    if not frame:
        return []
    return [f"- **the gyro's frame reads left-handed**: with its x and y columns swapped (or one axis's "
            f"sign flipped) the rates fit a rigid body to {_fmt(frame['rms_over_noise'])} times the noise "
            f"(principal ratios {_fmt(frame['principal_ratios'])}), {frame['delta_bic']:.0f} better in BIC "
            "than the explanation below: check the order and signs of the gyro's axes before reading "
            "the effects"]


def _clip_words(report: dict) -> list[str]:
    """A line where an axis is held at its extreme in a record's first or last samples
    (prepare.clips_at_the_ends: not left out, a rate may start or end at its peak).
    """
    ends = report.get("clipped_at_ends")  # absent from reports of older versions
    if not ends:
        return []
    return [f"- **held at its extreme at the record's end**: {'; '.join(ends)}: {CLIP_ADVICE}"]


def _invariants_words(inv: dict) -> str:
    """The invariants' drifts and their reading of the missing torque, in words."""
    if not inv.get("applicable"):
        return f"Invariants: not read ({inv.get('reason', 'not applicable')})."

    def drift(key: str, name: str) -> str:
        rel = inv[key]["relative_drift"]
        return f"{name} {'grows' if rel > 0 else 'falls'} {abs(rel):.1%} (z {inv[key]['z']:.0f})"

    head = (f"Invariants (torque-free they hold; read with the inertia of `fit_after`): over the record "
            f"{drift('momentum', '|H|')} and {drift('energy', 'the rotational energy')}")
    reading = inv["reading"]
    plain = {
        "none": "neither drifts beyond the noise: no torque acts that these rows would show.",
        "internal": "the energy drifts and |H| is kept: physics inside the body (dissipation, "
                    "a moving part), not an external torque.",
        "adds to the rotation": "a torque adds to the rotation: no drag does that.",
        "drains |H|, energy kept": "|H| falls while the energy holds: an external torque, neither "
                                   "a drag against the rates nor one against the angular momentum.",
        NOT_READ: "too little rotation, or a known internal momentum against it, to read the drifts.",
    }
    if reading in plain:
        return f"{head}: {plain[reading]}"
    if reading == "uncertain":
        both = inv["readings"]
        return (f"{head}: what this says of the missing torque depends "
                f"on the inertia, which neither fit pins (both leave more than noise): with the "
                f"rigid fit's it reads {both['rigid fit']!r}, with the explanation's "
                f"{both['explanation']!r}.")
    along_h, along_w = inv["against_momentum_ratio"], inv["against_rates_ratio"]
    refs = (f"a torque against the angular momentum (tau = -k H; without internal momentum a drag "
            f"-k J w, every motion slowed alike) gives {along_h:.2f} here, one against the rates "
            f"(tau = -c w) {along_w:.2f}")
    if abs(along_w / along_h - 1) < 0.05:
        refs += " (the two lie close: the rotation stays near a principal axis)"
    verdict = {
        "drains the energy beyond a drag": "faster than either: dissipation inside the body besides",
        "drains |H| beyond a drag": "slower than either: a torque across the rotation",
    }.get(reading, f"the missing torque reads as the one {reading}")
    return (f"{head}: the energy falls {inv['energy_per_momentum']:.2f} times as fast as |H|. "
            f"{refs[0].upper()}{refs[1:]}: {verdict}.")


def _beyond_words(report: dict) -> list[str]:
    """A warning where the explanation leaves the residual over BEYOND_CATALOGUE times the noise."""
    if not report.get("beyond_catalogue"):  # (a report written before the key existed: none)
        return []
    before, after = report["fit_before"], report["fit_after"]
    if not after["valid"]:
        return ["- **beyond the catalogue**: the best fit is not a valid fit: the recording holds "
                "physics the catalogue cannot model"]
    worst = max(after["rms_over_noise"])
    odd = [e for e in report["explanation"] if e.get("implausible")]
    refused = report.get("refused_implausible") or []
    if (odd or refused) and worst <= BEYOND_CATALOGUE:
        return ["- **beyond the catalogue**: " + "; ".join(
            [f"`{e['name']}` is not physics this body or sensor plausibly has ({e['implausible']})"
             for e in odd] + [f"`{r['name']}` would improve the fit (delta BIC {r['delta_bic']:.1f}) but is "
                              f"not physics this body or sensor plausibly has ({r['why']}), and is left out "
                              "of the explanation" for r in refused])
            + ": what it fits is physics the catalogue lacks, or a distortion of the record, not that "
            "effect"]
    words = (f"- **beyond the catalogue**: the best fit still leaves {_fmt(after['rms_over_noise'])} "
             f"times the noise (over {BEYOND_CATALOGUE:g}): the recording holds physics the catalogue "
             "lacks" + "".join(f"; `{r['name']}` would fit it better (delta BIC {r['delta_bic']:.1f}) "
                               f"but is not physics this body or sensor plausibly has ({r['why']})"
                               for r in refused))
    if not report["explanation"]:
        return [words + ", and none of its effects accounts for any of it"]
    return [words + f"; the explanation takes the worst axis from {max(before['rms_over_noise']):.3g} to "
            f"{worst:.3g} times the noise: read its effects as the catalogue's closest approximation "
            "of what is missing, not necessarily all of it, and what it leaves may have pulled "
            "them off"]


def _label(e: dict) -> str:
    """An explanation entry's name as its reading allows (:data:`READINGS`): the named physics,
    the physics if the body carries the part it needs, or what the fitted terms do.
    """
    model = REGISTRY.get(e["name"])
    form = [f"{e['form']} form"] if e.get("form") else []
    said = e.get("reading", "physics")
    if model is not None and e.get("implausible"):
        what = model.as_fitted.get(e.get("form") or "", model.as_fitted.get("", "a term"))
        return f"{what} (fitted as `{e['name']}`{', ' + form[0] if form else ''}; {e['implausible']})"
    if model is None or said == "physics":
        return f"`{e['name']}`" + (f" ({form[0]})" if form else "")
    what = model.as_fitted.get(e.get("form") or "", model.as_fitted[""])
    if said == "if_carried":
        return (f"`{e['name']}` ({'; '.join(form + [f'if the body carries a {model.hardware_words}'])}; "
                f"else {what})")
    return f"{what} (`{e['name']}`{', ' + form[0] if form else ''}; the sidecar says the body carries no " \
           f"{model.hardware_words})"


def _verdict(report: dict) -> str:
    """Whether the rigid model explains the record, what is missing, where, and how much."""
    before, after = report["fit_before"], report["fit_after"]
    worst_before, worst_after = max(before["rms_over_noise"]), max(after["rms_over_noise"])
    names = [_label(e) for e in report["explanation"]]
    if not report["mismatch_detected"]:
        text = (f"The model explains the record: its residuals are at the gyro's noise (worst axis "
                f"{worst_before:.3g} times it), and no effect of the catalogue improves the fit "
                "significantly.")
    elif not names:
        text = (f"The model misses something (worst axis {worst_before:.3g} times the noise), and no "
                "effect of the catalogue accounts for it.")
    else:
        text = (f"The model misses physics: {' and '.join(names)} "
                f"{'explains' if len(names) == 1 else 'explain'} the record, taking the worst axis from "
                f"{worst_before:.3g} to {worst_after:.3g} times the gyro's noise.")
    if report["locations"]:
        text += " The misfit shows " + "; ".join(
            f"over t = {w['t_start']:.3g}–{w['t_end']:.3g} s on {', '.join(w['axes'])}"
            for w in report["locations"]) + "."
    return text


def _physics_table(report: dict) -> list[str]:
    """The explanation's fitted parameters, one row each, with 95 % intervals and units."""
    if not report["explanation"]:
        return []
    rows = ["| effect | parameter | value | 95 % interval | unit |", "|---|---|---|---|---|"]
    for e in report["explanation"]:
        units = REGISTRY[e["name"]].units if e["name"] in REGISTRY else {}
        for key, value in e["params"].items():
            f = _fitted(value, e["ci95"][key])
            if f.counted:
                shown = f"{f.value.size} values, {f.value.min():.4g} to {f.value.max():.4g}"
                interval = "" if f.held else f"± up to {np.max(f.hi - f.lo) / 2:.3g}"
            else:
                shown = str(_significant(value))
                interval = "held" if f.held else f"{_significant(f.lo)} to {_significant(f.hi)}"
            rows.append(f"| {e['name']} | {key} | {shown} | {interval} | {units.get(key, '')} |")
    return rows


def _next_steps(report: dict) -> list[str]:
    """What a user does next, read from the verdict."""
    steps = []
    plausible = [e for e in report["explanation"] if not e.get("implausible")]
    if plausible:
        names = ", ".join(f"`{e['name']}`" for e in plausible)
        steps.append(f"Add {names} to the simulation with the fitted values above (report.json holds "
                     "them in full), then diagnose another recording of the body: physics that is "
                     "there is found again.")
    if report["ambiguous"] or any(e["confounded_with"] for e in report["explanation"]):
        steps.append("Effects this record cannot tell apart are named above: a recording with more "
                     "varied rates (another spin axis, a faster or a longer tumble) separates them.")
    implausible = ([(e["name"], e["implausible"]) for e in report["explanation"] if e.get("implausible")]
                   + [(r["name"], r["why"]) for r in report.get("refused_implausible") or []])
    if implausible:
        steps.append("Beyond the plausible range: "
                     + "; ".join(f"`{name}` ({why})" for name, why in implausible)
                     + ". Look for what else moves the rates so: the sensor's mounting, clock or "
                     "saturation, or a part of the body the catalogue does not hold.")
    if (report.get("beyond_catalogue") and not implausible) or report.get("unexplained_residual"):
        steps.append(f"The explanation leaves {max(report['fit_after']['rms_over_noise']):.3g} times the "
                     "noise on its worst axis: look at the located windows and the residual plot; "
                     "report.json's `sparse_terms` lists the torque terms a sparse regression finds in "
                     "what is left.")
    if not report["scale_identified"]:
        steps.append("This record does not fix the inertia's scale: a recording with a known torque "
                     "or a rotor's changing momentum does.")
    elif _scale_loose(report):
        steps.append("The scale is fixed only loosely: a stronger or longer torque, or a larger change "
                     "of the known momentum, fixes it better.")
    if not steps:
        steps.append("Nothing is missing that this record can show; a recording with a larger or "
                     "another excitation tests the model further.")
    return [f"- {step}" for step in steps]


def _scale_loose(report: dict) -> bool:
    """The record fixes the scale, but its trace's relative sigma is unbounded or over
    SCALE_SIGMA_IDENTIFIED.
    """
    if "scale_sigma" not in report:  # a report that does not carry the sigma says nothing of it
        return False
    sigma = report["scale_sigma"]
    return bool(report["scale_identified"]) and (sigma is None or sigma > SCALE_SIGMA_IDENTIFIED)


def markdown(report: dict, plots: list[str]) -> str:
    """A summary of one report for people: the verdict first, the fitted physics with intervals
    and units, the inertia, the record, every effect tried and what to do next. The raw values
    stay in report.json.
    """
    lines = [f"# Diagnosis of {report['recording']}", "", "## Verdict", "", _verdict(report),
             *_beyond_words(report)]
    lines += ["", "## What is missing", "", _explanation_words(report), "", *_physics_table(report)]
    told = {(e["name"], c["with"]) for e in report["explanation"] for c in e["confounded_with"]}
    for a in report["ambiguous"]:
        if tuple(a["effects"]) not in told:  # the explanation's words already say it
            lines.append(f"- cannot be told apart: {', '.join(a['effects'])}: {a['reason']}")
    lines += ["", "## The inertia", "", *_shape_words(report)]
    lines += ["", "## The record", "",
              f"- samples: {report['samples']}, duration {report['duration_s']:.2f} s",
              f"- gyro noise: {_significant(report['gyro_sigma'], 3)} rad/s "
              f"({report['gyro_sigma_source']})", *_noise_words(report),
              f"- fit rms / noise before: {_fmt(report['fit_before']['rms_over_noise'])}, "
              f"after: {_fmt(report['fit_after']['rms_over_noise'])}",
              *_clip_words(report), *_frame_words(report)]
    if report.get("retimed"):
        lines.append(f"- {retimed_note(report['retimed'])}")
    window = report.get("free_flight_window")
    note = window and window_note(window["t_start"], window["t_end"], window["source"])
    if note:
        lines.append(f"- {note}")
    lines += ["", "## Every effect tried", "",
              "Each effect fitted alone, by how much it improves the BIC (over 10: very strong "
              "evidence); its fitted values are in report.json.", "",
              "| effect | delta BIC | significant |", "|---|---|---|"]
    for e in report["effects"]:
        delta = "no valid fit" if e["delta_bic"] is None else f"{e['delta_bic']:.1f}"
        lines.append(f"| {e['name']} | {delta} | {'yes' if e['significant'] else 'no'} |")
    if report["skipped_effects"]:
        lines.append("")
    for name, why in report["skipped_effects"].items():
        lines.append(f"- not tested: {name}: {why}")
    lines += ["", "## Invariants", "", _invariants_words(report["invariants"])]
    lines += ["", "## What to do next", "", *_next_steps(report)]
    if plots:
        lines += ["", "## Plots", ""] + [f"![{p}]({p})" for p in plots]
    return "\n".join(lines) + "\n"
