"""A cheap linear start for the maximum-likelihood fit: the integral equation error.

With theta = (Jxx, Jxy, Jxz, Jyy, Jyz, Jzz), J w = Omega(w) theta is linear in theta, and
Euler's equation d/dt (J w + h) + w x (J w + h) = tau, multiplied by a window phi that vanishes
at both ends of an interval and integrated, needs no derivative of the gyro:

    integral (-phi' Omega(w) + phi [w]x Omega(w)) dt  theta  =  integral (phi' h - phi w x h + phi tau) dt

Stacking the three rows of every interval gives A theta = c. With a known torque or a non-zero h,
c != 0 and the least-squares solution carries the scale; without, c = 0 and theta is the right
singular vector of A with the smallest singular value, scaled to a given trace. The result is
projected onto physically valid inertias (positive definite, triangle inequality).
"""

from __future__ import annotations

import numpy as np


def omega_matrix(w) -> np.ndarray:
    """(n, 3, 6) Omega(w) with Omega(w) theta = J w for w (n, 3)."""
    n = w.shape[0]
    out = np.zeros((n, 3, 6))
    out[:, 0, 0], out[:, 0, 1], out[:, 0, 2] = w[:, 0], w[:, 1], w[:, 2]
    out[:, 1, 1], out[:, 1, 3], out[:, 1, 4] = w[:, 0], w[:, 1], w[:, 2]
    out[:, 2, 2], out[:, 2, 4], out[:, 2, 5] = w[:, 0], w[:, 1], w[:, 2]
    return out


def modulating_windows(t, samples_per_window: int):
    """Consecutive intervals of ~samples_per_window samples over t (n,) s, and on each the
    window phi = sin^2 that vanishes at both ends. Returns edges (K+1,) sample indices of the
    interval boundaries (the last is n - 1), phi (n,) and its time derivative phi' (n,) 1/s.
    """
    n = t.size
    m = max(4, int(samples_per_window))
    edges = np.arange(0, n, m)
    if n - 1 - edges[-1] >= 2:
        edges = np.append(edges, n - 1)
    else:
        edges[-1] = n - 1
    k = np.clip(np.searchsorted(edges, np.arange(n), side="right") - 1, 0, edges.size - 2)
    t_a, t_b = t[edges[k]], t[edges[k + 1]]
    u = (t - t_a) / (t_b - t_a)
    phi = np.sin(np.pi * u) ** 2
    dphi = np.pi * np.sin(2 * np.pi * u) / (t_b - t_a)
    return edges, phi, dphi


#: Fewest samples in a window (shorter windows' quadrature of phi' is too coarse: 8 samples cost
#: 8 % on noiseless data).
MIN_WINDOW_SAMPLES = 16
#: Fewest windows an equation-error estimate rests on when windows holding unusable samples
#: are left out (fewer: all are used).
MIN_WINDOWS = 3


