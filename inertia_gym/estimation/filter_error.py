"""Filter-error maximum likelihood: the inertia of a body whose rigid model is disturbed.

The output-error fit (estimation/ml.py) follows one rigid trajectory over the whole record; an
unmodelled torque (air drag on a thrown plate is the common one) accumulates in that trajectory
and the fit bends the inertia to absorb it. The filter-error method of flight-test system
identification lets the model error enter as process noise instead: an extended Kalman filter
runs the model over the record, and the inertia maximises the likelihood of its one-step
innovations. A disturbance then moves the filter's state, not the parameters.

State (body frame) x = [L (3), d (3), c (r), m (r)], n = 6 + 2r:

    L_dot = L x w + tau + d + n_w,   E n_w(t) n_w(s)^T = q_w I delta(t - s)   (q_w N²·m²·s)
    d_dot = n_d,                     E n_d n_d^T = q_d I delta                 (q_d N²·m²/s)
    h = h_ref + U c,   c_dot = m,    m_dot = n_m,   E n_m n_m^T = q_m I delta  (q_m N²·m²/s)
    w = J^-1 (L - h)

L the total angular momentum; tau the recorded torque (held per row); the disturbance torque
is white (n_w: broadband model error) plus a random walk d (slowly varying model error such as
air drag), each intensity estimated; h the internal momentum (a rotor, wheels) in the span
U (3, r) of its logged variation around h_ref (3,), m its rate (the motor torque, a random
walk). The logged h is a measurement, not an input: a logger holds, quantises and jitters it,
and treating it as exact (errors in variables) biases the inertia upwards as soon as process
noise lets the filter look at short time scales (a 1-ms lag or 5 rad/s of rotor-speed jitter
made the simulated scale run away).

Measurements at every row k: the gyro z_w = w + v_w (sigma_w (3,) rad/s); on rows where the
logged momentum is fresh (it changed since the previous row: loggers repeat a held value), its
projection U^T (z_h - h_ref) = c(t - delay) + v_h ~ c - delay m + v_h (sigma_h kg·m²/s per
component; delay s: the momentum log and the gyro come from different sensors and clocks).

Robust innovations: a log or gyro glitch (a rotor speed that dips at spin-up, a brake burst)
is one innovation far outside its distribution. The loss per row is Huber's on the
Mahalanobis distance d = sqrt(e^T S^-1 e) of the innovation e (covariance S), with the corner
at the HUBER_LEVEL quantile of the chi-square distribution of d²: beyond it the row costs
c d - c²/2 instead of d²/2 and its measurement noise is inflated by d / c in the update (the
M-estimator's weight), so that one row cannot dominate the fit. The loss per row is that plus
1/2 log det S (the negative log-likelihood without constants).

Unknowns v = [phi (6), log q_w, log q_d, delay]; phi the log-Cholesky inertia of
estimation/inertia_param.py (phi[0], the scale, held when the record does not fix it). q_m and
sigma_h belong to the momentum log alone and come from its own local-linear-trend likelihood
(log_hyper). The intensities stay above a floor where a disturbance would move the rate by a
tenth of the gyro noise over the record (intensity_floor: below it the likelihood is flat).
The initial state comes from the first row (L0 = J z_w0 + h0, c0 its log, d0 = m0 = 0 with the
spread their random walks reach over the record). v minimises the summed loss by projected
Newton steps (finite-difference gradient and Hessian); its covariance is the M-estimator's
sandwich A^-1 B A^-1, A the finite-difference Hessian of the loss and B the long-run
covariance of the per-row scores (Bartlett weights over as many lags as they stay correlated).
"""

from __future__ import annotations

import dataclasses
import math

import numba as nb
import numpy as np
from scipy.optimize import minimize
from scipy.stats import chi2

from inertia_gym.errors import ConfigError
from inertia_gym.estimation.ekf import cholesky_into
from inertia_gym.estimation.inertia_param import inertia_from_phi
from inertia_gym.estimation.longrun import correlation_lags, long_run_covariance

#: Huber's corner: the chi-square quantile of the squared Mahalanobis distance of an innovation.
HUBER_LEVEL = 0.99
#: Relative singular value below which a direction of the logged h counts as constant.
H_SPAN_TOL = 1e-3
#: Central-difference step in v (log-Cholesky and log-intensity units) and in the delay (s).
FD_STEP = 1e-4
DELAY_FD_STEP = 1e-5
#: Largest change of the inertia's log-Cholesky parameters in one Newton step (as estimation/ml).
MAX_PHI_STEP = 0.2
#: Largest change of a log-intensity (e-folds) and of the delay (s) in one Newton step.
MAX_LOG_Q_STEP = 2.0
MAX_DELAY_STEP = 1e-3


