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

from inertia_gym.dynamics import lane_entries9, mat3_entries, rk4_lanes, rk4_step_into
from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_norm_sq, theta_into
from inertia_gym.information import psi_entries
from inertia_gym.sensors import align_quaternion_sign, measurement_model, measurement_noise

N_STATE = 13


#: Rows of the per-lane transition coefficients (:func:`transition_coefficients_into`):
#: w / 2 (3), q / 2 (4), A_ww (9) and A_wtheta (18), row-major.
N_COEF = 34


@nb.njit(cache=True, forceinline=True)
def _times_inverse(j_inv, c0, c1, c2):
    """J^-1 c for c = (c0, c1, c2), j_inv row-major (9,); a 3-tuple."""
    return (j_inv[0] * c0 + j_inv[1] * c1 + j_inv[2] * c2,
            j_inv[3] * c0 + j_inv[4] * c1 + j_inv[5] * c2,
            j_inv[6] * c0 + j_inv[7] * c1 + j_inv[8] * c2)


@nb.njit(cache=True, forceinline=True)
def transition_coefficients_into(x, j, j_inv, tau, dist, coef, lane):
    """The blocks of the Jacobian A of (q_dot, w_dot) at lane `lane` into coef[:, lane].

    Lane arrays hold runs along their last axis: x (>= 7, L) rows (q, w); j, j_inv (9, L) J(phi)
    and its inverse, row-major (kg·m²); tau (3, L) N·m; coef (N_COEF, L). dist : the packed
    disturbance (the model uses h = dist[3:6] and the torque dist[0:3]). Writes w / 2, q / 2,
    A_ww = J^-1 ([J w + h]x - [w]x J) and A_wtheta = -J^-1 Psi(w, w_dot) (eq. 9
    differentiated, w_dot the model's acceleration), row-major; A_qq = 1/2 Omega(w) and
    A_qw = 1/2 Xi(q) are read off w / 2 and q / 2.
    """
    qw, qx, qy, qz = x[0, lane], x[1, lane], x[2, lane], x[3, lane]
    wx, wy, wz = x[4, lane], x[5, lane], x[6, lane]
    jl, ji = lane_entries9(j, lane), lane_entries9(j_inv, lane)
    hx = jl[0] * wx + jl[1] * wy + jl[2] * wz + dist[3]
    hy = jl[3] * wx + jl[4] * wy + jl[5] * wz + dist[4]
    hz = jl[6] * wx + jl[7] * wy + jl[8] * wz + dist[5]
    mx = tau[0, lane] + dist[0] - (wy * hz - wz * hy)
    my = tau[1, lane] + dist[1] - (wz * hx - wx * hz)
    mz = tau[2, lane] + dist[2] - (wx * hy - wy * hx)
    ax, ay, az = _times_inverse(ji, mx, my, mz)
    # Columns of M = [J w + h]x - [w]x J, then of A_ww = J^-1 M.
    w0 = _times_inverse(ji, -(wy * jl[6] - wz * jl[3]), -(wz * jl[0] - wx * jl[6]) + hz,
                        -(wx * jl[3] - wy * jl[0]) - hy)
    w1 = _times_inverse(ji, -(wy * jl[7] - wz * jl[4]) - hz, -(wz * jl[1] - wx * jl[7]),
                        -(wx * jl[4] - wy * jl[1]) + hx)
    w2 = _times_inverse(ji, -(wy * jl[8] - wz * jl[5]) + hy, -(wz * jl[2] - wx * jl[8]) - hx,
                        -(wx * jl[5] - wy * jl[2]))
    p = psi_entries(wx, wy, wz, ax, ay, az)
    t0 = _times_inverse(ji, p[0], p[6], p[12])
    t1 = _times_inverse(ji, p[1], p[7], p[13])
    t2 = _times_inverse(ji, p[2], p[8], p[14])
    t3 = _times_inverse(ji, p[3], p[9], p[15])
    t4 = _times_inverse(ji, p[4], p[10], p[16])
    t5 = _times_inverse(ji, p[5], p[11], p[17])
    coef[0, lane], coef[1, lane], coef[2, lane] = 0.5 * wx, 0.5 * wy, 0.5 * wz
    coef[3, lane], coef[4, lane], coef[5, lane], coef[6, lane] = \
        0.5 * qw, 0.5 * qx, 0.5 * qy, 0.5 * qz
    coef[7, lane], coef[8, lane], coef[9, lane] = w0[0], w1[0], w2[0]
    coef[10, lane], coef[11, lane], coef[12, lane] = w0[1], w1[1], w2[1]
    coef[13, lane], coef[14, lane], coef[15, lane] = w0[2], w1[2], w2[2]
    coef[16, lane], coef[17, lane], coef[18, lane] = -t0[0], -t1[0], -t2[0]
    coef[19, lane], coef[20, lane], coef[21, lane] = -t3[0], -t4[0], -t5[0]
    coef[22, lane], coef[23, lane], coef[24, lane] = -t0[1], -t1[1], -t2[1]
    coef[25, lane], coef[26, lane], coef[27, lane] = -t3[1], -t4[1], -t5[1]
    coef[28, lane], coef[29, lane], coef[30, lane] = -t0[2], -t1[2], -t2[2]
    coef[31, lane], coef[32, lane], coef[33, lane] = -t3[2], -t4[2], -t5[2]