def equation_error_theta(t, w, tau=None, h=None, trace=1.0, samples_per_window=None,
                         usable=None) -> np.ndarray:
    """Linear estimate of theta (6,) from gyro rates w (n, 3) rad/s at times t (n,) s.

    tau (n, 3) N·m held per row, h (n, 3) kg·m²/s (None: zero). trace (kg·m²) fixes the scale
    when neither torque nor a non-zero h acts. usable (n,) bool or None: samples that are
    measurements (a clipped gyro's are not); the windows holding any other are left out, unless
    fewer than MIN_WINDOWS would remain. Returns theta of a valid inertia.
    """
    t = np.asarray(t, dtype=float)
    w = np.asarray(w, dtype=float)
    n = t.size
    tau = np.zeros((n, 3)) if tau is None else np.asarray(tau, dtype=float)
    h = np.zeros((n, 3)) if h is None else np.asarray(h, dtype=float)
    if samples_per_window is None:
        # A window spans about a third of a rotation and at least MIN_WINDOW_SAMPLES samples, at
        # most a tenth of the record.
        rate = float(np.median(np.linalg.norm(w, axis=1))) + 1e-12
        dt = float(np.median(np.diff(t)))
        samples_per_window = int(np.clip(2.0 / (rate * dt), MIN_WINDOW_SAMPLES,
                                         max(MIN_WINDOW_SAMPLES, n // 10)))
        if usable is not None and samples_per_window > MIN_WINDOW_SAMPLES:
            # unusable samples spread over the record: try the shortest windows before all of them
            edges = modulating_windows(t, samples_per_window)[0]
            if _clean_windows(edges, usable).sum() < MIN_WINDOWS:
                samples_per_window = MIN_WINDOW_SAMPLES
    edges, phi, dphi = modulating_windows(t, samples_per_window)
    starts = edges[:-1]
    quad = np.gradient(t)
    om = omega_matrix(w)
    wx = np.zeros((n, 3, 3))
    wx[:, 0, 1], wx[:, 0, 2], wx[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    wx[:, 1, 0], wx[:, 2, 0], wx[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    rows = (-dphi[:, None, None] * om + phi[:, None, None] * (wx @ om)) * quad[:, None, None]
    rhs = (dphi[:, None] * h - phi[:, None] * np.cross(w, h) + phi[:, None] * tau) * quad[:, None]
    a = np.add.reduceat(rows, starts, axis=0).reshape(-1, 6)
    c = np.add.reduceat(rhs, starts, axis=0).reshape(-1)
    if usable is not None:
        clean = _clean_windows(edges, usable)
        if clean.sum() >= MIN_WINDOWS:
            a, c = a.reshape(-1, 3, 6)[clean].reshape(-1, 6), c.reshape(-1, 3)[clean].reshape(-1)
    col = np.linalg.norm(a, axis=0) + 1e-300
    c_win = np.linalg.norm(c.reshape(-1, 3), axis=1)
    forced_win = c_win > 1e-3 * max(c_win.max(), 1e-300)
    forced = bool(np.any(c_win > 0.0)) and c_win.max() > 1e-9 * np.linalg.norm(a) * max(abs(trace), 1e-300)
    rows_free = np.repeat(~forced_win, 3)
    if not forced:
        theta = _null_vector(a, col)
        return valid_theta(theta * trace / (theta[0] + theta[3] + theta[5]), trace)
    if rows_free.sum() >= 9:
        # Shape from the unforced windows (A theta = 0 there), scale from the forced ones. Least
        # squares would shrink theta: A carries the gyro noise (errors in variables), so on
        # every window |A theta| falls with theta. The scale is therefore regressed the other
        # way round, the noisy A shape on the known forcing c: 1/s = <A shape, c> / <c, c>.
        shape = _null_vector(a[rows_free], col)
        shape *= np.sign(shape[0] + shape[3] + shape[5])
        pred, forcing = a[~rows_free] @ shape, c[~rows_free]
        theta = shape * float(forcing @ forcing) / float(pred @ forcing)
    else:
        theta = np.linalg.lstsq(a / col, c, rcond=None)[0] / col
    return valid_theta(theta)


def _clean_windows(edges, usable) -> np.ndarray:
    """(K,) bool: the windows between edges (K+1,) sample indices that hold only usable samples."""
    unusable = np.r_[0, np.cumsum(~np.asarray(usable, bool))]
    return unusable[edges[1:] + 1] - unusable[edges[:-1]] == 0


def _null_vector(a, col) -> np.ndarray:
    """The theta (6,) minimising |A theta| at unit norm of the column-scaled system."""
    return np.linalg.svd(a / col, full_matrices=False)[2][-1] / col


def valid_theta(theta, trace=None) -> np.ndarray:
    """The nearest physically valid inertia to theta (6,): principal moments clipped to at least
    1 % of the largest and to the triangle inequality (each at most the sum of the others).
    trace: rescale to this trace afterwards (None keeps the scale).
    """
    t = np.asarray(theta, dtype=float)
    j = np.array([[t[0], t[1], t[2]], [t[1], t[3], t[4]], [t[2], t[4], t[5]]])
    vals, vecs = np.linalg.eigh(j)
    if vals[-1] <= 0:
        vals = np.abs(vals) + 1e-300
    top = max(vals[-1], 1e-300)
    vals = np.clip(vals, 0.01 * top, None)
    for _ in range(3):
        total = vals.sum()
        vals = np.minimum(vals, 0.98 * (total - vals))
    j = (vecs * vals) @ vecs.T
    out = np.array([j[0, 0], j[0, 1], j[0, 2], j[1, 1], j[1, 2], j[2, 2]])
    if trace is not None:
        out *= trace / (out[0] + out[3] + out[5])
    return out
