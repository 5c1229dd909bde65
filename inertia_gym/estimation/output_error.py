"""Output-error maximum likelihood: the rigid model's trajectory fitted to a whole record.

Measurements: gyro z_w = w + b + noise (sigma_w rad/s per axis) and, where recorded, attitude
z_q = q (x) exp(n) (the sensor's sigma_q per quaternion component gives 2 sigma_q rad per axis
of the rotation vector 2 vec(q_hat^* (x) z_q)). The residuals are the measurements minus the
model's output (integrator.trajectory): no differentiated gyro enters the cost.

Unknowns p = [phi (6), w0 (3), dq0 (3) if attitude, c (3) if drag, b (3) if bias]: phi the
log-Cholesky inertia (inertia_param.py: J = e^s L L^T, s the pure scale, held where the record
cannot fix it), w0 the rate at the first grid point, dq0 a body-frame rotation vector
correcting the initial attitude, c a body-axis aerodynamic damping, b a constant gyro bias.

Long records: a single trajectory's phase is only locally linear in J (a 0.1 % inertia error
turns a 10 rad/s tumble by 1 rad in 1000 s), and a thin body's turns on a ratio of small
differences of its moments; so the fit starts from segments no longer than the start can
predict, each from its own initial state (multiple shooting: every segment starts inside its
basin), and joins them pairwise until one trajectory spans the record (continuation). Stages
before the last carry the start as a weak prior; the last is the pure likelihood. The solver is
estimation/solver.py's, whose arrow structure takes the segments' states as locals.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from inertia_gym.dynamics import quat_exp, quat_mul
from inertia_gym.estimation import solver
from inertia_gym.estimation.inertia_param import realizable_face, realizable_phi
from inertia_gym.estimation.integrator import N_DYN, substeps, trajectories
from inertia_gym.prepare import Prepared
from inertia_gym.sensors import attitude_error

#: Largest change of the inertia's log-Cholesky parameters in one step (the solver's trust
#: radius: on a short, poorly conditioned window an undamped step can leap to another basin).
MAX_PHI_STEP = 0.2
#: A merged shooting stage has slipped out of its basin where its residual rms exceeds the last
#: stage's by this factor: the joined rows are then not noise about the model but a lost phase.
SLIP_FACTOR = 1.5
#: Iterations of each shooting stage, and of the last (one trajectory over the whole record: a
#: curved, ill-conditioned valley, where a short flip's nutation fixes nearly one combination
#: of the moments, takes long to crawl to its floor).
STAGE_ITER, FINAL_ITER = 40, 400
#: A step gaining less than this (|r|^2, whitened: a step of about 0.03 standard deviations)
#: ends the solve.
TOL = 1e-3


@dataclasses.dataclass(frozen=True)
class Problem:
    """One record prepared for the output-error fit.

    t_grid (G,) s; tau_grid (G, 3) N·m held from each grid point on; h_grid (G, 3) kg·m²/s;
    n_sub (G,) integration sub-steps per interval; meas_idx (M,) grid index of each measurement;
    z_w (M, 3) rad/s gyro; z_q (M, 4) unit quaternions or None; sigma_w (3,) rad/s (or (M, 3),
    each measurement's: several records of one body in one problem);
    sigma_att rad (per axis of the attitude error); fit_bias: estimate a constant gyro bias;
    fix_scale: the scale s is not a free parameter (no torque and h zero); fit_drag:
    estimate a body-axis aerodynamic damping c (3,) N·m·s²; fixed_inertia: the inertia is held
    where p puts it and only the other parameters move (profile_cost).
    """

    t_grid: np.ndarray
    tau_grid: np.ndarray
    h_grid: np.ndarray
    n_sub: np.ndarray
    meas_idx: np.ndarray
    z_w: np.ndarray
    z_q: np.ndarray | None
    sigma_w: np.ndarray
    sigma_att: float
    fit_bias: bool
    fix_scale: bool
    fit_drag: bool = False
    fixed_inertia: bool = False

    @property
    def with_att(self) -> bool:
        """True when attitude measurements enter the fit."""
        return self.z_q is not None

    @property
    def n_params(self) -> int:
        """Length of p = [phi, w0, (dq0), (c), (b)]."""
        return 9 + 3 * (int(self.with_att) + int(self.fit_drag) + int(self.fit_bias))

    @property
    def drag_slice(self) -> slice:
        """Where the drag coefficients c sit in p (empty without fit_drag)."""
        start = 12 if self.with_att else 9
        return slice(start, start + (3 if self.fit_drag else 0))

    def start(self, phi) -> np.ndarray:
        """P (n_params,) from the inertia phi (6,) and the first measured rate, the rest zero."""
        p = np.zeros(self.n_params)
        p[:6], p[6:9] = phi, self.z_w[0]
        return p

    def free(self) -> np.ndarray:
        """Bool mask (n_params,) of the parameters the fit moves."""
        mask = np.ones(self.n_params, dtype=bool)
        mask[0] = not self.fix_scale
        if self.fixed_inertia:
            mask[:6] = False
        return mask

    def window(self, n_meas: int) -> "Problem":
        """The same problem restricted to its first n_meas measurements."""
        g_end = int(self.meas_idx[n_meas - 1]) + 1
        sigma = self.sigma_w if np.ndim(self.sigma_w) == 1 else self.sigma_w[:n_meas]
        return dataclasses.replace(
            self, t_grid=self.t_grid[:g_end], tau_grid=self.tau_grid[:g_end],
            h_grid=self.h_grid[:g_end], n_sub=self.n_sub[:g_end], meas_idx=self.meas_idx[:n_meas],
            z_w=self.z_w[:n_meas], z_q=None if self.z_q is None else self.z_q[:n_meas], sigma_w=sigma)


def problem_from(prep: Prepared, sigma_w=None, fit_bias: bool = False,
                 fit_drag: bool = False) -> Problem:
    """The output-error problem of a prepared record: grid = its rows, torque held per row, h
    linear; the measurements are its usable rows (where the integration plans for twice a
    clipped row's rate).
    """
    rec = prep.rec
    t = rec.t - rec.t[0]
    n = t.size
    meas = np.flatnonzero(prep.usable)
    sigma_w = prep.level if sigma_w is None else sigma_w
    quat_sigma = float(rec.meta.get("quat_sigma", 0.0) or 0.0)
    rate = np.linalg.norm(rec.w, axis=1)
    rate[~prep.usable] *= 2.0
    return Problem(
        t_grid=t, tau_grid=np.asarray(rec.tau if rec.tau is not None else np.zeros((n, 3)), float),
        h_grid=np.asarray(rec.h if rec.h is not None else np.zeros((n, 3)), float),
        n_sub=substeps(t, rate), meas_idx=meas, z_w=np.asarray(rec.w[meas], float),
        z_q=None if rec.q is None else np.asarray(rec.q[meas], float),
        sigma_w=np.broadcast_to(np.asarray(sigma_w, float), (3,)).copy(),
        sigma_att=2.0 * quat_sigma if quat_sigma > 0 else 0.02, fit_bias=bool(fit_bias or rec.q is not None),
        fix_scale=not rec.sees_scale, fit_drag=bool(fit_drag))


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """Model output at p: weighted residuals r (R,) (gyro block, then attitude block), their
    Jacobian dr/dp (R, n_params) or None, gyro residual e_w (M, 3) rad/s and attitude residual
    e_att (M, 3) rad (or None); ok: the trajectory stayed finite.
    """

    r: np.ndarray
    jac: np.ndarray | None
    e_w: np.ndarray
    e_att: np.ndarray | None
    ok: bool


def _integrated(prob: Problem, seg, p, w0s, q0s, with_jac: bool) -> tuple:
    """(Evaluation without Jacobian, the weighted Jacobian blocks or None) of the problem cut at
    measurement indices seg (S+1,), every segment from its rate w0s[s] and attitude q0s[s], the
    inertia, damping and bias those of p (the problem's layout). The blocks (gyro, then
    attitude) are (3M, n_params) each, the columns of w0 and dq0 those of each row's own segment.
    """
    m = prob.meas_idx.size
    nd = N_DYN + (3 if prob.fit_drag else 0)
    out_w = np.zeros((m, 3))
    out_sw = np.zeros((m, 3, nd)) if with_jac else np.zeros((1, 3, nd))
    out_q = np.zeros((m, 4)) if prob.with_att else np.zeros((1, 4))
    out_sa = np.zeros((m, 3, nd)) if (with_jac and prob.with_att) else np.zeros((1, 3, nd))
    drag = np.ascontiguousarray(p[prob.drag_slice]) if prob.fit_drag else None
    ok = trajectories(prob.t_grid, prob.tau_grid, prob.h_grid, prob.n_sub, prob.meas_idx, seg,
                      np.ascontiguousarray(p[:6]), np.ascontiguousarray(w0s), np.ascontiguousarray(q0s),
                      with_jac, prob.with_att, out_w, out_sw, out_q, out_sa, drag)
    e_w = prob.z_w - out_w - (p[-3:] if prob.fit_bias else np.zeros(3))
    parts = [(e_w / prob.sigma_w).ravel()]
    e_att = None
    if prob.with_att:
        e_att = attitude_error(out_q, prob.z_q)
        parts.append((e_att / prob.sigma_att).ravel())
    r = np.concatenate(parts)
    ok = ok and bool(np.all(np.isfinite(r)))
    whole = Evaluation(r, None, e_w, e_att, ok)
    if not (with_jac and ok):
        return whole, None
    blocks = []
    for sens, weight in [(out_sw, np.asarray(prob.sigma_w)[..., None])] + (
            [(out_sa, prob.sigma_att)] if prob.with_att else []):
        jw = np.zeros((m, 3, prob.n_params))
        jw[:, :, :(12 if prob.with_att else 9)] = sens[:, :, :(12 if prob.with_att else 9)]
        jw[:, :, prob.drag_slice] = sens[:, :, N_DYN:]
        if prob.fit_bias and sens is out_sw:
            jw[:, :, -3:] = np.eye(3)
        blocks.append(-(jw / weight).reshape(-1, prob.n_params))  # r = z - model: dr/dp = -dmodel/dp
    return whole, blocks


def evaluate(prob: Problem, p, q_ref, with_jac: bool) -> Evaluation:
    """Weighted residuals (and Jacobian) of the problem at p; q_ref (4,) the attitude that dq0
    perturbs (q0 = q_ref (x) exp(dq0/2)).
    """
    q0 = quat_mul(q_ref, quat_exp(p[9:12])) if prob.with_att else np.array([1.0, 0, 0, 0])
    seg = np.array([0, prob.meas_idx.size])
    whole, blocks = _integrated(prob, seg, p, p[None, 6:9], q0[None], with_jac)
    return whole if blocks is None else dataclasses.replace(whole, jac=np.concatenate(blocks, axis=0))


@dataclasses.dataclass(frozen=True)
class Prior:
    """A Gaussian prior on p: mean (n,) and information (n, n) (inverse covariance)."""

    mean: np.ndarray
    info: np.ndarray

    def rows(self, free) -> np.ndarray:
        """R_p (k, F) with R_p^T R_p = the information's free block."""
        vals, vecs = np.linalg.eigh(self.info[np.ix_(free, free)])
        keep = vals > 1e-12 * max(vals.max(), 1e-300)
        return (vecs[:, keep] * np.sqrt(vals[keep])).T


@dataclasses.dataclass(frozen=True)
class Fit:
    """The output-error fit: p (n,) with q0 (4,) its initial attitude (or None: no attitude);
    evaluation at p over the whole record (its Jacobian gives the Fisher information J^T J
    under white noise at sigma; None where the record is followed by several trajectories);
    iterations; stages (shooting stages solved); converged (the last stage met its tolerance);
    segments: the trajectories the estimate rests on (1: one over the whole record; more where
    no single trajectory follows it, each from its own initial state, p's then the first's);
    global_cov (n_global, n_global): with segments > 1, (J^T J)^-1 of [phi, c, b], the segments'
    states eliminated.
    """

    p: np.ndarray
    q0: np.ndarray | None
    evaluation: Evaluation
    iterations: int
    stages: int
    converged: bool
    segments: int = 1
    global_cov: np.ndarray | None = None

    @property
    def cost(self) -> float:
        """|r|^2 over the whole record (whitened: a chi-square)."""
        return float(self.evaluation.r @ self.evaluation.r)

    @property
    def rms(self) -> float:
        """The whitened residual's rms."""
        return math.sqrt(self.cost / max(self.evaluation.r.size, 1))


def global_indices(prob: Problem) -> np.ndarray:
    """Indices in p of the parameters every segment shares: phi, c, b."""
    return np.r_[np.arange(6), np.arange(prob.n_params)[prob.drag_slice],
                 np.arange(prob.n_params - 3, prob.n_params) if prob.fit_bias else []].astype(int)


def local_indices(prob: Problem) -> np.ndarray:
    """Indices in p of a segment's own initial state: w0 (and dq0 with attitude)."""
    return np.arange(6, 12 if prob.with_att else 9)


@dataclasses.dataclass(frozen=True)
class Shooting:
    """prob cut at measurement indices seg (S+1,) into S segments, each from its own initial
    state; x = [p's globals (phi, c, b), each segment's locals (w0, dq0)].
    """

    prob: Problem
    seg: np.ndarray

    @property
    def segments(self) -> int:
        """S."""
        return self.seg.size - 1

    def p_of(self, x, s: int) -> np.ndarray:
        """Segment s's p in the problem's layout."""
        gl, lo = global_indices(self.prob), local_indices(self.prob)
        p = np.zeros(self.prob.n_params)
        p[gl] = x[:gl.size]
        p[lo] = x[gl.size + s * lo.size: gl.size + (s + 1) * lo.size]
        return p

    def evaluate(self, x, q_refs, with_jac: bool):
        """(Evaluation of the whole record without Jacobian, Linearization or None), every
        segment integrated in one compiled call (integrator.trajectories).
        """
        prob = self.prob
        gl, lo = global_indices(prob), local_indices(prob)
        free = prob.free()[gl]
        s_count = self.segments
        states = np.asarray(x[gl.size:], float).reshape(s_count, lo.size)
        p0 = self.p_of(x, 0)
        if prob.with_att:
            q0s = quat_mul(q_refs, quat_exp(states[:, 3:6]))
        else:
            q0s = np.tile([1.0, 0.0, 0.0, 0.0], (s_count, 1))
        whole, blocks = _integrated(prob, self.seg, p0, states[:, :3], q0s, with_jac)
        if blocks is None:
            return whole, None
        seg_of = np.repeat(np.arange(s_count), np.diff(self.seg))
        g_cols = [jw[:, gl][:, free] for jw in blocks]
        l_cols = [jw[:, lo] for jw in blocks]
        rows_seg = np.concatenate([np.repeat(seg_of, 3)] * len(blocks))
        return whole, solver.Linearization(whole.r, np.concatenate(g_cols), np.concatenate(l_cols), rows_seg)


@dataclasses.dataclass(frozen=True)
class _Stage:
    """One solve's end: p (the problem's layout; with several segments, the first's), q_ref,
    evaluation (with Jacobian where one segment), iterations, converged, and with several
    segments x, q_refs and the globals' covariance.
    """

    p: np.ndarray
    q_ref: np.ndarray
    evaluation: Evaluation
    iterations: int
    converged: bool
    x: np.ndarray | None = None
    q_refs: np.ndarray | None = None
    global_cov: np.ndarray | None = None

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.evaluation.r ** 2)))


