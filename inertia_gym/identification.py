"""Identify a body's inertia from its recording, with honest error bars.

``identify(recording, method="ml" | "ekf" | "ukf")`` (several records: identify_joint).

The record passes down once: prepare.prepared (retiming, clipped rows, end impulses, the noise
level), then the estimation core. Two estimates are always made:

* the equation error (estimation/equation_error.py): Euler's equation integrated against smooth
  windows, linear in the inertia, local (a model error stays in its window), its covariance the
  sandwich of the windows' residuals;
* the output error (estimation/output_error.py, ml.py): the rigid model's trajectory fitted to
  every gyro (and attitude) sample by maximum likelihood, efficient where the model holds, its
  covariance the Fisher bound, the coloured-noise sandwich or the model-error covariance.

Which is reported (uncertainty.choose): where the data accept the rigid model (the lack-of-fit
test), the one whose covariance expects the smaller error (a torque the model leaves out and
the residuals hide still colours them, which widens the output error's); where they reject it,
each is fitted on one half of the record and predicts the other (held_out). Where the two agree
within their intervals, the output error is reported only where it predicts significantly
better (a Diebold-Mariano test that counts the rows' correlation), else the equation error,
whose error from a model error stays in the windows it acts in; where they disagree beyond
them, the better predictor. Both covariances count the model error as a white disturbance
torque of the intensity the residuals' excess implies.

The scale is a quantity: with a known torque or a known internal momentum h that is not zero
the inertia is absolute, its intervals carrying the scale's uncertainty; only without either is
it reported normalised (to the sidecar's nominal trace, or 1) with ``scale_identified: false``.
The filters (``ekf``, ``ukf``) run the paper's estimator once over the rows, started from the
equation error; their covariance is the filter's own.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
from scipy import stats

from inertia_gym.errors import ConfigError, EstimatorDivergedError, RecordingError
from inertia_gym.estimation import ml, output_error, profile
from inertia_gym.estimation.equation_error import EquationError, equation_error
from inertia_gym.estimation.filters import run_over_recording
from inertia_gym.estimation.inertia_param import nearest_realizable, phi_from_inertia, theta_from_phi
from inertia_gym.estimation.nested import Extended, lack_of_fit, with_bias_or_drag
from inertia_gym.estimation.uncertainty import (
    SCALE_SIGMA_IDENTIFIED,
    TEST_LEVEL,
    TRACE_WEIGHTS,
    Agreement,
    Forecast,
    InertiaEstimate,
    NoiseModel,
    agreement,
    choose,
    forecast_comparison,
    inertia_estimate,
    relative_frobenius_bound,
    with_gyro_scale,
)
from inertia_gym.prepare import MIN_SAMPLES, Prepared, clip_hint, prepared
from inertia_gym.recordings import Recording
from inertia_gym.sensors import coarse_lattice_note, stated_noise_note

METHODS = ("ml", "ekf", "ukf")
#: An identified scale this many times off the nominal's (either way) gets a note on units.
NOMINAL_SCALE_FACTOR = 3.0


@dataclasses.dataclass(frozen=True)
class Identification:
    """identify()'s result for one recording (segment).

    name; method; estimate (InertiaEstimate, the reported one); estimator ('output error',
    'equation error' or the filter's name); reference (InertiaEstimate: the equation error);
    agreement (Agreement of the two, None for the filters); crlb; rms (3,) rad/s post-fit gyro
    residual; rms_over_noise; noise (NoiseModel of the output-error fit); bias (3,) rad/s or
    None; t (M,) s; w_meas, w_fit (M, 3) rad/s; converged; wall_s; notes; reference_q N²·m²·s (the
    intensity of a white unmodelled torque the equation error's residuals imply); air_drag (3,)
    N·m·s² the body-axis drag c of the output-error fit, or None.
    """

    name: str
    method: str
    estimate: InertiaEstimate
    estimator: str
    reference: InertiaEstimate
    agreement: Agreement | None
    crlb: float
    rms: np.ndarray
    rms_over_noise: float
    noise: NoiseModel
    bias: np.ndarray | None
    t: np.ndarray
    w_meas: np.ndarray
    w_fit: np.ndarray
    converged: bool
    wall_s: float
    notes: tuple
    reference_q: float = 0.0
    air_drag: np.ndarray | None = None

    def summary(self) -> dict:
        """The JSON keys of identify.json (all finite numbers)."""
        return {"name": self.name, "method": self.method, **self.estimate.summary(),
                "estimator": self.estimator,
                "equation_error": {**self.reference.summary(), "disturbance_q": float(self.reference_q),
                                   **({} if self.agreement is None else {
                                       "agreement_chi2": float(self.agreement.statistic),
                                       "agreement_dof": self.agreement.dof,
                                       "agreement_p": float(self.agreement.p_value)})},
                "crlb": float(self.crlb), "rms": self.rms.tolist(),
                "rms_over_noise": float(self.rms_over_noise), "noise_model": self.noise.describe(),
                "noise_kind": self.noise.kind, "disturbance_q": float(self.noise.disturbance_q),
                "gyro_bias": None if self.bias is None else self.bias.tolist(),
                "air_drag": None if self.air_drag is None else self.air_drag.tolist(),
                "converged": bool(self.converged), "n_samples": int(self.t.size),
                "duration_s": float(self.t[-1] - self.t[0]), "notes": list(self.notes),
                "wall_s": float(self.wall_s)}


def _starts(ee_phi: np.ndarray, trace: float) -> list[np.ndarray]:
    """Starting inertias: the equation error's, then the elongated and flat bodies of its trace
    (a short flip can leave several inertias locally consistent).
    """
    out = [ee_phi]
    for diag in ([1.0, 1.0, 0.1], [1.0, 0.1, 1.0], [0.1, 1.0, 1.0], [1.0, 1.0, 1.0]):
        out.append(phi_from_inertia(np.diag(diag) * trace / sum(diag)))
    return out


#: Every start is fitted as if each of its log-Cholesky parameters were this far off (its prior
#: and its first shooting segments: ml.first_horizon): the equation error's own intervals say
#: how well it knows the inertia, not how far its trajectory keeps the phase, and a thin body's
#: phase turns on a ratio of small differences of its moments.
GUESS_SIGMA = 0.3


def _penalised_cost(fit: output_error.Fit, prob: output_error.Problem, level) -> float:
    """A fit's residual sum of squares at the noise level (3,) rad/s plus, for each segment
    beyond one, the chi-square quantile (TEST_LEVEL) of its initial state's parameters: fits of
    the same record from different starts compared by likelihood, more trajectories paying for
    the parameters they add (the likelihood-ratio test of the nested model).
    """
    extra = (fit.segments - 1) * output_error.local_indices(prob).size
    penalty = stats.chi2.ppf(TEST_LEVEL, extra) if extra else 0.0
    return float(np.sum((fit.evaluation.e_w / level) ** 2)) + penalty


def output_error_fit(prep: Prepared, prob: output_error.Problem, reference: InertiaEstimate,
                     ee_misfit: bool, trace_ref, nested: bool = False) -> Extended:
    """The maximum-likelihood fit with its statistics: from the equation error's inertia; where
    that fit is one trajectory that the data reject (lack_of_fit) while the equation error finds
    no model error (ee_misfit false) or disagrees with it beyond their intervals (agreement): a
    basin other than the equation error's, also from the other starts (_starts), the likelihood
    choosing (_penalised_cost). Without a stated noise level each fit is reweighted once by its
    own residuals' level. nested: a gyro bias or a drag may join the fit (with_bias_or_drag); one
    that makes the first basin's fit pass the lack-of-fit test explains its misfit, and no other
    basin is searched. Raises EstimatorDivergedError where no fit's error bars are finite.
    """
    q0 = None if prep.rec.q is None else prep.rec.q[0]
    stated = prep.sigma is not None
    ee_phi = phi_from_inertia(nearest_realizable(reference.inertia))
    guess = GUESS_SIGMA ** 2 * np.eye(6)

    def one(phi, final_iter: int = output_error.FINAL_ITER) -> tuple[output_error.Problem, output_error.Fit]:
        fit = ml.fit_from_prior(prob, prob.start(phi), q0, guess, final_iter)
        if stated:
            return prob, fit
        level = np.sqrt(np.mean(fit.evaluation.e_w ** 2, axis=0))  # refit at the residuals' own level
        weighted = dataclasses.replace(prob, sigma_w=np.maximum(level, 1e-9))
        return weighted, output_error.fit(weighted, fit.p, fit.q0) if fit.segments == 1 else fit

    def kept(refinement: ml.Refinement) -> Extended:
        if not nested:
            return Extended(prob, refinement, None)
        return with_bias_or_drag(prep, prob, refinement, trace_ref)

    fits, refused, tried = [], None, None
    try:
        fits.append(one(ee_phi))
        first = ml.statistics(*fits[0], trace_ref, prep.sigma_source, stated)
        if (fits[0][1].segments > 1 or lack_of_fit(first, prep.level, prob) >= 1.0 - TEST_LEVEL
                or (ee_misfit and not agreement(first.estimate, reference).disagree)):
            return kept(first)
        tried = kept(first)
        if tried.note is not None:
            return tried
    except (EstimatorDivergedError, ConfigError) as err:
        refused = err
    trace = float(TRACE_WEIGHTS @ theta_from_phi(np.ascontiguousarray(ee_phi)))
    for phi in _starts(ee_phi, trace)[1:]:  # each run to its basin, not to its floor
        try:
            fits.append(one(phi, output_error.STAGE_ITER))
        except (EstimatorDivergedError, ConfigError):
            continue
    for problem, fit in sorted(fits, key=lambda found: _penalised_cost(found[1], prob, prep.level)):
        if tried is not None and fit is fits[0][1]:
            return tried  # the first basin's fit, its nested terms already tested
        try:
            if fit is not fits[0][1] and fit.segments == 1:  # another start's basin: to its floor
                fit = output_error.fit(problem, fit.p, fit.q0)
            return kept(ml.statistics(problem, fit, trace_ref, prep.sigma_source, stated))
        except (EstimatorDivergedError, ConfigError) as err:
            refused = err
    raise refused


def _equation_error_estimate(prep: Prepared, trace_ref, bias=None) -> EquationError:
    """The equation-error estimate of a prepared record, from its rates less a gyro bias (3,)
    rad/s where one is given.
    """
    rec = prep.rec
    trace = trace_ref if trace_ref is not None else 1.0
    w = rec.w if bias is None else rec.w - bias
    return equation_error(rec.t - rec.t[0], w, rec.tau, rec.h, trace, prep.usable, sigma=prep.level)


def identify(rec: Recording, method: str = "ml", *, fit_bias: bool | None = None,
             fit_drag: bool = False) -> Identification:
    """Identify the inertia of the body in one recording (see the module docstring).

    method: 'ml' (both estimates, one reported), or 'ekf' / 'ukf' (the paper's filter run once
    over the record, started from the equation error). fit_bias (ml only): estimate a constant
    gyro bias (default: where the attitude is recorded, which makes it identifiable; on a
    gyro-only record, where the likelihood-ratio test finds one: nested.with_bias_or_drag). fit_drag
    (ml only): also estimate a body-axis aerodynamic damping (torque -c_i |w| w_i, c (3,)
    N·m·s²; by default on a gyro-only record where it fits better than a bias would).
    """
    if method not in METHODS:
        raise RecordingError(f"method must be one of {METHODS}, got {method!r}")
    started = time.perf_counter()
    return identify_prepared(prepared(rec), method, fit_bias=fit_bias, fit_drag=fit_drag, started=started)


def identify_prepared(prep: Prepared, method: str = "ml", *, fit_bias: bool | None = None,
                      fit_drag: bool = False, started: float | None = None) -> Identification:
    """identify() on a record already prepared (prepare.prepared)."""
    started = time.perf_counter() if started is None else started
    rec = prep.rec
    notes = list(prep.notes)
    nominal = rec.inertia_nominal
    trace_ref = float(np.trace(nominal)) if nominal is not None else None
    if method == "ml":
        return _identify_ml(prep, fit_bias, fit_drag, trace_ref, notes, started)
    ee = _equation_error_estimate(prep, trace_ref)
    reference = InertiaEstimate(ee.theta, ee.theta_cov, ee.scale_seen)
    ee_phi = phi_from_inertia(nearest_realizable(reference.inertia))
    prob = output_error.problem_from(prep, prep.sigma, bool(fit_bias), False)
    notes = [f"{n}'s start; the {method} uses them as read" if n.startswith("the gyro clipped") else n
             for n in notes]
    run = run_over_recording(rec, prob.t_grid, prob.tau_grid, prob.h_grid, ee_phi, prob.sigma_w, method,
                             prob.fix_scale)
    coarse = coarse_lattice_note(rec.w[prep.usable])
    notes += [coarse] if coarse else []
    est = inertia_estimate(run.phi, run.cov_phi, prob.fix_scale, trace_ref)
    bound = ml.cramer_rao_bound(prob, prob.start(run.phi), rec.q[0] if rec.q is not None else None, trace_ref)
    return dataclasses.replace(_result(prep, method, method, est, reference, None,
                   relative_frobenius_bound(bound.theta, bound.theta_cov), run.e_w,
                   NoiseModel("white", prob.sigma_w, "filter measurement noise R", 0, 1.0), None, True,
                   False, notes + list(run.notes), started), reference_q=ee.torque_q)


@dataclasses.dataclass(frozen=True)
class _Estimates:
    """Both estimates of one record: the equation error (ee; as an InertiaEstimate, reference),
    the output-error problem (prob, with a nested bias or drag: nested.with_bias_or_drag), its fit (oe), the
    note on that term.
    """

    ee: EquationError
    reference: InertiaEstimate
    prob: output_error.Problem
    oe: ml.Refinement
    bias_note: str | None


def _estimates(prep: Prepared, fit_bias: bool | None, fit_drag: bool, trace_ref,
               profiled: bool = True) -> _Estimates:
    """The equation error, then the output error started from it (output_error_fit, with its
    nested terms on a gyro-only record) and, profiled, its ratios' profile likelihood where the
    rigid model explains the record (_profiled); where that fits a gyro bias, the equation error
    again from the rates less it.
    """
    ee = _equation_error_estimate(prep, trace_ref)
    reference = InertiaEstimate(ee.theta, ee.theta_cov, ee.scale_seen)
    prob = output_error.problem_from(prep, prep.sigma, bool(fit_bias), fit_drag)
    found = output_error_fit(prep, prob, reference, ee.misfit_z > stats.norm.ppf(TEST_LEVEL), trace_ref,
                             nested=fit_bias is None and prep.rec.q is None)
    prob, oe, said = found.prob, found.refinement, found.note
    # the profile is the data's likelihood only where the rigid model explains them (the
    # lack-of-fit test); a rejected model's intervals are its model-error covariance's
    if profiled and oe.fit.segments == 1 and lack_of_fit(oe, prep.level, prob) >= 1 - TEST_LEVEL:
        oe = _profiled(prep, prob, oe, trace_ref)
    if prob.fit_bias:  # a sensor offset enters the windows' regressors: both estimates without it
        ee = _equation_error_estimate(prep, trace_ref, oe.fit.p[-3:])
        reference = InertiaEstimate(ee.theta, ee.theta_cov, ee.scale_seen)
    return _Estimates(ee, reference, prob, oe, said)


def _profiled(prep: Prepared, prob: output_error.Problem, oe: ml.Refinement, trace_ref) -> ml.Refinement:
    """The refinement oe with its principal ratios' profile-likelihood intervals
    (profile.ratio_profile). Where a constrained fit of the profile lies below the fit, the fit has
    stopped short of the likelihood's maximum: it is continued from there, kept where it ends
    lower, and profiled anew.
    """
    traced = profile.ratio_profile(prob, oe.fit, oe.estimate)
    if traced.better is not None:
        try:
            fit = output_error.fit(prob, *traced.better)
            moved = ml.statistics(prob, fit, trace_ref, prep.sigma_source, prep.sigma is not None)
        except (EstimatorDivergedError, ConfigError):
            moved = None
        if moved is not None and fit.segments == 1 and fit.cost < traced.cost:
            oe, traced = moved, profile.ratio_profile(prob, fit, moved.estimate)
    return dataclasses.replace(oe, estimate=dataclasses.replace(oe.estimate, ratio_ci=traced.intervals))


def held_out(prep: Prepared, fit_bias: bool | None, fit_drag: bool, trace_ref) -> Forecast | None:
    """The output error's and the equation error's predictions of held-out data: the record cut
    into two halves, both estimators fitted on one half (_estimates) and each inertia's profile
    losses on the other (output_error.profile_losses: each row's whitened squared residual, the
    initial state, bias and drag refitted), both folds compared (forecast_comparison, the
    output error first). None where a half has fewer usable rows than a fit takes or a half's
    fit fails.
    """
    n = prep.rec.t.size
    halves = ((0, n // 2), (n // 2, n))
    if min(int(np.count_nonzero(prep.usable[a:b])) for a, b in halves) < MIN_SAMPLES:
        return None
    losses = []
    for train, test in (halves, halves[::-1]):
        try:
            part = _estimates(prep.rows(*train), fit_bias, fit_drag, trace_ref, profiled=False)
        except (EstimatorDivergedError, ConfigError, RecordingError):
            return None
        held = output_error.problem_from(prep.rows(*test), prep.level, part.prob.fit_bias, part.prob.fit_drag)
        q0 = None if prep.rec.q is None else prep.rec.q[test[0]]
        phis = [phi_from_inertia(nearest_realizable(e.inertia)) for e in (part.oe.estimate, part.reference)]
        losses.append(tuple(output_error.profile_losses(held, phi, q0) for phi in phis))
    return forecast_comparison(losses)


def _identify_ml(prep: Prepared, fit_bias: bool | None, fit_drag: bool, trace_ref, notes: list,
                 started: float) -> Identification:
    """identify_prepared's 'ml': both estimates, the one reported chosen as the module says."""
    both = _estimates(prep, fit_bias, fit_drag, trace_ref)
    prob, oe, reference = both.prob, both.oe, both.reference
    notes += [both.bias_note] if both.bias_note else []
    est = oe.estimate
    if oe.fit.segments == 1:
        est, replayed = ml.lattice_replayed(est, prob, oe.fit)
        notes += [replayed] if replayed else []
    else:
        notes.append(f"no single trajectory of the model follows the whole record: the output-error "
                     f"fit rests on {oe.fit.segments} pieces of it, each from its own initial state (the "
                     "sensitivity to the inertia grows too fast for one: a tumble near the separatrix, "
                     "or physics the model leaves out)")
    agree = agreement(est, reference)
    explained = lack_of_fit(oe, prep.level, prob) >= 1 - TEST_LEVEL
    nominal = prep.rec.inertia_nominal
    # An estimate NOMINAL_SCALE_FACTOR off the nominal's trace, where the other is not, is ruled
    # out (the sidecar's nominal excludes a scale that far off); where both are, no comparison
    # helps (a misfit so far off is refused in _result). With a drag fitted, the equation error
    # (no drag term) is not an estimate of the same model: the output error is reported.
    choice, forecast = None, None
    off = [_off(_nominal_factor(e, nominal)) for e in (est, reference)]
    if not fit_drag and off[0] == off[1]:
        if not explained and not off[0]:
            forecast = held_out(prep, fit_bias, fit_drag, trace_ref)
        choice = choose(est, reference, explained, forecast)

    estimator = "output error"
    if (choice is not None and not choice.efficient) or (off[0] and not off[1]):
        est, estimator = reference, "equation error"
    if off[0] != off[1] and (off[0] or not explained):  # where it decides, not where the fit holds
        names = ("output error", "equation error") if off[0] else ("equation error", "output error")
        notes.append(f"reported is the {names[1]}: the {names[0]}'s inertia comes out "
                     f"{_nominal_factor(reference if off[1] else oe.estimate, nominal):.3g} times the "
                     f"nominal's (trace), the {names[1]}'s within a factor {NOMINAL_SCALE_FACTOR:g}")
    elif choice is not None and explained and not choice.efficient:
        notes.append(f"reported is the equation error: its intervals expect a relative error of "
                     f"{100 * choice.expected[1]:.2g} %, the output error's {100 * choice.expected[0]:.2g} % "
                     "(residuals coloured by a model error widen the output error's)")
    if not explained:
        compared = ("" if forecast is None else
                    f"; fitted on one half, each predicts the other with a residual sum of "
                    f"{forecast.costs[0]:.4g} (output error) and {forecast.costs[1]:.4g} (equation error) "
                    f"noise variances (the output error better by z = {forecast.statistic:.3g}, the rows' "
                    "correlation counted; where the two agree within their intervals it is reported only "
                    "where significantly better, where they disagree the better predictor is)")
        notes.append(f"the rigid model leaves physics out (the output-error fit's residuals fail the "
                     f"lack-of-fit test): reported is the {estimator}{compared}; the intervals count the "
                     "model error as a white disturbance torque (run `inertia-gym diagnose` to find what "
                     "is missing)")
    if agree.disagree:
        notes.append(f"the output-error and equation-error estimates disagree beyond their intervals "
                     f"(chi-square {agree.statistic:.3g} on {agree.dof} degrees of freedom): the rigid "
                     "model misses something that moves them differently")
    bias = oe.fit.p[-3:].copy() if prob.fit_bias else None
    result = _result(prep, "ml", estimator, est, reference, agree, oe.crlb, oe.fit.evaluation.e_w, oe.noise,
                     bias, oe.fit.converged, not explained and _off(_nominal_factor(est, nominal)), notes,
                     started)
    return dataclasses.replace(result, reference_q=both.ee.torque_q,
                               air_drag=oe.fit.p[prob.drag_slice].copy() if prob.fit_drag else None)


def _nominal_factor(est: InertiaEstimate, nominal) -> float:
    """The estimate's trace over the nominal's (1 without a nominal or an identified scale)."""
    if nominal is None or not est.scale_identified:
        return 1.0
    return float(TRACE_WEIGHTS @ est.theta) / float(np.trace(nominal))


def _off(factor: float) -> bool:
    """Whether a trace factor is more than NOMINAL_SCALE_FACTOR off the nominal's, either way."""
    return not 1.0 / NOMINAL_SCALE_FACTOR <= factor <= NOMINAL_SCALE_FACTOR


def _result(prep: Prepared, method: str, estimator: str, est: InertiaEstimate,
            reference: InertiaEstimate, agree: Agreement | None, crlb: float, e_meas, noise: NoiseModel,
            bias, converged: bool, refused: bool, notes: list, started: float) -> Identification:
    """The Identification of one record: residuals on every row (NaN where the fit has none),
    the scale's notes; refused: raise EstimatorDivergedError instead (a record the rigid model
    does not explain whose reported inertia is NOMINAL_SCALE_FACTOR off the sidecar's nominal: two
    signs of columns in other units than stated, which no estimate survives).
    """
    rec = prep.rec
    e_w = np.full(rec.w.shape, np.nan)
    if e_meas.shape[0] == rec.t.size:
        e_w = e_meas
    else:
        e_w[np.flatnonzero(prep.usable)[: e_meas.shape[0]]] = e_meas
    rms = np.sqrt(np.nanmean(e_w ** 2, axis=0))
    rms_over_noise = float(np.sqrt(np.nanmean((e_w / prep.level) ** 2)))
    if est.scale_identified and rec.q is None:
        est, said = with_gyro_scale(est, reference, rec.meta.get("gyro_scale_sigma"))
        notes.append(said)
        reference = with_gyro_scale(reference, reference, rec.meta.get("gyro_scale_sigma"))[0]
    nominal = rec.inertia_nominal
    if est.scale_identified:
        sigma_s = est.scale_sigma()
        if sigma_s > SCALE_SIGMA_IDENTIFIED:
            notes.append(f"the scale is poorly determined (relative sigma of the trace {sigma_s:.2g}): the "
                         "intervals carry it; the ratios are known better than the absolute values")
        factor = _nominal_factor(est, nominal)
        if _off(factor):
            notes.append(f"the identified inertia is {factor:.3g} times the nominal's (trace): check the "
                         "units of the torque (N·m) and the momentum (kg·m²/s) columns, or the nominal; a "
                         "torque in mN·m makes the inertia 1000x")
    else:
        notes.append("neither a torque nor a known internal momentum acts: the inertia is identified up "
                     f"to scale; it is reported normalised to trace {TRACE_WEIGHTS @ est.theta:.6g} kg·m² "
                     + ("(the nominal's)" if nominal is not None else "(no nominal given)"))
    if refused:
        raise EstimatorDivergedError(
            f"the rigid-body model leaves residuals {rms_over_noise:.3g} times the noise and its inertia "
            f"comes out {_nominal_factor(est, nominal):.3g} times the nominal's: it does not explain this "
            "recording (check its units and columns, or run diagnose on it)" + clip_hint(rec))
    if not converged:
        notes.append("the output-error fit stopped at its iteration limit before converging: its "
                     "intervals, from the curvature where it stopped, may be far too narrow")
    if prep.sigma is not None:
        said = stated_noise_note(rec.w[prep.usable], prep.sigma, rms)
        notes += [said] if said else []
    if rms_over_noise > 3.0:
        notes.append(f"post-fit residuals are {rms_over_noise:.1f}x the gyro noise: the rigid model leaves "
                     "something out (run `inertia-gym diagnose`)" + clip_hint(rec))
    return Identification(rec.name, method, est, estimator, reference, agree, crlb, rms, rms_over_noise,
                          noise, bias, rec.t, rec.w, rec.w - e_w, converged,
                          time.perf_counter() - started, tuple(notes))