# ------------------------------------------------------------------------------------------
# Compiled filter
# ------------------------------------------------------------------------------------------


@nb.njit(cache=True, nogil=True)
def _momentum_rate(lx, ly, lz, wx, wy, wz, tau, out):
    """Write L x w + tau into out (3,)."""
    out[0] = ly * wz - lz * wy + tau[0]
    out[1] = lz * wx - lx * wz + tau[1]
    out[2] = lx * wy - ly * wx + tau[2]


@nb.njit(cache=True, nogil=True)
def _rate(l_vec, h_vec, jinv, out_w):
    """out_w (3,) = J^-1 (L - h)."""
    a0, a1, a2 = l_vec[0] - h_vec[0], l_vec[1] - h_vec[1], l_vec[2] - h_vec[2]
    for i in range(3):
        out_w[i] = jinv[i, 0] * a0 + jinv[i, 1] * a1 + jinv[i, 2] * a2


@nb.njit(cache=True, nogil=True)
def _cholesky_solve(s, e, nz, low, y):
    """Cholesky factor low of s (nz, nz) in place; y = low^-1 e; returns log det s (or nan)."""
    if not cholesky_into(s[:nz, :nz], low[:nz, :nz]):
        return math.nan
    logdet = 0.0
    for i in range(nz):
        logdet += 2.0 * math.log(low[i, i])
    for i in range(nz):
        acc = e[i]
        for k in range(i):
            acc -= low[i, k] * y[k]
        y[i] = acc / low[i, i]
    return logdet


@nb.njit(cache=True, nogil=True)
def _transition(f_ll, f_lc, hs, r, phi_ll, phi_ld, phi_lc, phi_lm):
    """The non-trivial blocks of Phi = I + F hs + F² hs²/2 (see innovation_loss): phi_ll (3, 3)
    = I + A hs + A² hs²/2, phi_ld (3, 3) = I hs + A hs²/2, phi_lc (3, r) = B hs + A B hs²/2,
    phi_lm (3, r) = B hs²/2, from f_ll = A (3, 3) and f_lc = B (3, r).
    """
    h2 = 0.5 * hs * hs
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += f_ll[i, k] * f_ll[k, j]
            phi_ll[i, j] = f_ll[i, j] * hs + acc * h2 + (1.0 if i == j else 0.0)
            phi_ld[i, j] = f_ll[i, j] * h2 + (hs if i == j else 0.0)
        for j in range(r):
            acc = 0.0
            for k in range(3):
                acc += f_ll[i, k] * f_lc[k, j]
            phi_lc[i, j] = f_lc[i, j] * hs + acc * h2
            phi_lm[i, j] = f_lc[i, j] * h2


@nb.njit(cache=True, nogil=True)
def _propagate_covariance(p, tmp, phi_ll, phi_ld, phi_lc, phi_lm, hs, r):
    """P = Phi P Phi^T in place for the block structure of innovation_loss (tmp (n, n) work)."""
    n = p.shape[0]
    c0, m0 = 6, 6 + r
    # tmp = Phi P: L rows mix all blocks, c rows add hs m rows, d and m rows are unchanged
    for i in range(3):
        for j in range(n):
            acc = 0.0
            for k in range(3):
                acc += phi_ll[i, k] * p[k, j] + phi_ld[i, k] * p[3 + k, j]
            for k in range(r):
                acc += phi_lc[i, k] * p[c0 + k, j] + phi_lm[i, k] * p[m0 + k, j]
            tmp[i, j] = acc
    for i in range(3, n):
        for j in range(n):
            tmp[i, j] = p[i, j]
    for i in range(r):
        for j in range(n):
            tmp[c0 + i, j] += hs * p[m0 + i, j]
    # P = tmp Phi^T: the same structure on the columns
    for i in range(n):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += tmp[i, k] * phi_ll[j, k] + tmp[i, 3 + k] * phi_ld[j, k]
            for k in range(r):
                acc += tmp[i, c0 + k] * phi_lc[j, k] + tmp[i, m0 + k] * phi_lm[j, k]
            p[i, j] = acc
        for j in range(3, n):
            p[i, j] = tmp[i, j]
        for j in range(r):
            p[i, c0 + j] += hs * tmp[i, m0 + j]


