"""Extended Kalman filter of x = (q, w, phi): 13 states, phi the scale-separated
log-Cholesky inertia (estimation/inertia_param.py).

Textbook names (filterpy): x, P, F (here the transition Phi over a measurement interval), Q, R,
H, K, S. Between measurements the mean is advanced with RK4 at the simulation step dt and the
transition matrix is accumulated from the analytic Jacobian (F_k = I + dt A_k, exploiting its
block structure); the covariance is propagated once per measurement interval:
P^- = Phi P Phi^T + Q_k. The update uses the Joseph form
P = (I - K H) P (I - K H)^T + K R K^T (written out so that it costs O(n^2 m)).
Q_k = alpha_k blkdiag(Q_q I4, Q_w I3, Q_phi) with Q_phi = D^-1 (Q_theta I6) D^-T (scale-shape
block kept zero), alpha_k = 0.999 gamma^k + q_min, k = number of updates so far.

Measurement vector z = (gyro w (3), [attitude q (4)], [gravity (3), magnetic field (3)]).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from inertia_gym.dynamics import rk4_step_into
from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_norm_sq, theta_into
from inertia_gym.information import psi_into
from inertia_gym.sensors import align_quaternion_sign, measurement_model, measurement_noise

N_STATE = 13


@nb.njit(cache=True)
def accumulate_transition(x, inertia, inertia_inv, tau, dt, phi_top, work, dist):
    """phi_top <- (I + dt A) phi_top for the (q, w) rows, theta columns in theta coordinates.

    phi_top : (7, 13) rows (q, w), columns (q, w, theta). A is the Jacobian of (q_dot, w_dot)
    at x: A_qq = 1/2 Omega(w), A_qw = 1/2 Xi(q), A_ww = J^-1 ([J w + h]x - [w]x J),
    A_wtheta = -J^-1 Psi(w, w_dot) (eq. 9 differentiated). The w rows have zero q columns, which
    the loops skip. work : (13, 13) scratch; allocation-free. dist : the packed disturbance of
    dynamics.py, of which the filter's model uses the known internal momentum h = dist[3:6]
    (N·m·s) and the extra torque dist[0:3] (N·m, e.g. -h_dot); zeros in the simulator.
    """
    qw, qx, qy, qz = x[0], x[1], x[2], x[3]
    wx, wy, wz = x[4], x[5], x[6]
    hx = inertia[0, 0] * wx + inertia[0, 1] * wy + inertia[0, 2] * wz + dist[3]
    hy = inertia[1, 0] * wx + inertia[1, 1] * wy + inertia[1, 2] * wz + dist[4]
    hz = inertia[2, 0] * wx + inertia[2, 1] * wy + inertia[2, 2] * wz + dist[5]
    mx = tau[0] + dist[0] - (wy * hz - wz * hy)
    my = tau[1] + dist[1] - (wz * hx - wx * hz)
    mz = tau[2] + dist[2] - (wx * hy - wy * hx)
    acc = work[0, 0:3]
    for i in range(3):
        acc[i] = inertia_inv[i, 0] * mx + inertia_inv[i, 1] * my + inertia_inv[i, 2] * mz
    # M = [J w]x - [w]x J, then A_ww = J^-1 M
    m = work[1:4, 0:3]
    for j in range(3):
        m[0, j] = -(wy * inertia[2, j] - wz * inertia[1, j])
        m[1, j] = -(wz * inertia[0, j] - wx * inertia[2, j])
        m[2, j] = -(wx * inertia[1, j] - wy * inertia[0, j])
    m[0, 1] -= hz
    m[0, 2] += hy
    m[1, 0] += hz
    m[1, 2] -= hx
    m[2, 0] -= hy
    m[2, 1] += hx
    a_ww = work[4:7, 0:3]
    psi = work[7:10, 0:6]
    psi_into(x[4:7], acc, psi)
    a_wth = work[10:13, 0:6]
    for i in range(3):
        for j in range(3):
            a_ww[i, j] = inertia_inv[i, 0] * m[0, j] + inertia_inv[i, 1] * m[1, j] \
                + inertia_inv[i, 2] * m[2, j]
        for j in range(6):
            a_wth[i, j] = -(inertia_inv[i, 0] * psi[0, j] + inertia_inv[i, 1] * psi[1, j]
                            + inertia_inv[i, 2] * psi[2, j])
    # A_qq = 1/2 Omega(w) (zero diagonal), A_qw = 1/2 Xi(q) and A_ww (b), as scalars.
    hwx, hwy, hwz = 0.5 * wx, 0.5 * wy, 0.5 * wz
    hqw, hqx, hqy, hqz = 0.5 * qw, 0.5 * qx, 0.5 * qy, 0.5 * qz
    b00, b01, b02 = a_ww[0, 0], a_ww[0, 1], a_ww[0, 2]
    b10, b11, b12 = a_ww[1, 0], a_ww[1, 1], a_ww[1, 2]
    b20, b21, b22 = a_ww[2, 0], a_ww[2, 1], a_ww[2, 2]
    # Column by column: c <- c + dt A c, the column's old values held in scalars.
    for j in range(N_STATE):
        c0, c1, c2, c3 = phi_top[0, j], phi_top[1, j], phi_top[2, j], phi_top[3, j]
        c4, c5, c6 = phi_top[4, j], phi_top[5, j], phi_top[6, j]
        phi_top[0, j] = c0 + dt * ((-hwx * c1 - hwy * c2 - hwz * c3)
                                   + (-hqx * c4 - hqy * c5 - hqz * c6))
        phi_top[1, j] = c1 + dt * ((hwx * c0 + hwz * c2 - hwy * c3)
                                   + (hqw * c4 - hqz * c5 + hqy * c6))
        phi_top[2, j] = c2 + dt * ((hwy * c0 - hwz * c1 + hwx * c3)
                                   + (hqz * c4 + hqw * c5 - hqx * c6))
        phi_top[3, j] = c3 + dt * ((hwz * c0 + hwy * c1 - hwx * c2)
                                   + (-hqy * c4 + hqx * c5 + hqw * c6))
        if j >= 4:  # the rate rows have zero attitude columns
            d4 = b00 * c4 + b01 * c5 + b02 * c6
            d5 = b10 * c4 + b11 * c5 + b12 * c6
            d6 = b20 * c4 + b21 * c5 + b22 * c6
            if j >= 7:
                d4 += a_wth[0, j - 7]
                d5 += a_wth[1, j - 7]
                d6 += a_wth[2, j - 7]
            phi_top[4, j] = c4 + dt * d4
            phi_top[5, j] = c5 + dt * d5
            phi_top[6, j] = c6 + dt * d6


@nb.njit(cache=True)
def alpha_schedule(k, gamma, q_min):
    """alpha_k = 0.999 gamma^k + q_min (paper, simulation section)."""
    return 0.999 * gamma**k + q_min


@nb.njit(cache=True)
def small_inverse(a):
    """Inverse of a small well-conditioned square matrix by Gauss-Jordan with partial pivoting."""
    n = a.shape[0]
    m = a.copy()
    inv = np.eye(n)
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(m[r, c]) > abs(m[piv, c]):
                piv = r
        if piv != c:
            for k in range(n):
                m[c, k], m[piv, k] = m[piv, k], m[c, k]
                inv[c, k], inv[piv, k] = inv[piv, k], inv[c, k]
        d = 1.0 / m[c, c]
        for k in range(n):
            m[c, k] *= d
            inv[c, k] *= d
        for r in range(n):
            if r != c and m[r, c] != 0.0:
                f = m[r, c]
                for k in range(n):
                    m[r, k] -= f * m[c, k]
                    inv[r, k] -= f * inv[c, k]
    return inv


@nb.njit(cache=True)
def add_process_noise(P, x, n_updates, cfg):
    """P += Q_k = alpha_k blkdiag(Q_q I4, Q_w I3, Q_phi), Q_phi = D^-1 Q_theta D^-T (in place)."""
    alpha = alpha_schedule(n_updates, cfg.alpha_gamma, cfg.alpha_qmin)
    for i in range(4):
        P[i, i] += alpha * cfg.Q_quat
    for i in range(4, 7):
        P[i, i] += alpha * cfg.Q_omega
    if cfg.Q_theta > 0.0:
        d_inv = small_inverse(dtheta_dphi(x[7:13]))
        for i in range(6):
            for j in range(6):
                if (i == 0) != (j == 0):  # keep scale and shape uncorrelated (inertia_param.py)
                    continue
                acc = 0.0
                for k in range(6):
                    acc += d_inv[i, k] * d_inv[j, k]
                P[7 + i, 7 + j] += alpha * cfg.Q_theta * acc


@nb.njit(cache=True)
def propagate_covariance(P, phi_top, x, n_updates, cfg, work):
    """P <- P^- = Phi P Phi^T + Q_k in place (P symmetric, as the filter keeps it), with phi_top
    from :func:`accumulate_transition`.

    Phi = [[phi_top (q, w, theta D)], [0, 0, I6]]: the inertia rows are the identity, so with
    T = Phi_top P (7, 13) the prediction is [[T Phi_top^T, T_theta], [T_theta^T, P_theta]],
    about 1.8k multiply-adds instead of 4.4k. work : (14, 13) scratch.
    """
    d = dtheta_dphi(x[7:13])
    phi = work[0:7]  # Phi_top with its theta columns in phi coordinates
    for i in range(7):
        for j in range(7):
            phi[i, j] = phi_top[i, j]
        for j in range(6):
            acc = 0.0
            for k in range(6):
                acc += phi_top[i, 7 + k] * d[k, j]
            phi[i, 7 + j] = acc
    t = work[7:14]  # T = Phi_top P
    for i in range(7):
        for j in range(N_STATE):
            acc = 0.0
            for k in range(N_STATE):
                acc += phi[i, k] * P[k, j]
            t[i, j] = acc
    for i in range(7):
        for j in range(7):
            acc = 0.0
            for k in range(N_STATE):
                acc += t[i, k] * phi[j, k]
            P[i, j] = acc
        for j in range(7, N_STATE):
            P[i, j] = t[i, j]
            P[j, i] = t[i, j]
    add_process_noise(P, x, n_updates, cfg)
    for i in range(7):
        for j in range(i + 1, 7):
            avg = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = avg
            P[j, i] = avg


@nb.njit(cache=True)
def limit_inertia_step(x, gain, innov, limit):
    """Damp the inertia rows of the gain so one update changes J by at most ``limit`` (relative).

    ||J(phi + d_phi) - J(phi)||_F <= limit ||J(phi)||_F. The Joseph form stays the exact
    covariance of the damped (suboptimal) gain, so the filter remains consistent; far from the
    truth this turns a wild linearised jump into a sequence of short, re-linearised steps.
    """
    if limit <= 0.0:
        return
    phi_new = np.empty(6)  # phi + d_phi
    d_phi = np.empty(6)
    theta_old = np.empty(6)
    theta_new = np.empty(6)
    for i in range(6):
        acc = 0.0
        for j in range(innov.shape[0]):
            acc += gain[7 + i, j] * innov[j]
        d_phi[i] = acc
    theta_into(x[7:13], theta_old)
    allowed = limit * math.sqrt(inertia_norm_sq(theta_old))
    for _ in range(60):
        for i in range(6):
            phi_new[i] = x[7 + i] + d_phi[i]
        theta_into(phi_new, theta_new)
        for i in range(6):
            theta_new[i] -= theta_old[i]
        change = math.sqrt(inertia_norm_sq(theta_new))
        if change <= allowed:
            return
        scale = max(0.5, 0.9 * allowed / change)
        for i in range(7, 13):
            for j in range(gain.shape[1]):
                gain[i, j] *= scale
        for i in range(6):
            d_phi[i] *= scale


@nb.njit(cache=True)
def _cholesky_into(s, low):
    """Lower Cholesky factor of the small SPD matrix s into low; False if not positive definite."""
    n = s.shape[0]
    for i in range(n):
        for j in range(i + 1):
            acc = s[i, j]
            for k in range(j):
                acc -= low[i, k] * low[j, k]
            if i == j:
                if not acc > 0.0:
                    return False
                low[i, i] = math.sqrt(acc)
            else:
                low[i, j] = acc / low[j, j]
        for j in range(i + 1, n):
            low[i, j] = 0.0
    return True


@nb.njit(cache=True)
def _solve_lower(low, b, out):
    for i in range(b.shape[0]):
        acc = b[i]
        for k in range(i):
            acc -= low[i, k] * out[k]
        out[i] = acc / low[i, i]


@nb.njit(cache=True)
def _solve_upper_t(low, b, out):
    """Solve L^T out = b."""
    n = b.shape[0]
    for i in range(n - 1, -1, -1):
        acc = b[i]
        for k in range(i + 1, n):
            acc -= low[k, i] * out[k]
        out[i] = acc / low[i, i]


@nb.njit(cache=True)
def _innovation_covariance(P, big_h, r, pht, s):
    """Fill pht = P H^T (n, m) and S = H P H^T + diag(r) (m, m).

    Only H's non-zero entries are visited: rate and attitude rows select one state each, so
    this costs O(n m) instead of O(n^2 m); the sums run in the same order as the dense product.
    """
    n, m = P.shape[0], big_h.shape[0]
    for i in range(n):
        for j in range(m):
            pht[i, j] = 0.0
    for j in range(m):
        for k in range(n):
            h_jk = big_h[j, k]
            if h_jk != 0.0:
                for i in range(n):
                    pht[i, j] += P[i, k] * h_jk
    for i in range(m):
        for j in range(m):
            s[i, j] = r[i] if i == j else 0.0
        for k in range(n):
            h_ik = big_h[i, k]
            if h_ik != 0.0:
                for j in range(m):
                    s[i, j] += h_ik * pht[k, j]


@nb.njit(cache=True)
def ekf_update(x, P, z, cfg):
    """EKF update in place (Joseph form); returns the normalised innovation squared (NIS).

    The covariance update is the Joseph form expanded, P+ = P - K H P - P H^T K^T + K S K^T,
    which equals (I - K H) P (I - K H)^T + K R K^T for any gain K (so it stays exact for the
    damped gain of :func:`limit_inertia_step`). Raises ValueError if S is not positive definite.

    Consistency guard: when the NIS exceeds cfg.nis_gate times the measurement size, the
    rate and attitude prior variances are raised (adaptive process noise) until it does not.
    Far from the true inertia the model's one-interval prediction of w is poor; explaining that
    as process noise keeps the rate on the gyro and lets theta learn in small, well-linearised
    steps instead of a wild Gauss-Newton jump onto a wrong inertia.
    """
    align_quaternion_sign(z, x, cfg)
    h, big_h = measurement_model(x, cfg)
    r = measurement_noise(cfg)
    m = r.shape[0]
    innov = z - h
    gate = cfg.nis_gate * m
    add_w = (innov[0] ** 2 + innov[1] ** 2 + innov[2] ** 2) / 3.0
    add_q = 0.0
    if cfg.use_quat > 0:
        add_q = (innov[3] ** 2 + innov[4] ** 2 + innov[5] ** 2 + innov[6] ** 2) / 4.0
    pht = np.empty((N_STATE, m))
    s = np.empty((m, m))
    low = np.empty((m, m))
    y = np.empty(m)
    nis_raw = 0.0
    for attempt in range(40):
        _innovation_covariance(P, big_h, r, pht, s)
        if not _cholesky_into(s, low):
            raise ValueError("innovation covariance is not positive definite")
        _solve_lower(low, innov, y)
        nis = 0.0
        for i in range(m):
            nis += y[i] * y[i]
        if attempt == 0:
            nis_raw = nis
        if gate <= 0.0 or nis <= gate:
            break
        for i in range(4, 7):
            P[i, i] += add_w
        for i in range(4):
            P[i, i] += add_q
        add_w *= 2.0
        add_q *= 2.0
    # K = P H^T S^-1: solve S k_i = (P H^T)_i for each row i.
    gain = np.empty((N_STATE, m))
    for i in range(N_STATE):
        _solve_lower(low, pht[i], y)
        _solve_upper_t(low, y, gain[i])
    limit_inertia_step(x, gain, innov, cfg.inertia_step_limit)
    for i in range(N_STATE):
        acc = 0.0
        for j in range(m):
            acc += gain[i, j] * innov[j]
        x[i] += acc
    ks = np.empty((N_STATE, m))  # K S
    for i in range(N_STATE):
        for j in range(m):
            acc = 0.0
            for k in range(m):
                acc += gain[i, k] * s[k, j]
            ks[i, j] = acc
    for i in range(N_STATE):
        for j in range(i, N_STATE):
            acc = P[i, j]
            for k in range(m):
                acc += -gain[i, k] * pht[j, k] - pht[i, k] * gain[j, k] + ks[i, k] * gain[j, k]
            P[i, j] = acc
            P[j, i] = acc
    norm = math.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2 + x[3] ** 2)
    for i in range(4):
        x[i] /= norm
    return nis_raw


@nb.njit(cache=True)
def ekf_predict_step(x, tau, dt, inertia, inertia_inv, phi_top, scratch_jac, dist):
    """Advance the EKF mean by one dt (RK4) and accumulate the transition; x updated in place.

    inertia, inertia_inv : J(phi) and its inverse for the current x (phi is constant between
    updates, so the caller computes them once per measurement interval).
    scratch_jac : (13, 13). dist : (20,) packed disturbance; the model uses its internal
    momentum h and extra torque (see :func:`accumulate_transition`).
    """
    accumulate_transition(x, inertia, inertia_inv, tau, dt, phi_top, scratch_jac, dist)
    rk4_step_into(x, dt, inertia, inertia_inv, tau, dist, x)


@nb.njit(cache=True)
def state_is_sane(x, P):
    """False when the estimate has left its domain: non-finite values or negative variances."""
    for i in range(N_STATE):
        if not math.isfinite(x[i]) or P[i, i] < 0.0:
            return False
        for j in range(N_STATE):
            if not math.isfinite(P[i, j]):
                return False
    for i in (7, 9, 12):  # log-scale and log-diagonals: |phi| > 40 means a factor e^40
        if abs(x[i]) > 40.0:
            return False
    return True