def _minimised(n_global: int, free, x0, max_iter: int, linearize, residuals, segments: int = 0,
               local_size: int = 3, drag=()) -> solver.Result:
    """The damped Gauss-Newton run of both solves: x (n_global globals, then `segments` blocks of
    local_size locals) from x0 over the free globals, phi kept on the bodies that exist and the
    drag coefficients x[drag] non-negative (_limits), phi moved at most MAX_PHI_STEP a step (its
    trust radius).
    """
    max_step = np.full(n_global, np.inf)
    max_step[:6] = MAX_PHI_STEP
    project, face = _limits(n_global, np.asarray(drag, int))
    spec = solver.Problem(n_global=n_global, free=free, segments=segments, project=project, face=face,
                          max_step=max_step, local_size=local_size)
    return solver.run(solver.levenberg_marquardt(spec, np.asarray(x0, float), max_iter, tol=TOL), linearize,
                      residuals)


def _folded(q_ref, dq) -> np.ndarray:
    """The unit attitude q_ref (x) exp(dq/2): a fit's attitude correction dq taken into its
    reference attitude (the correction then restarts at zero).
    """
    q = quat_mul(q_ref, quat_exp(dq))
    return q / np.linalg.norm(q)


def _limits(n: int, drag: np.ndarray):
    """(project, face) keeping phi = x[:6] on the bodies that exist, its scale coordinate kept
    (inertia_param.realizable_phi), and the drag coefficients x[drag] at or above zero (air only
    takes energy out of the rotation); along the limits where x sits on them (realizable_face,
    and c_i = 0).
    """
    def project(x):
        out = x.copy()
        out[:6] = realizable_phi(x[:6], keep_scale=True)
        out[drag] = np.maximum(out[drag], 0.0)
        return out

    def face(x):
        limit = realizable_face(x[:6])
        at_zero = drag[x[drag] <= 0.0]
        rows = np.zeros((limit.shape[0] + at_zero.size, n))
        rows[:limit.shape[0], :6] = limit
        rows[limit.shape[0] + np.arange(at_zero.size), at_zero] = 1.0
        return rows

    return project, face


