"""Information metric of the paper: regressor Psi, Gram matrices, windowed lambda_min, cost J.

theta = (Jxx, Jxy, Jxz, Jyy, Jyz, Jzz) (eq. 8). Psi is derived from tau = J w_dot + w x (J w)
(eq. 6) and corrects two entries printed wrongly in eq. (10): row 1, column 6 is w_y w_z (printed
w_y w_x) and row 3, column 1 is -w_x w_y (printed 0).
"""

from __future__ import annotations

import math
import threading

import numba as nb
import numpy as np

from inertia_gym.errors import ConfigError


@nb.njit(cache=True, forceinline=True)
def psi_entries(wx, wy, wz, ax, ay, az):
    """The 18 entries of Psi(w, w_dot), shape (3, 6) row-major, as a tuple; w rad/s, w_dot
    (ax, ay, az) rad/s².
    """
    return (ax, ay - wx * wz, az + wx * wy, -wy * wz, wy * wy - wz * wz, wy * wz,
            wx * wz, ax + wy * wz, wz * wz - wx * wx, ay, az - wx * wy, -wx * wz,
            -wx * wy, wx * wx - wy * wy, ax - wy * wz, wx * wy, ay + wx * wz, az)


@nb.njit(cache=True)
def psi_into(w, w_dot, out):
    """Write Psi(w, w_dot), shape (3, 6), into out. w in rad/s, w_dot in rad/s²."""
    p = psi_entries(w[0], w[1], w[2], w_dot[0], w_dot[1], w_dot[2])
    for i in range(3):
        for j in range(6):
            out[i, j] = p[6 * i + j]


def psi(w, w_dot) -> np.ndarray:
    """Regressor of eq. (9) with the errata fixed: Psi(w, w_dot) theta = J w_dot + w x J w.

    w, w_dot : (..., 3) arrays (rad/s, rad/s²). Returns (..., 3, 6).
    """
    w = np.asarray(w, dtype=float)
    w_dot = np.asarray(w_dot, dtype=float)
    if w.shape != w_dot.shape or w.shape[-1:] != (3,):
        raise ConfigError(f"w and w_dot must both have shape (..., 3), got {w.shape}, {w_dot.shape}")
    flat_w, flat_a = w.reshape(-1, 3), w_dot.reshape(-1, 3)
    out = np.empty((flat_w.shape[0], 3, 6))
    for k in range(flat_w.shape[0]):
        psi_into(flat_w[k], flat_a[k], out[k])
    return out.reshape(w.shape[:-1] + (3, 6))


def theta_from_inertia(inertia) -> np.ndarray:
    """Theta (..., 6) of eq. (8) from symmetric inertia matrices (..., 3, 3)."""
    j = np.asarray(inertia, dtype=float)
    return np.stack(
        [j[..., 0, 0], j[..., 0, 1], j[..., 0, 2], j[..., 1, 1], j[..., 1, 2], j[..., 2, 2]], -1
    )


def inertia_from_theta(theta) -> np.ndarray:
    """Symmetric inertia (..., 3, 3) from theta (..., 6) of eq. (8)."""
    t = np.asarray(theta, dtype=float)
    rows = [
        np.stack([t[..., 0], t[..., 1], t[..., 2]], -1),
        np.stack([t[..., 1], t[..., 3], t[..., 4]], -1),
        np.stack([t[..., 2], t[..., 4], t[..., 5]], -1),
    ]
    return np.stack(rows, -2)


@nb.njit(cache=True)
def window_grams_into(w_hat, w_dot_hat, starts, n_window, epsilon, out):
    """The regularised window Grams G_bar(s) = sum_{k=s}^{s+N-1} G_k + eps I6 (eq. 14) of
    G_k = Psi_k^T Psi_k (eq. 13), for each s of the strictly increasing starts, into out
    (len(starts), 6, 6).

    w_hat, w_dot_hat : (>= max(starts) + N, 3) rad/s, rad/s²; N = n_window. Each window is the
    difference C[s + N] - C[s] of the prefix sums C[t] = sum_{k<t} G_k, accumulated in time
    order; only the prefix values where a window starts are kept, so memory is O(windows).
    """
    n_win = starts.shape[0]
    if n_win == 0:
        return
    c = np.zeros((6, 6))  # upper triangle of C[t]
    low = np.empty((n_win, 6, 6))
    p = np.empty((3, 6))
    opened = closed = 0
    last = starts[n_win - 1] + n_window
    for t in range(last + 1):
        if opened < n_win and starts[opened] == t:
            for i in range(6):
                for j in range(6):
                    low[opened, i, j] = c[i, j]
            opened += 1
        if closed < n_win and starts[closed] + n_window == t:
            for i in range(6):
                for j in range(i, 6):
                    g = (c[i, j] - low[closed, i, j]) + epsilon * (1.0 if i == j else 0.0)
                    out[closed, i, j] = g
                    out[closed, j, i] = g
            closed += 1
        if t < last:
            psi_into(w_hat[t], w_dot_hat[t], p)
            for i in range(6):
                for j in range(i, 6):
                    c[i, j] = c[i, j] + (p[0, i] * p[0, j] + p[1, i] * p[1, j] + p[2, i] * p[2, j])


@nb.njit(cache=True)
def _runs_window_grams(w_hat, w_dot_hat, starts, offsets, n_window, epsilon, out, r):
    """:func:`window_grams_into` for run r of :func:`runs_window_grams`' arguments."""
    a, b = offsets[r], offsets[r + 1]
    window_grams_into(w_hat[r], w_dot_hat[r], starts[a:b], n_window[r], epsilon, out[a:b])


