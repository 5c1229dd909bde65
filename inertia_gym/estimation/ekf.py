"""Extended Kalman filter of x = (q, w, phi): 13 states, phi the scale-separated
log-Cholesky inertia (estimation/inertia_param.py).

Textbook names (filterpy): x, P, F (here the transition Phi over a measurement interval), Q, R,
H, K, S. Between measurements the mean is advanced with RK4 at the simulation step dt and the
transition matrix is accumulated from the analytic Jacobian (F_k = I + dt A_k, exploiting its
block structure); the covariance is propagated once per measurement interval:
P^- = Phi P Phi^T + Q_k. The update uses the Joseph form
P = (I - K H) P (I - K H)^T + K R K^T. Q_k = alpha_k blkdiag(Q_q I4, Q_w I3, Q_phi) with
Q_phi = D^-1 (Q_theta I6) D^-T (scale-shape block kept zero), alpha_k = 0.999 gamma^k + q_min, k = number of updates so far.

Measurement vector z = (gyro w (3), [attitude q (4)], [gravity (3), magnetic field (3)]).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from inertia_gym.dynamics import rk4_step_into
from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_from_phi
from inertia_gym.information import psi_into

N_STATE = 13
# Indices into the packed filter configuration vector (see simulation.pack_filter_config).
C_DT, C_GYRO, C_QUAT, C_ACC, C_MAG, C_QQ, C_QW, C_QTH, C_GAMMA, C_QMIN = range(10)
C_USE_QUAT, C_USE_VEC = 10, 11
C_GRAV = slice(12, 15)
C_MAGREF = slice(15, 18)
C_NIS_GATE = 18
C_STEP_LIMIT = 19
CONFIG_SIZE = 20


@nb.njit(cache=True)
def accumulate_transition(x, inertia, inertia_inv, tau, dt, phi_top, work):
    """phi_top <- (I + dt A) phi_top for the (q, w) rows, theta columns in theta coordinates.

    phi_top : (7, 13) rows (q, w), columns (q, w, theta). A is the Jacobian of
    (q_dot, w_dot) at x; d w_dot / d theta = -J^-1 Psi(w, w_dot) (eq. 9 differentiated).
    work : (3, 6) scratch.
    """
    qw, qx, qy, qz = x[0], x[1], x[2], x[3]
    wx, wy, wz = x[4], x[5], x[6]
    w = x[4:7]
    hx = inertia[0, 0] * wx + inertia[0, 1] * wy + inertia[0, 2] * wz
    hy = inertia[1, 0] * wx + inertia[1, 1] * wy + inertia[1, 2] * wz
    hz = inertia[2, 0] * wx + inertia[2, 1] * wy + inertia[2, 2] * wz
    mx = tau[0] - (wy * hz - wz * hy)
    my = tau[1] - (wz * hx - wx * hz)
    mz = tau[2] - (wx * hy - wy * hx)
    acc = np.empty(3)
    for i in range(3):
        acc[i] = inertia_inv[i, 0] * mx + inertia_inv[i, 1] * my + inertia_inv[i, 2] * mz
    # M = [J w]x - [w]x J ; A_ww = J^-1 M
    m = np.empty((3, 3))
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
    a_ww = inertia_inv @ m
    psi_into(w, acc, work)
    a_wth = -(inertia_inv @ work)
    # q rows: A_qq = 1/2 Omega(w), A_qw = 1/2 Xi(q)
    a_qq = 0.5 * np.array(
        ((0.0, -wx, -wy, -wz), (wx, 0.0, wz, -wy), (wy, -wz, 0.0, wx), (wz, wy, -wx, 0.0))
    )
    a_qw = 0.5 * np.array(((-qx, -qy, -qz), (qw, -qz, qy), (qz, qw, -qx), (-qy, qx, qw)))
    new_q = phi_top[0:4] + dt * (a_qq @ phi_top[0:4] + a_qw @ phi_top[4:7])
    new_w = phi_top[4:7] + dt * (a_ww @ phi_top[4:7])
    for i in range(3):
        for j in range(6):
            new_w[i, 7 + j] += dt * a_wth[i, j]
    phi_top[0:4] = new_q
    phi_top[4:7] = new_w


@nb.njit(cache=True)
def alpha_schedule(k, gamma, q_min):
    """alpha_k = 0.999 gamma^k + q_min (paper, simulation section)."""
    return 0.999 * gamma**k + q_min


@nb.njit(cache=True)
def propagate_covariance(P, phi_top, x, n_updates, cfg):
    """P^- = Phi P Phi^T + Q_k, with phi_top from :func:`accumulate_transition`. Returns P^-."""
    d = dtheta_dphi(x[7:13])
    full = np.eye(N_STATE)
    full[0:7, 0:7] = phi_top[:, 0:7]
    full[0:7, 7:13] = phi_top[:, 7:13] @ d
    p_new = full @ P @ full.T
    alpha = alpha_schedule(n_updates, cfg[C_GAMMA], cfg[C_QMIN])
    for i in range(4):
        p_new[i, i] += alpha * cfg[C_QQ]
    for i in range(4, 7):
        p_new[i, i] += alpha * cfg[C_QW]
    if cfg[C_QTH] > 0.0:
        d_inv = np.linalg.inv(d)
        q_phi = alpha * cfg[C_QTH] * (d_inv @ d_inv.T)
        for i in range(6):
            for j in range(6):
                if (i == 0) != (j == 0):  # keep scale and shape uncorrelated (inertia_param.py)
                    continue
                p_new[7 + i, 7 + j] += q_phi[i, j]
    return 0.5 * (p_new + p_new.T)


@nb.njit(cache=True)
def measurement_size(cfg):
    """Length of z for this configuration: 3 (+4 attitude) (+6 vector sensors)."""
    return 3 + (4 if cfg[C_USE_QUAT] > 0 else 0) + (6 if cfg[C_USE_VEC] > 0 else 0)


@nb.njit(cache=True)
def body_vector_and_jacobian(q, v):
    """R(q)^T v (inertial -> body) and its derivative d/dq, shape (3,) and (3, 4)."""
    q0, qv = q[0], q[1:4]
    dot = qv[0] * v[0] + qv[1] * v[1] + qv[2] * v[2]
    cr = np.array(
        (qv[1] * v[2] - qv[2] * v[1], qv[2] * v[0] - qv[0] * v[2], qv[0] * v[1] - qv[1] * v[0])
    )
    sq = q0 * q0 - (qv[0] ** 2 + qv[1] ** 2 + qv[2] ** 2)
    out = sq * v + 2.0 * dot * qv - 2.0 * q0 * cr
    jac = np.empty((3, 4))
    jac[:, 0] = 2.0 * q0 * v - 2.0 * cr
    skew_v = np.array(((0.0, -v[2], v[1]), (v[2], 0.0, -v[0]), (-v[1], v[0], 0.0)))
    for i in range(3):
        for j in range(3):
            jac[i, 1 + j] = (
                -2.0 * v[i] * qv[j] + 2.0 * qv[i] * v[j] + 2.0 * q0 * skew_v[i, j]
                + (2.0 * dot if i == j else 0.0)
            )
    return out, jac


@nb.njit(cache=True)
def measurement_model(x, cfg):
    """Predicted measurement h(x) (m,) and its Jacobian H (m, 13)."""
    m = measurement_size(cfg)
    h = np.zeros(m)
    big_h = np.zeros((m, N_STATE))
    for i in range(3):
        h[i] = x[4 + i]
        big_h[i, 4 + i] = 1.0
    row = 3
    if cfg[C_USE_QUAT] > 0:
        for i in range(4):
            h[row + i] = x[i]
            big_h[row + i, i] = 1.0
        row += 4
    if cfg[C_USE_VEC] > 0:
        g_b, g_jac = body_vector_and_jacobian(x[0:4], cfg[C_GRAV])
        m_b, m_jac = body_vector_and_jacobian(x[0:4], cfg[C_MAGREF])
        h[row:row + 3] = g_b
        h[row + 3:row + 6] = m_b
        big_h[row:row + 3, 0:4] = g_jac
        big_h[row + 3:row + 6, 0:4] = m_jac
    return h, big_h


@nb.njit(cache=True)
def measurement_noise(cfg):
    """Diagonal of R, shape (m,)."""
    m = measurement_size(cfg)
    r = np.empty(m)
    r[0:3] = cfg[C_GYRO] ** 2
    row = 3
    if cfg[C_USE_QUAT] > 0:
        r[row:row + 4] = cfg[C_QUAT] ** 2
        row += 4
    if cfg[C_USE_VEC] > 0:
        r[row:row + 3] = cfg[C_ACC] ** 2
        r[row + 3:row + 6] = cfg[C_MAG] ** 2
    return r


@nb.njit(cache=True)
def align_quaternion_sign(z, x, cfg):
    """Flip the measured quaternion to the hemisphere of the estimate (q and -q are one attitude)."""
    if cfg[C_USE_QUAT] > 0:
        dot = z[3] * x[0] + z[4] * x[1] + z[5] * x[2] + z[6] * x[3]
        if dot < 0.0:
            for i in range(3, 7):
                z[i] = -z[i]


@nb.njit(cache=True)
def limit_inertia_step(x, gain, innov, limit):
    """Damp the inertia rows of the gain so one update changes J by at most ``limit`` (relative).

    ||J(phi + d_phi) - J(phi)||_F <= limit ||J(phi)||_F. The Joseph form stays the exact
    covariance of the damped (suboptimal) gain, so the filter remains consistent; far from the
    truth this turns a wild linearised jump into a sequence of short, re-linearised steps.
    """
    if limit <= 0.0:
        return
    d_phi = gain[7:13] @ innov
    j_old = inertia_from_phi(x[7:13])
    for _ in range(60):
        change = np.sqrt(np.sum((inertia_from_phi(x[7:13] + d_phi) - j_old) ** 2))
        if change <= limit * np.sqrt(np.sum(j_old**2)):
            return
        scale = max(0.5, 0.9 * limit * np.sqrt(np.sum(j_old**2)) / change)
        for i in range(7, 13):
            for j in range(gain.shape[1]):
                gain[i, j] *= scale
        d_phi *= scale


@nb.njit(cache=True)
def ekf_update(x, P, z, cfg):
    """Joseph-form EKF update in place. Returns the normalised innovation squared (NIS).

    Consistency guard: when the NIS exceeds cfg[C_NIS_GATE] times the measurement size, the
    rate and attitude prior variances are raised (adaptive process noise) until it does not.
    Far from the true inertia the model's one-interval prediction of w is poor; explaining that
    as process noise keeps the rate on the gyro and lets theta learn in small, well-linearised
    steps instead of a wild Gauss-Newton jump onto a wrong inertia.
    """
    align_quaternion_sign(z, x, cfg)
    h, big_h = measurement_model(x, cfg)
    r = measurement_noise(cfg)
    innov = z - h
    m = r.shape[0]
    gate = cfg[C_NIS_GATE] * m
    add_w = (innov[0] ** 2 + innov[1] ** 2 + innov[2] ** 2) / 3.0
    add_q = 0.0
    if cfg[C_USE_QUAT] > 0:
        add_q = (innov[3] ** 2 + innov[4] ** 2 + innov[5] ** 2 + innov[6] ** 2) / 4.0
    for attempt in range(40):
        pht = P @ big_h.T
        s = big_h @ pht
        for i in range(m):
            s[i, i] += r[i]
        low = np.linalg.cholesky(s)
        y = np.linalg.solve(low, innov)
        nis = float(y @ y)
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
    # K = P H^T S^-1 via two triangular solves on the transposed system.
    k_t = np.linalg.solve(low.T, np.linalg.solve(low, pht.T))
    gain = k_t.T
    limit_inertia_step(x, gain, innov, cfg[C_STEP_LIMIT])
    x += gain @ innov
    i_kh = np.eye(N_STATE) - gain @ big_h
    new_p = i_kh @ P @ i_kh.T
    for i in range(m):
        for a in range(N_STATE):
            for b in range(N_STATE):
                new_p[a, b] += gain[a, i] * r[i] * gain[b, i]
    P[:, :] = 0.5 * (new_p + new_p.T)
    norm = math.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2 + x[3] ** 2)
    for i in range(4):
        x[i] /= norm
    return nis_raw


@nb.njit(cache=True)
def ekf_predict_step(x, tau, dt, phi_top, scratch_model, scratch_psi, y_new):
    """Advance the EKF mean by one dt (RK4) and accumulate the transition; x updated in place."""
    inertia = inertia_from_phi(x[7:13])
    inertia_inv = np.linalg.inv(inertia)
    accumulate_transition(x, inertia, inertia_inv, tau, dt, phi_top, scratch_psi)
    rk4_step_into(x[0:7], dt, inertia, inertia_inv, tau, _NO_DIST, y_new, scratch_model)
    x[0:7] = y_new


_NO_DIST = np.zeros(20)


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