@nb.njit(cache=True, nogil=True)
def innovation_loss(t_grid, n_sub, tau_grid, z_w, sigma_w, z_c, fresh, h_ref, u, phi, q_w, q_d,
                    q_m, sigma_h, delay, huber_c2, out_rows):
    """Run the filter over the rows and return the summed loss (NaN if the filter failed).

    State x = [L (3), d (3), c (r), m (r)] (module docstring), F = dx_dot/dx with blocks
    A = [L]x J^-1 - [w]x (L on L), I (L on d), B = -[L]x J^-1 U (L on c), I (c on m); process
    noise diag(q_w I3, q_d I3, 0, q_m Ir). Per sub-step hs: Phi = I + F hs + F² hs²/2 and
    Qd = Qc hs + (F Qc + Qc F^T) hs²/2 + F Qc F^T hs³/3.

    t_grid (M,) s; n_sub (M,) sub-steps per interval; tau_grid (M, 3) N·m held per row; z_w
    (M, 3) rad/s; sigma_w (3,) rad/s; z_c (M, r) projected momentum log U^T (z_h - h_ref);
    fresh (M,) bool, the rows whose log is a new sample; h_ref (3,), u (3, r); phi (6,); q_w
    N²·m²·s, q_d N²·m²/s, q_m N²·m²/s, sigma_h kg·m²/s; delay s: the log reads c(t - delay)
    ~ c - delay m; huber_c2 (3 + r + 1,) the squared Huber corner per measurement count (index
    nz). Writes the loss of each row into out_rows (M,) (row 0: 0, the state starts from it).
    """
    r = u.shape[1]
    n = 6 + 2 * r
    c0, m0 = 6, 6 + r
    jm = inertia_from_phi(phi)
    jinv = np.linalg.inv(jm)
    jinv_u = jinv @ u  # the rate's sensitivity to c is -J^-1 U
    x = np.zeros(n)
    h_vec = np.empty(3)
    for i in range(3):
        h_vec[i] = h_ref[i]
        for j in range(r):
            h_vec[i] += u[i, j] * z_c[0, j]
    for i in range(3):
        x[i] = h_vec[i] + jm[i, 0] * z_w[0, 0] + jm[i, 1] * z_w[0, 1] + jm[i, 2] * z_w[0, 2]
    for j in range(r):
        x[c0 + j] = z_c[0, j]
    # P0: L0 = J z_w0 + h0 carries the first row's gyro and log noise; d0 and m0 are zero with
    # the spread their random walks reach over the record
    p = np.zeros((n, n))
    var_h = sigma_h * sigma_h
    duration = max(t_grid[-1] - t_grid[0], 1e-12)
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += jm[i, k] * sigma_w[k] * sigma_w[k] * jm[j, k]
            for k in range(r):
                acc += var_h * u[i, k] * u[j, k]
            p[i, j] = acc
        for k in range(r):
            p[i, c0 + k] = var_h * u[i, k]
            p[c0 + k, i] = var_h * u[i, k]
        p[3 + i, 3 + i] = q_d * duration
    for k in range(r):
        p[c0 + k, c0 + k] = var_h
        p[m0 + k, m0 + k] = q_m * duration
    tmp = np.zeros((n, n))
    f_ll, f_lc = np.zeros((3, 3)), np.zeros((3, r))
    phi_ll, phi_ld = np.zeros((3, 3)), np.zeros((3, 3))
    phi_lc, phi_lm = np.zeros((3, r)), np.zeros((3, r))
    w = np.empty(3)
    l_vec = np.empty(3)
    k1, k2, k3, k4, lt = np.empty(3), np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    hm = np.empty(3)
    he = np.empty(3)
    torque = np.empty(3)
    nz_max = 3 + r
    s = np.zeros((nz_max, nz_max))
    low = np.zeros((nz_max, nz_max))
    e = np.zeros(nz_max)
    y = np.zeros(nz_max)
    ph = np.zeros((n, nz_max))
    gain = np.zeros((n, nz_max))
    rdiag = np.zeros(nz_max)
    total = 0.0
    out_rows[0] = 0.0
    for row in range(1, t_grid.shape[0]):
        ns = n_sub[row - 1]
        hs = (t_grid[row] - t_grid[row - 1]) / ns
        for _ in range(ns):
            # h at the sub-step's start, middle and end (c moves at the constant rate m)
            for i in range(3):
                h_vec[i] = h_ref[i]
                hm[i] = 0.0
                for j in range(r):
                    h_vec[i] += u[i, j] * x[c0 + j]
                    hm[i] += u[i, j] * x[m0 + j]
                he[i] = h_vec[i] + hm[i] * hs
                hm[i] = h_vec[i] + 0.5 * hm[i] * hs
                l_vec[i] = x[i]
                torque[i] = tau_grid[row - 1, i] + x[3 + i]
            # linearisation at the sub-step's start
            _rate(l_vec, h_vec, jinv, w)
            lx, ly, lz = x[0], x[1], x[2]
            for j in range(3):  # ([L]x J^-1)[:, j] = L x (J^-1)[:, j]
                cx, cy, cz = jinv[0, j], jinv[1, j], jinv[2, j]
                f_ll[0, j] = ly * cz - lz * cy
                f_ll[1, j] = lz * cx - lx * cz
                f_ll[2, j] = lx * cy - ly * cx
            f_ll[0, 1] += w[2]
            f_ll[0, 2] -= w[1]
            f_ll[1, 0] -= w[2]
            f_ll[1, 2] += w[0]
            f_ll[2, 0] += w[1]
            f_ll[2, 1] -= w[0]
            for j in range(r):
                cx, cy, cz = jinv_u[0, j], jinv_u[1, j], jinv_u[2, j]
                f_lc[0, j] = -(ly * cz - lz * cy)
                f_lc[1, j] = -(lz * cx - lx * cz)
                f_lc[2, j] = -(lx * cy - ly * cx)
            _transition(f_ll, f_lc, hs, r, phi_ll, phi_ld, phi_lc, phi_lm)
            _propagate_covariance(p, tmp, phi_ll, phi_ld, phi_lc, phi_lm, hs, r)
            # + Qd
            h2, h3 = 0.5 * hs * hs, hs ** 3 / 3.0
            for i in range(3):
                for j in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += f_ll[i, k] * f_ll[j, k]
                    p[i, j] += q_w * h2 * (f_ll[i, j] + f_ll[j, i]) + q_w * h3 * acc
                p[i, i] += q_w * hs + q_d * h3
                p[i, 3 + i] += q_d * h2
                p[3 + i, i] += q_d * h2
                p[3 + i, 3 + i] += q_d * hs
            for k in range(r):
                p[c0 + k, c0 + k] += q_m * h3
                p[c0 + k, m0 + k] += q_m * h2
                p[m0 + k, c0 + k] += q_m * h2
                p[m0 + k, m0 + k] += q_m * hs
            # mean: RK4 on L with h linear over the sub-step; c advances at rate m
            _momentum_rate(l_vec[0], l_vec[1], l_vec[2], w[0], w[1], w[2], torque, k1)
            for i in range(3):
                lt[i] = l_vec[i] + 0.5 * hs * k1[i]
            _rate(lt, hm, jinv, w)
            _momentum_rate(lt[0], lt[1], lt[2], w[0], w[1], w[2], torque, k2)
            for i in range(3):
                lt[i] = l_vec[i] + 0.5 * hs * k2[i]
            _rate(lt, hm, jinv, w)
            _momentum_rate(lt[0], lt[1], lt[2], w[0], w[1], w[2], torque, k3)
            for i in range(3):
                lt[i] = l_vec[i] + hs * k3[i]
            _rate(lt, he, jinv, w)
            _momentum_rate(lt[0], lt[1], lt[2], w[0], w[1], w[2], torque, k4)
            for i in range(3):
                x[i] = l_vec[i] + hs / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            for j in range(r):
                x[c0 + j] += hs * x[m0 + j]
        # measurement update: the gyro on every row, the momentum log where fresh
        nz = 3 + (r if fresh[row] else 0)
        for i in range(3):
            h_vec[i] = h_ref[i]
            for j in range(r):
                h_vec[i] += u[i, j] * x[c0 + j]
            l_vec[i] = x[i]
        _rate(l_vec, h_vec, jinv, w)
        # H = [[J^-1, 0, -J^-1 U, 0], [0, 0, I, -delay I] (fresh log rows)]: P H^T and
        # S = H P H^T + R through H's non-zero blocks
        for i in range(3):
            e[i] = z_w[row, i] - w[i]
            rdiag[i] = sigma_w[i] * sigma_w[i]
        for j in range(nz - 3):
            e[3 + j] = z_c[row, j] - x[c0 + j] + delay * x[m0 + j]
            rdiag[3 + j] = var_h
        for i in range(n):
            for j in range(3):
                acc = p[i, 0] * jinv[j, 0] + p[i, 1] * jinv[j, 1] + p[i, 2] * jinv[j, 2]
                for k in range(r):
                    acc -= p[i, c0 + k] * jinv_u[j, k]
                ph[i, j] = acc
            for j in range(nz - 3):
                ph[i, 3 + j] = p[i, c0 + j] - delay * p[i, m0 + j]
        for a in range(nz):
            for b in range(a, nz):
                if a < 3:
                    acc = jinv[a, 0] * ph[0, b] + jinv[a, 1] * ph[1, b] + jinv[a, 2] * ph[2, b]
                    for k in range(r):
                        acc -= jinv_u[a, k] * ph[c0 + k, b]
                else:
                    acc = ph[c0 + a - 3, b] - delay * ph[m0 + a - 3, b]
                s[a, b] = acc
                s[b, a] = acc
            s[a, a] += rdiag[a]
        logdet = _cholesky_solve(s, e, nz, low, y)
        if not math.isfinite(logdet):
            return math.nan
        d2 = 0.0
        for i in range(nz):
            d2 += y[i] * y[i]
        c2 = huber_c2[nz]
        loss = 0.5 * d2
        if d2 > c2:
            # Huber: this row's measurement noise inflated by d / c
            d = math.sqrt(d2)
            c = math.sqrt(c2)
            loss = c * d - 0.5 * c2
            for i in range(nz):
                s[i, i] += rdiag[i] * (d / c - 1.0)
            _cholesky_solve(s, e, nz, low, y)
        total += loss + 0.5 * logdet
        out_rows[row] = loss + 0.5 * logdet
        # gain K = P H^T S^-1 (row i of K solves S k = (P H^T)[i])
        for i in range(n):
            for j in range(nz):
                acc = ph[i, j]
                for k in range(j):
                    acc -= low[j, k] * gain[i, k]
                gain[i, j] = acc / low[j, j]
            for j in range(nz - 1, -1, -1):
                acc = gain[i, j]
                for k in range(j + 1, nz):
                    acc -= low[k, j] * gain[i, k]
                gain[i, j] = acc / low[j, j]
        for i in range(n):
            acc = 0.0
            for j in range(nz):
                acc += gain[i, j] * e[j]
            x[i] += acc
        # P = P - K (P H^T)^T = P - P H^T S^-1 H P (symmetric; the gain is optimal for the noise
        # used)
        for i in range(n):
            for j in range(i, n):
                acc = 0.0
                for k in range(nz):
                    acc += gain[i, k] * ph[j, k]
                p[i, j] -= acc
                p[j, i] = p[i, j]
        if not (math.isfinite(x[0]) and math.isfinite(x[1]) and math.isfinite(x[2])):
            return math.nan
    return total


