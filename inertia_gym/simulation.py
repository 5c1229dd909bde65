"""Closed loop of truth, sensors, estimator and burst law, compiled and batched over runs.

One call to :func:`run_segment` advances B independent runs (seeds) by a segment of time steps:
truth (RK4 at dt, dynamics.py) -> intermittent noisy sensors -> EKF (estimation/ekf.py), with
the torque of eq. (18) computed from the filter's rate at each burst start and held over the
burst. All randomness is drawn beforehand from explicit numpy Generators, so a run is a pure
function of its inputs. Per step it records w_hat and w_dot_hat of eq. (12) for the information
metric; per measurement it records the estimate for plots and validation.

The compiled code here and in the kernels it calls copies arrays element by element: numba
compiles a shape-check error path for each signature of an array assigned into a slice, 2-4 s
of every process's first compile.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import threading

import numba as nb
import numpy as np

from inertia_gym import sensors
from inertia_gym.dynamics import (
    DISTURBANCE_SIZE,
    NO_DISTURBANCE,
    check_rigid_steps,
    disturbance_entries,
    euler_to_quat,
    inv3,
    lane_entries9,
    mat3_entries,
    rk4_lanes,
)
from inertia_gym.errors import ConfigError
from inertia_gym.estimation import ekf, ukf
from inertia_gym.estimation.config import FilterConfig
from inertia_gym.estimation.ekf import N_STATE
from inertia_gym.estimation.inertia_param import (
    decouple_scale,
    dtheta_dphi,
    inertia_from_phi,
    phi_from_inertia,
    theta_from_phi,
    theta_into,
)
from inertia_gym.excitation import burst_torque_into
from inertia_gym.scenario import Scenario

STATUS_OK, STATUS_DIVERGED = 0, 1


def pack_filter_config(sc: Scenario) -> np.void:
    """The filter configuration record the compiled kernels read (estimation/config.py)."""
    return FilterConfig.from_scenario(sc).record()


@dataclasses.dataclass(frozen=True)
class SimState:
    """State of B closed-loop runs between segments (arrays have leading dimension B).

    y_true (B, 7) true (q, w); x (B, 13) filter mean (q, w, phi); P (B, 13, 13) filter covariance
    at the last update; n_updates (B,) filter updates so far; steps_to_meas (B,) steps until the
    next measurement; step (B,) time steps elapsed; diverged (B,) bool. The prediction since the
    last update carries over a segment boundary: phi_top (B, 7, 13) the EKF's transition
    accumulated so far, sigma (B, 26, 13) the UKF's propagated sigma points (sigma_fresh (B,):
    none drawn yet).
    """

    y_true: np.ndarray
    x: np.ndarray
    P: np.ndarray
    n_updates: np.ndarray
    steps_to_meas: np.ndarray
    step: np.ndarray
    diverged: np.ndarray
    phi_top: np.ndarray
    sigma: np.ndarray
    sigma_fresh: np.ndarray

    @property
    def batch(self) -> int:
        """Number of runs B."""
        return self.y_true.shape[0]

    def theta_hat(self) -> np.ndarray:
        """Estimated theta (B, 6) of eq. (8)."""
        return np.array([theta_from_phi(x[7:13]) for x in self.x])

    def inertia_hat(self) -> np.ndarray:
        """Estimated inertia (B, 3, 3), kg·m²."""
        return np.array([inertia_from_phi(x[7:13]) for x in self.x])

    def P_theta(self) -> np.ndarray:
        """Covariance of theta (B, 6, 6) by the delta method, P_theta = D P_phi D^T."""
        out = np.empty((self.batch, 6, 6))
        for b in range(self.batch):
            d = dtheta_dphi(self.x[b, 7:13])
            out[b] = d @ self.P[b, 7:13, 7:13] @ d.T
        return out

    def select(self, index) -> "SimState":
        """Sub-batch (index: int, slice or array)."""
        idx = np.atleast_1d(np.arange(self.batch)[index])
        return SimState(*(getattr(self, f.name)[idx] for f in dataclasses.fields(self)))

    def with_rows(self, index, rows: "SimState") -> "SimState":
        """A copy with the runs at `index` (ints, slice or bool mask) replaced by `rows`."""
        fields = {}
        for f in dataclasses.fields(self):
            merged = getattr(self, f.name).copy()
            merged[index] = getattr(rows, f.name)
            fields[f.name] = merged
        return SimState(**fields)


def _meas_interval_steps(sc: Scenario, rng: np.random.Generator, count: int) -> np.ndarray:
    """``count`` intervals between measurements, in steps (>= 1), from U[meas_interval] s."""
    lo, hi = sc.meas_interval
    return np.maximum(1, np.rint(rng.uniform(lo, hi, size=count) / sc.dt)).astype(np.int64)


def _measurement_schedule(
    sc: Scenario, rng: np.random.Generator, first: int, n_steps: int
) -> tuple[np.ndarray, int]:
    """Steps (from the segment start) of the measurements in [first, n_steps], and the number
    of steps from the segment's end to the next measurement after them.

    One interval is drawn per measurement taken, exactly as drawing them one at a time would
    (the generator ends in the same state); they are drawn as one vector, since a Python loop
    over ~7k draws per 1000 s costs as much as a tenth of the compiled simulation.
    """
    if first > n_steps:
        return np.zeros(0, dtype=np.int64), first - n_steps
    shortest = max(1, int(round(sc.meas_interval[0] / sc.dt)))
    at_most = (n_steps - first) // shortest + 1  # no more measurements fit in the segment
    saved = rng.bit_generator.state
    times = first + np.cumsum(np.r_[0, _meas_interval_steps(sc, rng, at_most)])
    count = int(np.searchsorted(times, n_steps, side="right"))
    rng.bit_generator.state = saved  # draw again, only the intervals actually used
    times = first + np.cumsum(np.r_[0, _meas_interval_steps(sc, rng, count)])
    return times[:count], int(times[count]) - n_steps


def initial_state(sc: Scenario, rngs: list[np.random.Generator]) -> SimState:
    """B runs at the scenario's start; the filter's (q, w) come from a first noisy measurement."""
    q0 = euler_to_quat(sc.attitude0_euler_deg)
    y0 = np.concatenate([q0, sc.omega0])
    phi0 = phi_from_inertia(sc.inertia_guess_array)
    d0_inv = np.linalg.inv(dtheta_dphi(phi0))
    p0 = np.zeros((13, 13))
    p0[:7, :7] = sc.P0_attitude_rate * np.eye(7)
    p0[7:, 7:] = d0_inv @ np.array(sc.P0_theta) @ d0_inv.T
    p0[7:, 7:] = decouple_scale(0.5 * (p0[7:, 7:] + p0[7:, 7:].T))
    batch = len(rngs)
    x = np.empty((batch, 13))
    for b, rng in enumerate(rngs):
        q_meas = q0 + sc.quat_sigma * rng.standard_normal(4)
        x[b, :4] = q_meas / np.linalg.norm(q_meas)
        x[b, 4:7] = np.asarray(sc.omega0) + sc.gyro_sigma * rng.standard_normal(3)
        x[b, 7:] = phi0
    return SimState(
        y_true=np.tile(y0, (batch, 1)),
        x=x,
        P=np.tile(p0, (batch, 1, 1)),
        n_updates=np.zeros(batch, dtype=np.int64),
        steps_to_meas=np.array([_meas_interval_steps(sc, r, 1)[0] for r in rngs], dtype=np.int64),
        step=np.zeros(batch, dtype=np.int64),
        diverged=np.zeros(batch, dtype=bool),
        phi_top=np.tile(np.eye(7, 13), (batch, 1, 1)),
        sigma=np.zeros((batch, ukf.N_SIGMA, 13)),
        sigma_fresh=np.ones(batch, dtype=bool),
    )


@dataclasses.dataclass(frozen=True)
class Trace:
    """What a segment recorded, per run b (arrays padded to the longest run of the batch).

    w_hat, w_dot_hat, tau : (B, n, 3) per step; n_steps (B,).
    meas_step (B, m) step index of each measurement from the run's start; n_meas (B,);
    theta_hat, theta_var (B, m, 6) posterior mean and variance of theta after each update;
    measurements (B, m, 14): the true (q, w) at each measurement, then the gyro reading (3) and
    the quaternion reading (4, NaN without an attitude sensor); w_est (B, m, 3); nis (B, m).
    Mission limits (Scenario.impulse_budget, rate_limit), per run over the segment: impulse (B,)
    N·m·s spent, sum_i integral |tau_i| dt (with impulse_spent); demand (B,) N·m·s the burst law
    asked for in this segment before the limits cut it; rate_peak (B,) the largest true |w| rad/s;
    budget_spent (B,) bool, the budget ran out; rate_cuts (B,) the bursts the rate monitor cut.
    """

    w_hat: np.ndarray
    w_dot_hat: np.ndarray
    tau: np.ndarray
    n_steps: np.ndarray
    meas_step: np.ndarray
    n_meas: np.ndarray
    theta_hat: np.ndarray
    theta_var: np.ndarray
    measurements: np.ndarray
    w_est: np.ndarray
    nis: np.ndarray
    impulse: np.ndarray
    demand: np.ndarray
    rate_peak: np.ndarray
    budget_spent: np.ndarray
    rate_cuts: np.ndarray

    @property
    def w_true(self) -> np.ndarray:
        """(B, m, 3) rad/s true rate at each measurement."""
        return self.measurements[..., 4:7]


#: Arrays of a batch of B runs handed to the compiled loop, grouped by role (leading axis B).
#: Truth: y (B, 7) true (q, w), inertia (3, 3), dist (DISTURBANCE_SIZE,) packed disturbance on
#: the truth.
Truth = collections.namedtuple("Truth", "y inertia dist")
#: Estimator: x (B, 13), P (B, 13, 13), and the prediction in progress: phi_top (B, 7, 13),
#: sigma (B, 26, 13) (see SimState). The 1-D per-run counters and flags (n_updates,
#: sigma_fresh) go to the compiled loop as plain arguments: written through a namedtuple inside
#: numba's parallel loop, their updates are lost.
Estimator = collections.namedtuple("Estimator", "x P phi_top sigma")
#: Plan: n_steps (B,); bursts (B, nb, 2) [start, stop) steps and n_bursts (B,); xi (B, 3);
#: v (B, 3) burst directions; tau_max N·m; meas_at (B, m) steps of the measurements and
#: n_meas (B,); z_noise (B, m, 13) noise draws; record_steps: keep the per-step log;
#: impulse_budget N·m·s and rate_limit rad/s, the segment's limits (inf: none; Scenario);
#: min_impulse_bit N·m·s (0: none).
Plan = collections.namedtuple("Plan", "n_steps bursts n_bursts xi v tau_max meas_at n_meas z_noise "
                                      "record_steps impulse_budget rate_limit min_impulse_bit")
#: Logs (see Trace): w_hat, w_dot_hat, tau (B, n, 3) per step; theta, var (B, m, 6),
#: measurements (B, m, 14), w_est (B, m, 3), nis (B, m) per measurement; per run over the
#: segment: impulse (B,) N·m·s spent (1-norm), demand (B,) N·m·s the burst law asked for before
#: the limits cut it, rate_peak (B,) largest true |w| rad/s, cuts
#: (B, 2): 1 once the budget is spent, and the number of bursts the rate monitor cut short.
Logs = collections.namedtuple("Logs", "w_hat w_dot_hat tau theta var measurements w_est nis "
                                      "impulse demand rate_peak cuts")


#: Runs advanced in lock-step by one task of the compiled loop: the lanes of its vector
#: instructions (8 float64 fill one 512-bit register). The loop is compiled for this many
#: lanes and for one (a lone run); each lane count is about half a minute of compiling.
LANES = 8
#: Runs per task when a batch of more than HALF_LANES and at most LANES runs is split over
#: threads (fewer runs go one per task, on one lane each).
HALF_LANES = LANES // 2
#: The filter's model of the body: no disturbance, no wheel (a tuple: a compile-time constant).
MODEL_DISTURBANCE = tuple(NO_DISTURBANCE.tolist())
#: Rows of the lane buffer of :func:`_advance_lanes` (one column per lane): true (q, w) (7),
#: filter mean (13), true inertia and inverse, J_hat and inverse (9 each, row-major), torque
#: (3), moving and predicting flags (1.0 / 0.0), transition coefficients, transition (7 x 13).
_Y, _X, _J_TRUE, _J_TRUE_INV, _J_HAT, _J_HAT_INV, _TAU, _MOVING, _PREDICTING, _COEF, _PHI, \
    _ROWS = np.cumsum([0, 7, N_STATE, 9, 9, 9, 9, 3, 1, 1, ekf.N_COEF, 7 * N_STATE]).tolist()


@nb.njit(cache=True, forceinline=True)
def _set_lane9(rows, lane, values):
    """rows[:, lane] = values, a 9-tuple."""
    for i in range(9):
        rows[i, lane] = values[i]


@nb.njit(cache=True, error_model="numpy")
def _advance_lanes(truth, est, plan, logs, cfg, n_updates, sigma_fresh, status, first, stop,
                   lanes):
    """Advance runs first .. min(first + lanes, stop) - 1 of the batch (those that have not
    diverged) by plan.n_steps[r] steps each, in lock-step; their truth, estimate, counters
    (n_updates, sigma_fresh, status: (B,)) and logs change in place. first, stop : int64
    (never literal constants: each distinct argument type compiles the loop anew).
    lanes : a literal integer (compiled once per value): LANES, or 1 for one run, which would
    otherwise pay for LANES - 1 idle lanes.

    The runs' (q, w), filter means, inertias, torques and transitions are held lane by lane,
    runs along the last axis of one buffer of constant shape (:data:`_ROWS`, lanes), so that
    the truth's RK4 and the EKF's prediction of all lanes run as one stream of vector
    instructions; bursts, measurements and filter updates, at each run's own times, are
    handled run by run. Each run computes exactly what it computes alone: a lane never reads
    another lane.
    """
    nb.literally(lanes)
    count = min(lanes, stop - first)  # lanes past `stop` mirror run `first`, idle
    dt = cfg.dt
    use_ukf = cfg.ukf > 0
    n_sigma = ukf.N_SIGMA if use_ukf else 0
    buf = np.zeros((_ROWS, lanes))
    y, x, tau = buf[_Y:_X], buf[_X:_J_TRUE], buf[_TAU:_MOVING]
    j_true, j_true_inv = buf[_J_TRUE:_J_TRUE_INV], buf[_J_TRUE_INV:_J_HAT]
    j_hat, j_hat_inv = buf[_J_HAT:_J_HAT_INV], buf[_J_HAT_INV:_TAU]
    moving, predicting = buf[_MOVING], buf[_PREDICTING]
    coef, phi_top = buf[_COEF:_PHI], buf[_PHI:_ROWS]
    runs = np.empty(lanes, dtype=np.int64)
    active = np.zeros(lanes, dtype=np.bool_)  # the lane holds a run that this segment advances
    burst_i = np.zeros(lanes, dtype=np.int64)
    meas_i = np.zeros(lanes, dtype=np.int64)
    sigma_inertia = np.empty((lanes, n_sigma, 3, 3))
    sigma_inertia_inv = np.empty((lanes, n_sigma, 3, 3))
    dist = disturbance_entries(truth.dist)
    n_max = 0
    for lane in range(lanes):
        r = first + lane if lane < count else first
        runs[lane] = r
        for i in range(7):
            y[i, lane] = truth.y[r, i]
        for i in range(N_STATE):
            x[i, lane] = est.x[r, i]
        for i in range(7):
            for k in range(N_STATE):
                phi_top[N_STATE * i + k, lane] = est.phi_top[r, i, k]
        _set_lane9(j_true, lane, mat3_entries(truth.inertia))
        _set_lane9(j_true_inv, lane, mat3_entries(inv3(truth.inertia)))
        inertia_hat = inertia_from_phi(est.x[r, 7:13])
        _set_lane9(j_hat, lane, mat3_entries(inertia_hat))
        _set_lane9(j_hat_inv, lane, mat3_entries(inv3(inertia_hat)))
        if lane >= count or status[r] != 0:
            continue
        if use_ukf:
            fresh, sigma_fresh[r] = sigma_fresh[r], False
            if not fresh:  # carry on with the points propagated in the last segment
                ukf.sigma_inertias(est.sigma[r], sigma_inertia[lane], sigma_inertia_inv[lane])
            elif not ukf.draw_sigma_points(est.x[r], est.P[r], est.sigma[r], sigma_inertia[lane],
                                           sigma_inertia_inv[lane]):
                status[r] = STATUS_DIVERGED
                continue
        active[lane] = True
        n_max = max(n_max, plan.n_steps[r])
    cov_work = np.empty((14, N_STATE))
    x_run = np.empty(N_STATE)
    y_run = np.empty(7)
    phi_run = np.empty((7, N_STATE))
    z = np.empty(sensors.measurement_size(cfg))
    for k in range(n_max):
        for lane in range(count):
            r = runs[lane]
            on = active[lane] and k < plan.n_steps[r]
            moving[lane] = 1.0 if on else 0.0
            predicting[lane] = 1.0 if on and status[r] == 0 and not use_ukf else 0.0
            if not on:
                continue
            # Burst law (18): from the filter's rate at the burst start, held over the burst.
            b = burst_i[lane]
            if b < plan.n_bursts[r] and k == plan.bursts[r, b, 1]:
                tau[:, lane] = 0.0
                b += 1
            if b < plan.n_bursts[r] and k == plan.bursts[r, b, 0]:
                burst_torque_into(plan.xi[r, 0], plan.xi[r, 1], (x[4, lane], x[5, lane], x[6, lane]),
                                  plan.v[r], plan.tau_max, tau[:, lane])
                held = min(plan.bursts[r, b, 1], plan.n_steps[r]) - k
                # An axis whose pulse would deliver less than the actuator's minimum impulse
                # bit does not fire (a thruster cannot open for less).
                for i in range(3):
                    if abs(tau[i, lane]) * dt * held < plan.min_impulse_bit:
                        tau[i, lane] = 0.0
                # The impulse the law asks for over the burst, before any limit cuts it.
                logs.demand[r] += (abs(tau[0, lane]) + abs(tau[1, lane]) + abs(tau[2, lane])) * dt * held
            burst_i[lane] = b
            _apply_limits(tau[:, lane], (x[4, lane], x[5, lane], x[6, lane]), dt, plan, logs, r)
            if plan.record_steps:
                _record_step((x[4, lane], x[5, lane], x[6, lane]),
                             (tau[0, lane], tau[1, lane], tau[2, lane]),
                             lane_entries9(j_hat, lane), lane_entries9(j_hat_inv, lane),
                             logs.w_hat[r, k], logs.w_dot_hat[r, k])
                for i in range(3):
                    logs.tau[r, k, i] = tau[i, lane]
        rk4_lanes(y, j_true, j_true_inv, tau, dist, dt, moving)
        ekf.ekf_predict_lanes(x, j_hat, j_hat_inv, tau, MODEL_DISTURBANCE, dt, phi_top, coef,
                              predicting)
        for lane in range(count):
            if moving[lane] == 0.0:
                continue
            r = runs[lane]
            rate = math.sqrt(y[4, lane] ** 2 + y[5, lane] ** 2 + y[6, lane] ** 2)
            logs.rate_peak[r] = max(logs.rate_peak[r], rate)
            if use_ukf and status[r] == 0:
                ukf.predict_sigma_points(est.sigma[r], sigma_inertia[lane],
                                         sigma_inertia_inv[lane], tau[:, lane], dt,
                                         MODEL_DISTURBANCE)
                ukf.sigma_mean(est.sigma[r], x_run)
                for i in range(N_STATE):
                    x[i, lane] = x_run[i]
            m = meas_i[lane]
            if m >= plan.n_meas[r] or plan.meas_at[r, m] != k + 1:
                continue
            for i in range(7):
                y_run[i] = y[i, lane]
            for i in range(N_STATE):
                x_run[i] = x[i, lane]
            P = est.P[r]
            sensors.simulate_measurement(y_run, plan.z_noise[r, m], cfg, z)
            if status[r] == 0:
                for i in range(7):
                    for c in range(N_STATE):
                        phi_run[i, c] = phi_top[N_STATE * i + c, lane]
                status[r] = _filter_update(x_run, P, phi_run, cov_work, est.sigma[r],
                                           n_updates[r], cfg, z, logs.nis[r], m)
                n_updates[r] += 1
                for i in range(N_STATE):
                    x[i, lane] = x_run[i]
                for i in range(7):
                    for c in range(N_STATE):
                        phi_top[N_STATE * i + c, lane] = phi_run[i, c]
                if status[r] == 0:
                    inertia_hat = inertia_from_phi(x_run[7:13])
                    _set_lane9(j_hat, lane, mat3_entries(inertia_hat))
                    _set_lane9(j_hat_inv, lane, mat3_entries(inv3(inertia_hat)))
                    if use_ukf and not ukf.draw_sigma_points(x_run, P, est.sigma[r],
                                                             sigma_inertia[lane],
                                                             sigma_inertia_inv[lane]):
                        status[r] = STATUS_DIVERGED
            _log_theta(x_run, P, logs.theta[r, m], logs.var[r, m])
            _log_measurement(y_run, z, cfg, logs.measurements[r, m])
            for i in range(3):
                logs.w_est[r, m, i] = x_run[4 + i]
            meas_i[lane] = m + 1
    for lane in range(count):
        r = runs[lane]
        for i in range(7):
            truth.y[r, i] = y[i, lane]
        for i in range(N_STATE):
            est.x[r, i] = x[i, lane]
        for i in range(7):
            for k in range(N_STATE):
                est.phi_top[r, i, k] = phi_top[N_STATE * i + k, lane]


@nb.njit(cache=True)
def _apply_limits(tau, w_hat, dt, plan, logs, r):
    """Cut the torque tau (3,) of run r's coming step to the segment's limits, in place, and
    count what it spends into logs.impulse[r].

    Rate limit: at |w_hat| >= plan.rate_limit the torque is switched off for the rest of the
    burst (a safety monitor inhibits the actuator; the next burst starts the law afresh).
    Impulse budget: a step spends |tau|_1 dt; the step that would overdraw the budget is
    scaled to spend exactly what is left, which leaves every later step at zero.
    """
    spend = (abs(tau[0]) + abs(tau[1]) + abs(tau[2])) * dt
    if spend == 0.0:
        return
    if w_hat[0] ** 2 + w_hat[1] ** 2 + w_hat[2] ** 2 >= plan.rate_limit ** 2:
        tau[:] = 0.0
        logs.cuts[r, 1] += 1
        return
    left = plan.impulse_budget - logs.impulse[r]
    if spend >= left:
        scale = max(left, 0.0) / spend
        for i in range(3):
            tau[i] *= scale
        logs.cuts[r, 0] = 1
        logs.impulse[r] = plan.impulse_budget
    else:
        logs.impulse[r] += spend


@nb.njit(cache=True)
def _log_measurement(y_true, z, cfg, out):
    """Write the true state (q, w) and the gyro and quaternion readings into out (14,); the
    quaternion reading is NaN when the scenario has no attitude sensor.
    """
    for i in range(7):
        out[i] = y_true[i]
    for i in range(3):
        out[7 + i] = z[i]
    for i in range(4):
        out[10 + i] = z[3 + i] if cfg.use_quat > 0 else np.nan


@nb.njit(cache=True)
def _log_theta(x, P, theta, var):
    """Write theta of the estimate x (13,) and the diagonal of P_theta = D P_phi D^T (delta
    method, D = dtheta/dphi) into theta (6,) and var (6,).
    """
    theta_into(x[7:13], theta)
    d = dtheta_dphi(x[7:13])
    for i in range(6):
        acc = 0.0
        for j in range(6):
            for k in range(6):
                acc += d[i, j] * P[7 + j, 7 + k] * d[i, k]
        var[i] = acc


@nb.njit(cache=True)
def _record_step(w, tau, j, j_inv, w_hat, w_dot_hat):
    """w_hat = w and w_dot_hat = J_hat^-1 (tau - w x J_hat w) of eq. (12) into the outputs (3,);
    w, tau 3-sequences (rad/s, N·m), j, j_inv row-major 9-sequences (J_hat, kg·m²).
    """
    wx, wy, wz = w[0], w[1], w[2]
    hx = j[0] * wx + j[1] * wy + j[2] * wz
    hy = j[3] * wx + j[4] * wy + j[5] * wz
    hz = j[6] * wx + j[7] * wy + j[8] * wz
    rx = tau[0] - (wy * hz - wz * hy)
    ry = tau[1] - (wz * hx - wx * hz)
    rz = tau[2] - (wx * hy - wy * hx)
    for i in range(3):
        w_hat[i] = w[i]
        w_dot_hat[i] = j_inv[3 * i] * rx + j_inv[3 * i + 1] * ry + j_inv[3 * i + 2] * rz


@nb.njit(cache=True)
def _filter_update(x, P, phi_top, cov_work, sigma, n_updates, cfg, z, log_nis, meas_i):
    """Covariance prediction + update with the measurement z; returns STATUS_DIVERGED instead
    of raising.

    EKF: P^- from the accumulated transition; UKF: from the propagated sigma points.
    """
    if cfg.ukf > 0:
        cov = ukf.sigma_covariance(sigma, x, n_updates, cfg)
        for i in range(N_STATE):
            for c in range(N_STATE):
                P[i, c] = cov[i, c]
    if not ekf.state_is_sane(x, P):
        return 1
    try:
        if cfg.ukf == 0:
            ekf.propagate_covariance(P, phi_top, x, n_updates, cfg, cov_work)
        phi_top[:, :] = 0.0
        for i in range(7):
            phi_top[i, i] = 1.0
        log_nis[meas_i] = ekf.ekf_update(x, P, z, cfg)
    except Exception:  # a failed factorisation: the estimate has left its domain
        return 1
    return 0 if ekf.state_is_sane(x, P) else 1


@nb.njit(cache=True, parallel=True)
def _segment_tasks(truth, est, plan, logs, cfg_array, n_updates, sigma_fresh, status, per_task):
    """Advance every run of the batch on LANES lanes, per_task runs per task (per_task <=
    LANES), tasks in parallel.

    cfg_array : (1,) array of the filter configuration record (a record is handed to the
    parallel loop inside an array: numba cannot pass a bare record into a parfor).
    n_updates, sigma_fresh, status : (B,) per-run counters and flags, updated in place.
    """
    batch = truth.y.shape[0]
    for task in nb.prange((batch + per_task - 1) // per_task):
        first = np.int64(task * per_task)
        stop = min(first + per_task, batch)
        _advance_lanes(truth, est, plan, logs, cfg_array[0], n_updates, sigma_fresh, status,
                       first, stop, LANES)


@nb.njit(cache=True, parallel=True)
def _segment_tasks_one_lane(truth, est, plan, logs, cfg_array, n_updates, sigma_fresh, status):
    """:func:`_segment_tasks` with one run per task, on one lane (a few runs over the cores)."""
    for task in nb.prange(truth.y.shape[0]):
        first = np.int64(task)
        _advance_lanes(truth, est, plan, logs, cfg_array[0], n_updates, sigma_fresh, status,
                       first, first + 1, 1)


@nb.njit(cache=True)
def _segment_one(truth, est, plan, logs, cfg_array, n_updates, sigma_fresh, status):
    """A lone run, on one lane, without the threading layer's launch cost."""
    first = np.int64(0)
    _advance_lanes(truth, est, plan, logs, cfg_array[0], n_updates, sigma_fresh, status,
                   first, first + 1, 1)


