"""Long-horizon validation of an excitation xi: does the estimator find the inertia?

Runs the closed loop (simulation.py) for many seeds at once with bursts of T_on separated by
coasts (paper: about 90-100 s), v refreshed from P_theta before each burst, and scores the final
estimate against the truth: relative Frobenius error, the same after trace normalisation (the
part torque-free motion can identify), 95% interval coverage, divergence, and whether the scale
was identified (the filter's posterior on the log-scale shrank).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from inertia_gym.errors import ConfigError
from inertia_gym.excitation import burst_direction, validation_schedule
from inertia_gym.information import theta_from_inertia
from inertia_gym.scenario import Scenario, steps
from inertia_gym.simulation import initial_state, run_segment

# The scale counts as identified when the posterior standard deviation of log-scale is at most
# this (a 5% relative scale uncertainty) and has at least halved from the prior.
SCALE_SIGMA_IDENTIFIED = 0.05


@dataclasses.dataclass(frozen=True)
class ValidationResult:
    """Per-seed scores and the time series behind the plots.

    rel_errors (S,) ||J_hat - J||_F / ||J||_F at the end; ratio_rel_errors (S,) the same after
    dividing each by its trace; covered (S, 6) bool truth inside +-1.96 sigma; diverged (S,) bool;
    scale_identified (S,) bool; t_meas (S, m) s; theta_hat, theta_sigma (S, m, 6); w_est, w_true
    (S, m, 3); t_step (n,) and tau (S, n, 3) the applied torque (when recorded).
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

    def summary(self) -> dict:
        """The contract keys of DESIGN.md section 3 (validate's result.json)."""
        ok = ~self.diverged
        return {
            "xi": None if self.xi is None else list(self.xi),
            "duration": self.duration,
            "seeds": list(self.seeds),
            "rel_errors": [float(x) for x in self.rel_errors],
            "median_rel_error": float(np.median(self.rel_errors[ok])) if ok.any() else None,
            "ratio_rel_errors": [float(x) for x in self.ratio_rel_errors],
            "median_ratio_rel_error": (
                float(np.median(self.ratio_rel_errors[ok])) if ok.any() else None
            ),
            "ci95_coverage": float(self.covered[ok].mean()) if ok.any() else None,
            "diverged": int(self.diverged.sum()),
            "scale_identified": bool(ok.any() and self.scale_identified[ok].mean() > 0.5),
            "scale_identified_per_seed": [bool(x) for x in self.scale_identified],
            "inertia_true": self.inertia_true.tolist(),
            "inertia_hat": self.inertia_hat.tolist(),
            "wall_s": self.wall_s,
        }


def relative_error(j_hat, j_true) -> np.ndarray:
    """||J_hat - J||_F / ||J||_F over the last two axes."""
    return np.linalg.norm(j_hat - j_true, axis=(-2, -1)) / np.linalg.norm(j_true)


def ratio_error(j_hat, j_true) -> np.ndarray:
    """Relative error after dividing both by their trace (what torque-free data identify)."""
    jn = j_hat / np.trace(j_hat, axis1=-2, axis2=-1)[..., None, None]
    return relative_error(jn, j_true / np.trace(j_true))


def validate(sc: Scenario, xi, duration: float, seeds, *, record_torque: bool = True,
             disturbance=None) -> ValidationResult:
    """Validate xi = (a, b, T_on) (or None: no torque at all) over `duration` s for each seed."""
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
    t_on = None if xi is None else float(xi[2])
    xi_arr = np.zeros(3) if xi is None else np.asarray(xi, dtype=float)
    schedules = [validation_schedule(sc, t_on, duration, r) for r in schedule_rngs]
    n_seg = max(len(s) for s in schedules)
    state = initial_state(sc, sensor_rngs)
    prior_sigma_s = np.sqrt(state.P[:, 7, 7])
    logs, torques = [], []
    for i in range(n_seg):
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
            record_steps=record_torque, disturbance=disturbance,
        )
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
    scale_ok = (sigma_s <= SCALE_SIGMA_IDENTIFIED) & (sigma_s <= 0.5 * prior_sigma_s)
    t_meas, th, th_sig, w_est, w_true = _concat_logs(logs, sc.dt)
    t_step, tau = _concat_torque(torques, sc.dt) if record_torque else (np.zeros(0),
                                                                        np.zeros((len(seeds), 0, 3)))
    return ValidationResult(
        seeds=seeds, xi=None if xi is None else tuple(float(x) for x in xi), duration=duration,
        rel_errors=relative_error(j_hat, inertia_true), ratio_rel_errors=ratio_error(j_hat, inertia_true),
        covered=covered, diverged=state.diverged.copy(), scale_identified=scale_ok,
        inertia_hat=j_hat, inertia_true=inertia_true, t_meas=t_meas, theta_hat=th,
        theta_sigma=th_sig, w_est=w_est, w_true=w_true, t_step=t_step, tau=tau,
        wall_s=time.perf_counter() - t0,
    )


def _concat_logs(logs, dt):
    batch = logs[0].n_meas.shape[0]
    per_run = []
    for r in range(batch):
        parts = [(tr.meas_step[r, : tr.n_meas[r]], tr.theta_hat[r, : tr.n_meas[r]],
                  tr.theta_var[r, : tr.n_meas[r]], tr.w_est[r, : tr.n_meas[r]],
                  tr.w_true[r, : tr.n_meas[r]]) for tr in logs]
        per_run.append([np.concatenate(p) for p in zip(*parts)])
    m = max(len(p[0]) for p in per_run)
    t = np.full((batch, m), np.nan)
    th = np.full((batch, m, 6), np.nan)
    sig = np.full((batch, m, 6), np.nan)
    we = np.full((batch, m, 3), np.nan)
    wt = np.full((batch, m, 3), np.nan)
    for r, (st, tht, var, west, wtrue) in enumerate(per_run):
        k = len(st)
        t[r, :k], th[r, :k], sig[r, :k] = st * dt, tht, np.sqrt(np.clip(var, 0, None))
        we[r, :k], wt[r, :k] = west, wtrue
    return t, th, sig, we, wt


def _concat_torque(torques, dt):
    batch = torques[0][1].shape[0]
    rows = [np.concatenate([tau[r, : n[r]] for n, tau in torques]) for r in range(batch)]
    n = max(len(x) for x in rows)
    out = np.zeros((batch, n, 3))
    for r, x in enumerate(rows):
        out[r, : len(x)] = x
    return np.arange(n) * dt, out


__all__ = ["ValidationResult", "validate", "relative_error", "ratio_error", "steps"]
