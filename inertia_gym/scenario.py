"""Scenario: every physical and estimator constant of one experiment, validated at the boundary.

The defaults are the paper's simulation section (Basu & Sanfelice). A user overrides any field
from a TOML or JSON file (`Scenario.load`) or a mapping (`Scenario.from_mapping`). Every choice the
paper leaves open is a field here, with the value we chose and why in its comment.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from inertia_gym.errors import ConfigError

PAPER_INERTIA = ((100.0, 6.0, -4.0), (6.0, 80.0, 3.0), (-4.0, 3.0, 70.0))
PAPER_GUESS = ((85.0, 0.0, 0.0), (0.0, 135.0, 0.0), (0.0, 0.0, 210.0))


def _matrix3(name: str, value: Any, *, spd: bool) -> tuple[tuple[float, ...], ...]:
    arr = _finite_array(name, value)
    if arr.shape != (3, 3):
        raise ConfigError(f"{name} must be a 3x3 matrix, got shape {arr.shape}")
    if spd:
        if not np.allclose(arr, arr.T, rtol=1e-9, atol=1e-12 * np.abs(arr).max()):
            raise ConfigError(f"{name} must be symmetric, got {arr.tolist()}")
        eig = np.linalg.eigvalsh(arr)
        if eig.min() <= 0:
            raise ConfigError(
                f"{name} must be positive definite, its eigenvalues are {eig.tolist()}"
            )
    return tuple(tuple(float(x) for x in row) for row in arr)


def _finite_array(name: str, value: Any) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{name} must be numeric, got {value!r}") from exc
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite, got {np.asarray(value).tolist()}")
    return arr


def _vector(name: str, value: Any, size: int) -> tuple[float, ...]:
    arr = _finite_array(name, value)
    if arr.shape != (size,):
        raise ConfigError(f"{name} must have {size} components, got shape {arr.shape}")
    return tuple(float(x) for x in arr)


def _positive(name: str, value: Any, *, allow_zero: bool = False) -> float:
    arr = _finite_array(name, value)
    if arr.shape != ():
        raise ConfigError(f"{name} must be a scalar, got shape {arr.shape}")
    x = float(arr)
    if x < 0 or (x == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{name} must be {bound}, got {x}")
    return x


def _interval(name: str, value: Any, *, allow_zero: bool = False) -> tuple[float, float]:
    lo, hi = _vector(name, value, 2)
    if lo < 0 or (lo == 0 and not allow_zero) or hi < lo:
        raise ConfigError(f"{name} must be [min, max] with 0 < min <= max, got [{lo}, {hi}]")
    return lo, hi


def _p0_theta(value: Any) -> tuple[tuple[float, ...], ...]:
    arr = _finite_array("P0_theta", value)
    if arr.shape == ():
        arr = float(arr) * np.eye(6)
    elif arr.shape == (6,):
        arr = np.diag(arr)
    if arr.shape != (6, 6):
        raise ConfigError(f"P0_theta must be a scalar, 6 variances or a 6x6 matrix, got {arr.shape}")
    return _matrix6("P0_theta", arr)


def _matrix6(name: str, arr: np.ndarray) -> tuple[tuple[float, ...], ...]:
    if not np.allclose(arr, arr.T) or np.linalg.eigvalsh(arr).min() <= 0:
        raise ConfigError(f"{name} must be symmetric positive definite")
    return tuple(tuple(float(x) for x in row) for row in arr)


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One experiment: truth, sensors, actuator limits, schedule, estimator and metric constants.

    Units: inertia kg·m², rates rad/s, torques N·m, times s. Matrices are nested tuples so the
    dataclass stays hashable and frozen; use the ``*_array`` properties for numpy views.
    """

    # --- truth -------------------------------------------------------------------------------
    inertia_true: tuple = PAPER_INERTIA
    omega0: tuple = (0.5, 10.0, 0.45)
    # Roll, pitch, yaw in degrees, composed as q = qz(yaw) * qy(pitch) * qx(roll) (ZYX).
    attitude0_euler_deg: tuple = (0.92, 0.0, 0.5)
    dt: float = 0.01
    # --- sensors -----------------------------------------------------------------------------
    gyro_sigma: float = 3e-2
    quat_sigma: float = 1e-2
    meas_interval: tuple = (0.10, 0.20)
    # Optional eqs. (4)-(5): body-frame gravity and magnetic field vectors (inertial-frame
    # references below), each with its own noise sigma. Off by default, as in the paper's runs.
    use_vector_sensors: bool = False
    gravity_inertial: tuple = (0.0, 0.0, -9.81)
    mag_inertial: tuple = (0.2, 0.0, 0.45)
    accel_sigma: float = 0.05
    mag_sigma: float = 0.01
    # --- actuator and schedule ---------------------------------------------------------------
    tau_max: float = 5.0
    bursts_per_episode: int = 4
    dwell: tuple = (5.0, 20.0)
    t_on: tuple = (0.05, 1.0)
    # Bounds of a and b. None means the paper's formula: a in [0, tau_max/omega_ref] with
    # omega_ref = max(|omega0|, 1e-3), b in [0, tau_max]. The paper's reported xi* lies outside
    # those bounds (a = 3.76 > 0.5): pass explicit bounds to search wider.
    a_bounds: tuple | None = None
    b_bounds: tuple | None = None
    # Long-horizon validation: bursts of T_on separated by coasts drawn from this interval.
    validation_coast: tuple = (90.0, 100.0)
    # --- estimator ---------------------------------------------------------------------------
    estimator: str = "ekf"  # "ekf" or "ukf"
    inertia_guess: tuple = PAPER_GUESS
    P0_theta: tuple = tuple(tuple(15000.0 if i == j else 0.0 for j in range(6)) for i in range(6))
    P0_attitude_rate: float = 1e-2  # variance of each of the 7 (q, omega) components
    # Q_k = alpha_k * blkdiag(Qbar, Q_theta); Qbar = blkdiag(1e-3 I3 (omega), 1e-4 I4 (q)).
    # The paper's I3/I4 sizes pair 1e-3 with omega and 1e-4 with q. Q is added once per
    # measurement update (the filter's step), and k counts measurement updates.
    Q_omega: float = 1e-3
    Q_quat: float = 1e-4
    Q_theta: float = 5e-2
    alpha_gamma: float = 0.99
    alpha_qmin: float = 1e-6
    # Covariance inflation when an innovation is inconsistent: NIS > nis_gate * dim(z) inflates
    # the prior covariance (0 disables). Needed from the paper's start, see estimation/ekf.py.
    nis_gate: float = 10.0
    # Largest relative change of J one update may make (damped gain, Joseph form keeps the
    # covariance exact for it); 0 disables. See estimation/ekf.py:limit_inertia_step.
    inertia_step_limit: float = 0.05
    # --- information metric ------------------------------------------------------------------
    epsilon: float = 1e-8  # regularisation of the windowed Gram, eq. (14)
    epsilon_lambda: float = 1e-8  # floor inside the log of eq. (15)
    softmin_beta: float = 1.0  # beta of the soft-min, eq. (24)
    # Which windows enter the soft-min: "burst" (windows that overlap a torque burst) or
    # "episode" (every window of the episode). Torque-free windows carry no information on
    # the inertia's scale by construction (Psi(w, w_dot) theta_hat = 0 there), so "episode"
    # mostly measures how long the coasts are.
    window_set: str = "burst"

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "inertia_true", _matrix3("inertia_true", self.inertia_true, spd=True))
        set_(self, "inertia_guess", _matrix3("inertia_guess", self.inertia_guess, spd=True))
        set_(self, "omega0", _vector("omega0", self.omega0, 3))
        set_(self, "attitude0_euler_deg", _vector("attitude0_euler_deg", self.attitude0_euler_deg, 3))
        set_(self, "P0_theta", _p0_theta(self.P0_theta))
        for name in ("dt", "gyro_sigma", "quat_sigma", "tau_max", "accel_sigma", "mag_sigma",
                     "P0_attitude_rate", "epsilon", "epsilon_lambda", "softmin_beta"):
            set_(self, name, _positive(name, getattr(self, name)))
        for name in ("Q_omega", "Q_quat", "Q_theta", "alpha_qmin", "nis_gate",
                     "inertia_step_limit"):
            set_(self, name, _positive(name, getattr(self, name), allow_zero=True))
        gamma = _positive("alpha_gamma", self.alpha_gamma, allow_zero=True)
        if gamma > 1:
            raise ConfigError(f"alpha_gamma must lie in [0, 1], got {gamma}")
        set_(self, "alpha_gamma", gamma)
        for name in ("meas_interval", "dwell", "t_on", "validation_coast"):
            set_(self, name, _interval(name, getattr(self, name)))
        for name in ("a_bounds", "b_bounds"):
            if getattr(self, name) is not None:
                set_(self, name, _interval(name, getattr(self, name), allow_zero=True))
        set_(self, "gravity_inertial", _vector("gravity_inertial", self.gravity_inertial, 3))
        set_(self, "mag_inertial", _vector("mag_inertial", self.mag_inertial, 3))
        n = self.bursts_per_episode
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ConfigError(f"bursts_per_episode must be an integer >= 1, got {n!r}")
        if self.estimator not in ("ekf", "ukf"):
            raise ConfigError(f"estimator must be 'ekf' or 'ukf', got {self.estimator!r}")
        if self.window_set not in ("burst", "episode"):
            raise ConfigError(f"window_set must be 'burst' or 'episode', got {self.window_set!r}")
        if self.meas_interval[0] < self.dt:
            raise ConfigError(
                f"meas_interval minimum {self.meas_interval[0]} s is shorter than dt {self.dt} s"
            )
        if self.t_on[0] < self.dt:
            raise ConfigError(f"t_on minimum {self.t_on[0]} s is shorter than dt {self.dt} s")

    # --- derived quantities ------------------------------------------------------------------
    @property
    def inertia_true_array(self) -> np.ndarray:
        """True inertia, shape (3, 3), kg·m²."""
        return np.array(self.inertia_true)

    @property
    def inertia_guess_array(self) -> np.ndarray:
        """Estimator's initial inertia, shape (3, 3), kg·m²."""
        return np.array(self.inertia_guess)

    @property
    def omega_ref(self) -> float:
        """max(|omega0|, 1e-3) in rad/s, the paper's reference rate for the bound of a."""
        return max(float(np.linalg.norm(self.omega0)), 1e-3)

    @property
    def xi_bounds(self) -> np.ndarray:
        """Bounds of xi = (a, b, T_on), shape (2, 3): row 0 lower, row 1 upper."""
        a = self.a_bounds if self.a_bounds is not None else (0.0, self.tau_max / self.omega_ref)
        b = self.b_bounds if self.b_bounds is not None else (0.0, self.tau_max)
        return np.array([[a[0], b[0], self.t_on[0]], [a[1], b[1], self.t_on[1]]])

    def replace(self, **changes: Any) -> "Scenario":
        """Return a copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form (lists instead of tuples)."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "Scenario":
        """Build from a mapping of field overrides; unknown keys raise ConfigError."""
        fields = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - fields)
        if unknown:
            raise ConfigError(f"unknown scenario field(s) {unknown}; known fields: {sorted(fields)}")
        return cls(**dict(data))

    @classmethod
    def load(cls, path: str | Path | None) -> "Scenario":
        """Load overrides from a TOML or JSON file; None gives the paper's scenario."""
        if path is None:
            return cls()
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"scenario file {path} does not exist")
        text = path.read_text()
        try:
            if path.suffix.lower() == ".toml":
                data = tomllib.loads(text)
            else:
                data = json.loads(text)
        except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
            raise ConfigError(f"scenario file {path} is not valid {path.suffix[1:]}: {exc}") from exc
        if not isinstance(data, dict):
            raise ConfigError(f"scenario file {path} must hold a table/object of fields")
        return cls.from_mapping(data)


def steps(duration: float, dt: float) -> int:
    """Number of integration steps of length dt covering duration (rounded), at least 1."""
    return max(1, int(math.floor(duration / dt + 0.5)))