@nb.njit(cache=True, forceinline=True)
def _transition_column(phi_top, col, lane, dt, coef, on, rate_rows, theta_column):
    """Column `col` of lane `lane` of phi_top <- c + dt A c (unless on[lane] == 0).

    phi_top (7 * 13, L): entry (i, col) of a lane's (7, 13) transition in row 13 i + col (a
    2-D view of one buffer keeps its strides constant). coef from
    :func:`transition_coefficients_into`. The rate rows have zero attitude columns:
    rate_rows False (columns 0-3) leaves them; theta_column (columns 7-12) adds A_wtheta.
    Both are constants at every call, so the branches fold away.
    """
    c0, c1, c2 = phi_top[col, lane], phi_top[N_STATE + col, lane], phi_top[2 * N_STATE + col, lane]
    c3, c4 = phi_top[3 * N_STATE + col, lane], phi_top[4 * N_STATE + col, lane]
    c5, c6 = phi_top[5 * N_STATE + col, lane], phi_top[6 * N_STATE + col, lane]
    hwx, hwy, hwz = coef[0, lane], coef[1, lane], coef[2, lane]
    hqw, hqx, hqy, hqz = coef[3, lane], coef[4, lane], coef[5, lane], coef[6, lane]
    keep = on[lane] == 0.0
    n0 = c0 + dt * ((-hwx * c1 - hwy * c2 - hwz * c3) + (-hqx * c4 - hqy * c5 - hqz * c6))
    n1 = c1 + dt * ((hwx * c0 + hwz * c2 - hwy * c3) + (hqw * c4 - hqz * c5 + hqy * c6))
    n2 = c2 + dt * ((hwy * c0 - hwz * c1 + hwx * c3) + (hqz * c4 + hqw * c5 - hqx * c6))
    n3 = c3 + dt * ((hwz * c0 + hwy * c1 - hwx * c2) + (-hqy * c4 + hqx * c5 + hqw * c6))
    phi_top[col, lane] = c0 if keep else n0
    phi_top[N_STATE + col, lane] = c1 if keep else n1
    phi_top[2 * N_STATE + col, lane] = c2 if keep else n2
    phi_top[3 * N_STATE + col, lane] = c3 if keep else n3
    if rate_rows:
        d4 = coef[7, lane] * c4 + coef[8, lane] * c5 + coef[9, lane] * c6
        d5 = coef[10, lane] * c4 + coef[11, lane] * c5 + coef[12, lane] * c6
        d6 = coef[13, lane] * c4 + coef[14, lane] * c5 + coef[15, lane] * c6
        if theta_column:
            d4 += coef[9 + col, lane]  # A_wtheta[:, col - 7]
            d5 += coef[15 + col, lane]
            d6 += coef[21 + col, lane]
        phi_top[4 * N_STATE + col, lane] = c4 if keep else c4 + dt * d4
        phi_top[5 * N_STATE + col, lane] = c5 if keep else c5 + dt * d5
        phi_top[6 * N_STATE + col, lane] = c6 if keep else c6 + dt * d6