@nb.njit(cache=True)
def _segment_lanes(truth, est, plan, logs, cfg_array, n_updates, sigma_fresh, status):
    """A batch of at most LANES runs as one task on LANES lanes (one thread)."""
    first = np.int64(0)
    _advance_lanes(truth, est, plan, logs, cfg_array[0], n_updates, sigma_fresh, status,
                   first, first + truth.y.shape[0], LANES)


def _kernel_for(batch: int, threads: int) -> tuple:
    """(kernel, its extra arguments) that advances a batch of `batch` runs with `threads`
    threads: more than LANES runs go LANES per task; a few runs over several threads one per
    task (or HALF_LANES per task on LANES lanes); otherwise one task.
    """
    if batch > LANES:
        return _segment_tasks, (LANES,)
    if batch > 1 and threads > 1:  # the cores share a batch one task would hold
        return (_segment_tasks_one_lane, ()) if batch <= HALF_LANES else (_segment_tasks, (HALF_LANES,))
    return (_segment_one, ()) if batch == 1 else (_segment_lanes, ())


#: The loop's kernels, each compiled (or loaded from numba's on-disk cache) on its first use.
KERNELS = ("_segment_one", "_segment_lanes", "_segment_tasks_one_lane", "_segment_tasks")
#: Names of the kernels that have run in this process (under _loop_lock on first use).
_ready: set[str] = set()
_loop_lock = threading.Lock()