def projected(prob: Problem, p) -> np.ndarray:
    """The parameters p (n,) taken onto the limits every solve keeps (_limits): the inertia on
    the bodies that exist, its scale kept, and the drag at or above zero.
    """
    return _limits(prob.n_params, np.arange(prob.n_params)[prob.drag_slice])[0](np.asarray(p, float))


def solve_shooting(sh: Shooting, x, q_refs, prior: Prior | None, max_iter: int) -> _Stage:
    """Minimise |r|^2 (+ the prior's on phi) of the segmented problem over its globals and every
    segment's state (the solver's arrow structure), the inertia kept on the bodies that exist.
    """
    prob = sh.prob
    gl, lo = global_indices(prob), local_indices(prob)
    free = prob.free()[gl]
    q_refs = np.asarray(q_refs, float)
    prior_rows = None
    if prior is not None:
        rows = prior.rows(prob.free())
        keep = np.isin(np.flatnonzero(prob.free()), gl)
        prior_rows = rows[:, keep]
        prior_mean = prior.mean[gl][free]

    def with_prior(r, x):
        return r if prior_rows is None else np.r_[r, prior_rows @ (x[:gl.size][free] - prior_mean)]

    def residuals(x):
        whole, _ = sh.evaluate(x, q_refs, False)
        return with_prior(whole.r if whole.ok else np.full(whole.r.size, np.inf), x)

    def linearize(x):
        whole, lin = sh.evaluate(x, q_refs, True)
        if lin is None:
            rows = whole.r.size
            return solver.Linearization(np.full(rows, np.inf), np.zeros((rows, int(free.sum()))),
                                        np.zeros((rows, lo.size)), np.zeros(rows, int))
        if prior_rows is None:
            return lin
        k = prior_rows.shape[0]
        return solver.Linearization(with_prior(lin.r, x), np.vstack([lin.g, prior_rows]),
                                    np.vstack([lin.js, np.zeros((k, lo.size))]),
                                    np.r_[lin.seg_of, np.full(k, -1)])

    res = _minimised(gl.size, free, x, max_iter, linearize, residuals, sh.segments, lo.size,
                     drag=np.flatnonzero(np.isin(gl, np.arange(prob.n_params)[prob.drag_slice])))
    x_new = res.x.copy()
    if prob.with_att:  # each segment's attitude correction taken into its reference attitude
        for s in range(sh.segments):
            at = gl.size + s * lo.size + 3
            q_refs[s] = _folded(q_refs[s], x_new[at:at + 3])
            x_new[at:at + 3] = 0.0
    whole, lin = sh.evaluate(x_new, q_refs, True)
    cov = None
    if lin is not None:
        cov = np.zeros((gl.size, gl.size))
        cov[np.ix_(free, free)] = solver.global_covariance(lin, sh.segments)
    return _Stage(sh.p_of(x_new, 0), q_refs[0], whole, res.iterations, res.converged, x_new, q_refs, cov)