@nb.njit(cache=True, forceinline=True)
def accumulate_transition_lanes(x, j, j_inv, tau, dist, dt, phi_top, coef, on):
    """phi_top <- (I + dt A) phi_top for every lane l with on[l] != 0 (the others unchanged).

    phi_top (7 * 13, L): per lane the (7, 13) transition (rows (q, w), columns (q, w, theta),
    theta in theta coordinates), entry (i, k) in row 13 i + k; A the Jacobian of
    (q_dot, w_dot) at x; x, j, j_inv, tau, coef, dist as for
    :func:`transition_coefficients_into`; on (L,) 1.0 / 0.0. Inlined into a kernel whose lane
    arrays are views of one array of constant shape (so the compiler sees they cannot
    overlap), the loop over lanes runs as SIMD instructions (one lane per vector slot).
    """
    for lane in range(x.shape[1]):  # columns written out: this is the (only) vector loop
        transition_coefficients_into(x, j, j_inv, tau, dist, coef, lane)
        _transition_column(phi_top, 0, lane, dt, coef, on, False, False)
        _transition_column(phi_top, 1, lane, dt, coef, on, False, False)
        _transition_column(phi_top, 2, lane, dt, coef, on, False, False)
        _transition_column(phi_top, 3, lane, dt, coef, on, False, False)
        _transition_column(phi_top, 4, lane, dt, coef, on, True, False)
        _transition_column(phi_top, 5, lane, dt, coef, on, True, False)
        _transition_column(phi_top, 6, lane, dt, coef, on, True, False)
        _transition_column(phi_top, 7, lane, dt, coef, on, True, True)
        _transition_column(phi_top, 8, lane, dt, coef, on, True, True)
        _transition_column(phi_top, 9, lane, dt, coef, on, True, True)
        _transition_column(phi_top, 10, lane, dt, coef, on, True, True)
        _transition_column(phi_top, 11, lane, dt, coef, on, True, True)
        _transition_column(phi_top, 12, lane, dt, coef, on, True, True)


#: Rows of the one-lane buffer of :func:`accumulate_transition`: x (7), j (9), j_inv (9),
#: tau (3), on (1), coefficients, phi_top (7 x 13).
_ONE_LANE_ROWS = 7 + 9 + 9 + 3 + 1 + N_COEF + 7 * N_STATE


