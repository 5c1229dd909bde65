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

import math

import numpy as np

from inertia_gym import sensors
from inertia_gym.dynamics import DISTURBANCE_SIZE, inv3
from inertia_gym.errors import ConfigError, EstimatorDivergedError
from inertia_gym.estimation import ekf, ukf
from inertia_gym.estimation.config import FilterConfig
from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_from_phi, theta_from_phi


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