@dataclasses.dataclass(frozen=True)
class Pin:
    """A stiff residual row weight * (value(phi) - target) that holds a function of the inertia
    at a target while the rest is fitted (a profile likelihood's constrained fit): value(phi)
    returns the function and its gradient (6,) in phi.
    """

    value: Callable[[np.ndarray], tuple[float, np.ndarray]]
    target: float
    weight: float

    def row(self, x, idx) -> tuple[float, np.ndarray]:
        """The row's residual and its Jacobian over the free parameters idx."""
        v, grad = self.value(x[:6])
        full = np.zeros(x.size)
        full[:6] = grad
        return self.weight * (v - self.target), self.weight * full[idx]


def solve(prob: Problem, p, q_ref, prior: Prior | None = None, max_iter: int = STAGE_ITER,
          pin: Pin | None = None) -> _Stage:
    """Minimise |r|^2 (+ the prior's, + the pin's row) over the free parameters of one trajectory
    from p (q_ref the attitude dq0 perturbs), the inertia kept on the bodies that exist,
    MAX_PHI_STEP its trust radius. The stage's evaluation holds the measurements' rows alone.
    """
    free = prob.free()
    idx = np.flatnonzero(free)
    q_ref = np.asarray(q_ref, float)
    prior_rows = None if prior is None else prior.rows(free)

    def extra(x) -> tuple[np.ndarray, np.ndarray]:
        rows, jac = [np.zeros(0)], [np.zeros((0, idx.size))]
        if prior_rows is not None:
            rows.append(prior_rows @ (x - prior.mean)[free])
            jac.append(prior_rows)
        if pin is not None:
            r_pin, j_pin = pin.row(x, idx)
            rows.append(np.array([r_pin]))
            jac.append(j_pin[None])
        return np.concatenate(rows), np.vstack(jac)

    def residuals(x) -> np.ndarray:
        ev = evaluate(prob, x, q_ref, False)
        r = ev.r if ev.ok else np.full(ev.r.size, np.inf)
        return np.r_[r, extra(x)[0]]

    def linearize(x) -> solver.Linearization:
        ev = evaluate(prob, x, q_ref, True)
        if not ev.ok:
            return solver.Linearization(np.full(ev.r.size, np.inf), np.zeros((ev.r.size, idx.size)))
        r_extra, j_extra = extra(x)
        return solver.Linearization(np.r_[ev.r, r_extra], np.vstack([ev.jac[:, idx], j_extra]))

    res = _minimised(prob.n_params, free, p, max_iter, linearize, residuals,
                     drag=np.arange(prob.n_params)[prob.drag_slice])
    p_new = res.x.copy()
    if prob.with_att:  # the attitude correction taken into the reference attitude
        q_ref = _folded(q_ref, p_new[9:12])
        p_new[9:12] = 0.0
    return _Stage(p_new, q_ref, evaluate(prob, p_new, q_ref, True), res.iterations, res.converged)