@nb.njit(cache=True, parallel=True)
def _runs_window_grams_parallel(w_hat, w_dot_hat, starts, offsets, n_window, epsilon, out):
    for r in nb.prange(offsets.shape[0] - 1):
        _runs_window_grams(w_hat, w_dot_hat, starts, offsets, n_window, epsilon, out, r)


def runs_window_grams(w_hat, w_dot_hat, starts, offsets, n_window, epsilon) -> np.ndarray:
    """The window Grams of R runs at once (in parallel over runs), stacked: (W, 6, 6).

    w_hat, w_dot_hat : (R, n, 3); run r's windows start at starts[offsets[r]:offsets[r + 1]]
    (strictly increasing) and are n_window[r] samples long; offsets (R + 1,) int. The rows of
    run r in the result are those of :func:`window_grams` of its own arrays.
    """
    out = np.empty((int(offsets[-1]), 6, 6))
    args = (np.ascontiguousarray(w_hat, dtype=float), np.ascontiguousarray(w_dot_hat, dtype=float),
            np.asarray(starts, dtype=np.int64), np.asarray(offsets, dtype=np.int64),
            np.asarray(n_window, dtype=np.int64), float(epsilon), out)
    if len(offsets) == 2:  # one run: no thread launch
        _runs_window_grams(*args, 0)
    else:
        _runs_window_grams_parallel(*args)
    return out


def window_grams(w_hat, w_dot_hat, starts, n_window: int, epsilon: float) -> np.ndarray:
    """G_bar(s) (len(starts), 6, 6) of eq. (14) for the strictly increasing window starts of
    one episode's per-step estimates w_hat, w_dot_hat (n, 3) rad/s, rad/s²; see
    :func:`window_grams_into`.
    """
    starts = np.asarray(starts, dtype=np.int64)
    if np.any(np.diff(starts) <= 0):
        raise ConfigError("window starts must be strictly increasing")
    w_hat, w_dot_hat = np.asarray(w_hat, dtype=float), np.asarray(w_dot_hat, dtype=float)
    if starts.size and (starts[0] < 0 or starts[-1] + n_window > len(w_hat)):
        raise ConfigError(f"windows of {n_window} samples from {starts[0]} to {starts[-1]} do "
                          f"not fit in {len(w_hat)} samples")
    return runs_window_grams(w_hat[None], w_dot_hat[None], starts, [0, starts.size], [n_window],
                             epsilon)


def window_length(t_on: float, dt: float) -> int:
    """N_T = max(5, ceil(T_on / dt)) samples (paper, simulation section)."""
    return max(5, int(math.ceil(t_on / dt - 1e-9)))


def window_starts(n: int, n_window: int, bursts=None) -> np.ndarray:
    """Valid window starts S of an episode of n samples.

    With bursts = None every start s with s + n_window <= n is valid ("episode" window set).
    With bursts an (m, 2) array of [start, stop) sample indices, only windows overlapping a
    burst are kept ("burst" window set).
    """
    starts = np.arange(max(n - n_window + 1, 0))
    if bursts is None:
        return starts
    keep = np.zeros(starts.shape, dtype=bool)
    for b0, b1 in np.asarray(bursts, dtype=np.int64).reshape(-1, 2):
        keep |= (starts < b1) & (starts + n_window > b0)
    return starts[keep]


#: Stacks of at least this many Grams are split between two threads by :func:`lambda_min`
#: (a thread's start and join cost about as much as 50 eigenvalue problems of 6x6).
SPLIT_EIGVALSH = 256


def lambda_min(grams) -> np.ndarray:
    """Smallest eigenvalue of each symmetric matrix of the stack grams (W, 6, 6): (W,).

    numpy's eigvalsh (LAPACK syevd), one matrix at a time; a stack of SPLIT_EIGVALSH or more is
    split in two halves solved on two threads (numpy releases the GIL) when numba may use
    more than one, each matrix giving exactly what it gives alone.
    """
    grams = np.asarray(grams, dtype=float)
    if not len(grams):
        return np.empty(0)
    if len(grams) < SPLIT_EIGVALSH or nb.get_num_threads() < 2:
        return np.linalg.eigvalsh(grams)[:, 0]
    half = len(grams) // 2
    out = np.empty(len(grams))
    errors: list[BaseException] = []

    def first_half() -> None:
        try:
            out[:half] = np.linalg.eigvalsh(grams[:half])[:, 0]
        except BaseException as exc:  # re-raised in the calling thread
            errors.append(exc)

    helper = threading.Thread(target=first_half, name="lambda_min")
    helper.start()
    try:
        out[half:] = np.linalg.eigvalsh(grams[half:])[:, 0]
    finally:
        helper.join()
    if errors:
        raise errors[0]
    return out


def soft_min(values, beta: float) -> float:
    """Alpha = -1/beta log(mean exp(-beta v)) (eq. 24), computed stably; -> min as beta -> inf."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        raise ConfigError("soft-min of an empty set of windows: the episode is shorter than N_T")
    if not beta > 0:
        raise ConfigError(f"softmin_beta must be > 0, got {beta}")
    m = v.min()
    return float(m - np.log(np.mean(np.exp(-beta * (v - m)))) / beta)


def cost(alpha: float, epsilon_lambda: float) -> float:
    """J = -log(alpha + eps_lambda) (eq. 15)."""
    return float(-np.log(alpha + epsilon_lambda))
