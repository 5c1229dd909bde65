"""Scenario: every physical and estimator constant of one experiment, validated at the boundary.

The body, actuator and sensors default to the paper's simulation section (Basu & Sanfelice). A
user overrides any field from a TOML or JSON file (`Scenario.load`, which also takes the name of
a scenario shipped in ``inertia_gym/scenarios/``) or a mapping (`Scenario.from_mapping`). Every
choice the paper leaves open is a field here, with the value we chose and why in its comment.

Scale-free defaults: every estimator, metric and schedule constant that carries units defaults to
None and is then derived from the body's own scales (the guess's trace, the torque limit, the
sensor noises, the sampling interval; never the truth, which a user does not know) by the rules
of :func:`derived_defaults`. Each rule is the paper's number times a power of (scale / the paper's
scale), so the paper's scenario gets exactly the paper's numbers and any other body gets the same
non-dimensional filter and metric. ``Scenario.derived`` names the fields that were derived.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
import warnings
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from inertia_gym.errors import ConfigError

PAPER_INERTIA = ((100.0, 6.0, -4.0), (6.0, 80.0, 3.0), (-4.0, 3.0, 70.0))
PAPER_GUESS = ((85.0, 0.0, 0.0), (0.0, 135.0, 0.0), (0.0, 0.0, 210.0))

# The paper's scales, against which the derived defaults are written (derived_defaults).
PAPER_GUESS_TRACE = 430.0  # kg·m², trace(PAPER_GUESS)
PAPER_TAU_MAX = 5.0  # N·m
PAPER_GYRO_SIGMA = 3e-2  # rad/s
PAPER_QUAT_SIGMA = 1e-2  # per quaternion component
PAPER_BURST_TIME = 1.0  # s, the paper's longest burst (T_on upper bound)

#: A guess whose sorted principal moments differ from the truth's by more than this factor is
#: warned about (ScenarioWarning).
GUESS_FACTOR_WARNING = 10.0
#: Largest magnitude of any number in a scenario: its squares and products stay finite.
MAGNITUDE_LIMIT = 1e100
#: Relative tolerance of the triangle inequality on principal moments (a flat plate is exact).
TRIANGLE_TOLERANCE = 1e-6


class ScenarioWarning(UserWarning):
    """A scenario that is valid but implausible (far guess, unidentifiable or too violent torque)."""


#: Folder of the example scenarios shipped with the package (``Scenario.load("cubesat-6u")``).
SHIPPED_SCENARIOS = Path(__file__).parent / "scenarios"


def _inertia(name: str, value: Any) -> tuple[tuple[float, ...], ...]:
    """A physical inertia (3, 3) kg·m²: symmetric, positive definite, and its principal moments
    obey the triangle inequality (each at most the sum of the other two, TRIANGLE_TOLERANCE).
    """
    arr = _finite_array(name, value)
    if arr.shape != (3, 3):
        raise ConfigError(f"{name} must be a 3x3 matrix, got shape {arr.shape}")
    if not np.allclose(arr, arr.T, rtol=1e-9, atol=1e-12 * np.abs(arr).max()):
        raise ConfigError(f"{name} must be symmetric, got {arr.tolist()}")
    moments = np.linalg.eigvalsh(0.5 * (arr + arr.T))
    if moments.min() <= 0:
        raise ConfigError(f"{name} must be positive definite, its eigenvalues are {moments.tolist()}")
    if moments[2] > (moments[0] + moments[1]) * (1.0 + TRIANGLE_TOLERANCE):
        raise ConfigError(
            f"{name} is not a rigid body's inertia: its principal moments {_fmt(moments)} kg·m² "
            f"break the triangle inequality ({moments[2]:.6g} > {moments[0]:.6g} + {moments[1]:.6g})"
        )
    return tuple(tuple(float(x) for x in row) for row in arr)


def _fmt(values) -> str:
    return "[" + ", ".join(f"{x:.6g}" for x in values) + "]"


def _finite_array(name: str, value: Any) -> np.ndarray:
    """The value as a float array; ConfigError for text, booleans, ragged or non-finite input."""
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as exc:  # ragged nested lists
        raise ConfigError(f"{name} must be numeric, got {value!r}") from exc
    if raw.dtype.kind not in "iuf":
        raise ConfigError(f"{name} must be numeric (a number or a list of numbers), got {value!r}")
    arr = raw.astype(float)
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite, got {raw.tolist()}")
    if np.any(np.abs(arr) > MAGNITUDE_LIMIT):
        raise ConfigError(f"{name} must be at most {MAGNITUDE_LIMIT:g} in magnitude (its products and "
                          f"squares must stay finite), got {raw.tolist()}")
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
        raise ConfigError(f"{name} must be symmetric positive definite, got {arr.tolist()}")
    return tuple(tuple(float(x) for x in row) for row in arr)


def burst_time_scale(guess_trace: float, tau_max: float, gyro_sigma: float,
                     meas_interval_max: float) -> float:
    """T_b (s), the longest default burst, from which every default time of the schedule follows.

    At least five of the longest measurement intervals (a burst the filter sees in several
    readings: the paper's 1 s at 0.1-0.2 s sampling), and long enough that a full burst at
    tau_max moves the rate of the mean principal moment J_m = guess_trace / 3 by one gyro sigma
    (J_m sigma_g / tau_max: 0.86 s for the paper, so its 1 s stands), capped at 100 times the first
    (a torque too weak even then is warned about: ScenarioWarning).
    """
    floor = 5.0 * meas_interval_max
    return min(max(floor, guess_trace / 3.0 * gyro_sigma / tau_max), 100.0 * floor)


def derived_defaults(guess_trace: float, tau_max: float, gyro_sigma: float, quat_sigma: float,
                     dt: float, meas_interval_max: float) -> dict[str, Any]:
    """Every scale-carrying default, from the body's own scales (docs/scenarios.md).

    guess_trace kg·m² (trace of the estimator's initial inertia: the truth is not known to a
    user), tau_max N·m, gyro_sigma rad/s, quat_sigma (quaternion component), dt and
    meas_interval_max s. Each value is the paper's number times a power of (scale / paper's
    scale), so the paper's scales give exactly the paper's numbers:

    - P0_theta, Q_theta (kg·m²)^2 scale with (trace)^2: the prior and the random walk of the
      inertia are the same fractions of the body's size (prior sigma 0.28 of the trace).
    - Q_omega (rad/s)^2 with gyro_sigma^2 and Q_quat with quat_sigma^2: process noise keeps the
      paper's ratio to the measurement noise it competes with (1.11 and 1).
    - P0_attitude_rate: 1e-2 times the larger of (gyro_sigma/0.03)^2 and (quat_sigma/0.01)^2, the
      paper's prior on the first reading, wide against both sensors.
    - epsilon, epsilon_lambda ((rad/s^2)^2, the Gram's units) with (tau_max / trace)^2 and
      softmin_beta with its inverse: the smallest eigenvalue the metric scores is the scale
      direction's, excited only by the torque (Psi theta = tau), so it scales as (tau/J)^2.
    - t_on = [5 dt (the metric's shortest window, N_T >= 5 samples), T_b]; dwell = [5, 20] T_b
      and validation_coast = [90, 100] T_b, T_b from burst_time_scale (1 s for the paper).
    """
    inertia = guess_trace / PAPER_GUESS_TRACE
    gyro = gyro_sigma / PAPER_GYRO_SIGMA
    quat = quat_sigma / PAPER_QUAT_SIGMA
    accel = (tau_max / PAPER_TAU_MAX) / inertia
    t_b = burst_time_scale(guess_trace, tau_max, gyro_sigma, meas_interval_max)
    times = t_b / PAPER_BURST_TIME
    return {
        "P0_theta": 15000.0 * inertia ** 2,
        "Q_theta": 5e-2 * inertia ** 2,
        "Q_omega": 1e-3 * gyro ** 2,
        "Q_quat": 1e-4 * quat ** 2,
        "P0_attitude_rate": 1e-2 * max(gyro, quat) ** 2,
        "epsilon": 1e-8 * accel ** 2,
        "epsilon_lambda": 1e-8 * accel ** 2,
        "softmin_beta": 1.0 / accel ** 2,
        "t_on": (5.0 * dt, t_b),
        "dwell": (5.0 * times, 20.0 * times),
        "validation_coast": (90.0 * times, 100.0 * times),
    }


#: The mission limits: None means unlimited.
LIMIT_FIELDS = ("impulse_budget", "rate_limit", "min_impulse_bit")
#: Fields that default to None and are then derived (derived_defaults).
DERIVED_FIELDS = ("P0_theta", "Q_theta", "Q_omega", "Q_quat", "P0_attitude_rate", "epsilon",
                  "epsilon_lambda", "softmin_beta", "t_on", "dwell", "validation_coast")


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One experiment: truth, sensors, actuator limits, schedule, estimator and metric constants.

    Units: inertia kg·m², rates rad/s, torques N·m, times s. Matrices are nested tuples so the
    dataclass stays hashable and frozen; use the ``*_array`` properties for numpy views. Fields
    left at None are derived from the body's scales (derived_defaults; ``derived`` lists them);
    after construction every field holds a number.
    """

    # --- truth -------------------------------------------------------------------------------
    inertia_true: tuple = PAPER_INERTIA
    omega0: tuple = (0.5, 10.0, 0.45)
    # Roll, pitch, yaw in degrees, composed as q = qz(yaw) * qy(pitch) * qx(roll) (ZYX).
    attitude0_euler_deg: tuple = (0.92, 0.0, 0.5)
    dt: float = 0.01
    # --- sensors -----------------------------------------------------------------------------
    gyro_sigma: float = PAPER_GYRO_SIGMA
    quat_sigma: float = PAPER_QUAT_SIGMA
    meas_interval: tuple = (0.10, 0.20)
    # Optional eqs. (4)-(5): body-frame gravity and magnetic field vectors (inertial-frame
    # references below), each with its own noise sigma. Off by default, as in the paper's runs.
    use_vector_sensors: bool = False
    gravity_inertial: tuple = (0.0, 0.0, -9.81)
    mag_inertial: tuple = (0.2, 0.0, 0.45)
    accel_sigma: float = 0.05
    mag_sigma: float = 0.01
    # --- actuator and schedule ---------------------------------------------------------------
    tau_max: float = PAPER_TAU_MAX
    bursts_per_episode: int = 4
    # None: [5, 20] T_b (burst_time_scale; the paper's 5-20 s).
    dwell: tuple | None = None
    # None: [5 dt, T_b] (the paper's 0.05-1 s).
    t_on: tuple | None = None
    # Bounds of a and b. None means the paper's formula: a in [0, tau_max/omega_ref] with
    # omega_ref = max(|omega0|, the rate one full burst gives the mean moment), b in
    # [0, tau_max]. The paper's reported xi* lies outside those bounds (a = 3.76 > 0.5): pass
    # explicit bounds to search wider.
    a_bounds: tuple | None = None
    b_bounds: tuple | None = None
    # Mission limits per episode (None: unlimited). impulse_budget N·m·s bounds the 1-norm
    # impulse sum_i integral |tau_i| dt: each body axis is torqued by its own actuator pair
    # (the per-axis saturation above), so the 1-norm is what the pairs spend together, like a
    # thruster set's propellant. The actuator stops when an episode has spent it (the last step
    # is scaled to spend it exactly). rate_limit rad/s: a safety monitor inhibits the rest of a
    # burst once the filter's rate estimate |w_hat| reaches it (the flight software acts on what
    # it knows; the true peak rate is reported beside it).
    # min_impulse_bit N·m·s: an axis's pulse that would deliver less does not fire.
    impulse_budget: float | None = None
    rate_limit: float | None = None
    min_impulse_bit: float | None = None
    # Long-horizon validation: bursts of T_on separated by coasts drawn from this interval.
    # None: [90, 100] T_b (the paper's 90-100 s).
    validation_coast: tuple | None = None
    # --- estimator ---------------------------------------------------------------------------
    estimator: str = "ekf"  # "ekf" or "ukf"
    inertia_guess: tuple = PAPER_GUESS
    # Prior of theta (kg·m²)²: a scalar, 6 variances or 6x6. None: 15000 (trace/430)^2 I6.
    P0_theta: Any = None
    # Variance of each of the 7 (q, omega) components. None: 1e-2 max(gyro/0.03, quat/0.01)^2.
    P0_attitude_rate: float | None = None
    # Q_k = alpha_k * blkdiag(Qbar, Q_theta); Qbar = blkdiag(1e-3 I3 (omega), 1e-4 I4 (q)).
    # The paper's I3/I4 sizes pair 1e-3 with omega and 1e-4 with q. Q is added once per
    # measurement update (the filter's step), and k counts measurement updates.
    # None: Q_omega = 1e-3 (gyro_sigma/0.03)^2, Q_quat = 1e-4 (quat_sigma/0.01)^2,
    # Q_theta = 5e-2 (trace(inertia_guess)/430)^2 (the paper's values for the paper's body).
    Q_omega: float | None = None
    Q_quat: float | None = None
    Q_theta: float | None = None
    alpha_gamma: float = 0.99
    alpha_qmin: float = 1e-6  # dimensionless floor of alpha_k (a fraction of Q)
    # Covariance inflation when an innovation is inconsistent: NIS > nis_gate * dim(z) inflates
    # the prior covariance (0 disables). Needed from the paper's start, see estimation/ekf.py.
    nis_gate: float = 10.0
    # Largest relative change of J one update may make (damped gain, Joseph form keeps the
    # covariance exact for it); 0 disables. See estimation/ekf.py:limit_inertia_step.
    inertia_step_limit: float = 0.05
    # --- information metric ------------------------------------------------------------------
    # In the Gram's units (rad/s^2)^2. None: 1e-8 ((tau_max/5) / (trace/430))^2 each, and
    # softmin_beta = 1 / that ratio squared (the paper's 1e-8, 1e-8 and 1 for its body).
    epsilon: float | None = None  # regularisation of the windowed Gram, eq. (14)
    epsilon_lambda: float | None = None  # floor inside the log of eq. (15)
    softmin_beta: float | None = None  # beta of the soft-min, eq. (24)
    # Which windows enter the soft-min: "burst" (windows that overlap a torque burst) or
    # "episode" (every window of the episode). Torque-free windows carry no information on
    # the inertia's scale by construction (Psi(w, w_dot) theta_hat = 0 there), so "episode"
    # mostly measures how long the coasts are.
    window_set: str = "burst"
    # Names of the fields derived from the body's scales (not an input).
    derived: tuple = dataclasses.field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "inertia_true", _inertia("inertia_true", self.inertia_true))
        set_(self, "inertia_guess", _inertia("inertia_guess", self.inertia_guess))
        set_(self, "omega0", _vector("omega0", self.omega0, 3))
        set_(self, "attitude0_euler_deg", _vector("attitude0_euler_deg", self.attitude0_euler_deg, 3))
        for name in ("dt", "gyro_sigma", "quat_sigma", "tau_max", "accel_sigma", "mag_sigma"):
            set_(self, name, _positive(name, getattr(self, name)))
        set_(self, "meas_interval", _interval("meas_interval", self.meas_interval))
        if self.meas_interval[0] < self.dt:
            raise ConfigError(
                f"meas_interval minimum {self.meas_interval[0]} s is shorter than dt {self.dt} s"
            )
        rules = derived_defaults(self.guess_trace, self.tau_max, self.gyro_sigma, self.quat_sigma,
                                 self.dt, self.meas_interval[1])
        derived = tuple(name for name in DERIVED_FIELDS if getattr(self, name) is None)
        for name in derived:
            set_(self, name, rules[name])
        set_(self, "derived", derived)
        set_(self, "P0_theta", _p0_theta(self.P0_theta))
        for name in ("P0_attitude_rate", "epsilon", "epsilon_lambda", "softmin_beta"):
            set_(self, name, _positive(name, getattr(self, name)))
        for name in ("Q_omega", "Q_quat", "Q_theta", "alpha_qmin", "nis_gate",
                     "inertia_step_limit"):
            set_(self, name, _positive(name, getattr(self, name), allow_zero=True))
        gamma = _positive("alpha_gamma", self.alpha_gamma, allow_zero=True)
        if gamma > 1:
            raise ConfigError(f"alpha_gamma must lie in [0, 1], got {gamma}")
        set_(self, "alpha_gamma", gamma)
        for name in ("dwell", "t_on", "validation_coast"):
            set_(self, name, _interval(name, getattr(self, name)))
        for name in LIMIT_FIELDS:
            if getattr(self, name) is not None:
                set_(self, name, _positive(name, getattr(self, name)))
        for name in ("a_bounds", "b_bounds"):
            if getattr(self, name) is not None:
                set_(self, name, _interval(name, getattr(self, name), allow_zero=True))
        set_(self, "gravity_inertial", _vector("gravity_inertial", self.gravity_inertial, 3))
        set_(self, "mag_inertial", _vector("mag_inertial", self.mag_inertial, 3))
        n = self.bursts_per_episode
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ConfigError(f"bursts_per_episode must be an integer >= 1, got {n!r}")
        if not isinstance(self.use_vector_sensors, (bool, np.bool_)):
            raise ConfigError(f"use_vector_sensors must be true or false, got {self.use_vector_sensors!r}")
        if not isinstance(self.estimator, str) or self.estimator not in ("ekf", "ukf"):
            raise ConfigError(f"estimator must be 'ekf' or 'ukf', got {self.estimator!r}")
        if not isinstance(self.window_set, str) or self.window_set not in ("burst", "episode"):
            raise ConfigError(f"window_set must be 'burst' or 'episode', got {self.window_set!r}")
        if self.t_on[0] < self.dt:
            raise ConfigError(f"t_on minimum {self.t_on[0]} s is shorter than dt {self.dt} s")
        for message in self.implausibilities():
            warnings.warn(message, ScenarioWarning, stacklevel=3)

    def implausibilities(self) -> list[str]:
        """Why this valid scenario looks physically implausible (empty when it does not).

        The guess's sorted principal moments differ from the truth's by more than
        GUESS_FACTOR_WARNING; the longest burst at tau_max moves the rate of the guessed mean
        moment by less than a tenth of gyro_sigma (the scale cannot be identified); or the rate
        after an episode of full bursts turns the body by more than 0.5 rad per step dt (the
        torque is implausible for the inertia, or dt too coarse); or a mission limit leaves no
        room to excite (rate_limit at or below |omega0|, impulse_budget under one step of one
        axis at tau_max, min_impulse_bit above the longest burst at tau_max).
        """
        out = []
        truth = np.linalg.eigvalsh(self.inertia_true_array)
        guess = np.linalg.eigvalsh(self.inertia_guess_array)
        ratio = guess / truth
        factor = max(ratio.max(), 1.0 / ratio.min())
        if factor > GUESS_FACTOR_WARNING:
            out.append(f"inertia_guess's principal moments {_fmt(guess)} kg·m² are off the "
                       f"inertia_true's {_fmt(truth)} by a factor up to {factor:.3g} (more than "
                       f"{GUESS_FACTOR_WARNING:g}): is the guess for this body?")
        kick = self.tau_max * self.t_on[1] / (self.guess_trace / 3.0)
        if kick < 0.1 * self.gyro_sigma:
            out.append(f"a full burst (tau_max {self.tau_max:.3g} N·m for t_on {self.t_on[1]:.3g} s) "
                       f"changes the guessed body's rate by {kick:.3g} rad/s, under a tenth of "
                       f"gyro_sigma {self.gyro_sigma:.3g} rad/s: the inertia's scale will not be identified")
        fastest = float(np.linalg.norm(self.omega0)) + self.bursts_per_episode * kick
        if fastest * self.dt > 0.5:
            out.append(f"the rate after an episode of full bursts, up to {fastest:.3g} rad/s, turns "
                       f"the body {fastest * self.dt:.3g} rad per dt = {self.dt:.3g} s (over 0.5): "
                       "tau_max is implausible for this inertia, or dt too coarse")
        rate0 = float(np.linalg.norm(self.omega0))
        if self.rate_limit is not None and self.rate_limit <= rate0:
            out.append(f"rate_limit {self.rate_limit:.3g} rad/s is at or below the starting rate "
                       f"|omega0| = {rate0:.3g} rad/s: the safety monitor inhibits every burst")
        if self.impulse_budget is not None and self.impulse_budget < self.tau_max * self.dt:
            out.append(f"impulse_budget {self.impulse_budget:.3g} N·m·s is less than one step of "
                       f"one axis at tau_max ({self.tau_max * self.dt:.3g} N·m·s): the bursts "
                       "can barely fire")
        if self.min_impulse_bit is not None and self.min_impulse_bit > self.tau_max * self.t_on[1]:
            out.append(f"min_impulse_bit {self.min_impulse_bit:.3g} N·m·s is more than the longest "
                       f"burst at tau_max delivers ({self.tau_max * self.t_on[1]:.3g} N·m·s): "
                       "no burst can fire")
        return out

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
    def guess_trace(self) -> float:
        """trace(inertia_guess) in kg·m², the inertia scale of the derived defaults."""
        return float(np.trace(self.inertia_guess_array))

    @property
    def burst_time(self) -> float:
        """T_b in s (burst_time_scale), the time scale of the derived schedule defaults."""
        return burst_time_scale(self.guess_trace, self.tau_max, self.gyro_sigma, self.meas_interval[1])

    @property
    def omega_ref(self) -> float:
        """Reference rate in rad/s for the bound of a: |omega0| (the paper's), or for a body near
        rest the rate a full burst of T_b at tau_max gives the guessed mean moment.
        """
        return max(float(np.linalg.norm(self.omega0)),
                   self.tau_max * self.burst_time / (self.guess_trace / 3.0))

    @property
    def limited(self) -> bool:
        """True when an impulse budget or a rate limit constrains the episodes."""
        return self.impulse_budget is not None or self.rate_limit is not None

    @property
    def xi_bounds(self) -> np.ndarray:
        """Bounds of xi = (a, b, T_on), shape (2, 3): row 0 lower, row 1 upper."""
        a = self.a_bounds if self.a_bounds is not None else (0.0, self.tau_max / self.omega_ref)
        b = self.b_bounds if self.b_bounds is not None else (0.0, self.tau_max)
        return np.array([[a[0], b[0], self.t_on[0]], [a[1], b[1], self.t_on[1]]])

    def replace(self, **changes: Any) -> "Scenario":
        """Return a copy with some fields changed (validated again). Fields that were derived
        and are not in ``changes`` are derived again from the new scales.
        """
        fields = {f.name: None if f.name in self.derived else getattr(self, f.name)
                  for f in dataclasses.fields(self) if f.init}
        return type(self)(**{**fields, **changes})

    def to_dict(self) -> dict[str, Any]:
        """Plain-JSON form of every input field as used (lists instead of tuples, derived values
        filled in; ``derived`` is not included). The mission limits appear only where set, so a
        scenario without them serialises (and a benchmark's settings key hashes) as it did
        before the limits existed.
        """
        return json.loads(json.dumps({f.name: getattr(self, f.name)
                                      for f in dataclasses.fields(self) if f.init
                                      and not (f.name in LIMIT_FIELDS and getattr(self, f.name) is None)}))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> "Scenario":
        """Build from a mapping of field overrides; unknown keys raise ConfigError."""
        if not isinstance(data, Mapping):
            raise ConfigError(f"a scenario must be a table/mapping of fields, got {type(data).__name__}")
        fields = {f.name for f in dataclasses.fields(cls) if f.init}
        unknown = sorted(str(k) for k in set(data) - fields)
        if unknown:
            raise ConfigError(f"unknown scenario field(s) {unknown}; known fields: {sorted(fields)}")
        return cls(**dict(data))

    @classmethod
    def load(cls, path: str | Path | None) -> "Scenario":
        """Load overrides from a TOML or JSON file, or the name of a shipped scenario
        (shipped_scenarios(): e.g. "cubesat-6u"); None gives the paper's scenario.
        """
        if path is None:
            return cls()
        path = scenario_path(path)
        try:
            text = path.read_text()
            if path.suffix.lower() == ".toml":
                data = tomllib.loads(text)
            else:
                data = json.loads(text)
        except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as exc:
            kind = path.suffix[1:] or "JSON"
            raise ConfigError(f"scenario file {path} is not valid {kind}: {exc}") from exc
        except OSError as exc:
            raise ConfigError(f"scenario file {path} cannot be read: {exc}") from exc
        if not isinstance(data, dict):
            raise ConfigError(f"scenario file {path} must hold a table/object of fields")
        return cls.from_mapping(data)


def shipped_scenarios() -> list[str]:
    """Names of the example scenarios shipped in inertia_gym/scenarios/ (without .toml)."""
    return sorted(p.stem for p in SHIPPED_SCENARIOS.glob("*.toml"))


def scenario_path(path: str | Path) -> Path:
    """The file a --scenario value names: an existing file, else a shipped scenario's name."""
    given = Path(path)
    if given.is_file():
        return given
    shipped = SHIPPED_SCENARIOS / f"{given.name}.toml"
    if given.suffix == "" and given.parent == Path(".") and shipped.is_file():
        return shipped
    raise ConfigError(f"scenario file {given} does not exist (shipped scenarios: "
                      f"{', '.join(shipped_scenarios())})")


def steps(duration: float, dt: float) -> int:
    """Number of integration steps of length dt covering duration (rounded), at least 1."""
    return max(1, int(math.floor(duration / dt + 0.5)))