def evaluate_rms(prob: Problem, p, q_ref) -> float:
    """The whitened residual's rms of one trajectory over the whole record from p."""
    ev = evaluate(prob, p, q_ref, False)
    return float(np.sqrt(np.mean(ev.r ** 2))) if ev.ok else np.inf


def profile_losses(prob: Problem, phi, q_ref=None, max_iter: int = STAGE_ITER) -> np.ndarray:
    """(M,) each measurement row's whitened squared residual (gyro and attitude summed) at the
    inertia phi (6,), the other parameters (initial rate and attitude, bias, drag) fitted in at
    most max_iter iterations: the profile likelihood of that inertia row by row (an inertia
    whose trajectory needs more iterations than a stage's to follow the record predicts it
    poorly); infinite where the trajectory does not stay finite.
    """
    fixed = dataclasses.replace(prob, fixed_inertia=True)
    p = prob.start(phi)
    q_ref = np.array([1.0, 0.0, 0.0, 0.0]) if q_ref is None else np.asarray(q_ref, float)
    ev = solve(fixed, p, q_ref, None, max_iter).evaluation
    m = prob.meas_idx.size
    if not (ev.ok and np.all(np.isfinite(ev.r))):
        return np.full(m, np.inf)
    return np.sum(ev.r.reshape(-1, m, 3) ** 2, axis=(0, 2))