# ------------------------------------------------------------------------------------------
# Problem, fit, covariance
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FilterErrorProblem:
    """One record prepared for the filter-error fit (rows = grid = measurements).

    t_grid (M,) s from 0; n_sub (M,) RK4 sub-steps per interval; tau_grid (M, 3) N·m held per
    row; z_w (M, 3) rad/s gyro; sigma_w (3,) rad/s; h_ref (3,) kg·m²/s and u (3, r) orthonormal:
    the logged internal momentum varies in h_ref + span(u); z_c (M, r) its projection
    u^T (h_log - h_ref); fresh (M,) bool: the rows whose log is a new sample; fix_scale: the
    record does not fix the scale (phi[0] held).
    """

    t_grid: np.ndarray
    n_sub: np.ndarray
    tau_grid: np.ndarray
    z_w: np.ndarray
    sigma_w: np.ndarray
    h_ref: np.ndarray
    u: np.ndarray
    z_c: np.ndarray
    fresh: np.ndarray
    fix_scale: bool

    @property
    def huber_c2(self) -> np.ndarray:
        """(3 + r + 1,) squared Huber corner per measurement count nz (chi-square quantile)."""
        dims = np.arange(3 + self.u.shape[1] + 1)
        return np.where(dims > 0, chi2.ppf(HUBER_LEVEL, np.maximum(dims, 1)), 0.0)

    def loss(self, phi, q_w, q_d, q_m, sigma_h, delay=0.0, out_rows=None) -> float:
        """Summed robust loss (inf where the filter fails) at phi (6,), q_w N²·m²·s (white
        disturbance), q_d N²·m²/s (random-walk disturbance), q_m N²·m²/s, sigma_h kg·m²/s and
        delay s (the log lags the gyro); out_rows (M,) receives the per-row loss.
        """
        rows = np.empty(self.t_grid.size) if out_rows is None else out_rows
        value = innovation_loss(self.t_grid, self.n_sub, self.tau_grid, self.z_w, self.sigma_w,
                                self.z_c, self.fresh, self.h_ref, self.u, np.ascontiguousarray(phi),
                                q_w, q_d, q_m, sigma_h, delay, self.huber_c2, rows)
        return value if math.isfinite(value) else math.inf


