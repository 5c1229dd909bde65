"""Unscented prediction for the joint (q, w, phi) estimator (the second estimator, estimator="ukf").

Sigma points x +- c * columns of chol(P) (the symmetric set of 2n points, n = 13, spread
c = SPREAD standard deviations, as in the divided-difference filters of Norgaard et al.) are
propagated through the same RK4 model as the EKF, each with its own inertia J(phi_i), which the
log-Cholesky parameterisation keeps positive definite for every sigma point. At a measurement
the predicted mean (the points' average) and covariance (sum of outer products of the
deviations / (2 c^2), exact for linear dynamics) are formed (quaternion re-normalised), Q_k is
added as in the EKF, and the update reuses :func:`ekf.ekf_update`: the measurement models
(gyro, quaternion) are linear in the state, so a linear update is exact there, and the optional
vector sensors are linearised at the predicted mean. The unscented transform replaces the
EKF's first-order transition where the dynamics are most nonlinear: in the inertia.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from inertia_gym.dynamics import inv3, rk4_step_into
from inertia_gym.estimation.ekf import N_STATE, add_process_noise
from inertia_gym.estimation.inertia_param import inertia_from_phi

N_SIGMA = 2 * N_STATE
# Spread of the sigma points in standard deviations. The textbook sqrt(n) = 3.6 sends points of
# the paper's prior (sigma of log-moments ~ 1) to inertias so extreme that RK4 at dt is unstable.
SPREAD = 1.0


@nb.njit(cache=True)
def covariance_root(P):
    """(low (n, n), ok): a lower factor with low low^T = P (n, n). A held state, whose row and
    column of P are zero (a parameter the filter keeps fixed: the scale of a torque-free record,
    identification.py), gets a zero column, so its sigma points all keep the estimate's value;
    ok is False where P is not positive definite over the other states (the estimate has left
    its domain).
    """
    sym = 0.5 * (P + P.T)
    n = sym.shape[0]
    low = np.zeros((n, n))
    try:
        return np.linalg.cholesky(sym), True
    except Exception:  # not positive definite: held states, or divergence
        pass
    free = np.zeros(n, np.bool_)
    for i in range(n):
        for j in range(n):
            if sym[i, j] != 0.0:
                free[i] = True
    idx = np.flatnonzero(free)
    if idx.size == n or idx.size == 0:
        return low, idx.size == 0
    sub = np.empty((idx.size, idx.size))
    for a in range(idx.size):
        for b in range(idx.size):
            sub[a, b] = sym[idx[a], idx[b]]
    try:
        sub_low = np.linalg.cholesky(sub)
    except Exception:
        return low, False
    for a in range(idx.size):
        for b in range(idx.size):
            low[idx[a], idx[b]] = sub_low[a, b]
    return low, True


@nb.njit(cache=True)
def draw_sigma_points(x, P, sigma, inertia, inertia_inv):
    """Fill sigma (2n, 13) and each point's J, J^-1 (2n, 3, 3); False if P is not positive
    definite (held states aside: covariance_root).
    """
    low, ok = covariance_root(P)
    if not ok:
        return False
    spread = SPREAD
    for j in range(N_STATE):
        for i in range(N_STATE):
            sigma[j, i] = x[i] + spread * low[i, j]
            sigma[N_STATE + j, i] = x[i] - spread * low[i, j]
    sigma_inertias(sigma, inertia, inertia_inv)
    return True


@nb.njit(cache=True)
def sigma_inertias(sigma, inertia, inertia_inv):
    """Each sigma point's J and J^-1 (2n, 3, 3) from its phi (sigma (2n, 13)), in place."""
    for k in range(N_SIGMA):
        j = inertia_from_phi(sigma[k, 7:13])
        j_inv = inv3(j)
        for a in range(3):
            for b in range(3):
                inertia[k, a, b] = j[a, b]
                inertia_inv[k, a, b] = j_inv[a, b]


@nb.njit(cache=True)
def predict_sigma_points(sigma, inertia, inertia_inv, tau, dt, dist):
    """Advance every sigma point's (q, w) by one dt with RK4, in place; dist (20,) the packed
    disturbance of the filter's model (known internal momentum and extra torque; zeros in the
    simulator).
    """
    for k in range(N_SIGMA):
        rk4_step_into(sigma[k], dt, inertia[k], inertia_inv[k], tau, dist, sigma[k])


@nb.njit(cache=True)
def sigma_mean(sigma, x):
    """Mean of the sigma points into x (quaternion re-normalised)."""
    for i in range(N_STATE):
        acc = 0.0
        for k in range(N_SIGMA):
            acc += sigma[k, i]
        x[i] = acc / N_SIGMA
    norm = math.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2 + x[3] ** 2)
    for i in range(4):
        x[i] /= norm


@nb.njit(cache=True)
def sigma_covariance(sigma, x, n_updates, cfg):
    """Predicted covariance of the sigma points about x, plus Q_k (same Q as the EKF)."""
    P = np.zeros((N_STATE, N_STATE))
    dev = np.empty(N_STATE)
    for k in range(N_SIGMA):
        for i in range(N_STATE):
            dev[i] = sigma[k, i] - x[i]
        for i in range(N_STATE):
            for j in range(i, N_STATE):
                P[i, j] += dev[i] * dev[j] / (2.0 * SPREAD**2)
    for i in range(N_STATE):
        for j in range(i + 1, N_STATE):
            P[j, i] = P[i, j]
    add_process_noise(P, x, n_updates, cfg)
    return P
