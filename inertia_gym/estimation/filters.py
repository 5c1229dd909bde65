"""The paper's joint (q, w, phi) filter as a library object usable on any data.

``InertiaFilter`` is filterpy-like: ``predict(dt, tau, h, h_dot)`` advances the estimate by dt
seconds under a known body torque and a known internal momentum h (its rate h_dot enters as the
torque -h_dot), ``update(z)`` takes one measurement and exposes the innovation ``y``, its
covariance ``S`` and ``nis``; ``x``, ``P`` (posterior) and ``x_prior``, ``P_prior`` (before the
last update) are plain arrays. Every step calls the same compiled kernels as the simulator's
closed loop (simulation.py): estimation/ekf.py for the EKF's mean, transition and update,
estimation/ukf.py for the unscented prediction, sensors.py for h(x), H and R, so a filter run
here over a recording computes the same numbers as the filter inside ``validate``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from inertia_gym import sensors
from inertia_gym.dynamics import DISTURBANCE_SIZE, inv3
from inertia_gym.errors import ConfigError, EstimatorDivergedError, RecordingError
from inertia_gym.estimation import ekf, ukf
from inertia_gym.estimation.config import FilterConfig
from inertia_gym.estimation.inertia_param import (
    REALIZABLE_TOLERANCE,
    dtheta_dphi,
    inertia_from_phi,
    realizable_phi,
    theta_from_phi,
)
from inertia_gym.estimation.integrator import MAX_ROTATION_PER_STEP
from inertia_gym.estimation.uncertainty import TRACE_WEIGHTS


class InertiaFilter:
    """EKF (or UKF, per ``config.estimator``) of x = (q (4), w (3) rad/s, phi (6)).

    config : FilterConfig. x0 (13,), P0 (13, 13): the start (phi the log-Cholesky inertia of
    estimation/inertia_param.py). The mean is integrated with RK4 in steps of at most
    config.dt; the covariance is propagated once per update (EKF) or from the sigma points (UKF).
    """

    def __init__(self, config: FilterConfig, x0, P0):
        self.config = config
        self._cfg = config.record()
        self.x = np.array(x0, dtype=float)
        self.P = np.array(P0, dtype=float)
        if self.x.shape != (13,) or self.P.shape != (13, 13):
            raise ConfigError(f"x0 must have shape (13,) and P0 (13, 13), got {self.x.shape}, "
                              f"{self.P.shape}")
        if not (np.all(np.isfinite(self.x)) and np.all(np.isfinite(self.P))):
            raise ConfigError("x0 and P0 must be finite")
        self.x[:4] /= np.linalg.norm(self.x[:4])
        self.P = 0.5 * (self.P + self.P.T)
        self.x_prior, self.P_prior = self.x.copy(), self.P.copy()
        self.y = np.zeros(0)
        self.S = np.zeros((0, 0))
        self.nis = math.nan
        self.n_updates = 0
        self._ukf = config.estimator == "ukf"
        self._phi_top = np.eye(7, 13)
        self._cov_work = np.empty((14, 13))
        self._dist = np.zeros(DISTURBANCE_SIZE)
        n_sigma = ukf.N_SIGMA if self._ukf else 0
        self._sigma = np.empty((n_sigma, 13))
        self._sigma_inertia = np.empty((n_sigma, 3, 3))
        self._sigma_inertia_inv = np.empty((n_sigma, 3, 3))
        self._refresh()

    @property
    def measurement_size(self) -> int:
        """Length of z: 3 (gyro) + 4 (quaternion, if used) + 6 (vector sensors, if used)."""
        return int(sensors.measurement_size(self._cfg))

    @property
    def inertia(self) -> np.ndarray:
        """Current inertia estimate (3, 3), kg·m²."""
        return inertia_from_phi(self.x[7:13])

    @property
    def theta(self) -> np.ndarray:
        """Current theta (6,) = (Jxx, Jxy, Jxz, Jyy, Jyz, Jzz), kg·m²."""
        return theta_from_phi(self.x[7:13])

    @property
    def theta_cov(self) -> np.ndarray:
        """Covariance of theta (6, 6) by the delta method, D P_phi D^T."""
        d = dtheta_dphi(self.x[7:13])
        return d @ self.P[7:13, 7:13] @ d.T

    def _refresh(self) -> None:
        self._inertia = inertia_from_phi(self.x[7:13])
        self._inertia_inv = inv3(self._inertia)
        if self._ukf and not ukf.draw_sigma_points(self.x, self.P, self._sigma, self._sigma_inertia,
                                                   self._sigma_inertia_inv):
            raise EstimatorDivergedError("the filter's covariance is not positive definite")

    def predict(self, dt: float, tau=None, h=None, h_dot=None) -> None:
        """Advance the estimate by dt s under torque tau (3,) N·m and internal momentum h (3,)
        kg·m²/s changing at h_dot (3,) N·m (all held over dt; None: zero).
        """
        if not (math.isfinite(dt) and dt >= 0):
            raise ConfigError(f"dt must be a finite number >= 0, got {dt}")
        tau = np.zeros(3) if tau is None else np.asarray(tau, dtype=float)
        self._dist[:] = 0.0
        if h is not None:
            self._dist[3:6] = h
        if h_dot is not None:
            self._dist[0:3] = -np.asarray(h_dot, dtype=float)
        n = max(1, int(math.ceil(dt / self.config.dt - 1e-9))) if dt > 0 else 0
        step = dt / n if n else 0.0
        try:
            for _ in range(n):
                if self._ukf:
                    ukf.predict_sigma_points(self._sigma, self._sigma_inertia,
                                             self._sigma_inertia_inv, tau, step, self._dist)
                    ukf.sigma_mean(self._sigma, self.x)
                else:
                    ekf.ekf_predict_step(self.x, tau, step, self._inertia, self._inertia_inv,
                                         self._phi_top, self._dist)
        except ZeroDivisionError as exc:  # a degenerate sigma point or quaternion
            raise EstimatorDivergedError(f"the filter's prediction failed: {exc}") from exc
        if not np.all(np.isfinite(self.x)):
            raise EstimatorDivergedError("the filter's prediction is not finite")

    def update(self, z) -> float:
        """Take one measurement z (measurement_size,); returns the NIS. Raises
        EstimatorDivergedError when the estimate leaves its domain.
        """
        z = np.array(z, dtype=float)
        if z.shape != (self.measurement_size,) or not np.all(np.isfinite(z)):
            raise ConfigError(f"z must be {self.measurement_size} finite numbers, got {z.tolist()}")
        if self._ukf:
            self.P[:, :] = ukf.sigma_covariance(self._sigma, self.x, self.n_updates, self._cfg)
        if not ekf.state_is_sane(self.x, self.P):
            raise EstimatorDivergedError("the filter's estimate is not finite")
        if not self._ukf:
            ekf.propagate_covariance(self.P, self._phi_top, self.x, self.n_updates, self._cfg,
                                     self._cov_work)
        self._phi_top[:, :] = np.eye(7, 13)
        self.x_prior, self.P_prior = self.x.copy(), self.P.copy()
        sensors.align_quaternion_sign(z, self.x, self._cfg)
        h, big_h = sensors.measurement_model(self.x, self._cfg)
        self.y = z - h
        self.S = big_h @ self.P @ big_h.T + np.diag(sensors.measurement_noise(self._cfg))
        try:
            self.nis = float(ekf.ekf_update(self.x, self.P, z, self._cfg))
        except Exception as exc:  # a failed factorisation inside the compiled update
            raise EstimatorDivergedError(f"the filter's update failed: {exc}") from exc
        self.n_updates += 1
        if not ekf.state_is_sane(self.x, self.P):
            raise EstimatorDivergedError("the filter's estimate is not finite")
        self._refresh()
        return self.nis


#: Start uncertainty of the filter's inertia (standard deviation of each log-Cholesky parameter).
FILTER_START_SIGMA = 0.3


def filter_config_for(rec, sigma_w, estimator: str, trace: float) -> FilterConfig:
    """The paper's filter sized to a recording: integration step from the sampling and the
    rate, noise from the sensors, process noise scaled like the paper's (Q_omega ~ sigma_w^2,
    Q_quat = sigma_q^2, Q_theta relative to the inertia's size).
    """
    dt_rows = float(np.median(np.diff(rec.t)))
    peak = float(np.max(np.linalg.norm(rec.w, axis=1)))
    quat_sigma = float(rec.meta.get("quat_sigma", 0.01) or 0.01)
    gyro = float(np.mean(sigma_w))
    return FilterConfig(
        dt=min(dt_rows, MAX_ROTATION_PER_STEP / max(peak, 1e-12)), gyro_sigma=gyro,
        quat_sigma=quat_sigma, Q_quat=quat_sigma ** 2, Q_omega=1.1 * gyro ** 2,
        Q_theta=PAPER_Q_THETA * (trace / PAPER_GUESS_TRACE) ** 2, use_quat=rec.q is not None,
        estimator=estimator)


#: The paper's Q_theta (kg·m²)² for its guess of trace 430 kg·m²: scaled by (trace / 430)².
PAPER_Q_THETA, PAPER_GUESS_TRACE = 5e-2, 430.0


@dataclasses.dataclass(frozen=True)
class FilterRun:
    """One pass of the paper's filter over a recording: phi (6,) its final inertia (the nearest
    body's where it ended beyond the triangle inequality), cov_phi (6, 6) the filter's own
    covariance (widened by any such move), e_w (n, 3) rad/s its gyro innovations (the first row
    is the start), notes.
    """

    phi: np.ndarray
    cov_phi: np.ndarray
    e_w: np.ndarray
    notes: tuple[str, ...]


def run_over_recording(rec, t, tau, h, phi0, sigma_w, estimator: str, fix_scale: bool) -> FilterRun:
    """The paper's EKF or UKF run once over the rows of rec (t (n,) s from 0, tau (n, 3) N·m,
    h (n, 3) kg·m²/s), started from phi0 (6,) with FILTER_START_SIGMA on each log-Cholesky
    parameter (the scale held where the record cannot fix it) and the first row's rate.
    """
    trace = float(TRACE_WEIGHTS @ theta_from_phi(phi0))
    cfg = filter_config_for(rec, sigma_w, estimator, trace)
    x0 = np.r_[rec.q[0] if rec.q is not None else [1.0, 0, 0, 0], rec.w[0], phi0]
    p0 = np.zeros((13, 13))
    p0[:4, :4] = np.eye(4) * (3 * cfg.quat_sigma) ** 2  # unobserved (and harmless) without q
    p0[4:7, 4:7] = np.eye(3) * (3 * cfg.gyro_sigma) ** 2
    p0[7:, 7:] = np.eye(6) * FILTER_START_SIGMA ** 2
    if fix_scale:
        p0[7, 7] = 0.0  # torque-free data cannot move the scale: keep it at the start's
    filt = InertiaFilter(cfg, x0, p0)
    e_w = np.zeros_like(rec.w)  # the first row is the start, not a prediction
    try:
        for k in range(1, t.size):
            dt = t[k] - t[k - 1]
            filt.predict(dt, tau[k - 1], 0.5 * (h[k - 1] + h[k]), (h[k] - h[k - 1]) / dt)
            filt.update(rec.w[k] if rec.q is None else np.r_[rec.w[k], rec.q[k]])
            e_w[k] = filt.y[:3]
    except EstimatorDivergedError as exc:
        raise RecordingError(f"{rec.name}: the {estimator} diverged on this recording ({exc}); "
                             "try --method ml") from exc
    notes = [f"{estimator.upper()} over {t.size} rows, final NIS {filt.nis:.3g}; its covariance is "
             "the filter's own (process noise included), not a likelihood bound"]
    phi, cov_phi, beyond = realizable_estimate(filt.x[7:13], filt.P[7:13, 7:13].copy(), fix_scale)
    notes += [beyond] if beyond else []
    return FilterRun(phi, cov_phi, e_w, tuple(notes))


def realizable_estimate(phi, cov, scale_fixed: bool) -> tuple[np.ndarray, np.ndarray, str | None]:
    """A filter's final inertia phi (6,) (log-Cholesky) with its covariance cov (6, 6), and,
    where no body has J(phi) (the largest principal moment above the sum of the other two), the
    note that says so: phi is then replaced by the nearest inertia a body can have
    (inertia_param.realizable_phi, the principal axes kept; the scale coordinate kept where the
    data do not fix it), and the shift s it moved is added to the covariance, cov + s s^T (the
    mean square error about the projected estimate: its intervals reach back to the filter's
    own). The filter itself runs unconstrained, as in the paper; this is the estimate projection
    of constrained Kalman filtering: on a nearly flat body the filter's mean can cross the limit
    while the estimate it carries is usable.
    """
    phi, cov = np.asarray(phi, dtype=float), np.asarray(cov, dtype=float)
    moments = np.linalg.eigvalsh(inertia_from_phi(phi))
    excess = (moments[2] - moments[0] - moments[1]) / moments[2]
    if not excess > REALIZABLE_TOLERANCE:
        return phi, cov, None
    projected = realizable_phi(phi, keep_scale=scale_fixed)
    shift = phi - projected
    moved = np.linalg.eigvalsh(inertia_from_phi(projected))
    return projected, cov + np.outer(shift, shift), (
        f"the filter's estimate has principal moments {np.array2string(moments, precision=4)}: the "
        f"largest exceeds the sum of the other two by {100 * excess:.2g} % of it, which no body "
        f"does; reported is the nearest inertia a body can have (a flat plate's, axes kept: "
        f"{np.array2string(moved, precision=4)}), its intervals widened by the distance it moved. "
        "A filter ending this far outside often means the model leaves physics out: compare "
        "--method ml, or run diagnose on the recording")