def problem_from_rows(t, z_w, h_log, sigma_w, tau=None, n_sub=None,
                      fix_scale: bool = False) -> FilterErrorProblem:
    """The filter-error problem of a gyro record with a logged internal momentum.

    t (M,) s; z_w (M, 3) rad/s; h_log (M, 3) kg·m²/s as logged (held values allowed); sigma_w
    (3,) rad/s; tau (M, 3) N·m or None; n_sub (M,) sub-steps (default one per row).
    The momentum's span u keeps the directions of h_log's variation whose singular value
    exceeds H_SPAN_TOL of the largest (a single rotor: its axis; a constant momentum: none).
    """
    t = np.asarray(t, float) - float(t[0])
    h_log = np.asarray(h_log, float)
    h_ref = h_log.mean(axis=0)
    _, sv, vt = np.linalg.svd(h_log - h_ref, full_matrices=False)
    # relative to the largest variation, and that to the momentum itself (rounding is no span)
    size = max(float(np.abs(h_log).max()) * math.sqrt(t.size), 1e-300)
    keep = (sv > H_SPAN_TOL * float(sv[0])) & (sv > 1e-9 * size)
    u = np.ascontiguousarray(vt[keep].T)
    fresh = np.ones(t.size, dtype=np.bool_)
    fresh[1:] = np.any(np.diff(h_log, axis=0) != 0.0, axis=1)
    m = t.size
    return FilterErrorProblem(
        t_grid=t, n_sub=np.ones(m, np.int64) if n_sub is None else np.asarray(n_sub, np.int64),
        tau_grid=np.zeros((m, 3)) if tau is None else np.asarray(tau, float),
        z_w=np.asarray(z_w, float), sigma_w=np.broadcast_to(np.asarray(sigma_w, float), (3,)).copy(),
        h_ref=h_ref, u=u, z_c=np.ascontiguousarray((h_log - h_ref) @ u), fresh=fresh,
        fix_scale=bool(fix_scale))


