"""Maximum likelihood with its statistics: the output-error fit, its noise model and covariance.

refine() fits a record's rigid model (output_error.fit) and decides how its residuals are to be
read (uncertainty.py): white at the noise level, coloured noise (the Bartlett sandwich), or
model error (residuals in excess of the stated noise: the disturbance torque's covariance added
to the Fisher bound). identify() and validate's refinement both call it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from inertia_gym.errors import EstimatorDivergedError
from inertia_gym.estimation import output_error
from inertia_gym.estimation.inertia_param import theta_from_phi
from inertia_gym.estimation.longrun import correlation_lags
from inertia_gym.estimation.uncertainty import (
    TRACE_WEIGHTS,
    InertiaEstimate,
    NoiseModel,
    inertia_estimate,
    jacobian_covariance,
    model_error_covariance,
    relative_frobenius_bound,
    sandwich_covariance,
)
from inertia_gym.sensors import lattice_replays, quantisation_step, repeat_share

#: The largest share of the rates (a phase error in rad) the start's uncertainty may move the
#: predicted rates by within the first horizon.
FIRST_HORIZON_PHASE = 0.5
#: Largest standard deviation of a log-Cholesky shape parameter (phi[1:6]) a covariance may give:
#: e^1000 in a moment ratio says nothing, and the delta method overflows.
MAX_SHAPE_SIGMA = 1e3


@dataclasses.dataclass(frozen=True)
class Refinement:
    """An ML fit with its statistics: fit (output_error.Fit); cov (n, n) the parameters'
    covariance as reported; fisher_cov (n, n) inverse Fisher (white noise at sigma: the
    Cramér-Rao bound); noise (NoiseModel); estimate (InertiaEstimate); crlb (relative Frobenius
    bound at the estimate).
    """

    fit: output_error.Fit
    cov: np.ndarray
    fisher_cov: np.ndarray
    noise: NoiseModel
    estimate: InertiaEstimate
    crlb: float


def cramer_rao_bound(prob: output_error.Problem, p, q_ref=None,
                     trace_ref: float | None = None) -> InertiaEstimate:
    """The inertia at the parameters p (n,) with the Cramér-Rao covariance of the problem there:
    (J^T J)^-1 of the weighted sensitivities (white noise at prob.sigma_w), q_ref (4,) the
    initial attitude (None: identity, for records without attitude).
    """
    q_ref = np.array([1.0, 0.0, 0.0, 0.0]) if q_ref is None else q_ref
    ev = output_error.evaluate(prob, p, q_ref, True)
    cov = jacobian_covariance(ev.jac, prob.free())
    return inertia_estimate(p[:6], cov[:6, :6], prob.fix_scale, trace_ref)


def first_horizon(prob: output_error.Problem, p, q0, cov_phi) -> int:
    """Measurements in the first shooting segments from the start p (n,) (q0 its attitude) whose
    inertia's log-Cholesky parameters have the covariance cov_phi (6, 6): the rows over which
    that uncertainty, carried by the sensitivities, moves the predicted rates by less than a
    phase error of FIRST_HORIZON_PHASE rad would (a shift of the motion by that angle's time,
    FIRST_HORIZON_PHASE / |w|, moves the rates by that times |w_dot|: the rms of both over the
    start's own trajectory), beyond which the fit's linearization no longer holds and iterating
    may not bring the phase back; at least half a rotation and 20 measurements.
    """
    q_ref = np.array([1.0, 0, 0, 0]) if q0 is None else q0
    ev = output_error.evaluate(prob, np.asarray(p, float), q_ref, True)
    m = prob.meas_idx.size
    if not ev.ok:
        return min(20, m)
    sens = -ev.jac[: 3 * m, :6].reshape(m, 3, 6) * np.asarray(prob.sigma_w)[..., None]  # d w / d phi
    spread = np.sqrt(np.maximum(np.einsum("mip,pq,miq->m", sens, np.asarray(cov_phi, float), sens), 0.0))
    t = prob.t_grid[prob.meas_idx]
    model = prob.z_w - ev.e_w
    rate = np.linalg.norm(prob.z_w, axis=1) + 1e-12
    if m > 2:
        accel = float(np.sqrt(np.mean(np.sum(np.gradient(model, t, axis=0) ** 2, axis=1))))
        shift = FIRST_HORIZON_PHASE * accel / float(np.sqrt(np.mean(rate ** 2)))
    else:
        shift = np.inf
    lost = np.flatnonzero(spread > shift)
    half_turn = int(np.searchsorted(t, t[0] + math.pi / float(np.percentile(rate, 90))))
    return int(min(m, max(20, half_turn, lost[0] if lost.size else m)))


def _check_error_bars(q_dist: float, cov: np.ndarray, rms_ratio: float) -> None:
    """Raise EstimatorDivergedError where the parameters' covariance cov (n, n) in phi
    coordinates, or the model error's intensity q_dist, is not finite, or gives a shape
    parameter a standard deviation over MAX_SHAPE_SIGMA: error bars that say nothing.
    """
    shape_sigma = np.sqrt(np.abs(np.diag(cov)[1:6])) if np.all(np.isfinite(cov)) else np.inf
    if np.isfinite(q_dist) and np.max(shape_sigma) <= MAX_SHAPE_SIGMA:
        return
    raise EstimatorDivergedError(
        f"the fitted model leaves residuals {rms_ratio:.3g} times the noise and its error bars "
        "overflow: the rigid-body model does not explain this recording (check its units and "
        "columns, or run diagnose on it)")


def statistics(prob: output_error.Problem, fit: output_error.Fit, trace_ref: float | None,
               sigma_source: str, model_error: bool = True) -> Refinement:
    """The covariance of a fit and the noise model behind it.

    White residuals: the Fisher bound, widened by their rms over the noise where above 1.
    Coloured residuals (correlated beyond chance: longrun.correlation_lags) in excess of the
    noise level (model_error, where that level is stated, not fitted): the excess is model
    error, the Fisher bound plus the disturbance torque's covariance (a sandwich over the same
    residuals would count it twice); without an excess, the Bartlett sandwich.
    """
    free = prob.free()
    ev = fit.evaluation
    if not ev.ok or (fit.segments == 1 and ev.jac is None) or (fit.segments > 1 and fit.global_cov is None):
        # a trajectory that leaves the finite numbers has no Jacobian, hence no error bars
        raise EstimatorDivergedError("the fitted trajectory does not stay finite over the record: the "
                                     "rigid-body model does not follow it from this start")
    m = prob.meas_idx.size
    channels = ev.r.reshape(-1, m, 3).transpose(1, 0, 2).reshape(m, -1) if fit.segments == 1 else \
        ev.e_w / prob.sigma_w
    lags = correlation_lags(channels)
    rms_ratio = float(np.sqrt(np.mean(ev.r ** 2)))
    if fit.segments > 1:  # several trajectories: their Fisher bound, widened as the residuals say
        fisher_cov = np.zeros((prob.n_params, prob.n_params))
        gl = output_error.global_indices(prob)
        fisher_cov[np.ix_(gl, gl)] = fit.global_cov
        cov = fisher_cov * max(1.0, rms_ratio ** 2) * (1 + lags)
        noise = NoiseModel("white" if lags == 0 else "coloured", prob.sigma_w, sigma_source, lags,
                           max(1.0, rms_ratio) * math.sqrt(1 + lags))
    elif lags == 0:
        fisher_cov = jacobian_covariance(ev.jac, free)
        cov = fisher_cov * max(1.0, rms_ratio ** 2)
        noise = NoiseModel("white", prob.sigma_w, sigma_source, 0, max(1.0, rms_ratio))
    else:
        fisher_cov = jacobian_covariance(ev.jac, free)
        q_dist, cov_model = model_error_covariance(prob, fit.p, ev) if model_error else (0.0, None)
        if q_dist > 0:
            cov = fisher_cov + cov_model
        else:
            cov = np.zeros_like(fisher_cov)
            cov[np.ix_(free, free)] = sandwich_covariance(ev.jac[:, free], ev.r, m, lags)
        _check_error_bars(q_dist, cov, rms_ratio)
        ratio = np.sqrt(np.clip(np.diag(cov)[:6][free[:6]], 0, None)
                        / np.clip(np.diag(fisher_cov)[:6][free[:6]], 1e-300, None))
        noise = NoiseModel("coloured", prob.sigma_w, sigma_source, lags, float(np.median(ratio)), q_dist)
    phi = fit.p[:6]
    estimate = inertia_estimate(phi, cov[:6, :6], prob.fix_scale, trace_ref)
    bound = inertia_estimate(phi, fisher_cov[:6, :6], prob.fix_scale, trace_ref)
    crlb = relative_frobenius_bound(bound.theta, bound.theta_cov)
    return Refinement(fit, cov, fisher_cov, noise, estimate, crlb)


def refine(prob: output_error.Problem, p_start, q_start, start_cov_phi, trace_ref: float | None,
           sigma_source: str, model_error: bool = True) -> Refinement:
    """Fit the problem from a start whose inertia has the covariance start_cov_phi (6, 6) (a
    prior on the early horizon stages, which also plans the first one: first_horizon) and build
    its statistics (statistics()).
    """
    return statistics(prob, fit_from_prior(prob, p_start, q_start, start_cov_phi), trace_ref, sigma_source,
                      model_error)


def fit_from_prior(prob: output_error.Problem, p_start, q_start, start_cov_phi,
                   final_iter: int = output_error.FINAL_ITER) -> output_error.Fit:
    """output_error.fit from p_start whose inertia has the covariance start_cov_phi (6, 6): its
    inverse a prior on the early horizon stages, which also plans the first (first_horizon).
    """
    info = np.zeros((prob.n_params, prob.n_params))
    keep = np.flatnonzero(prob.free()[:6])
    start = np.asarray(start_cov_phi, float)[np.ix_(keep, keep)]
    info[np.ix_(keep, keep)] = np.linalg.pinv(start, hermitian=True)
    horizon = first_horizon(prob, p_start, q_start, start_cov_phi)
    return output_error.fit(prob, p_start, q_start, info, horizon, final_iter=final_iter)


#: Share of consecutive rows an axis reads alike from which the gyro's rounding is counted by
#: replays of the fit on its lattice (REPLAYS of them: the widening's own scatter is about
#: sqrt(2 / (REPLAYS x 5)), 12 %).
REPLAY_REPEAT_SHARE, REPLAYS = 0.25, 8


def lattice_replayed(est: InertiaEstimate, prob: output_error.Problem, fit: output_error.Fit) -> tuple:
    """The estimate with the rounding of a gyro read on a lattice coarse beside its noise counted
    (an axis repeats its reading on REPLAY_REPEAT_SHARE or more of the rows): the rounding error
    follows the motion, and no noise model of the residuals counts it. REPLAYS records of the
    fit's rates with the noise beneath the step added, read on the lattice shifted by a random
    fraction of a step (seeded), are refitted; the mean outer product of their errors joins the
    covariance. Returns (estimate, note) or (est, None) where no axis is read so.
    """
    w = prob.z_w
    step = quantisation_step(w)
    coarse = (repeat_share(w) >= REPLAY_REPEAT_SHARE) & (step > 0)
    if not coarse.any():
        return est, None
    e_meas = fit.evaluation.e_w
    beneath = np.sqrt(np.maximum(np.mean(e_meas ** 2, axis=0) - step ** 2 / 12.0, 0.0))
    trace = float(TRACE_WEIGHTS @ est.theta)
    spread = np.zeros((6, 6))
    for read in lattice_replays(w - e_meas, beneath, step, REPLAYS, first_unshifted=False):
        replay = output_error.fit(dataclasses.replace(prob, z_w=read), fit.p, fit.q0)
        theta = theta_from_phi(np.ascontiguousarray(replay.p[:6]))
        if not est.scale_identified:
            theta = theta * trace / float(TRACE_WEIGHTS @ theta)
        spread += np.outer(theta - est.theta, theta - est.theta) / REPLAYS
    widened = dataclasses.replace(est, theta_cov=est.theta_cov + spread)
    ratio = np.sqrt(np.diag(widened.theta_cov)[est.sigma > 0] / est.sigma[est.sigma > 0] ** 2)
    axes = ", ".join(f"{'xyz'[i]} {step[i]:.3g}" for i in np.flatnonzero(coarse))
    return widened, (f"the gyro reads on a lattice coarse beside its noise and the motion between rows "
                     f"(steps {axes} rad/s), whose rounding error follows the motion: the spread of "
                     f"{REPLAYS} replays of the fit read on that lattice is added to the covariance, which "
                     f"widens the intervals of the inertia's entries {ratio.min():.2f}-{ratio.max():.2f}x")


__all__ = ["Refinement", "lattice_replayed", "cramer_rao_bound", "first_horizon", "refine", "statistics"]
