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
    FLEX_BAND,
    REGISTRY,
    EffectModel,
    flex_filters,
    quat_rotations,
    skew,
)
from inertia_gym.discrepancy.recordings import Recording
from inertia_gym.estimation.equation_error import modulating_windows
from inertia_gym.information import inertia_from_theta, theta_from_inertia
from inertia_gym.sensors import estimate_white_noise

SIGNIFICANT_DELTA_BIC = 10.0  # "very strong" evidence on the Kass-Raftery scale
AMBIGUOUS_DELTA_BIC = 6.0
#: At most this many effects in a compound explanation.
MAX_EFFECTS = 3
#: Solver evaluations per start when a candidate is screened on top of a fit (select()).
SCREEN_NFEV = 4


@dataclasses.dataclass(frozen=True)
class Data:
    """A recording prepared for the integral equation error.

    t, w (n, 3), tau (n, 3) N·m (zero-order hold, zeros when absent), rot (n, 3, 3) or None;
    edges (K+1,) sample indices of the interval boundaries; phi, dphi (n,) the modulating
    window sin^2 of each interval and its time derivative (1/s), both zero at the boundaries;
    quad (n,) trapezoid weights (s); sigma (3,) rad/s gyro noise; scale_fixed: the inertia trace
    is pinned to trace0 (no torque, or a trusted nominal); inertia0 (3, 3) kg·m²: the sidecar's
    nominal inertia, or None (replay() runs the user's model with it as given).
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
    inertia0: np.ndarray | None = None


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
                sigma, source, rec.has_torque, trace0, (not rec.has_torque) or nominal is not None,
                nominal)


def _modulated(d: "Data", mom, g) -> np.ndarray:
    """Per interval: integral of (-phi' mom + phi g) dt = integral of phi (d mom/dt + g) dt."""
    return np.add.reduceat((-d.dphi[:, None] * mom + d.phi[:, None] * g) * d.quad[:, None],
                           d.edges[:-1], axis=0)


def _names(names) -> tuple[str, ...]:
    """None (the nominal model), one effect name, or a sequence of them -> a tuple of names."""
    if names is None:
        return ()
    return (names,) if isinstance(names, str) else tuple(names)


def _parts(names: tuple[str, ...], x) -> list[tuple[EffectModel, np.ndarray]]:
    """Each effect's model and its slice of x = [theta (6), p_1, p_2, ...]."""
    out, i = [], 6
    for name in names:
        model = REGISTRY[name]
        out.append((model, x[i:i + model.size]))
        i += model.size
    return out


def _model_inertia(parts, x) -> np.ndarray:
    """The model's inertia (3, 3): an effect's (inertia_offset) if it sets one, else theta's."""
    for model, p in parts:
        j = model.inertia(p)
        if j is not None:
            return j
    return inertia_from_theta(x[:6])


def _free(names: tuple[str, ...], d: Data) -> np.ndarray:
    """Bool mask over x = [theta, p_1, ...] of what the solver moves: theta unless an effect
    sets the inertia itself (inertia_offset), and every effect parameter not held.
    """
    theta_free = not any(REGISTRY[n].sets_inertia for n in names)
    return np.concatenate([np.full(6, theta_free)] + [~REGISTRY[n].held(d) for n in names])


def _rates(parts, w):
    """Gyro reading (n, 3) -> rates corrected by the sensor effects, and their gain (3,)."""
    gain = np.ones(3)
    for model, p in parts:
        w, gain = model.rates(p, w, gain)
    return w, gain


def residual(x, names, d: Data) -> np.ndarray:
    """Integral equation error (K, 3), N·m·s, for x = [theta (6), p_1, p_2, ...] of the effects
    `names` (None or () for the rigid model alone, one name, or a sequence).
    """
    parts = _parts(_names(names), x)
    jm = _model_inertia(parts, x)
    w, _ = _rates(parts, d.w)
    jw = w @ jm.T
    for model, p in parts:
        step = model.inertia_step(p, d)
        if step is not None:
            jw = jw + step[0][:, None] * (w @ step[1].T)
    mom = jw
    for model, p in parts:
        extra = model.modal_momentum(p, d, w)
        if extra is not None:
            mom = mom + extra
    tau = d.tau
    for model, p in parts:
        tau = model.actuate(p, d, tau)
    g = np.cross(w, mom) - tau
    for model, p in parts:
        torque = model.torque(p, d, w, jw, jm)
        if torque is not None:
            g = g - torque
    return _modulated(d, mom, g)


@dataclasses.dataclass(frozen=True)
class Fit:
    """One fitted model: names of its effects (() = nominal), x = [theta, p_1, ...], residual
    e (K, 3) N·m·s, rate residual r (K, 3) rad/s, bic, k (free parameters).
    """

    names: tuple[str, ...]
    x: np.ndarray
    e: np.ndarray
    r: np.ndarray
    bic: float
    k: int

    @property
    def name(self) -> str | None:
        """The last effect added (the only one of a single-effect fit), None for the nominal."""
        return self.names[-1] if self.names else None

    @property
    def inertia(self) -> np.ndarray:
        """Fitted inertia (3, 3)."""
        return _model_inertia(_parts(self.names, self.x), self.x)

    @property
    def effect_params(self) -> dict:
        """Effect name -> its named parameters, in the order the effects were added."""
        return {m.name: m.unpack(p) for m, p in _parts(self.names, self.x)}

    @property
    def params(self) -> dict:
        """The last effect's named parameters ({} for the nominal)."""
        return self.effect_params[self.name] if self.names else {}


def whitener(d: Data, x, names=None) -> np.ndarray:
    """(K, 3, 3) inverse Cholesky factors of cov(e_k) under white gyro noise for x = [theta, p].

    The noise is propagated through the rigid terms with the candidate's own inertia (J(t) for
    inertia_change, the corrected rates for gyro_bias / gyro_scale, J - delta delta^T with the
    modal momentum for flexible_mode), so the whitened residual cannot shrink by shrinking J:
    it is measured in units of the gyro noise.
    """
    parts = _parts(_names(names), x)
    jm = _model_inertia(parts, x)
    w, gain = _rates(parts, d.w)
    jt = np.broadcast_to(jm, (w.shape[0], 3, 3))
    for model, p in parts:
        step = model.inertia_step(p, d)
        if step is not None:
            jt = jt + step[0][:, None, None] * step[1]
    jw = np.einsum("nij,nj->ni", jt, w)
    for model, p in parts:
        extra = model.modal_momentum(p, d, w)
        if extra is not None:
            jw = jw + extra
        noise = model.noise_inertia(p)
        if noise is not None:
            jt = jt - noise
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


def _z(d: Data, x, names, e) -> np.ndarray:
    return np.einsum("kij,kj->ki", whitener(d, x, names), e)


def _objective(x, names, d: Data):
    res = _z(d, x, names, residual(x, names, d)).ravel()
    res = np.where(np.isfinite(res), res, 1e6)
    if d.scale_fixed:
        weight = 1e3 * np.sqrt(res.size)
        rows = [(x[0] + x[3] + x[5] - d.trace0) / d.trace0]
        for model, p in _parts(_names(names), x):
            rows += model.penalty(p, d)
        res = np.append(res, weight * np.asarray(rows))
    return res


def _finish(names, x, d: Data, k: int) -> Fit:
    names = _names(names)
    e = residual(x, names, d)
    positive = np.all(np.linalg.eigvalsh(_model_inertia(_parts(names, x), x)) > 0)
    z = _z(d, x, names, e) if positive else e * np.inf
    r = z * d.sigma
    n = z.size
    mse = float(np.mean(z ** 2))
    bic = n * np.log(max(mse, 1e-300)) + k * np.log(n) if np.isfinite(mse) else np.inf
    return Fit(names, x, e, r, float(bic), k)


def _affine_solve(names, d: Data, x_fixed: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Exact least squares over the free components of x for models affine in them
    (finite-difference columns of the whitened residual).
    """
    base = _objective(x_fixed, names, d)
    cols = []
    for i in np.flatnonzero(free):
        xi = x_fixed.copy()
        xi[i] += 1.0
        cols.append(_objective(xi, names, d) - base)
    sol = np.linalg.lstsq(np.stack(cols, 1), -base, rcond=None)[0]
    x = x_fixed.copy()
    x[free] += sol
    return x


def fit_nominal(d: Data) -> tuple[Fit, Data]:
    """The rigid model alone: inertia fitted (trace pinned when the scale is not identifiable).

    Returns the fit and the data.
    """
    x = theta_from_inertia(np.eye(3) * d.trace0 / 3)
    x = _affine_solve((), d, x, np.ones(6, bool))  # exact for the frozen whitener, then refine
    x = optimize.least_squares(_objective, x, args=((), d), x_scale="jac").x
    return _finish((), x, d, 6 - int(d.scale_fixed)), d


@dataclasses.dataclass(frozen=True)
class Probe:
    """What an effect's starts() may ask while it is added to the fit `base`: the joint
    vector of a start, affine solves and costs of the joint model `names` (base's + the new one).
    """

    names: tuple[str, ...]
    d: Data
    base: Fit

    def x(self, p) -> np.ndarray:
        """base.x with the new effect's vector p appended."""
        return np.concatenate([self.base.x, p])

    def effect_part(self, x) -> np.ndarray:
        """The new effect's vector p of a joint x."""
        return x[self.base.x.size:]

    def affine(self, p, free_new) -> tuple[float, np.ndarray]:
        """Cost and joint x after an exact solve over the inertia and the new effect's
        components free_new (bool (size,)), the base's effect parameters held.
        """
        free = np.concatenate([np.ones(6, bool), np.zeros(self.base.x.size - 6, bool), free_new])
        x = _affine_solve(self.names, self.d, self.x(p), free)
        return float(np.sum(_objective(x, self.names, self.d) ** 2)), x

    def flex_screen(self, keep: int = 3, zeta: float = 0.03) -> list[np.ndarray]:
        """Starts of the flexible-mode fit from a linear screen over the modal frequency.

        For a fixed frequency and damping the modal momentum delta eta_dot = -M s^2 H w is linear
        in M = delta delta^T, so J and M (12 numbers) follow from one least-squares solve with the
        base whitener. The `keep` best local minima over a geometric grid of frequencies
        (FLEX_BAND, about 3 % apart, finer than a lightly damped resonance) give
        delta = sqrt(lambda) v from M's leading eigenpair. A random or single start misses the
        resonance: the cost is flat away from it.
        """
        d, base = self.d, self.base
        room = 0.5 * np.linalg.eigvalsh(base.inertia)[0]  # keep J - delta delta^T positive definite
        dt = float(np.median(np.diff(d.t)))
        wmat = whitener(d, base.x, base.names)
        if room <= 0 or not np.all(np.isfinite(wmat)):  # no valid rigid body to add a mode to
            return []
        z0 = np.einsum("kij,kj->ki", wmat, base.e).ravel()
        w = d.w
        basis = [inertia_from_theta(c) for c in np.eye(6)]

        def column(mom):
            return np.einsum("kij,kj->ki", wmat, _modulated(d, mom, np.cross(w, mom))).ravel()

        jcols = np.stack([column(w @ b.T) for b in basis], 1)
        f_hi = FLEX_BAND[1] * 0.5 / dt
        freqs = np.geomspace(FLEX_BAND[0], f_hi, max(2, int(np.log(f_hi / FLEX_BAND[0]) / 0.03)))
        costs, sols = [], []
        for f in freqs:
            (_, _), (_, _), (b2, a2) = flex_filters(2 * np.pi * f, zeta, dt)
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
                out.append(self.x(np.concatenate([[2 * np.pi * freqs[i], zeta], delta])))
            if len(out) == keep:
                break
        return out


def _n_free(names: tuple[str, ...], d: Data) -> int:
    """Free parameters of a model for the BIC (a scanned t_change counts)."""
    theta = 0 if any(REGISTRY[n].sets_inertia for n in names) else 6 - int(d.scale_fixed)
    return theta + sum(REGISTRY[n].size for n in names)


def replay(d: Data) -> Fit | None:
    """The user's model as given: the sidecar's nominal inertia, nothing fitted (None without one)."""
    if d.inertia0 is None:
        return None
    return _finish((), theta_from_inertia(d.inertia0), d, 0)


def fit_model(names, d: Data, base: Fit, joint: bool = True, start=None) -> Fit:
    """Fit the effects `names` jointly with the inertia, the last one added to the fit `base`
    of the others (its x is the start of everything but the new effect).

    joint=False fits only the new effect's parameters (the base's held) with at most
    SCREEN_NFEV evaluations per start and no polish: a cheap screen, refitted jointly after;
    start: one joint x to start from instead of the new effect's own starts.
    """
    names = _names(names)
    new = REGISTRY[names[-1]]
    parts = [REGISTRY[n] for n in names]
    lb = np.concatenate([np.full(6, -np.inf)] + [m.bounds(d)[0] for m in parts])
    ub = np.concatenate([np.full(6, np.inf)] + [m.bounds(d)[1] for m in parts])
    free = _free(names, d)
    if not joint:
        free[:base.x.size] = False
    probe = Probe(names, d, base)

    def solve(x0, max_nfev):
        def objective(y):
            x = x0.copy()
            x[free] = y
            return _objective(x, names, d)

        sol = optimize.least_squares(objective, x0[free], x_scale="jac", bounds=(lb[free], ub[free]),
                                     max_nfev=max_nfev)
        x = x0.copy()
        x[free] = sol.x
        return sol, x

    best = None
    nfev = new.start_nfev if joint else min(new.start_nfev or SCREEN_NFEV, SCREEN_NFEV)
    for x0 in new.starts(d, base, probe) if start is None else [start]:
        x0 = np.clip(x0, lb + 1e-9, ub - 1e-9)
        sol, x = solve(x0, nfev)
        if best is None or sol.cost < best[0].cost:
            best = (sol, x)
    if best is None:  # no start (e.g. no valid base whitener for a mode): the base, effect zero
        return _finish(names, probe.x(np.zeros(new.size)), d, _n_free(names, d))
    if joint and new.start_nfev is not None and best[0].status == 0:
        best = solve(best[1], 200)
    return _finish(names, best[1], d, _n_free(names, d))


def fit_effect(name: str, d: Data, nominal: Fit) -> Fit:
    """Fit one effect jointly with the inertia, starting from the nominal inertia."""
    return fit_model((name,), d, nominal)


def candidates(d: Data) -> tuple[list[str], dict]:
    """Effects the data can test, and why the others are skipped."""
    names, skipped = [], {}
    for name, model in REGISTRY.items():
        reason = model.skip_reason(d)
        if reason is None:
            names.append(name)
        else:
            skipped[name] = reason
    return names, skipped


def fit_all(d: Data) -> tuple[Fit, list[Fit], dict, Data]:
    """Nominal fit, every testable effect's fit (ranked by delta BIC, best first), skipped ones,
    and the data.
    """
    nominal, d = fit_nominal(d)
    names, skipped = candidates(d)
    # actuator_scale is only a candidate with the trace pinned to a trusted nominal
    # (skip_reason), so it is fitted like every other effect: J at the nominal trace, torque
    # scaled by 1 + s. (Fitting J and s freely and rescaling afterwards is degenerate along
    # (c J, c (1 + s)); the rescaled s must then be c (1 + s) - 1, not c - 1.)
    # Exactly confounded effects (actuator_scale and inertia_offset: c J with c tau) tie to
    # rounding; the tie goes to the earlier one in the catalogue, the report names both.
    order = {name: i for i, name in enumerate(REGISTRY)}
    fits = sorted((fit_effect(name, d, nominal) for name in names),
                  key=lambda f: (np.round(f.bic, 6), order[f.name]))
    return nominal, fits, skipped, d


@dataclasses.dataclass(frozen=True)
class Explanation:
    """A compound explanation: the fits of the chain nominal -> +e1 -> +e1+e2 ..., the BIC each
    effect added along that chain, and what the selection tried and left out.

    chain: fits, chain[i] holds the first i+1 effects; added: (name, delta BIC) per effect;
    dropped: {name: reason} of effects removed by the backward check or never added.
    """

    chain: tuple[Fit, ...]
    added: tuple[tuple[str, float], ...]
    dropped: dict

    @property
    def fit(self) -> Fit | None:
        """The compound fit (None when no effect is selected)."""
        return self.chain[-1] if self.chain else None


def _chain(names: tuple[str, ...], d: Data, nominal: Fit, singles: dict) -> list[Fit]:
    """Fits of the prefixes of names, each added to the previous one (singles reused)."""
    out = [singles[names[0]]]
    for i in range(1, len(names)):
        out.append(fit_model(names[:i + 1], d, out[-1]))
    return out


def select(d: Data, nominal: Fit, singles: list[Fit], max_effects: int = MAX_EFFECTS) -> Explanation:
    """Forward selection over the catalogue, then a backward check.

    Step 1 takes the best single-effect fit if it beats the nominal by SIGNIFICANT_DELTA_BIC.
    Each further step fits every remaining candidate's own parameters on top of the current
    fit (everything else held: a screen), refits the best of them jointly with the inertia and
    the effects already chosen, and keeps it if that improves the BIC by the same margin; at
    most max_effects. Every testable effect is screened at every step, also those that explain
    nothing alone: a large effect can hide a second one (a gyro bias hides an actuator
    misalignment that alone improves the BIC by nothing). The backward
    check then refits without each chosen effect and drops any whose removal costs less than
    the margin, until none does. Returns the Explanation.
    """
    by_name = {f.name: f for f in singles}
    ranked = [f for f in singles if np.isfinite(f.bic) and nominal.bic - f.bic > SIGNIFICANT_DELTA_BIC]
    dropped = {f.name: f"alone it improves the BIC by {nominal.bic - f.bic:.1f} "
                       f"<= {SIGNIFICANT_DELTA_BIC:g}" if np.isfinite(f.bic) else "no valid fit"
               for f in singles if f not in ranked}
    if not ranked:
        return Explanation((), (), dropped)
    chosen, current = [ranked[0].name], ranked[0]
    chain = [current]
    pool_names = [f.name for f in singles if np.isfinite(f.bic)]
    while len(chosen) < max_effects:
        # screen with the chosen effects and the inertia held, then refit the best jointly
        trials = [fit_model((*chosen, n), d, current, joint=False) for n in pool_names
                  if n not in chosen]
        trials = [t for t in trials if np.isfinite(t.bic)]
        if not trials:
            break
        screened = min(trials, key=lambda t: t.bic)
        best = fit_model(screened.names, d, current, start=screened.x)
        if not current.bic - best.bic > SIGNIFICANT_DELTA_BIC:
            break
        chosen.append(best.name)
        current = best
        chain.append(best)
    changed = len(chosen) > 1
    while changed and len(chosen) > 1:
        changed = False
        for name in list(chosen):
            rest = tuple(n for n in chosen if n != name)
            rest_chain = _chain(rest, d, nominal, by_name)
            if rest_chain[-1].bic - current.bic <= SIGNIFICANT_DELTA_BIC:
                dropped[name] = (f"removing it from the explanation costs only "
                                 f"{rest_chain[-1].bic - current.bic:.1f} in BIC (backward check)")
                chosen, current, chain, changed = list(rest), rest_chain[-1], rest_chain, True
                break
    for name in pool_names:
        if name not in chosen and not dropped.get(name, "").startswith("removing"):
            dropped[name] = (f"alone it improves the BIC by {nominal.bic - by_name[name].bic:.1f}, "
                             f"and it adds <= {SIGNIFICANT_DELTA_BIC:g} once "
                             f"{', '.join(chosen)} {'is' if len(chosen) == 1 else 'are'} in")
    bics = [nominal.bic] + [f.bic for f in chain]
    added = tuple((n, float(bics[i] - bics[i + 1])) for i, n in enumerate(chosen))
    return Explanation(tuple(chain), added, dropped)


def intervals(fit: Fit, d: Data, level: float = 0.95) -> dict:
    """Two-sided intervals of every named parameter of fit's effects: {name: {param: {lo, hi}}}.

    The covariance of the free components of x is (A^T A)^-1 times the mean square of the
    whitened residual (at least 1), A the central-difference Jacobian of the objective (the
    trace constraint rows included); named parameters follow by the delta method through each
    class's unpack. Held parameters (a scanned t_change) get no width from the fit.
    """
    from scipy import stats

    x = fit.x
    free = np.flatnonzero(_free(fit.names, d))
    steps = 1e-5 * np.maximum(np.abs(x), 1e-3 * np.abs(x[:6]).mean() if x.size else 1.0)
    cols = []
    for i in free:
        hi, lo = x.copy(), x.copy()
        hi[i] += steps[i]
        lo[i] -= steps[i]
        cols.append((_objective(hi, fit.names, d) - _objective(lo, fit.names, d)) / (2 * steps[i]))
    a = np.stack(cols, 1)
    z = _z(d, x, fit.names, fit.e)
    mse = max(1.0, float(np.mean(z ** 2))) if np.all(np.isfinite(z)) else 1.0
    cov = np.zeros((x.size, x.size))
    cov[np.ix_(free, free)] = np.linalg.pinv(a.T @ a) * mse
    k = float(stats.norm.ppf(0.5 + level / 2))
    out = {}
    for model, p in _parts(fit.names, x):
        i0 = 6 + sum(REGISTRY[n].size for n in fit.names[:fit.names.index(model.name)])
        sub = cov[i0:i0 + model.size, i0:i0 + model.size]
        named = model.unpack(p)
        flat = np.concatenate([np.ravel(v) for v in named.values()])
        jac = np.zeros((flat.size, model.size))
        for j in range(model.size):
            h = steps[i0 + j]
            up, dn = p.copy(), p.copy()
            up[j] += h
            dn[j] -= h
            jac[:, j] = (np.concatenate([np.ravel(v) for v in model.unpack(up).values()])
                         - np.concatenate([np.ravel(v) for v in model.unpack(dn).values()])) / (2 * h)
        half = k * np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", jac, sub, jac), 0.0))
        res, i = {}, 0
        for key, v in named.items():
            size = np.size(v)
            shape = np.shape(v)
            res[key] = {"lo": (flat[i:i + size] - half[i:i + size]).reshape(shape),
                        "hi": (flat[i:i + size] + half[i:i + size]).reshape(shape)}
            i += size
        out[model.name] = res
    return out


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