def profile_cost(prob: Problem, phi, q_ref=None, max_iter: int = STAGE_ITER) -> float:
    """The record's whitened residual sum of squares at the inertia phi (6,), minimised over the
    other parameters (profile_losses summed); infinite where the trajectory does not stay finite.
    """
    return float(np.sum(profile_losses(prob, phi, q_ref, max_iter)))


def _row_losses(ev: Evaluation, m: int) -> np.ndarray:
    """(M,) each measurement's whitened squared residual, gyro and attitude summed (inf where
    the trajectory did not stay finite).
    """
    return np.sum(ev.r.reshape(-1, m, 3) ** 2, axis=(0, 2)) if ev.ok else np.full(m, np.inf)


def _kept_after_joining(prob: Problem, seg, stage: _Stage) -> np.ndarray:
    """Indices of the stage's segments that start a segment of the next stage.

    A cut is dropped where the trajectory of the segment before it, at the stage's estimate,
    follows the rows of the segment after it within SLIP_FACTOR of the stage's own rms over the
    rows of both: the joined problem then starts in its basin, while a cut that the trajectory
    cannot cross (its phase lost over the next segment) stays. Both pairings (0 with 1, 2 with
    3, ... and 1 with 2, 3 with 4, ...) are tested, two integrations of the record; of the
    crossable cuts, no two adjacent ones are dropped (a joined segment spans at most two of the
    stage's, the join that was tested).
    """
    m = prob.meas_idx.size
    gl, lo = global_indices(prob), local_indices(prob)
    count = seg.size - 1
    states = stage.x[gl.size:].reshape(count, lo.size)
    held = np.add.reduceat(_row_losses(stage.evaluation, m), seg[:-1])
    crossable = np.zeros(count - 1, dtype=bool)
    for offset in (0, 1):
        firsts = np.arange(offset, count - 1, 2)  # segment s carried over segment s + 1
        starts = np.setdiff1d(np.arange(count), firsts + 1)
        joined = np.r_[seg[starts], m]
        x = np.r_[stage.x[:gl.size], states[starts].ravel()]
        whole, _ = Shooting(prob, joined).evaluate(x, stage.q_refs[starts], False)
        carried = np.add.reduceat(_row_losses(whole, m), seg[:-1])
        crossable[firsts] = (carried[firsts] + carried[firsts + 1]
                             <= SLIP_FACTOR ** 2 * (held[firsts] + held[firsts + 1]))
    drop = np.zeros(count, dtype=bool)  # drop[s]: segment s joins segment s - 1
    for s in range(1, count):
        drop[s] = crossable[s - 1] and not drop[s - 1]
    return np.flatnonzero(~drop)