def _call_kernel(kernel, args) -> None:
    """kernel(*args); its first call in this process runs in a thread of its own.

    Why a thread: numba compiles recursively, and CPython 3.11 frees a frame-stack chunk each
    time the stack pops back over the chunk's start. Started deep in a caller's stack (the
    CLI's optimize: agent, env, episode, run_segment), the compile crosses such a border so
    often that it spends 170 s of system time and 20 M page faults on it. A new thread's stack
    starts empty, whoever calls. Each kernel compiles only when a batch first needs it, so a
    command pays for the kernels it uses.
    """
    name = kernel.__name__
    if name in _ready:
        kernel(*args)
        return
    with _loop_lock:
        if name in _ready:
            kernel(*args)
            return
        failure: list[BaseException] = []

        def first_call():
            try:
                kernel(*args)
            except BaseException as exc:  # re-raised in the caller's thread
                failure.append(exc)

        thread = threading.Thread(target=first_call, name=f"inertia-gym-compile-{name}")
        thread.start()
        thread.join()
        if failure:
            raise failure[0]
        _ready.add(name)


def compile_loop(kernels: tuple[str, ...] = KERNELS) -> None:
    """Compile (or load) the simulation loop's kernels now (default all of :data:`KERNELS`), each
    on a tiny batch, rather than on first use; later calls return at once. For a process that
    will run batches of every size (a test session's warm-up, a service); processes that compile
    different kernels side by side share the compiled callees through numba's on-disk cache.
    """
    unknown = set(kernels) - set(KERNELS)
    if unknown:
        raise ConfigError(f"kernels must be among {KERNELS}, got {sorted(unknown)}")
    sc = Scenario()
    for name in kernels:
        if name in _ready:
            continue
        batch = 1 if name == "_segment_one" else 2
        rngs = [np.random.default_rng(r) for r in range(batch)]
        run_segment(sc, initial_state(sc, rngs), 1, np.zeros((batch, 0, 2)), [0.0, 0.0, 1.0],
                    [1.0, 0.0, 0.0], rngs, record_steps=False, kernel=name)