@dataclasses.dataclass(frozen=True)
class FilterErrorFit:
    """Result of fit(): v (9,) = [phi (6), log q_w, log q_d, delay s] at the optimum and cov
    (9, 9) its sandwich covariance (zero rows for held entries); q_m N²·m²/s and sigma_h kg·m²/s, the
    momentum log's own hyperparameters (held in the fit); loss the summed robust loss;
    converged (the optimiser's verdict); n_eval the optimiser's filter runs.
    """

    v: np.ndarray
    cov: np.ndarray
    q_m: float
    sigma_h: float
    loss: float
    converged: bool
    n_eval: int

    @property
    def phi(self) -> np.ndarray:
        """(6,) log-Cholesky inertia."""
        return self.v[:6]

    @property
    def q_w(self) -> float:
        """Intensity of the white disturbance torque, N²·m²·s."""
        return math.exp(self.v[6])

    @property
    def q_d(self) -> float:
        """Intensity of the random-walk disturbance torque's rate, N²·m²/s."""
        return math.exp(self.v[7])

    @property
    def delay(self) -> float:
        """Lag of the momentum log behind the gyro, s."""
        return float(self.v[8])


@nb.njit(cache=True, nogil=True)
def log_trend_loss(t, z, q_m, sigma_h) -> float:
    """Negative log-likelihood (constants dropped) of a momentum log z (N, r) at times t (N,) s
    under the local linear trend c_dot = m, m_dot = white (q_m N²·m²/s), z = c + noise
    (sigma_h kg·m²/s): the log's own model, without the gyro (a Kalman filter per component).
    """
    total = 0.0
    var_h = sigma_h * sigma_h
    duration = max(t[-1] - t[0], 1e-12)
    for j in range(z.shape[1]):
        c, m = z[0, j], 0.0
        p00, p01, p11 = var_h, 0.0, q_m * duration
        for k in range(1, t.shape[0]):
            dt = t[k] - t[k - 1]
            c += m * dt
            p00 += 2.0 * dt * p01 + dt * dt * p11 + q_m * dt ** 3 / 3.0
            p01 += dt * p11 + q_m * dt * dt / 2.0
            p11 += q_m * dt
            s = p00 + var_h
            e = z[k, j] - c
            total += 0.5 * (e * e / s + math.log(s))
            k0, k1 = p00 / s, p01 / s
            c += k0 * e
            m += k1 * e
            p11 -= k1 * p01
            p01 -= k0 * p01
            p00 -= k0 * p00
    return total


def log_hyper(prob: FilterErrorProblem) -> tuple[float, float]:
    """(q_m N²·m²/s, sigma_h kg·m²/s): maximum likelihood of the momentum log's own local
    linear trend over its fresh samples (no gyro). The log alone determines both: how fast the
    internal momentum accelerates and how much the logger jitters.
    """
    t, z = prob.t_grid[prob.fresh], prob.z_c[prob.fresh]
    span = max(float(np.ptp(prob.z_c, axis=0).max()), 1e-300)
    duration = max(float(prob.t_grid[-1]), 1e-12)
    start = [math.log(span ** 2 / duration ** 3), math.log(span * 1e-3)]
    best = minimize(lambda x: log_trend_loss(t, z, math.exp(x[0]), math.exp(x[1])), start,
                    method="Nelder-Mead", options=dict(xatol=0.01, fatol=1e-3, maxiter=400)).x
    return math.exp(best[0]), math.exp(best[1])


