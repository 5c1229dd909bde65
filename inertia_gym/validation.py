"""Long-horizon validation of an excitation xi: does the estimator find the inertia?

Runs the closed loop (simulation.py) for many seeds at once with bursts of T_on separated by
coasts (paper: about 90-100 s), v refreshed from P_theta before each burst, and scores the final
estimate against the truth: relative Frobenius error, the same after trace normalisation (the
part torque-free motion can identify), 95% interval coverage, divergence, and whether the scale
was identified (the filter's posterior on the log-scale shrank).

Beside the filter, every run is refined by batch maximum likelihood over its whole record
(estimation/ml.refine: output error on the gyro and quaternion readings the filter saw, the applied
torque known, started from the filter's final estimate) and scored against the Cramér-Rao bound
of the run (the inverse Fisher information from the sensitivities at the truth, same unknowns:
inertia, initial rate and attitude, gyro bias). Without torque the scale is not fitted and the
refined errors, coverage and bound are those of the trace-normalised inertia.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from inertia_gym.errors import ConfigError
from inertia_gym.estimation import output_error
from inertia_gym.estimation.inertia_param import phi_from_inertia
from inertia_gym.estimation.ml import cramer_rao_bound, refine
from inertia_gym.estimation.uncertainty import SCALE_SIGMA_IDENTIFIED, relative_frobenius_bound
from inertia_gym.excitation import burst_direction, validation_schedule
from inertia_gym.information import inertia_from_theta, theta_from_inertia
from inertia_gym.scenario import Scenario, steps
from inertia_gym.simulation import initial_state, run_segment


@dataclasses.dataclass(frozen=True)
class ValidationResult:
    """Per-seed scores and the time series behind the plots.

    rel_errors (S,) ||J_hat - J||_F / ||J||_F at the end; ratio_rel_errors (S,) the same after
    dividing each by its trace; covered (S, 6) bool truth inside +-1.96 sigma; diverged (S,) bool;
    scale_identified (S,) bool; t_meas (S, m) s; theta_hat, theta_sigma (S, m, 6); w_est, w_true
    (S, m, 3); t_step (n,) and tau (S, n, 3) the applied torque (when recorded); refined (the
    batch-ML scores, when asked for); measurements (S, m, 14) the true (q, w) and the gyro and
    quaternion readings the filter took at t_meas. impulse (S,) N·m·s the bursts spent over the
    horizon (sc.impulse_budget renews every sc.bursts_per_episode bursts, as per episode);
    rate_peak (S,) the largest true |w| rad/s.
    """

    seeds: tuple
    xi: tuple | None
    duration: float
    rel_errors: np.ndarray
    ratio_rel_errors: np.ndarray
    covered: np.ndarray
    diverged: np.ndarray
    scale_identified: np.ndarray
    inertia_hat: np.ndarray
    inertia_true: np.ndarray
    t_meas: np.ndarray
    theta_hat: np.ndarray
    theta_sigma: np.ndarray
    w_est: np.ndarray
    w_true: np.ndarray
    t_step: np.ndarray
    tau: np.ndarray
    wall_s: float
    refined: "RefinedScores | None" = None
    measurements: np.ndarray | None = None
    impulse: np.ndarray | None = None
    rate_peak: np.ndarray | None = None

    def summary(self) -> dict:
        """The contract keys of docs/contracts.md (validate's result.json)."""
        ok = ~self.diverged
        return {
            "xi": None if self.xi is None else list(self.xi),
            "duration": self.duration,
            "seeds": list(self.seeds),
            "rel_errors": finite_or_none(self.rel_errors),
            "median_rel_error": float(np.median(self.rel_errors[ok])) if ok.any() else None,
            "ratio_rel_errors": finite_or_none(self.ratio_rel_errors),
            "median_ratio_rel_error": (
                float(np.median(self.ratio_rel_errors[ok])) if ok.any() else None
            ),
            "ci95_coverage": float(self.covered[ok].mean()) if ok.any() else None,
            "diverged": int(self.diverged.sum()),
            "scale_identified": bool(ok.any() and self.scale_identified[ok].mean() > 0.5),
            "scale_identified_per_seed": [bool(x) for x in self.scale_identified],
            "inertia_true": self.inertia_true.tolist(),
            "inertia_hat": finite_or_none(self.inertia_hat),
            "wall_s": self.wall_s,
            **({"impulse_used": finite_or_none(self.impulse),
                "rate_peak": finite_or_none(self.rate_peak)} if self.impulse is not None else {}),
            **(self.refined.summary(ok) if self.refined is not None else {}),
        }


@dataclasses.dataclass(frozen=True)
class RefinedScores:
    """Batch-ML refinement of each run against the Cramér-Rao bound (NaN for diverged runs).

    rel_errors (S,) ||J_ml - J||_F / ||J||_F (trace-normalised when the scale is not fitted);
    crlb (S,) the bound's relative Frobenius error at the truth; covered (S, 6) truth inside
    the ML estimate's +-1.96 sigma; inertia (S, 3, 3); scale_fitted: the torque let the fit
    free the scale.
    """

    rel_errors: np.ndarray
    crlb: np.ndarray
    covered: np.ndarray
    inertia: np.ndarray
    scale_fitted: bool
    wall_s: float

    def summary(self, ok) -> dict:
        """The refined keys of validate's result.json (JSON, no NaN: diverged runs give null)."""
        good = ok & np.isfinite(self.rel_errors)
        eff = self.rel_errors[good] / self.crlb[good]
        return {
            "crlb_rel_errors": finite_or_none(self.crlb),
            "refined_rel_errors": finite_or_none(self.rel_errors),
            "refined_median_rel_error": float(np.median(self.rel_errors[good])) if good.any() else None,
            "refined_ci95_coverage": float(self.covered[good].mean()) if good.any() else None,
            "efficiency": float(np.median(eff)) if good.any() else None,
            "refined_errors_are_ratios": not self.scale_fitted,
            "refined_inertia": finite_or_none(self.inertia),
            "refined_wall_s": self.wall_s,
        }


def finite_or_none(values) -> list:
    """An array as nested lists for JSON, each non-finite number (a diverged or unrefined run)
    as None: result.json never holds NaN.
    """
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 0:
        return float(arr) if np.isfinite(arr) else None
    return [finite_or_none(x) for x in arr]


def relative_error(j_hat, j_true) -> np.ndarray:
    """||J_hat - J||_F / ||J||_F over the last two axes."""
    return np.linalg.norm(j_hat - j_true, axis=(-2, -1)) / np.linalg.norm(j_true)


def ratio_error(j_hat, j_true) -> np.ndarray:
    """Relative error after dividing both by their trace (what torque-free data identify)."""
    jn = j_hat / np.trace(j_hat, axis1=-2, axis2=-1)[..., None, None]
    return relative_error(jn, j_true / np.trace(j_true))


def validate(sc: Scenario, xi, duration: float, seeds, *, record_torque: bool = True,
             disturbance=None, refine_ml: bool = False) -> ValidationResult:
    """Validate xi = (a, b, T_on) (or None: no torque at all) over `duration` s for each seed.

    refine_ml: also refine each run by batch maximum likelihood and score it against the
    Cramér-Rao bound (needs the applied torque, so it records it).
    """
    t0 = time.perf_counter()
    if not (np.isfinite(duration) and duration > 0):
        raise ConfigError(f"duration must be a positive number of seconds, got {duration}")
    seeds = tuple(int(s) for s in seeds)
    if not seeds or min(seeds) < 0:
        raise ConfigError(f"seeds must be a non-empty list of integers >= 0, got {list(seeds)}")
    if xi is not None:
        xi = np.asarray(xi, dtype=float)
        if xi.shape != (3,) or not np.all(np.isfinite(xi)) or xi[2] <= 0:
            raise ConfigError(f"xi must be finite (a, b, T_on) with T_on > 0, got {xi.tolist()}")
    sensor_rngs = [np.random.default_rng([s, 0]) for s in seeds]
    schedule_rngs = [np.random.default_rng([s, 1]) for s in seeds]
    record_torque = record_torque or refine_ml
    t_on = None if xi is None else float(xi[2])
    xi_arr = np.zeros(3) if xi is None else np.asarray(xi, dtype=float)
    schedules = [validation_schedule(sc, t_on, duration, r) for r in schedule_rngs]
    n_seg = max(len(s) for s in schedules)
    state = initial_state(sc, sensor_rngs)
    prior_sigma_s = np.sqrt(state.P[:, 7, 7])
    logs, torques = [], []
    spent = np.zeros(len(seeds))  # of the current episode's budget
    impulse = np.zeros(len(seeds))
    rate_peak = np.zeros(len(seeds))
    for i in range(n_seg):
        if (i - 1) % sc.bursts_per_episode == 0:
            spent[:] = 0.0  # segment i >= 1 holds burst i: a new episode's budget every N bursts
        n_steps = np.array([s[i].n_steps if i < len(s) else 0 for s in schedules])
        bursts = np.zeros((len(seeds), 1 if t_on is not None else 0, 2), dtype=np.int64)
        for r, s in enumerate(schedules):
            if i < len(s) and len(s[i].bursts):
                bursts[r] = s[i].bursts
            elif bursts.shape[1]:
                bursts[r] = (-1, -1)  # no burst in this segment for this run
        p_theta = state.P_theta()
        v = np.array([burst_direction(p) if not d else np.array([1.0, 0, 0])
                      for p, d in zip(p_theta, state.diverged)])
        state, trace = run_segment(
            sc, state, n_steps, bursts, np.tile(xi_arr, (len(seeds), 1)), v, sensor_rngs,
            record_steps=record_torque, disturbance=disturbance, impulse_spent=spent,
        )
        impulse += trace.impulse - spent
        spent = trace.impulse
        rate_peak = np.maximum(rate_peak, trace.rate_peak)
        logs.append(trace)
        if record_torque:
            torques.append((n_steps, trace.tau))
    inertia_true = sc.inertia_true_array
    j_hat = state.inertia_hat()
    theta_true = theta_from_inertia(inertia_true)
    theta_hat = state.theta_hat()
    sigma = np.sqrt(np.clip(np.diagonal(state.P_theta(), axis1=1, axis2=2), 0, None))
    covered = np.abs(theta_hat - theta_true) <= 1.96 * sigma
    sigma_s = np.sqrt(state.P[:, 7, 7])
    # Identified: the log-scale's posterior sigma is at most SCALE_SIGMA_IDENTIFIED (5 %) and at
    # most half the prior's.
    scale_ok = (sigma_s <= SCALE_SIGMA_IDENTIFIED) & (sigma_s <= 0.5 * prior_sigma_s)
    log = _concat_logs(logs, sc.dt)
    t_meas, th, th_sig, w_est, measurements = log.t, log.theta, log.theta_sigma, log.w_est, log.measurements
    w_true = measurements[..., 4:7]
    t_step, tau = _concat_torque(torques, sc.dt) if record_torque else (np.zeros(0),
                                                                        np.zeros((len(seeds), 0, 3)))
    refined = None
    if refine_ml:
        refined = refine_runs(sc, state, t_meas, measurements, tau, xi is not None and bool(
            np.any(tau != 0.0)))
    return ValidationResult(
        seeds=seeds, xi=None if xi is None else tuple(float(x) for x in xi), duration=duration,
        rel_errors=relative_error(j_hat, inertia_true), ratio_rel_errors=ratio_error(j_hat, inertia_true),
        covered=covered, diverged=state.diverged.copy(), scale_identified=scale_ok,
        inertia_hat=j_hat, inertia_true=inertia_true, t_meas=t_meas, theta_hat=th,
        theta_sigma=th_sig, w_est=w_est, w_true=w_true, t_step=t_step, tau=tau,
        wall_s=time.perf_counter() - t0, refined=refined, measurements=measurements,
        impulse=impulse, rate_peak=rate_peak,
    )


def _refine_one(sc: Scenario, x_final, p_final, t_meas, meas, tau, forced: bool):
    """ML refinement of one run: (theta estimate, its covariance, bound covariance at truth,
    fix_scale) or None when the run has no usable record.
    """
    valid = np.isfinite(t_meas) & np.all(np.isfinite(meas[:, 7:10]), axis=1)
    with_att = sc.quat_sigma > 0 and np.all(np.isfinite(meas[valid, 10:14]))
    steps = np.rint(t_meas[valid] / sc.dt).astype(np.int64)
    if steps.size < 30:
        return None
    first = int(steps[0])
    grid_t = np.arange(first, int(steps[-1]) + 1) * sc.dt
    tau_grid = np.zeros((grid_t.size, 3))
    hi = min(tau.shape[0], int(steps[-1]) + 1)
    tau_grid[: max(0, hi - first)] = tau[first:hi]
    z = meas[valid]
    prob = output_error.Problem(
        t_grid=grid_t - grid_t[0], tau_grid=tau_grid, h_grid=np.zeros_like(tau_grid),
        # The truth is RK4 at dt: the model integrates on the same grid with the same steps.
        n_sub=np.ones(grid_t.size, dtype=np.int64), meas_idx=steps - first,
        z_w=z[:, 7:10], z_q=z[:, 10:14] if with_att else None,
        sigma_w=np.full(3, sc.gyro_sigma), sigma_att=2.0 * sc.quat_sigma, fit_bias=with_att,
        fix_scale=not forced)
    n = prob.n_params
    p0 = np.zeros(n)
    p0[:6], p0[6:9] = x_final[7:13], z[0, 7:10]
    q0 = z[0, 10:14] if with_att else None
    # the filter's own uncertainty of its inertia: the refinement's prior and its first horizon
    ref = refine(prob, p0, q0, p_final[7:13, 7:13], None, "scenario gyro_sigma")
    # The bound at the truth: the same problem's Fisher information at the true parameters.
    truth = np.zeros(n)
    truth[:6] = phi_from_inertia(sc.inertia_true_array)
    if prob.fix_scale:
        truth[0] = p0[0]
    truth[6:9] = z[0, 4:7]
    bound = cramer_rao_bound(prob, truth, z[0, 0:4] if with_att else None)
    return ref.estimate, bound, prob.fix_scale


def refine_runs(sc: Scenario, state, t_meas, measurements, tau, forced: bool) -> RefinedScores:
    """Refine every non-diverged run (see the module docstring) and score it."""
    t0 = time.perf_counter()
    batch = state.batch
    theta_true = theta_from_inertia(sc.inertia_true_array)
    rel = np.full(batch, np.nan)
    crlb = np.full(batch, np.nan)
    covered = np.zeros((batch, 6), dtype=bool)
    inertia = np.full((batch, 3, 3), np.nan)
    fix_scale = not forced
    for r in range(batch):
        if state.diverged[r]:
            continue
        try:
            out = _refine_one(sc, state.x[r], state.P[r], t_meas[r], measurements[r], tau[r], forced)
        except ConfigError:
            out = None
        if out is None:
            continue
        est, bound, fix_scale = out
        truth = theta_true if est.scale_identified else theta_true * (
            (est.theta[0] + est.theta[3] + est.theta[5]) / (theta_true[0] + theta_true[3] + theta_true[5]))
        rel[r] = relative_error(est.inertia, inertia_from_theta(truth))
        crlb[r] = relative_frobenius_bound(bound.theta, bound.theta_cov)
        covered[r] = np.abs(est.theta - truth) <= 1.96 * est.sigma
        inertia[r] = est.inertia
    return RefinedScores(rel, crlb, covered, inertia, not fix_scale, time.perf_counter() - t0)


@dataclasses.dataclass(frozen=True)
class _RunLogs:
    """Each run's measurement log over all its episodes, NaN-padded to the longest run: t
    (R, M) s, theta (R, M, 6) and theta_sigma (R, M, 6) the filter's estimate and its standard
    deviations, w_est (R, M, 3) rad/s, measurements (R, M, 14) the rows as measured.
    """

    t: np.ndarray
    theta: np.ndarray
    theta_sigma: np.ndarray
    w_est: np.ndarray
    measurements: np.ndarray


def _concat_logs(logs, dt) -> _RunLogs:
    batch = logs[0].n_meas.shape[0]
    per_run = []
    for r in range(batch):
        parts = [(tr.meas_step[r, : tr.n_meas[r]], tr.theta_hat[r, : tr.n_meas[r]],
                  tr.theta_var[r, : tr.n_meas[r]], tr.w_est[r, : tr.n_meas[r]],
                  tr.measurements[r, : tr.n_meas[r]]) for tr in logs]
        per_run.append([np.concatenate(p) for p in zip(*parts)])
    m = max(len(p[0]) for p in per_run)
    t = np.full((batch, m), np.nan)
    th = np.full((batch, m, 6), np.nan)
    sig = np.full((batch, m, 6), np.nan)
    we = np.full((batch, m, 3), np.nan)
    meas = np.full((batch, m, 14), np.nan)
    for r, (st, tht, var, west, z) in enumerate(per_run):
        k = len(st)
        t[r, :k], th[r, :k], sig[r, :k] = st * dt, tht, np.sqrt(np.clip(var, 0, None))
        we[r, :k], meas[r, :k] = west, z
    return _RunLogs(t, th, sig, we, meas)


def _concat_torque(torques, dt):
    batch = torques[0][1].shape[0]
    rows = [np.concatenate([tau[r, : n[r]] for n, tau in torques]) for r in range(batch)]
    n = max(len(x) for x in rows)
    out = np.zeros((batch, n, 3))
    for r, x in enumerate(rows):
        out[r, : len(x)] = x
    return np.arange(n) * dt, out


__all__ = ["ValidationResult", "validate", "relative_error", "ratio_error", "steps"]