def _limit(value: float | None) -> float:
    """A scenario's limit as the compiled loop reads it: inf for none."""
    return math.inf if value is None else float(value)


def run_segment(
    sc: Scenario,
    state: SimState,
    n_steps,
    bursts,
    xi,
    v,
    rngs: list[np.random.Generator],
    *,
    record_steps: bool = True,
    disturbance=None,
    kernel: str | None = None,
    impulse_spent=None,
) -> tuple[SimState, Trace]:
    """Advance B runs by one segment.

    n_steps : (B,) int steps per run (0 leaves a run as it is).
    bursts : (B, nb, 2) int [start, stop) step indices from the
    segment start (nb may be 0).  xi : (B, 3) (a, b, T_on); T_on only enters through bursts.
    v : (B, 3) unit burst directions.  rngs : one Generator per run (measurement times, noise).
    record_steps : keep w_hat, w_dot_hat, tau per step (needed for the information metric).
    disturbance : packed (DISTURBANCE_SIZE,) vector of dynamics.Disturbance acting on the truth,
    or None.
    kernel : the name of one of :data:`KERNELS` to run the batch with (any of them gives the
    same result); by default the one suited to the batch's size and the threads.
    impulse_spent : (B,) N·m·s of sc.impulse_budget already spent before this segment (a budget
    that spans several segments); zero by default. trace.impulse includes it.
    Runs that had diverged are left untouched. The kernel is compiled on its first use in the
    process.
    """
    batch = state.batch
    n_steps = np.broadcast_to(np.asarray(n_steps, dtype=np.int64), (batch,)).copy()
    if np.any(n_steps < 0) or not np.any(n_steps > 0):
        raise ConfigError(f"segment lengths must be >= 0 steps, one > 0; got {n_steps.tolist()}")
    bursts = np.array(bursts, dtype=np.int64, order="C").reshape(batch, -1, 2)
    n_bursts = np.full(batch, bursts.shape[1], dtype=np.int64)
    # Writable C-ordered copies, whatever was passed: another layout or a read-only view
    # would be another argument type, which compiles the loop once more.
    xi = np.array(np.broadcast_to(np.asarray(xi, dtype=float), (batch, 3)), order="C")
    v = np.array(np.broadcast_to(np.asarray(v, dtype=float), (batch, 3)), order="C")
    if not (np.all(np.isfinite(xi)) and np.all(np.isfinite(v))):
        raise ConfigError("xi and v must be finite")
    cfg = pack_filter_config(sc)
    # Measurement schedule and noise, per run, from its own generator.
    schedules, steps_to_meas = [], state.steps_to_meas.copy()
    for r in range(batch):
        at, steps_to_meas[r] = _measurement_schedule(
            sc, rngs[r], int(steps_to_meas[r]), int(n_steps[r]))
        schedules.append(at)
    max_meas = max(1, max(len(s) for s in schedules))
    meas_at = np.zeros((batch, max_meas), dtype=np.int64)
    n_meas = np.array([len(s) for s in schedules], dtype=np.int64)
    sigmas = sensors.noise_sigmas(cfg)
    z_noise = np.zeros((batch, max_meas, 13))
    for r in range(batch):
        meas_at[r, : n_meas[r]] = schedules[r]
        z_noise[r, : n_meas[r]] = sigmas * rngs[r].standard_normal((n_meas[r], 13))
    n_max = max(1, int(n_steps.max())) if record_steps else 1
    out_w_hat = np.zeros((batch, n_max, 3))
    out_w_dot_hat = np.zeros((batch, n_max, 3))
    out_tau = np.zeros((batch, n_max, 3))
    log_theta = np.full((batch, max_meas, 6), np.nan)
    log_var = np.full((batch, max_meas, 6), np.nan)
    log_meas = np.full((batch, max_meas, 14), np.nan)
    log_w_est = np.full((batch, max_meas, 3), np.nan)
    log_nis = np.full((batch, max_meas), np.nan)
    impulse = np.zeros(batch) if impulse_spent is None else np.array(
        np.broadcast_to(np.asarray(impulse_spent, dtype=float), (batch,)))
    rate_peak = np.linalg.norm(state.y_true[:, 4:7], axis=1)
    demand = np.zeros(batch)
    cuts = np.zeros((batch, 2), dtype=np.int64)
    y_true, x, P = state.y_true.copy(), state.x.copy(), state.P.copy()
    n_updates = state.n_updates.copy()
    phi_top, sigma, sigma_fresh = state.phi_top.copy(), state.sigma.copy(), state.sigma_fresh.copy()
    status = state.diverged.astype(np.int64)
    dist = np.array(NO_DISTURBANCE if disturbance is None else disturbance, dtype=float,
                    order="C")
    if dist.shape != (DISTURBANCE_SIZE,):
        raise ConfigError(f"disturbance must be a packed ({DISTURBANCE_SIZE},) vector "
                          f"(dynamics.Disturbance.pack()), got shape {dist.shape}")
    check_rigid_steps(dist)
    args = (
        Truth(y_true, sc.inertia_true_array, dist),
        Estimator(x, P, phi_top, sigma),
        Plan(n_steps, bursts, n_bursts, xi, v, sc.tau_max, meas_at, n_meas, z_noise, record_steps,
             _limit(sc.impulse_budget), _limit(sc.rate_limit), float(sc.min_impulse_bit or 0.0)),
        Logs(out_w_hat, out_w_dot_hat, out_tau, log_theta, log_var, log_meas, log_w_est, log_nis,
             impulse, demand, rate_peak, cuts),
        np.array([cfg]), n_updates, sigma_fresh, status,
    )
    if kernel is None:
        chosen, extra = _kernel_for(batch, nb.get_num_threads())
    elif kernel in KERNELS:
        chosen = globals()[kernel]
        extra = (LANES,) if kernel == "_segment_tasks" else ()
        most = {"_segment_one": 1, "_segment_lanes": LANES}.get(kernel, batch)
        if batch > most:
            raise ConfigError(f"{kernel} holds at most {most} runs, got {batch}")
    else:
        raise ConfigError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    _call_kernel(chosen, (*args, *extra))
    new_state = SimState(
        y_true=y_true, x=x, P=P, n_updates=n_updates, steps_to_meas=steps_to_meas,
        step=state.step + n_steps, diverged=status != STATUS_OK, phi_top=phi_top, sigma=sigma,
        sigma_fresh=sigma_fresh,
    )
    trace = Trace(
        w_hat=out_w_hat, w_dot_hat=out_w_dot_hat, tau=out_tau, n_steps=n_steps,
        meas_step=state.step[:, None] + meas_at, n_meas=n_meas, theta_hat=log_theta,
        theta_var=log_var, measurements=log_meas, w_est=log_w_est, nis=log_nis,
        impulse=impulse, demand=demand, rate_peak=rate_peak, budget_spent=cuts[:, 0] > 0,
        rate_cuts=cuts[:, 1],
    )
    return new_state, trace
