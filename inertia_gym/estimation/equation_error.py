"""The equation error: a linear, local estimate of the inertia with its covariance.

With theta = (Jxx, Jxy, Jxz, Jyy, Jyz, Jzz), J w = Omega(w) theta is linear in theta, and
Euler's equation d/dt (J w + h) + w x (J w + h) = tau, multiplied by a window phi that vanishes
at both ends of an interval and integrated, needs no derivative of the gyro:

    integral (-phi' Omega(w) + phi [w]x Omega(w)) dt  theta  =  integral (phi' h - phi w x h + phi tau) dt

The windows (phi = sin^4, about a radian of rotation, overlapping by three quarters) stack into
A theta = c. The gyro's noise enters A too (errors in variables: least squares would shrink the
inertia where the forcing is weak beside the noise), so its expected share of A^T A and A^T c is
taken off (the noise-corrected, or bias-corrected, least squares). With a known torque or a
non-zero h, c != 0 and the solution carries the scale; without, theta is the corrected Gram's
null vector at a given trace. The result is projected onto physically valid inertias. Its
covariance counts the gyro's noise and an unmodelled torque whose intensity the residuals'
excess implies (equation_error). It is the linear start of the output-error fit and the robust
reference identify reports beside it; an unmodelled torque moves it only through the windows it
acts in.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.dynamics import skew
from inertia_gym.estimation.inertia_param import nearest_realizable
from inertia_gym.information import inertia_from_theta
from inertia_gym.sensors import estimate_white_noise


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


#: Fewest samples in a window: its sin^4 weights integrate a rigid body's motion to about 1e-6 of
#: its inertia with 32 samples (3e-5 with 16), below the noise of any record here.
MIN_WINDOW_SAMPLES = 32
#: Rotation (rad) a window spans: a torque-free body's rates change by their own size over about
#: a radian (w_dot ~ w^2), so a longer window averages the motion away, and a shorter one lets the
#: gyro's noise into the regressors (errors in variables).
WINDOW_TURN = 1.0
#: Windows start every 1/WINDOW_HOP of a window's length.
WINDOW_HOP = 4
#: Least principal moment of an equation-error estimate, as a share of its largest: a body that
#: thin (a rod) has no finite log-Cholesky parameters, and no record here resolves a thinner one.
MOMENT_FLOOR = 0.01
#: Fewest windows an equation-error estimate rests on when windows holding unusable samples
#: are left out (fewer: all are used).
MIN_WINDOWS = 3


def equation_error_theta(t, w, tau=None, h=None, trace=1.0, samples_per_window=None,
                         usable=None, sigma=None) -> np.ndarray:
    """Linear estimate of theta (6,) from gyro rates w (n, 3) rad/s at times t (n,) s.

    tau (n, 3) N·m held per row, h (n, 3) kg·m²/s (None: zero). trace (kg·m²) fixes the scale
    when neither torque nor a non-zero h acts. usable (n,) bool or None: samples that are
    measurements (a clipped gyro's are not); the windows holding any other are left out, unless
    fewer than MIN_WINDOWS would remain. sigma (3,) rad/s: the gyro's white noise (None: read
    from the samples' high-order differences). Returns theta of a valid inertia.
    """
    return equation_error(t, w, tau, h, trace, usable, samples_per_window, sigma).theta


def _system(t, w, tau, h, trace, usable, samples_per_window, sigma) -> dict:
    """The stacked windows' system A theta = c (a (K, 3, 6), c (K, 3)) with the gyro noise's
    expected contribution to A^T A and A^T c (noise_aa (6, 6), noise_ac (6,)); forced: a known
    torque or momentum acts; overlap: windows a sample belongs to. Windows of samples_per_window
    intervals start every 1/WINDOW_HOP of a window: overlapping, they use every sample as a
    smoothing filter would.

    The noise terms: a white noise n (sigma per axis) in the rates moves window k's rows by
    sum_j M_kj n_j, M_kj = -phi'_kj Omega(.) + phi_kj ([.]x Omega(w_j) + [w_j]x Omega(.)) (and
    its right side by -phi_kj (. x h_j)), so E[dA^T dA] = sum_kj M_kj^T Sigma M_kj: what least
    squares would take for signal (errors in variables, which shrink the inertia wherever the
    forcing is weak beside the noise: 38 % on a simulated record at 0.1 % noise).
    """
    t = np.asarray(t, dtype=float)
    w = np.asarray(w, dtype=float)
    n = t.size
    tau = np.zeros((n, 3)) if tau is None else np.asarray(tau, dtype=float)
    h = np.zeros((n, 3)) if h is None else np.asarray(h, dtype=float)
    if samples_per_window is None:
        # A window spans about WINDOW_TURN rad of rotation and at least MIN_WINDOW_SAMPLES
        # samples, at most a quarter of the record.
        rate = float(np.median(np.linalg.norm(w, axis=1))) + 1e-12
        dt = float(np.median(np.diff(t)))
        samples_per_window = int(np.clip(WINDOW_TURN / (rate * dt), MIN_WINDOW_SAMPLES,
                                         max(MIN_WINDOW_SAMPLES, (n - 1) // 4)))
    width = int(min(max(4, samples_per_window), n - 1))
    hop = max(1, width // WINDOW_HOP)
    starts = np.arange(0, n - width, hop)
    idx = starts[:, None] + np.arange(width + 1)[None, :]
    if usable is not None:
        clean = np.all(np.asarray(usable, bool)[idx], axis=1)
        if clean.sum() >= MIN_WINDOWS:
            idx = idx[clean]
    if sigma is None:
        sigma = estimate_white_noise(w if usable is None else w[np.asarray(usable, bool)])
    var = np.broadcast_to(np.asarray(sigma, float) ** 2, (3,))
    tw = t[idx]
    span = tw[:, -1:] - tw[:, :1]
    u = (tw - tw[:, :1]) / span
    quad = np.gradient(tw, axis=1)
    wq = np.sin(np.pi * u) ** 4 * quad
    dq = 4 * np.pi * np.sin(np.pi * u) ** 3 * np.cos(np.pi * u) / span * quad
    om = omega_matrix(w)
    spin = skew(w) @ om
    a = np.einsum("kj,kjrc->krc", -dq, om[idx]) + np.einsum("kj,kjrc->krc", wq, spin[idx])
    c = np.einsum("kj,kjr->kr", dq, h[idx]) + np.einsum("kj,kjr->kr", wq, tau[idx] - np.cross(w, h)[idx])
    # each sample's summed weights over the windows it is in
    s_dd, s_dw, s_ww = (np.bincount(idx.ravel(), (x * y).ravel(), minlength=n)
                        for x, y in ((dq, dq), (dq, wq), (wq, wq)))
    noise_aa, noise_ac = np.zeros((6, 6)), np.zeros(6)
    for axis in range(3):
        unit = np.zeros((1, 3))
        unit[0, axis] = 1.0
        p = omega_matrix(unit)[0]  # (3, 6)
        q = skew(unit)[0] @ om + skew(w) @ p  # (n, 3, 6)
        nv = -np.cross(unit, h)  # the right side's: -(e_a x h_j)
        cross_term = np.einsum("j,ri,jrk->ik", s_dw, p, q)
        noise_aa += var[axis] * (s_dd.sum() * p.T @ p - cross_term - cross_term.T
                                 + np.einsum("j,jri,jrk->ik", s_ww, q, q))
        noise_ac += var[axis] * (np.einsum("j,jri,jr->i", s_ww, q, nv) - np.einsum("j,ri,jr->i", s_dw, p, nv))
    c_win = np.linalg.norm(c, axis=1)
    forced = bool(np.any(c_win > 0.0)) and c_win.max() > 1e-9 * np.linalg.norm(a) * max(abs(trace), 1e-300)
    return {"a": a, "c": c, "forced": forced, "noise_aa": noise_aa, "noise_ac": noise_ac, "idx": idx,
            "wq": wq, "dq": dq, "w": w, "h": h, "var": var, "dt": np.gradient(t)}


def _normal(system: dict) -> tuple[np.ndarray, np.ndarray]:
    """The noise-corrected normal equations (A^T A - E[dA^T dA], A^T c - E[dA^T dc]), the
    corrected Gram's eigenvalues kept above 1e-9 of its largest (noise that outweighs the signal
    along a direction leaves it undetermined, not negative).
    """
    a, c = system["a"].reshape(-1, 6), system["c"].reshape(-1)
    gram = a.T @ a - system["noise_aa"]
    vals, vecs = np.linalg.eigh(0.5 * (gram + gram.T))
    vals = np.maximum(vals, 1e-9 * max(vals.max(), 1e-300))
    return (vecs * vals) @ vecs.T, a.T @ c - system["noise_ac"]


def _solve_normal(gram, rhs, forced: bool, trace: float) -> np.ndarray:
    """Theta (6,) of a valid inertia from noise-corrected normal equations (_normal): their
    solution; without forcing, the corrected Gram's null vector at the given trace.
    """
    col = np.sqrt(np.maximum(np.diag(gram), 1e-300))
    scaled = gram / np.outer(col, col)
    if not forced:
        theta = np.linalg.eigh(scaled)[1][:, 0] / col
        return valid_theta(theta * trace / (theta[0] + theta[3] + theta[5]), trace)
    return valid_theta(np.linalg.solve(scaled, rhs / col) / col)


def valid_theta(theta, trace=None) -> np.ndarray:
    """The nearest inertia a body can have to theta (6,) (inertia_param.nearest_realizable: each
    principal moment at most the sum of the other two), its moments kept at least MOMENT_FLOOR of
    the largest so that its log-Cholesky parameters, the output error's start, are finite.
    trace: rescale to this trace afterwards (None keeps the scale).
    """
    t = np.asarray(theta, dtype=float)
    j = np.array([[t[0], t[1], t[2]], [t[1], t[3], t[4]], [t[2], t[4], t[5]]])
    vals, vecs = np.linalg.eigh(j)
    if vals[-1] <= 0:
        vals = np.abs(vals) + 1e-300
    vals = np.clip(vals, MOMENT_FLOOR * max(vals[-1], 1e-300), None)
    vals, vecs = np.linalg.eigh(nearest_realizable((vecs * vals) @ vecs.T))
    # the projection may leave a rod's zero moment; raising the least moment to the floor keeps
    # the triangle inequality (the largest moment stays at most the sum of the other two)
    vals = np.clip(vals, MOMENT_FLOOR * max(vals[-1], 1e-300), None)
    j = (vecs * vals) @ vecs.T
    out = np.array([j[0, 0], j[0, 1], j[0, 2], j[1, 1], j[1, 2], j[2, 2]])
    if trace is not None:
        out *= trace / (out[0] + out[3] + out[5])
    return out


@dataclasses.dataclass(frozen=True)
class EquationError:
    """The linear equation-error estimate: theta (6,) kg·m² (a valid inertia), its covariance
    theta_cov (6, 6) (the gyro's noise and the model error, see equation_error), scale_seen (a
    known torque or momentum fixed the scale; else theta is at the given trace and theta_cov is
    that of the normalised inertia), windows (the count it rests on), torque_q N²·m²·s (the
    intensity of a white unmodelled torque that the residuals' excess over the noise implies) and
    misfit_z (that excess in standard deviations of the noise's own: the rigid model leaves
    something out where it is large).
    """

    theta: np.ndarray
    theta_cov: np.ndarray
    scale_seen: bool
    windows: int
    torque_q: float = 0.0
    misfit_z: float = 0.0


def equation_error(t, w, tau=None, h=None, trace=1.0, usable=None, samples_per_window=None,
                   sigma=None) -> EquationError:
    """The noise-corrected equation-error estimate with its covariance (see EquationError).

    The covariance is G^-1 V G^-1 in the directions theta may move in (all, or those at a fixed
    trace without forcing), G the corrected Gram, V the covariance of the score sum_k A_k^T e_k
    (e_k = A_k theta - c_k, window k's residual) under the two things that move it: the gyro's
    white noise (sigma) and an unmodelled torque, white with intensity q (N²·m²·s), the model
    error (_score_covariance). q is the residuals' excess over what the noise explains (method of
    moments; 0 without an excess). Both terms are worked out from the windows' weights, so the
    covariance rests on one estimated number, not on the few independent windows a short
    record holds.
    """
    return pooled([_system(t, w, tau, h, trace, usable, samples_per_window, sigma)], trace)


def system_of(t, w, tau=None, h=None, trace=1.0, usable=None, sigma=None) -> dict:
    """One record's windows' system (for pooled()): the arguments as equation_error's."""
    return _system(t, w, tau, h, trace, usable, None, sigma)


def pooled(systems: list[dict], trace: float = 1.0) -> EquationError:
    """The equation-error estimate of one inertia from several records' systems (system_of):
    their noise-corrected normal equations summed, each record's model error (its own q from
    its own residuals) and noise in the covariance; forced where any record is.
    """
    forced = any(sy["forced"] for sy in systems)
    grams, rhss = zip(*(_normal(sy) for sy in systems))
    theta = _solve_normal(sum(grams), sum(rhss), forced, trace)
    basis = np.eye(6) if forced else np.linalg.svd(np.array([[1.0, 0, 0, 1.0, 0, 1.0]]))[2][1:].T
    meat, qs, zs = np.zeros((6, 6)), [], []
    for sy in systems:
        score = _score_covariance(sy, theta, basis.shape[1])
        meat += score.v_noise + score.q * score.v_torque
        qs.append(score.q)
        zs.append(score.misfit_z)
    bread = basis @ np.linalg.pinv(basis.T @ sum(grams) @ basis) @ basis.T
    cov = bread @ meat @ bread
    windows = sum(sy["a"].shape[0] for sy in systems)
    return EquationError(theta, 0.5 * (cov + cov.T), forced, windows, float(np.mean(qs)), float(max(zs)))


@dataclasses.dataclass(frozen=True)
class _ScoreCovariance:
    """The covariance (6, 6) of the score sum_k A_k^T e_k under the gyro's white noise (v_noise)
    and under a white torque of unit intensity (v_torque), that torque's intensity q from the
    residuals' excess, and the excess in standard deviations of the residuals' sum of squares
    under the noise alone (misfit_z; a chi-square of 3K / (WINDOW_HOP + 1) degrees of freedom:
    each sample lies in WINDOW_HOP + 1 windows).
    """

    v_noise: np.ndarray
    v_torque: np.ndarray
    q: float
    misfit_z: float


def _score_covariance(system: dict, theta, k_free: int) -> _ScoreCovariance:
    """The score's covariance and the model error's intensity at theta (see _ScoreCovariance).

    A noise n_j in the rates at sample j moves window k's residual by m_kj n_j, m_kj = -phi'_kj J
    + phi_kj ([w_j]x J - [J w_j + h_j]x) (dt weights included), so the score moves by B_j n_j,
    B_j = sum_k A_k^T m_kj, and V_noise = sum_j B_j Sigma B_j^T. A torque d adds -int phi_k d to
    e_k: V_torque = sum_j D_j D_j^T / dt_j, D_j = sum_k A_k^T phi_kj dt_j. The residuals' sum of
    squares, scaled for the k_free fitted parameters, less the noise's share, over the torque's
    share per unit q, gives q.
    """
    idx, wq, dq, w, h, var, dt = (system[k] for k in ("idx", "wq", "dq", "w", "h", "var", "dt"))
    a, c = system["a"], system["c"]
    e = np.einsum("kip,p->ki", a, theta) - c
    jm = inertia_from_theta(theta)
    n = w.shape[0]
    moment = skew(w) @ jm - skew(w @ jm.T + h)  # (n, 3, 3): [w]x J - [J w + h]x
    m = -dq[..., None, None] * jm + wq[..., None, None] * moment[idx]  # (K, W+1, 3, 3)
    b = np.zeros((n, 6, 3))
    np.add.at(b, idx, np.einsum("kip,kjia->kjpa", a, m))
    d = np.zeros((n, 6, 3))
    np.add.at(d, idx, np.einsum("kip,kj->kjpi", a, wq))
    v_noise = np.einsum("jpa,a,jqa->pq", b, var, b)
    v_torque = np.einsum("jpi,jqi,j->pq", d, d, 1.0 / dt)
    noise_share = float(np.einsum("kjia,a,kjia->", m, var, m))  # E sum_k |e_k|^2 under the noise
    torque_share = 3.0 * float(np.einsum("kj,kj,kj->", wq, wq, 1.0 / dt[idx]))
    rows = e.size
    excess = float(np.sum(e ** 2)) * rows / max(rows - k_free, 1) - noise_share
    dof = max(rows / (WINDOW_HOP + 1), 1.0)
    z = excess / max(noise_share * np.sqrt(2.0 / dof), 1e-300)
    return _ScoreCovariance(v_noise, v_torque, max(0.0, excess / max(torque_share, 1e-300)), float(z))
