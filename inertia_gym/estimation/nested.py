"""Terms nested in the rigid model, kept by the likelihood-ratio test: a constant gyro bias or a
body-axis air drag added to an output-error fit of a gyro-only record.

lack_of_fit tests a fit's residuals against the noise level; extended() adds one term and keeps
it where the gain is significant and the extended fit passes that test (a term that leaves a
misfit is soaking up other model error); with_bias_or_drag() chooses between the two terms by
likelihood. identify() calls them on its output-error fits.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import stats

from inertia_gym.errors import ConfigError, EstimatorDivergedError
from inertia_gym.estimation import ml, output_error
from inertia_gym.estimation.uncertainty import TEST_LEVEL
from inertia_gym.prepare import Prepared


@dataclasses.dataclass(frozen=True)
class Extended:
    """The fit with_bias_or_drag keeps: its problem (prob, with fit_bias or fit_drag where a
    term was kept), the refinement, and the note that says which term and why (None: the plain fit).
    """

    prob: output_error.Problem
    refinement: ml.Refinement
    note: str | None


def lack_of_fit(refinement: ml.Refinement, level: np.ndarray, prob: output_error.Problem) -> float:
    """The p-value of the fit's residuals against the noise level (3,) rad/s: their whitened sum
    of squares against a chi-square on the residuals' degrees of freedom (fewer where they are
    correlated: each run of correlated lags counts once). A fit in several segments is tested the
    same way, each segment's own initial state counted among the fitted parameters: a long tumble
    that no single trajectory follows numerically (its sensitivity to the inertia grows without
    bound) is still one rigid body wherever its segments leave residuals at the noise.
    """
    fit = refinement.fit
    z = fit.evaluation.e_w / level
    states = (fit.segments - 1) * output_error.local_indices(prob).size
    dof = max(z.size - prob.n_params - states, 1) / (1 + refinement.noise.hac_lags)
    return float(stats.chi2.sf(float(np.sum(z ** 2)) / (1 + refinement.noise.hac_lags), dof))


def extended(prep: Prepared, prob: output_error.Problem, plain: ml.Refinement, trace_ref, term: str):
    """(problem, refinement, whitened residual sum) of the plain fit extended by `term` ("fit_bias"
    or "fit_drag"), where the likelihood-ratio test finds it (chi-square on 3 degrees of freedom
    at TEST_LEVEL) and the extended fit passes the lack-of-fit test (a term that leaves a misfit
    is soaking up other model error); else None.
    """
    extended_prob = dataclasses.replace(prob, **{term: True})
    try:
        fit = output_error.fit(extended_prob, np.r_[plain.fit.p, np.zeros(3)], plain.fit.q0)
        fitted = ml.statistics(extended_prob, fit, trace_ref, prep.sigma_source, prep.sigma is not None)
    except (EstimatorDivergedError, ConfigError):
        return None
    if (fitted.fit.segments > plain.fit.segments
            or lack_of_fit(fitted, prep.level, extended_prob) < 1 - TEST_LEVEL):
        return None
    # the gain's discount for correlated rows: where the term leaves white residuals, the noise is
    # white and the gain a chi-square on 3 degrees of freedom (the plain fit's correlation is then
    # the term's own misfit, not noise); where correlation remains, model error beyond the term
    # is in both fits, and the longer of their correlations discounts it
    lags = 1 + (0 if fitted.noise.hac_lags == 0 else max(plain.noise.hac_lags, fitted.noise.hac_lags))
    cost = float(np.sum((fitted.fit.evaluation.e_w / prep.level) ** 2))
    gain = float(np.sum((plain.fit.evaluation.e_w / prep.level) ** 2)) - cost
    # nested fits in as many segments: the likelihood-ratio test; a term that lets fewer
    # trajectories follow the record is evidence of its own
    if plain.fit.segments == fitted.fit.segments and gain / lags < stats.chi2.ppf(TEST_LEVEL, 3):
        return None
    return extended_prob, fitted, cost


def with_bias_or_drag(prep: Prepared, prob: output_error.Problem, plain: ml.Refinement,
                      trace_ref) -> Extended:
    """The plain fit, or with a bias or a drag (extended) where the likelihood keeps one."""
    terms = ("fit_bias",) if prob.fit_drag else ("fit_bias", "fit_drag")
    found = {t: got for t in terms if (got := extended(prep, prob, plain, trace_ref, t)) is not None}
    if not found:
        return Extended(prob, plain, None)
    term = min(found, key=lambda k: found[k][2])  # both add 3 parameters: the smaller sum, more likely
    chosen_prob, chosen, cost = found[term]
    values = chosen.fit.p[-3:] if term == "fit_bias" else chosen.fit.p[chosen_prob.drag_slice]
    shown = np.array2string(values, formatter={"float_kind": lambda v: f"{v:.3g}"})  # 3 significant digits
    what = (f"a constant gyro bias {shown} rad/s" if term == "fit_bias" else
            f"a body-axis air drag c = {shown} N·m·s² (torque -c_i |w| w_i)")
    note = f"{what} was fitted: the likelihood-ratio test finds it and with it the residuals are at the noise"
    for other in set(found) - {term}:  # the other term's residual sum beside the kept one's
        words = {"fit_bias": "a constant gyro bias", "fit_drag": "a body-axis air drag"}[other]
        note += (f"; {words} in its place fits too, less well (whitened residual sums {cost:.6g}, "
                 f"{found[other][2]:.6g})")
    return Extended(chosen_prob, chosen, note)