def intensity_floor(prob: FilterErrorProblem, phi) -> np.ndarray:
    """(2,) lower bounds of [log q_w, log q_d]: the intensities whose random walks move the rate
    by a tenth of the gyro noise over the whole record (below, a disturbance is invisible and
    its likelihood flat). q_w N²·m²·s from (sigma_w |J| / 10)² / T; q_d = 3 q_w / T².
    """
    duration = max(float(prob.t_grid[-1]), 1e-12)
    size = float(np.linalg.norm(inertia_from_phi(np.ascontiguousarray(phi)), 2))
    q_w = (0.1 * float(np.mean(prob.sigma_w)) * size) ** 2 / duration
    return np.array([math.log(q_w), math.log(3.0 * q_w / duration ** 2)])


def start_disturbance(prob: FilterErrorProblem, phi, q_m: float, sigma_h: float,
                      q_start: float, floor) -> np.ndarray:
    """Start (2,) of [log q_w, log q_d] at phi (6,): a derivative-free search (within the floor
    (2,) of intensity_floor) from q_w = q_start (N²·m²·s, e.g. the output-error residuals'
    excess) and the q_d whose random walk moves the momentum as far over the record, or either
    intensity at its floor where that is better.
    """
    duration = max(float(prob.t_grid[-1]), 1e-12)
    x0 = np.maximum([math.log(max(q_start, 1e-300)),
                     math.log(max(3.0 * q_start / duration ** 2, 1e-300))], floor + 3.0)

    def loss(x):
        x = np.maximum(x, floor)
        return prob.loss(phi, math.exp(x[0]), math.exp(x[1]), q_m, sigma_h)

    simplex = np.array([x0, x0 + [-3.0, 0.0], x0 + [0.0, 3.0]])
    res = minimize(loss, x0, method="Nelder-Mead",
                   options=dict(initial_simplex=simplex, xatol=0.3, fatol=0.5, maxiter=40))
    best = np.maximum(np.asarray(res.x, float), floor)
    # Either disturbance may be absent: the loss then falls towards its floor like a + b q,
    # an asymptote the search only crawls along. Try the floor outright.
    candidates = [best, np.array([floor[0], best[1]]), np.array([best[0], floor[1]])]
    return min(candidates, key=loss)


def _loss_at(prob: FilterErrorProblem, v, q_m: float, sigma_h: float, out_rows=None) -> float:
    """The loss at v (9,) = [phi, log q_w, log q_d, delay] with the log's q_m and sigma_h."""
    return prob.loss(v[:6], math.exp(v[6]), math.exp(v[7]), q_m, sigma_h, float(v[8]), out_rows)


def _fd_steps(idx) -> np.ndarray:
    """Central-difference steps for the entries idx of v: FD_STEP (log units), DELAY_FD_STEP s."""
    return np.where(np.asarray(idx) == 8, DELAY_FD_STEP, FD_STEP)


