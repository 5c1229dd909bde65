"""The filter's configuration: one frozen dataclass, read by the compiled kernels as a record.

``FilterConfig`` names every constant of the EKF/UKF (integration step, sensor noise, process
noise schedule, guards, which sensors are used); ``record()`` packs it into a numpy record of
:data:`FILTER_CONFIG_DTYPE` that numba kernels read by field name (``cfg.gyro_sigma``), so no
kernel takes a flat vector of magic indices.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.errors import ConfigError

FILTER_CONFIG_DTYPE = np.dtype([
    ("dt", np.float64),  # s, integration step of the filter's mean
    ("gyro_sigma", np.float64),  # rad/s
    ("quat_sigma", np.float64),  # per quaternion component
    ("accel_sigma", np.float64),  # gravity-vector sensor, same units as gravity
    ("mag_sigma", np.float64),  # magnetometer, same units as mag_reference
    ("Q_quat", np.float64),  # process noise added per update (scaled by alpha_k)
    ("Q_omega", np.float64),  # (rad/s)^2
    ("Q_theta", np.float64),  # (kg·m²)^2, in theta coordinates
    ("alpha_gamma", np.float64),
    ("alpha_qmin", np.float64),
    ("use_quat", np.float64),  # 1.0: the attitude quaternion is measured
    ("use_vector_sensors", np.float64),  # 1.0: gravity and magnetic vectors are measured
    ("gravity", np.float64, (3,)),  # inertial-frame reference of the gravity sensor
    ("mag_reference", np.float64, (3,)),  # inertial-frame reference of the magnetometer
    ("nis_gate", np.float64),  # NIS > nis_gate * dim(z) inflates the prior (0 disables)
    ("inertia_step_limit", np.float64),  # largest relative change of J per update (0 disables)
    ("ukf", np.float64),  # 1.0: unscented prediction
], align=True)


@dataclasses.dataclass(frozen=True)
class FilterConfig:
    """Every constant of the joint (q, w, phi) filter (units as in the scenario: s, rad/s, kg·m²).

    Q_k = alpha_k blkdiag(Q_quat I4, Q_omega I3, Q_theta I6 in theta), alpha_k = 0.999 gamma^k
    + q_min with k the number of updates; see estimation/ekf.py for the guards.
    """

    dt: float
    gyro_sigma: float
    quat_sigma: float = 0.0
    accel_sigma: float = 0.05
    mag_sigma: float = 0.01
    Q_quat: float = 1e-4
    Q_omega: float = 1e-3
    Q_theta: float = 5e-2
    alpha_gamma: float = 0.99
    alpha_qmin: float = 1e-6
    use_quat: bool = True
    use_vector_sensors: bool = False
    gravity: tuple = (0.0, 0.0, -9.81)
    mag_reference: tuple = (0.2, 0.0, 0.45)
    nis_gate: float = 10.0
    inertia_step_limit: float = 0.05
    estimator: str = "ekf"

    def __post_init__(self) -> None:
        for name in ("dt", "gyro_sigma"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"filter {name} must be a positive number, got {value!r}")
        if self.use_quat and not self.quat_sigma > 0:
            raise ConfigError(f"filter quat_sigma must be > 0 when the attitude is measured, "
                              f"got {self.quat_sigma!r}")
        if self.estimator not in ("ekf", "ukf"):
            raise ConfigError(f"estimator must be 'ekf' or 'ukf', got {self.estimator!r}")

    @classmethod
    def from_scenario(cls, sc) -> "FilterConfig":
        """The filter the scenario describes (inertia_gym.scenario.Scenario)."""
        return cls(
            dt=sc.dt, gyro_sigma=sc.gyro_sigma, quat_sigma=sc.quat_sigma, accel_sigma=sc.accel_sigma,
            mag_sigma=sc.mag_sigma, Q_quat=sc.Q_quat, Q_omega=sc.Q_omega, Q_theta=sc.Q_theta,
            alpha_gamma=sc.alpha_gamma, alpha_qmin=sc.alpha_qmin, use_quat=sc.quat_sigma > 0,
            use_vector_sensors=sc.use_vector_sensors, gravity=tuple(sc.gravity_inertial),
            mag_reference=tuple(sc.mag_inertial), nis_gate=sc.nis_gate,
            inertia_step_limit=sc.inertia_step_limit, estimator=sc.estimator)

    def record(self) -> np.record:
        """The numpy record (FILTER_CONFIG_DTYPE) the compiled kernels read; its fields are
        attributes in Python too (``cfg.gyro_sigma``).
        """
        rec = np.zeros(1, FILTER_CONFIG_DTYPE).view(np.recarray)[0]
        for name in FILTER_CONFIG_DTYPE.names:
            if name == "ukf":
                rec[name] = 1.0 if self.estimator == "ukf" else 0.0
            else:
                rec[name] = getattr(self, name)
        return rec