def _cuts(m: int, count: int) -> np.ndarray:
    """(count+1,) measurement indices cutting m measurements into count equal segments."""
    return np.unique(np.round(np.linspace(0, m, count + 1)).astype(int))


def fit(prob: Problem, p_start, q_start=None, start_info=None, first_horizon: int | None = None,
        max_iter: int = STAGE_ITER, final_iter: int = FINAL_ITER) -> Fit:
    """Maximum-likelihood fit of the problem from p_start (q_start: initial attitude guess).

    start_info (n, n): information (inverse covariance) of the start, a prior on the stages
    before the last; first_horizon: the measurements the start's trajectory can be trusted over
    (default: all). Multiple shooting with continuation: the record is cut into segments of at
    most first_horizon measurements, each from its own initial state (the measured rate and
    attitude at its start), and solved; then, where the first segment's trajectory does not
    yet follow the whole record within SLIP_FACTOR of the segments' rms, the cuts its
    neighbours' trajectories already cross are dropped (:func:`_kept_after_joining`: at most
    every other one), the kept segments' states carried over, and solved again, until one
    trajectory spans the record (solved without the prior for up to final_iter iterations) or
    no trajectory crosses a cut (near a separatrix, or over a tumble longer than the
    sensitivities' growth allows): the fit then rests on that stage's segments. A merge whose
    residual rms still exceeds the last stage's by SLIP_FACTOR has lost the trajectory, and the
    fit keeps the last stage's segments.
    """
    m = prob.meas_idx.size
    horizon = m if first_horizon is None else int(np.clip(first_horizon, 1, m))
    p = np.array(p_start, dtype=float)
    q_ref = np.array([1.0, 0.0, 0.0, 0.0]) if q_start is None else np.asarray(q_start, dtype=float)
    prior = None if start_info is None else Prior(p.copy(), np.asarray(start_info, float))
    count = int(np.ceil(m / horizon))
    iterations, stages, good = 0, 0, None
    if count > 1:
        gl, lo = global_indices(prob), local_indices(prob)
        seg = _cuts(m, count)
        states = np.array([np.r_[prob.z_w[a], np.zeros(lo.size - 3)] for a in seg[:-1]])
        states[0] = p[lo]
        q_refs = np.array([q_ref if s == 0 or prob.z_q is None else prob.z_q[a]
                           for s, a in enumerate(seg[:-1])])
        x = np.r_[p[gl], states.ravel()]
        while seg.size > 2:
            stage = solve_shooting(Shooting(prob, seg), x, q_refs, prior, max_iter)
            iterations += stage.iterations
            stages += 1
            if good is not None and stage.rms > SLIP_FACTOR * good[1].rms:
                break
            good = (seg, stage)
            if evaluate_rms(prob, stage.p, stage.q_ref) <= SLIP_FACTOR * stage.rms:
                # the first segment's trajectory already follows the whole record: join them all
                x = np.r_[stage.x[:gl.size], stage.x[gl.size:gl.size + lo.size]]
                q_refs, seg = stage.q_refs[:1], np.array([0, m])
                break
            keep = _kept_after_joining(prob, seg, stage)
            if keep.size == seg.size - 1:
                break  # no trajectory crosses a cut: the segments are the fit
            seg = np.r_[seg[:-1][keep], m]
            x = np.r_[stage.x[:gl.size], stage.x[gl.size:].reshape(-1, lo.size)[keep].ravel()]
            q_refs = stage.q_refs[keep]
        if seg.size == 2:
            p, q_ref = Shooting(prob, seg).p_of(x, 0), q_refs[0]
    if good is None or seg.size == 2:
        whole = solve(prob, p, q_ref, None, final_iter)
        iterations += whole.iterations
        stages += 1
        if good is None or whole.rms <= SLIP_FACTOR * good[1].rms:
            return Fit(whole.p, whole.q_ref if prob.with_att else None, whole.evaluation, iterations, stages,
                       whole.converged)
    seg, stage = good
    return Fit(stage.p, stage.q_ref if prob.with_att else None, stage.evaluation, iterations, stages,
               stage.converged, seg.size - 1, stage.global_cov)


__all__ = ["Problem", "Evaluation", "Prior", "Pin", "Fit", "Shooting", "evaluate", "projected", "solve",
           "solve_shooting", "fit", "profile_cost", "profile_losses"]