def fit(prob: FilterErrorProblem, phi_start, q_start: float, max_iter: int = 30,
        tol: float = 1e-3) -> FilterErrorFit:
    """Minimise the robust innovation loss over phi, the two log-intensities of the disturbance
    and the log's delay from phi_start (6,), q_start (N²·m²·s, see start_disturbance) and no
    delay, the momentum log's hyperparameters held at log_hyper's and the intensities above
    intensity_floor (without a varying momentum the delay is held at 0). Projected Newton steps
    on a finite-difference Hessian (computed at the start, then BFGS-updated; eigenvalues made
    positive, a step moves phi by at most MAX_PHI_STEP, a log-intensity by MAX_LOG_Q_STEP and
    the delay by MAX_DELAY_STEP, halved until the loss falls; an intensity pushed downwards is
    also tried on its floor), converged when a step's predicted
    and actual decrease are below tol (nats). Returns the optimum with its sandwich covariance.
    """
    q_m, sigma_h = log_hyper(prob)
    phi_start = np.asarray(phi_start, float)
    floor = intensity_floor(prob, phi_start)
    v0 = np.concatenate([phi_start, start_disturbance(prob, phi_start, q_m, sigma_h, q_start,
                                                      floor), [0.0]])
    free = np.ones(9, dtype=bool)
    free[0] = not prob.fix_scale
    free[8] = prob.u.shape[1] > 0
    idx = np.flatnonzero(free)
    low = np.r_[np.full(6, -np.inf), floor, -np.inf][idx]
    cap = np.r_[np.full(6, MAX_PHI_STEP), MAX_LOG_Q_STEP, MAX_LOG_Q_STEP, MAX_DELAY_STEP][idx]
    steps = _fd_steps(idx)
    count = [0]

    def total(x):
        v = v0.copy()
        v[idx] = np.maximum(x, low)
        count[0] += 1
        return _loss_at(prob, v, q_m, sigma_h)

    def grad(x):
        g = np.zeros(x.size)
        for i in range(x.size):
            e = np.zeros(x.size)
            e[i] = steps[i]
            g[i] = (total(x + e) - total(x - e)) / (2 * steps[i])
        return g

    x = v0[idx].copy()
    f = total(x)
    if not math.isfinite(f):
        raise ConfigError("the filter diverges at the output-error start")
    rows = np.empty(prob.t_grid.size)
    scores = np.zeros((prob.t_grid.size, x.size))
    for i in range(x.size):  # per-row scores: the gradient and, BHHH, a first Hessian model
        for sign in (1.0, -1.0):
            e = np.zeros(x.size)
            e[i] = sign * steps[i]
            v = v0.copy()
            v[idx] = np.maximum(x + e, low)
            count[0] += 1
            _loss_at(prob, v, q_m, sigma_h, rows)
            scores[:, i] += sign * rows / (2 * steps[i])
    g = scores.sum(axis=0)
    hess = scores.T @ scores
    converged = False
    for _ in range(max_iter):
        vals, vecs = np.linalg.eigh(0.5 * (hess + hess.T))
        vals = np.maximum(np.abs(vals), 1e-8 * max(float(np.abs(vals).max()), 1e-300))
        step = -(vecs / vals) @ (vecs.T @ g)
        step *= min(1.0, float(np.min(cap / np.maximum(np.abs(step), 1e-300))))
        step = np.maximum(x + step, low) - x  # projected onto the floor
        # An intensity the loss pushes down may have no optimum above its floor (the loss then
        # creeps down an asymptote): offer the step that puts it on the floor as well.
        options = [step]
        for i in np.flatnonzero(np.isfinite(low) & (g > 0) & (x > low)):
            options.append(step.copy())
            options[-1][i] = low[i] - x[i]
        f_new, step = min(((total(x + s), s) for s in options), key=lambda fs: fs[0])
        improved = f_new < f
        for _ in range(20):
            predicted = -float(g @ step) - 0.5 * float(step @ hess @ step)
            if improved:
                break
            step *= 0.5
            f_new = total(x + step)
            improved = f_new < f
        if not improved:
            converged = True  # no step lowers the loss: a minimum to working precision
            break
        drop = f - f_new
        g_new = grad(x + step)
        y = g_new - g
        if float(y @ step) > 0:  # BFGS update keeps the Hessian model current
            hs = hess @ step
            hess = hess + np.outer(y, y) / float(y @ step) - np.outer(hs, hs) / float(step @ hs)
        x, f, g = x + step, f_new, g_new
        if max(predicted, drop) < tol:
            converged = True
            break
    v = v0.copy()
    v[idx] = x
    cov = np.zeros((9, 9))
    cov[np.ix_(free, free)] = sandwich(prob, v, free, q_m, sigma_h)
    return FilterErrorFit(v, cov, q_m, sigma_h, float(f), converged, count[0])


def fd_hessian(func, x, step) -> np.ndarray:
    """Central-difference Hessian (n, n) of a scalar func at x (n,) with steps step (n,):
    diagonal from (f(x+h) - 2 f(x) + f(x-h)) / h², off-diagonal from the four-point formula.
    """
    n = x.size
    f0 = func(x)
    hess = np.zeros((n, n))
    e = [np.eye(n)[i] * step[i] for i in range(n)]
    for i in range(n):
        hess[i, i] = (func(x + e[i]) - 2 * f0 + func(x - e[i])) / step[i] ** 2
        for j in range(i):
            val = (func(x + e[i] + e[j]) - func(x + e[i] - e[j]) - func(x - e[i] + e[j])
                   + func(x - e[i] - e[j])) / (4 * step[i] * step[j])
            hess[i, j] = hess[j, i] = val
    return hess


def sandwich(prob: FilterErrorProblem, v, free, q_m: float, sigma_h: float) -> np.ndarray:
    """The M-estimator covariance A^-1 B A^-1 over the free entries of v (9,): A the Hessian of
    the summed loss, B the long-run covariance of the per-row scores (central differences,
    Bartlett weights over as many lags as the scores stay correlated).
    """
    idx = np.flatnonzero(free)
    steps = _fd_steps(idx)
    rows = np.empty(prob.t_grid.size)

    def total(x):
        w = v.copy()
        w[idx] = x
        return _loss_at(prob, w, q_m, sigma_h)

    hess = fd_hessian(total, v[idx], 10 * steps)
    scores = np.zeros((prob.t_grid.size, idx.size))
    for i in range(idx.size):
        for sign in (1.0, -1.0):
            w = v.copy()
            w[idx[i]] += sign * steps[i]
            _loss_at(prob, w, q_m, sigma_h, rows)
            scores[:, i] += sign * rows / (2 * steps[i])
    b = long_run_covariance(scores, correlation_lags(scores))
    a_inv = np.linalg.pinv(hess)
    cov = a_inv @ b @ a_inv
    return 0.5 * (cov + cov.T)
