"""Fit the nominal rigid model and every catalogue effect jointly with the inertia; rank by BIC.

Modulating-function equation error: over consecutive intervals [a_k, b_k] of m samples, with a
window phi = sin^2 that vanishes at both ends,
    e_k = integral phi (d(J w)/dt + w x (J w + h) - tau_applied - tau_ext) dt
        = integral (-phi' J w + phi (w x (J w + h) - tau_applied - tau_ext)) dt      (N·m·s)
(with the flexible-mode and inertia-change terms where they apply): no derivative of the noisy
gyro is taken. The intervals do not overlap, so the e_k are independent; each is whitened by the
covariance of the gyro noise propagated through the candidate's own rigid terms, so z_k is
unit white noise when the model explains the data, the BIC of a Gaussian fit is honest, and
sigma * rms(z) (rad/s) is the fit's `rms` (equal to the gyro noise for a correct model).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import optimize, signal

from inertia_gym.discrepancy.effects import (
    EFFECTS,
    NEEDS_ATTITUDE,
    NEEDS_TORQUE,
    _flex_filters,
    n_params,
    quat_rotations,
    rotvec_matrix,
    skew,
    unpack,
)
from inertia_gym.discrepancy.recordings import Recording
from inertia_gym.estimation.equation_error import modulating_windows
from inertia_gym.information import inertia_from_theta, theta_from_inertia
from inertia_gym.sensors import estimate_white_noise

SIGNIFICANT_DELTA_BIC = 10.0  # "very strong" evidence on the Kass-Raftery scale
AMBIGUOUS_DELTA_BIC = 6.0
#: Modal frequencies (Hz) screened for flexible_mode: lowest, and highest as a share of Nyquist.
FLEX_BAND = (0.2, 0.8)


@dataclasses.dataclass(frozen=True)
class Data:
    """A recording prepared for the integral equation error.

    t, w (n, 3), tau (n, 3) N·m (zero-order hold, zeros when absent), rot (n, 3, 3) or None;
    edges (K+1,) sample indices of the interval boundaries; phi, dphi (n,) the modulating
    window sin^2 of each interval and its time derivative (1/s), both zero at the boundaries;
    quad (n,) trapezoid weights (s); sigma (3,) rad/s gyro noise; scale_fixed: the inertia trace
    is pinned to trace0 (no torque, or a trusted nominal).
    """

    t: np.ndarray
    w: np.ndarray
    tau: np.ndarray
    rot: np.ndarray | None
    edges: np.ndarray
    phi: np.ndarray
    dphi: np.ndarray
    quad: np.ndarray
    sigma: np.ndarray
    sigma_source: str
    has_torque: bool
    trace0: float
    scale_fixed: bool


def prepare(rec: Recording) -> Data:
    """Intervals, noise level and scale handling for one recording."""
    n = rec.t.size
    edges, phi, dphi = modulating_windows(rec.t, int(np.clip(n // 150, 8, 40)))
    if "gyro_sigma" in rec.meta:
        sigma, source = np.full(3, float(rec.meta["gyro_sigma"])), "sidecar"
    else:
        sigma, source = np.maximum(estimate_white_noise(rec.w), 1e-6), "estimated from the data"
    nominal = rec.inertia_nominal
    trace0 = float(np.trace(nominal)) if nominal is not None else 1.0
    tau = rec.tau if rec.tau is not None else np.zeros_like(rec.w)
    t = rec.t
    quad = np.gradient(t)
    return Data(t, rec.w, tau, quat_rotations(rec.q) if rec.q is not None else None, edges, phi, dphi, quad,
                sigma, source, rec.has_torque, trace0, (not rec.has_torque) or nominal is not None)


def _modulated(d: "Data", mom, g) -> np.ndarray:
    """Per interval: integral of (-phi' mom + phi g) dt = integral of phi (d mom/dt + g) dt."""
    return np.add.reduceat((-d.dphi[:, None] * mom + d.phi[:, None] * g) * d.quad[:, None],
                           d.edges[:-1], axis=0)


def residual(x, name, d: Data) -> np.ndarray:
    """Integral equation error (K, 3), N·m·s, for x = [theta (6), effect params]."""
    theta, p = x[:6], x[6:]
    jm = inertia_from_theta(theta)
    w, tau, t = d.w, d.tau, d.t
    if name == "gyro_bias":
        w = w - p[:3]
    elif name == "gyro_scale":
        w = w / (1.0 + p[:3])
    jw = w @ jm.T
    if name == "inertia_change":
        dj = inertia_from_theta(p[1:7])
        jw = jw + (t >= p[0])[:, None] * (w @ dj.T)
    mom = jw.copy()
    g = np.cross(w, jw)
    if name == "actuator_scale":
        tau = tau * (1.0 + p[0])
    elif name == "actuator_misalignment":
        tau = tau @ rotvec_matrix(p[:3]).T
    elif name == "actuator_delay":
        idx = np.searchsorted(t, t - p[0], side="right") - 1
        tau = np.where((idx >= 0)[:, None], tau[np.clip(idx, 0, None)], 0.0)
    g = g - tau
    if name == "constant_body_torque":
        g = g - p[:3]
    elif name == "internal_momentum":
        g = g + np.cross(w, p[:3])
    elif name == "viscous_damping":
        g = g + p[:3] * w
    elif name == "aero_drag":
        g = g + p[0] * np.linalg.norm(w, axis=1, keepdims=True) * w
    elif name == "internal_dissipation":
        u = jw / np.linalg.norm(jw, axis=1, keepdims=True)
        g = g + p[0] * (w - u * np.sum(u * w, axis=1, keepdims=True))
    elif name == "gravity_gradient":
        r = np.einsum("nji,j->ni", d.rot, p[:3])
        g = g - 3.0 * np.cross(r, r @ jm.T)
    elif name == "flexible_mode":
        flex = _momentum(x, name, d, w, jw) - jw
        mom = mom + flex
        g = g + np.cross(w, flex)
    return _modulated(d, mom, g)


def _momentum(x, name, d: Data, w, jw) -> np.ndarray:
    """(n, 3) N·m·s: body momentum J w plus, for flexible_mode, the modal part delta eta_dot."""
    if name != "flexible_mode":
        return jw
    p = x[6:]
    dt = float(np.median(np.diff(d.t)))
    (_, _), (_, _), (b2, a2) = _flex_filters(abs(p[0]) + 1e-9, abs(p[1]), dt)
    eta_d = -signal.lfilter(b2, a2, w - w[0], axis=0) @ p[2:5]  # s^2 H applied to w = s H w_dot
    return jw + np.outer(eta_d, p[2:5])


@dataclasses.dataclass(frozen=True)
class Fit:
    """One fitted model: name (None = nominal), x = [theta, params], residual e (K, 3) N·m·s,
    rate residual r (K, 3) rad/s, bic, k (free parameters).
    """

    name: str | None
    x: np.ndarray
    e: np.ndarray
    r: np.ndarray
    bic: float
    k: int

    @property
    def inertia(self) -> np.ndarray:
        """Fitted inertia (3, 3)."""
        return inertia_from_theta(self.x[:6])

    @property
    def params(self) -> dict:
        """The effect's named parameters."""
        return unpack(self.name, self.x[6:])


def whitener(d: Data, x, name: str | None = None) -> np.ndarray:
    """(K, 3, 3) inverse Cholesky factors of cov(e_k) under white gyro noise for x = [theta, p].

    The noise is propagated through the rigid terms with the candidate's own inertia (J(t) for
    inertia_change, the corrected rates for gyro_bias / gyro_scale), so the whitened residual
    cannot shrink by shrinking J: it is measured in units of the gyro noise.
    """
    jm = inertia_from_theta(x[:6])
    w, gain = d.w, np.ones(3)
    if name == "gyro_bias":
        w = w - x[6:9]
    elif name == "gyro_scale":
        gain = 1.0 / (1.0 + x[6:9])
        w = w * gain
    jt = np.broadcast_to(jm, (w.shape[0], 3, 3))
    if name == "inertia_change":
        jt = jt + (d.t >= x[6])[:, None, None] * inertia_from_theta(x[7:13])
    jw = np.einsum("nij,nj->ni", jt, w)
    if name == "flexible_mode":
        # The modal momentum delta eta_dot = -delta s^2 H (delta . w) passes the gyro's white
        # noise at gain 1 (s^2 H -> 1 above the mode): to the noise the body's inertia is
        # J - delta delta^T. Without this the fit could "explain" noise by growing delta.
        delta = x[8:11]
        jw = _momentum(x, name, d, w, jw)
        jt = jt - np.outer(delta, delta)
        if np.linalg.eigvalsh(jt[0])[0] <= 0:  # the rigid part J - delta delta^T must be PD
            return np.full((d.edges.size - 1, 3, 3), np.nan)
    # d e_k / d w_raw,i = q_i (-phi'_i J_i + phi_i ([w_i]x J_i - [J_i w_i]x)) diag(gain)
    a = d.quad[:, None, None] * (-d.dphi[:, None, None] * jt
                                 + d.phi[:, None, None] * (skew(w) @ jt - skew(jw))) * gain
    cov = np.add.reduceat(np.einsum("nij,j,nkj->nik", a, d.sigma ** 2, a), d.edges[:-1], axis=0)
    cov = cov + 1e-12 * np.trace(cov, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    try:
        return np.linalg.inv(np.linalg.cholesky(cov))
    except np.linalg.LinAlgError:
        return np.full_like(cov, np.nan)


def _z(d: Data, x, name, e) -> np.ndarray:
    return np.einsum("kij,kj->ki", whitener(d, x, name), e)


def _objective(x, name, d: Data):
    res = _z(d, x, name, residual(x, name, d)).ravel()
    res = np.where(np.isfinite(res), res, 1e6)
    if d.scale_fixed:
        tr = x[0] + x[3] + x[5]
        res = np.append(res, 1e3 * (tr - d.trace0) / d.trace0 * np.sqrt(res.size))
        if name == "inertia_change":  # the change is fitted as a redistribution at fixed trace
            res = np.append(res, 1e3 * (x[7] + x[10] + x[12]) / d.trace0 * np.sqrt(res.size))
    return res


def _finish(name, x, d: Data, k: int) -> Fit:
    e = residual(x, name, d)
    z = _z(d, x, name, e) if np.all(np.linalg.eigvalsh(inertia_from_theta(x[:6])) > 0) else e * np.inf
    r = z * d.sigma
    n = z.size
    mse = float(np.mean(z ** 2))
    bic = n * np.log(max(mse, 1e-300)) + k * np.log(n) if np.isfinite(mse) else np.inf
    return Fit(name, x, e, r, float(bic), k)


def _affine_solve(name, d: Data, x_fixed: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Exact least squares over the free components of x for models affine in them
    (finite-difference columns of the whitened residual).
    """
    base = _objective(x_fixed, name, d)
    cols = []
    for i in np.flatnonzero(free):
        xi = x_fixed.copy()
        xi[i] += 1.0
        cols.append(_objective(xi, name, d) - base)
    sol = np.linalg.lstsq(np.stack(cols, 1), -base, rcond=None)[0]
    x = x_fixed.copy()
    x[free] += sol
    return x


def fit_nominal(d: Data) -> tuple[Fit, Data]:
    """The rigid model alone: inertia fitted (trace pinned when the scale is not identifiable).

    Returns the fit and the data.
    """
    x = theta_from_inertia(np.eye(3) * d.trace0 / 3)
    x = _affine_solve(None, d, x, np.ones(6, bool))  # exact for the frozen whitener, then refine
    x = optimize.least_squares(_objective, x, args=(None, d), x_scale="jac").x
    return _finish(None, x, d, 6 - int(d.scale_fixed)), d


def _starts(name, d: Data, nominal: Fit) -> list[np.ndarray]:
    """Initial effect-parameter vectors (several where the fit is not convex)."""
    if name == "actuator_delay":
        return [np.array([v]) for v in np.arange(0.05, 1.0, 0.1)]
    if name == "flexible_mode":
        return _flex_screen(d, nominal)
    if name == "gravity_gradient":
        return [0.02 * c for c in np.vstack([np.eye(3), -np.eye(3)])]
    return [np.zeros(n_params(name))]


def _flex_screen(d: Data, nominal: Fit, keep: int = 3, zeta: float = 0.03) -> list[np.ndarray]:
    """Starts of the flexible-mode fit from a linear screen over the modal frequency.

    For a fixed frequency and damping the modal momentum delta eta_dot = -M s^2 H w is linear in
    M = delta delta^T, so J and M (12 numbers) follow from one least-squares solve with the
    nominal whitener. The `keep` best local minima over a geometric grid of frequencies (FLEX_BAND,
    about 3 % apart, finer than a lightly damped resonance) give delta = sqrt(lambda) v from M's
    leading eigenpair. A random or single start misses the resonance: the cost is flat away from it.
    """
    room = 0.5 * np.linalg.eigvalsh(nominal.inertia)[0]  # keep J - delta delta^T positive definite
    dt = float(np.median(np.diff(d.t)))
    wmat = whitener(d, nominal.x, None)
    if room <= 0 or not np.all(np.isfinite(wmat)):  # no valid rigid body to add a mode to
        return []
    z0 = np.einsum("kij,kj->ki", wmat, nominal.e).ravel()
    w = d.w
    basis = [inertia_from_theta(c) for c in np.eye(6)]

    def column(mom):
        return np.einsum("kij,kj->ki", wmat, _modulated(d, mom, np.cross(w, mom))).ravel()

    jcols = np.stack([column(w @ b.T) for b in basis], 1)
    f_hi = FLEX_BAND[1] * 0.5 / dt
    freqs = np.geomspace(FLEX_BAND[0], f_hi, max(2, int(np.log(f_hi / FLEX_BAND[0]) / 0.03)))
    costs, sols = [], []
    for f in freqs:
        (_, _), (_, _), (b2, a2) = _flex_filters(2 * np.pi * f, zeta, dt)
        fw = signal.lfilter(b2, a2, w - w[0], axis=0)
        a = np.hstack([jcols, np.stack([column(-fw @ b.T) for b in basis], 1)])
        rhs = -z0
        if d.scale_fixed:  # keep the trace of J
            a = np.vstack([a, 1e3 * np.r_[1, 0, 0, 1, 0, 1, np.zeros(6)]])
            rhs = np.append(rhs, 0.0)
        sol = np.linalg.lstsq(a, rhs, rcond=None)[0]
        costs.append(float(np.sum((a @ sol - rhs) ** 2)))
        sols.append(sol)
    costs = np.array(costs)
    is_min = np.r_[True, costs[1:] < costs[:-1]] & np.r_[costs[:-1] < costs[1:], True]
    out = []
    for i in np.flatnonzero(is_min)[np.argsort(costs[is_min])]:
        lam, vec = np.linalg.eigh(inertia_from_theta(sols[i][6:]))
        if lam[-1] > 0:  # M must be (close to) delta delta^T with a real delta
            delta = np.sqrt(min(lam[-1], room)) * vec[:, -1]
            out.append(np.concatenate([[2 * np.pi * freqs[i], zeta], delta]))
        if len(out) == keep:
            break
    return out


def fit_effect(name: str, d: Data, nominal: Fit) -> Fit:
    """Fit one effect jointly with the inertia, starting from the nominal inertia."""
    k = 6 - int(d.scale_fixed) + n_params(name)
    if name == "inertia_change":
        best = None
        t_grid = d.t[d.edges[2:-2:max(1, (d.edges.size - 4) // 40)]]
        for tc in t_grid:
            x0 = np.concatenate([nominal.x[:6], [tc], np.zeros(6)])
            free = np.ones(13, bool)
            free[6] = False
            x = _affine_solve(name, d, x0, free)
            cost = np.sum(_objective(x, name, d) ** 2)
            if best is None or cost < best[0]:
                best = (cost, x)
        x = best[1]
        step = max(1, (d.edges[1] - d.edges[0]) // 8)  # refine t_change on a finer grid
        i0 = int(np.searchsorted(d.t, x[6]))
        span = 2 * (d.edges[1] - d.edges[0])
        for i in range(max(1, i0 - span), min(d.t.size - 1, i0 + span), step):
            xi = _affine_solve(name, d, np.concatenate([x[:6], [d.t[i]], x[7:]]), free)
            cost = np.sum(_objective(xi, name, d) ** 2)
            if cost < best[0]:
                best = (cost, xi)
        x = best[1]
        tc = x[6]

        def fixed_tc(y):
            return _objective(np.concatenate([y[:6], [tc], y[6:]]), name, d)

        y = optimize.least_squares(fixed_tc, np.delete(x, 6), x_scale="jac").x
        return _finish(name, np.concatenate([y[:6], [tc], y[6:]]), d, k)
    best = None
    for p0 in _starts(name, d, nominal):
        x0 = np.concatenate([nominal.x[:6], p0])
        lb, ub = np.full(x0.size, -np.inf), np.full(x0.size, np.inf)
        if name == "gyro_scale":
            lb[6:] = -0.5  # a gyro reading at least half the true rate
        if name == "flexible_mode":  # a mode inside the sampled band, damping in [0, 1]
            dt = float(np.median(np.diff(d.t)))
            lb[6:8] = 2 * np.pi * 0.5 * FLEX_BAND[0], 0.0
            ub[6:8] = 2 * np.pi * 0.5 / dt * 0.95, 1.0
            x0[6:8] = np.clip(x0[6:8], lb[6:8] + 1e-9, ub[6:8] - 1e-9)
        # flexible_mode: a short run from each screened start, then the best one to convergence
        sol = optimize.least_squares(_objective, x0, args=(name, d), x_scale="jac", bounds=(lb, ub),
                                     max_nfev=8 if name == "flexible_mode" else None)
        if best is None or sol.cost < best.cost:
            best = sol
    if best is None:  # no start (e.g. no valid nominal whitener): the nominal inertia, no mode
        return _finish(name, np.concatenate([nominal.x[:6], np.zeros(n_params(name))]), d, k)
    if name == "flexible_mode" and best.status == 0:
        best = optimize.least_squares(_objective, best.x, args=(name, d), x_scale="jac",
                                      bounds=(lb, ub), max_nfev=200)
    return _finish(name, best.x, d, k)


def candidates(d: Data) -> tuple[list[str], dict]:
    """Effects the data can test, and why the others are skipped."""
    names, skipped = [], {}
    for name in EFFECTS:
        if name in NEEDS_TORQUE and not d.has_torque:
            skipped[name] = "no commanded torque in the recording"
        elif name == "actuator_scale" and not d.scale_fixed:
            skipped[name] = ("indistinguishable from the inertia's scale: no nominal inertia in the "
                             "sidecar to pin it")
        elif name in NEEDS_ATTITUDE and d.rot is None:
            skipped[name] = "needs attitude (qw..qz) columns"
        elif name == "inertia_change" and d.edges.size < 12:
            skipped[name] = "recording too short to split"
        else:
            names.append(name)
    return names, skipped


def fit_all(d: Data) -> tuple[Fit, list[Fit], dict, Data]:
    """Nominal fit, every testable effect's fit (ranked by delta BIC, best first), skipped ones,
    and the data.
    """
    nominal, d = fit_nominal(d)
    names, skipped = candidates(d)
    fits = []
    for name in names:
        # actuator_scale is only a candidate with the trace pinned to a trusted nominal
        # (candidates()), so it is fitted like every other effect: J at the nominal trace, torque
        # scaled by 1 + s. (Fitting J and s freely and rescaling afterwards is degenerate along
        # (c J, c (1 + s)); the rescaled s must then be c (1 + s) - 1, not c - 1.)
        fits.append(fit_effect(name, d, nominal))
    fits.sort(key=lambda f: f.bic)
    return nominal, fits, skipped, d


def sparse_terms(d: Data, fit: Fit, threshold: float = 0.1) -> list[dict]:
    """Data-driven fallback: sequentially thresholded least squares of the remaining residual
    torque on a library of terms {1, w_i, w_i w_j, |w| w_i} (integrated like the model).

    Returns the surviving terms per axis as {axis, term, coefficient (N·m per unit term)}.
    """
    w = d.w
    lib = {"1": np.ones(len(w))}
    for i, a in enumerate("xyz"):
        lib[f"w{a}"] = w[:, i]
        lib[f"|w|w{a}"] = np.linalg.norm(w, axis=1) * w[:, i]
        for j in range(i, 3):
            lib[f"w{a}w{'xyz'[j]}"] = w[:, i] * w[:, j]
    names = list(lib)
    zero = np.zeros((len(w), 3))
    theta = np.stack([_modulated(d, zero, np.repeat(v[:, None], 3, 1))[:, 0] for v in lib.values()], 1)
    scale = np.linalg.norm(theta, axis=0)
    a = theta / scale
    out = []
    for axis in range(3):
        y = -fit.e[:, axis]
        coef = np.linalg.lstsq(a, y, rcond=None)[0]
        for _ in range(10):
            small = np.abs(coef) < threshold * np.abs(coef).max()
            coef[small] = 0.0
            if (~small).any():
                coef[~small] = np.linalg.lstsq(a[:, ~small], y, rcond=None)[0]
        for name, c, s in zip(names, coef, scale):
            if c != 0.0:
                out.append({"axis": "xyz"[axis], "term": name, "coefficient": float(c / s)})
    return out