@nb.njit(cache=True)
def accumulate_transition(x, inertia, inertia_inv, tau, dt, phi_top, dist):
    """phi_top <- (I + dt A) phi_top for the (q, w) rows, theta columns in theta coordinates.

    phi_top : (7, 13) rows (q, w), columns (q, w, theta); A the Jacobian of (q_dot, w_dot) at
    x (13,) (see :func:`transition_coefficients_into`); inertia, inertia_inv (3, 3) kg·m²;
    tau (3,) N·m. dist : the packed disturbance of dynamics.py, of which the filter's model
    uses the known internal momentum h = dist[3:6] (N·m·s) and the extra torque dist[0:3]
    (N·m, e.g. -h_dot); zeros in the simulator. :func:`accumulate_transition_lanes` on one lane.
    """
    buf = np.empty((_ONE_LANE_ROWS, 1))
    entries, inv_entries = mat3_entries(inertia), mat3_entries(inertia_inv)
    for i in range(7):
        buf[i, 0] = x[i]
    for i in range(9):
        buf[7 + i, 0] = entries[i]
        buf[16 + i, 0] = inv_entries[i]
    for i in range(3):
        buf[25 + i, 0] = tau[i]
    buf[28, 0] = 1.0
    lane_phi = buf[29 + N_COEF:]
    for i in range(7):
        for k in range(N_STATE):
            lane_phi[N_STATE * i + k, 0] = phi_top[i, k]
    accumulate_transition_lanes(buf[0:7], buf[7:16], buf[16:25], buf[25:28], dist, dt, lane_phi,
                                buf[29:29 + N_COEF], buf[28])
    for i in range(7):
        for k in range(N_STATE):
            phi_top[i, k] = lane_phi[N_STATE * i + k, 0]


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
def limit_inertia_step(x, gain_t, innov, limit):
    """Damp the inertia rows of the gain so one update changes J by at most ``limit`` (relative).

    gain_t : (m, 13) the gain K transposed (K^T), changed in place; innov (m,).
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
            acc += gain_t[j, 7 + i] * innov[j]
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
        for j in range(gain_t.shape[0]):
            for i in range(7, 13):
                gain_t[j, i] *= scale
        for i in range(6):
            d_phi[i] *= scale


@nb.njit(cache=True)
def cholesky_into(s, low):
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
    """Solve L out = b (forward substitution)."""
    for i in range(b.shape[0]):
        acc = b[i]
        for k in range(i):
            acc -= low[i, k] * out[k]
        out[i] = acc / low[i, i]


@nb.njit(cache=True)
def _gain_transposed(low, pht, gain_t):
    """K^T = S^-1 (P H^T)^T into gain_t (m, n), from S = L L^T (low) and pht = P H^T (n, m).

    Row i of K solves L y = pht[i] (forward) and L^T k = y (backward), every row with the same
    operations in the same order as one substitution at a time; the n rows advance together
    (innermost loop over rows, contiguous in gain_t), so the divisions and multiply-adds of
    different rows overlap instead of waiting on each other.
    """
    m, n = gain_t.shape
    for k in range(m):
        for i in range(n):
            gain_t[k, i] = pht[i, k]
        for p in range(k):
            f = low[k, p]
            for i in range(n):
                gain_t[k, i] -= f * gain_t[p, i]
        d = low[k, k]
        for i in range(n):
            gain_t[k, i] /= d
    for k in range(m - 1, -1, -1):
        for p in range(k + 1, m):
            f = low[p, k]
            for i in range(n):
                gain_t[k, i] -= f * gain_t[p, i]
        d = low[k, k]
        for i in range(n):
            gain_t[k, i] /= d


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
        if not cholesky_into(s, low):
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
    # K = P H^T S^-1, transposed: rows of K^T are contiguous for the loops below, whose
    # innermost index runs over the state (each sum in the order of the plain product).
    gain_t = np.empty((m, N_STATE))
    _gain_transposed(low, pht, gain_t)
    limit_inertia_step(x, gain_t, innov, cfg.inertia_step_limit)
    step = np.zeros(N_STATE)
    for j in range(m):
        for i in range(N_STATE):
            step[i] += gain_t[j, i] * innov[j]
    for i in range(N_STATE):
        x[i] += step[i]
    pht_t = np.empty((m, N_STATE))
    ks_t = np.zeros((m, N_STATE))  # (K S)^T
    for j in range(m):
        for i in range(N_STATE):
            pht_t[j, i] = pht[i, j]
        for k in range(m):
            s_kj = s[k, j]
            for i in range(N_STATE):
                ks_t[j, i] += gain_t[k, i] * s_kj
    row = np.empty(N_STATE)
    for i in range(N_STATE):
        for j in range(i, N_STATE):
            row[j] = P[i, j]
        for k in range(m):
            g_ki, p_ki, ks_ki = gain_t[k, i], pht_t[k, i], ks_t[k, i]
            for j in range(i, N_STATE):
                row[j] += -g_ki * pht_t[k, j] - p_ki * gain_t[k, j] + ks_ki * gain_t[k, j]
        for j in range(i, N_STATE):
            P[i, j] = row[j]
            P[j, i] = row[j]
    norm = math.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2 + x[3] ** 2)
    for i in range(4):
        x[i] /= norm
    return nis_raw


@nb.njit(cache=True)
def ekf_predict_step(x, tau, dt, inertia, inertia_inv, phi_top, dist):
    """Advance the EKF mean by one dt (RK4) and accumulate the transition; x updated in place.

    inertia, inertia_inv : J(phi) and its inverse for the current x (phi is constant between
    updates, so the caller computes them once per measurement interval). dist :
    (DISTURBANCE_SIZE,) packed disturbance; the model uses its internal momentum h and extra
    torque (see :func:`accumulate_transition`).
    """
    accumulate_transition(x, inertia, inertia_inv, tau, dt, phi_top, dist)
    rk4_step_into(x, dt, inertia, inertia_inv, tau, dist, x)


@nb.njit(cache=True, forceinline=True)
def ekf_predict_lanes(x, j, j_inv, tau, dist, dt, phi_top, coef, on):
    """:func:`ekf_predict_step` for every lane l with on[l] != 0 (the others unchanged).

    Lanes are runs along the last axis: x (13, L) means, j and j_inv (9, L) row-major J(phi)
    and inverse, tau (3, L) N·m, phi_top (7 * 13, L) (see :func:`accumulate_transition_lanes`),
    coef (N_COEF, L) scratch, on (L,) 1.0 /
    0.0; dist the filter model's packed disturbance, a tuple shared by all lanes. Each lane
    computes exactly what ekf_predict_step computes for it.
    """
    accumulate_transition_lanes(x, j, j_inv, tau, dist, dt, phi_top, coef, on)
    rk4_lanes(x, j, j_inv, tau, dist, dt, on)


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
