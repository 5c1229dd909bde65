"""The one least-squares solver: damped Gauss-Newton (Levenberg-Marquardt) with an arrow structure.

Every fit of the project minimises a sum of squares 0.5 |r(x)|^2 over x = [g (globals: the
inertia, effect and sensor parameters), s_1 .. s_S (locals: each segment's initial state, in a
multiply shot record)]. A residual row belongs to at most one segment, so the Jacobian is
arrow-shaped: dense in the globals, block-diagonal in the locals. The step eliminates the
locals segment by segment, projecting the global columns off the span of the segment's damped
local columns, and solves for the globals from the triangular factor of what is left; with no
locals it is the least-squares solution of the column-scaled Jacobian from its triangular
factor: Cholesky of the scaled normal matrix where that is well conditioned, else QR (over a
long tumble the sensitivities span eight orders and J^T J would square that condition number).

Marquardt's damping lam (on the scaled columns' unit diagonal) falls fourfold after a step that
lowers the cost and grows sixfold after one that does not. A step may be refused before it is
tried: it moves a global by more than its trust radius (a short, poorly conditioned window can
leap to another basin), or it leaves the parameters' physical domain (the caller's project()
then puts it back: an inertia beyond the triangle inequality, an effect past its limit). Where
the point sits on such a limit (the caller's face() gives its rows), the step kept on the
limit's face is tried beside the projected one, so a fit can move along the limit instead of
creeping by projections.

The solver is written as a generator: it yields what it needs evaluated, so that the caller may
answer with the rigid model's complex-step sensitivities (integrator.py) or with the effect
catalogue's finite differences batched over many points (discrepancy/fitting.py), and run
several solves side by side. run() drives one solve from a plain evaluate function.

Convergence: a point no damped step improves by more than ``tol + rel_tol * cost / N`` (N
residuals: rel_tol is in units of the mean square, i.e. of an information criterion) ends the
solve, at the initial damping or below (where the damping had grown along a curved valley, the
solve goes on once more from the initial damping). With ``decrement`` the solve instead
stops where the undamped step predicts a gain below ``decrement * cost / N``: a polish that
follows a curved valley to its floor, every improving step counting.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Generator

import numpy as np

#: Damping at the start of a solve (and at its one restart after a stall), its fall after an
#: accepted step and its growth after a refused one.
LM_START, LM_FALL, LM_GROWTH = 1e-3, 4.0, 6.0
#: Dampings one iteration tries at most, and how many of them one request holds (tried together:
#: a refused step costs no evaluation of its own).
LM_TRIES, SPECULATE = 12, 2


@dataclasses.dataclass(frozen=True)
class Linearization:
    """The residual r (N,) at a point and its derivatives: g (N, P) with respect to the free
    globals (in the order of their indices; or all globals, of which the free are taken), js
    (N, L) with respect to the L locals of each row's own segment (None without locals), seg_of
    (N,) each row's segment (-1: none).
    """

    r: np.ndarray
    g: np.ndarray
    js: np.ndarray | None = None
    seg_of: np.ndarray | None = None


@dataclasses.dataclass(frozen=True)
class Problem:
    """What the solver needs to know of a fit besides its evaluations.

    n_global: globals at the head of x; segments: S segments of local_size locals each at its
    tail (0: none); free (n_global,) bool: the globals it moves (the locals always move);
    locals_free: the locals move; project(x) -> x: the point put back into the parameters'
    domain (default: as it is); face(x) -> (m, n_global) rows A of the limits x sits on (steps
    with A dg = 0 stay on them; default none); max_step (n_global,): trust radius of each
    global (inf: none); bounds (lo, hi) over x: a step is clipped to them before project().
    """

    n_global: int
    free: np.ndarray
    segments: int = 0
    locals_free: bool = True
    project: Callable[[np.ndarray], np.ndarray] | None = None
    face: Callable[[np.ndarray], np.ndarray] | None = None
    max_step: np.ndarray | None = None
    local_size: int = 3
    bounds: tuple[np.ndarray, np.ndarray] | None = None


@dataclasses.dataclass(frozen=True)
class Result:
    """A solve's end: x, cost = |r|^2 at x (twice the least-squares objective), iterations, and
    converged (a convergence test met, not the iteration limit).
    """

    x: np.ndarray
    cost: float
    iterations: int
    converged: bool


def _segment_rows(seg_of: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """(order, ends): the rows sorted by segment (a segment's rows may come in several runs: its
    gyro rows, then its attitude rows) and where each group ends in that order: the rows of no
    segment (-1) are order[:ends[0]], segment s's order[ends[s]:ends[s + 1]].
    """
    order = np.argsort(seg_of, kind="stable")
    return order, np.searchsorted(seg_of[order], np.arange(-1, segments), side="right")


def _projected_factor(lin: Linearization, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """(R (P, P), col (P,)): the triangular factor of the global columns, scaled by their norms
    col (inf for a column the residual does not see), after each segment's rows are projected off
    the span of that segment's local columns. R^T R is the globals' information with the locals
    eliminated, without forming the normal equations: their Schur complement (A - B D^-1 B^T)
    squares the Jacobian's condition number and, over long segments whose sensitivities grow by
    orders of magnitude, loses the globals' information to rounding and can come out indefinite.
    """
    norm = np.linalg.norm(lin.g, axis=0)
    col = np.where(norm > 0, norm, np.inf)
    gsc = lin.g / col
    if lin.js is None or not segments:
        parts = [gsc]
    else:
        order, ends = _segment_rows(lin.seg_of, segments)
        parts = [gsc[order[:ends[0]]]]  # rows of no segment (a prior's)
        for a, b in zip(ends[:-1], ends[1:]):
            rows = order[a:b]
            if rows.size == 0:
                continue
            u, sv, _ = np.linalg.svd(lin.js[rows], full_matrices=False)
            u = u[:, sv > 1e-12 * max(float(sv.max()), 1e-300)]
            parts.append(gsc[rows] - u @ (u.T @ gsc[rows]))
    return np.linalg.qr(np.vstack(parts), mode="r"), col


def global_covariance(lin: Linearization, segments: int) -> np.ndarray:
    """(P, P) the globals' block of (J^T J)^-1 of a linearization over `segments` segments: the
    pseudo-inverse through the projected factor R (_projected_factor), never through R^T R.
    """
    r, col = _projected_factor(lin, segments)
    r_inv = np.linalg.pinv(r)
    return (r_inv @ r_inv.T) / np.outer(col, col)


def global_information(lin: Linearization, segments: int) -> np.ndarray:
    """(P, P) the globals' information with each segment's locals eliminated: R^T R of the
    projected factor (_projected_factor), positive semi-definite by construction; zero rows and
    columns for a global the residual does not see.
    """
    r, col = _projected_factor(lin, segments)
    seen = np.where(np.isfinite(col), col, 0.0)
    return (r.T @ r) * np.outer(seen, seen)


@dataclasses.dataclass(frozen=True)
class NormalBlocks:
    """The damping-free pieces of one Jacobian's step, formed once and reused for every damping.

    col (P,): the global columns' norms (inf for a column the residual does not see: it takes no
    step); rhs (P,): -g_scaled^T r. qr_r (P, P), qr_b (P,): the triangular factor of the scaled
    global columns and Q^T r, their rows first projected, segment by segment, off the span of
    that segment's local columns where the locals are free. With free locals, each segment's
    thin factor js = Q0 r0 (S, L, L), cmat = Q0^T g_scaled (S, L, P), cvec = Q0^T r (S, L) and
    dscale (S, L) the locals' damping scale (their columns' squared norms, floored).

    The locals are eliminated by orthogonal projection, not by the normal equations' Schur
    complement: over a long segment the sensitivities span many orders, and the complement
    (squaring the Jacobian's condition number) loses the globals' step to rounding.
    """

    col: np.ndarray
    rhs: np.ndarray
    qr_r: np.ndarray
    qr_b: np.ndarray
    r0: np.ndarray | None = None
    cmat: np.ndarray | None = None
    cvec: np.ndarray | None = None
    dscale: np.ndarray | None = None
    dfloor: float = 0.0

    @staticmethod
    def of(lin: Linearization, segments: int, locals_free: bool) -> "NormalBlocks":
        """The blocks of a linearization over `segments` segments."""
        norm = np.linalg.norm(lin.g, axis=0)
        col = np.where(norm > 0, norm, np.inf)
        gsc = lin.g / col
        rhs = -(gsc.T @ lin.r)
        if not (locals_free and segments and lin.js is not None):
            return NormalBlocks(col, rhs, *_triangular(gsc, lin.r))
        size, p = lin.js.shape[1], gsc.shape[1]
        r0 = np.zeros((segments, size, size))
        cmat = np.zeros((segments, size, p))
        cvec = np.zeros((segments, size))
        g_perp, r_perp = gsc.copy(), np.asarray(lin.r, float).copy()
        order, ends = _segment_rows(lin.seg_of, segments)
        finite = np.all(np.isfinite(lin.js)) and np.all(np.isfinite(gsc)) and np.all(np.isfinite(lin.r))
        counts = np.diff(ends)
        for n in np.unique(counts[counts > 0]) if finite else ():
            # the segments of n rows each, factored together: js = Q0 r0
            segs = np.flatnonzero(counts == n)
            rows = order[ends[segs][:, None] + np.arange(n)]  # (k, n)
            q0, r0_k = np.linalg.qr(lin.js[rows])
            k = r0_k.shape[1]  # fewer rows than locals: a short factor
            r0[segs, :k] = r0_k
            both = np.concatenate([gsc[rows], lin.r[rows][:, :, None]], axis=2)  # (k, n, P + 1)
            coef = np.swapaxes(q0, 1, 2) @ both
            cmat[segs, :k], cvec[segs, :k] = coef[:, :, :p], coef[:, :, p]
            left = both - q0 @ coef
            g_perp[rows], r_perp[rows] = left[:, :, :p], left[:, :, p]
        diag = np.einsum("sij,sij->sj", r0, r0)  # the local columns' squared norms
        floor = 1e-12 * max(float(diag.max()), 1e-300)
        # what is left is the globals' own conditioning: factored like a fit without locals
        qr_r, qr_b = _triangular(g_perp, r_perp)
        return NormalBlocks(col, rhs, qr_r, qr_b, r0=r0, cmat=cmat, cvec=cvec,
                            dscale=np.maximum(diag, floor), dfloor=floor)

    def step(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """The damped step (dg (P,), ds (S, L)). A system that is not finite gives a zero step."""
        dg_sc, ds = self._scaled(lam)
        return dg_sc / self.col, ds

    def decrement(self) -> float:
        """The cost's fall (|r|^2 units) that the undamped step predicts: what is left to gain."""
        dg_sc, ds = self._scaled(0.0)
        gain = float(self.rhs @ dg_sc)
        if self.r0 is not None:
            gain -= float(np.einsum("sji,sj,si->", self.r0, self.cvec, ds))  # (js^T r) . ds
        return gain

    def _scaled(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """The damped step on the scaled columns: min |J d + r|^2 + lam (|dg|^2 + ds^T D ds), D
        each local column's squared norm (Marquardt's diagonal), by least squares on factors.
        """
        p = self.col.size
        seen = np.isfinite(self.col).astype(float)  # an unseen column's diagonal: 0, floored
        damp = math.sqrt(lam) * np.diag(np.sqrt(np.maximum(seen, 1e-12)))
        if self.r0 is None:
            lhs = np.vstack([self.qr_r, damp]) if lam > 0 else self.qr_r
            rhs = np.concatenate([self.qr_b, np.zeros(p)]) if lam > 0 else self.qr_b
            if not (np.all(np.isfinite(lhs)) and np.all(np.isfinite(rhs))):
                return np.zeros(p), np.zeros((0, 3))
            return -np.linalg.lstsq(lhs, rhs, rcond=None)[0], np.zeros((0, 3))
        segments, size = self.cvec.shape
        zero = np.zeros((segments, size))
        if not all(np.all(np.isfinite(v)) for v in (self.qr_r, self.qr_b, self.cmat, self.cvec)):
            return np.zeros(p), zero
        # each segment's locals, damped: [r0; sqrt(lam D + floor)] = Q1 R1 (2L rows, L columns);
        # its globals' rows [cmat; 0] and right side [cvec; 0] are projected off Q1's span
        sq = np.sqrt(lam * self.dscale + self.dfloor)
        local = np.concatenate([self.r0, sq[:, :, None] * np.eye(size)], axis=1)
        q1, r1 = np.linalg.qr(local)
        e = np.concatenate([self.cmat, np.zeros_like(self.cmat)], axis=1)
        v = np.concatenate([self.cvec, zero], axis=1)
        qe = np.einsum("sji,sjp->sip", q1, e)
        qv = np.einsum("sji,sj->si", q1, v)
        w = e - np.einsum("sij,sjp->sip", q1, qe)
        wv = v - np.einsum("sij,sj->si", q1, qv)
        dg_sc = np.zeros(p)
        if p:
            lhs = np.vstack([self.qr_r, w.reshape(-1, p), damp])
            rhs = np.concatenate([self.qr_b, wv.ravel(), np.zeros(p)])
            if not (np.all(np.isfinite(lhs)) and np.all(np.isfinite(rhs))):
                return np.zeros(p), zero
            dg_sc = -np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        # ds = -R1^-1 Q1^T ([cmat; 0] dg + [cvec; 0])
        ds = -np.linalg.solve(r1, (np.einsum("sip,p->si", qe, dg_sc) + qv)[:, :, None])[:, :, 0]
        if not np.all(np.isfinite(ds)):
            return np.zeros(p), zero
        return dg_sc, ds


#: The scaled normal matrix is factored directly (Cholesky) while its condition number stays
#: below this (the Jacobian's squared: at 1e10 six of sixteen digits are kept); beyond, the
#: Jacobian itself is (QR), which keeps the digits but costs thirty times as much.
GRAM_CONDITION = 1e10


def _triangular(gsc: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R (P, P) upper triangular with R^T R = gsc^T gsc, and b = R^-T gsc^T r (= Q^T r), so that
    |gsc d + r|^2 = |R d + b|^2 + const. From the Cholesky factor of the normal matrix where it
    is well conditioned, else from a QR factor of [gsc, r].
    """
    p = gsc.shape[1]
    if p:
        normal = gsc.T @ gsc
        if np.all(np.isfinite(normal)):
            vals = np.linalg.eigvalsh(normal)
            if vals[0] > vals[-1] / GRAM_CONDITION:
                upper = np.linalg.cholesky(normal).T
                return upper, np.linalg.solve(upper.T, gsc.T @ r)
    if not (np.all(np.isfinite(gsc)) and np.all(np.isfinite(r))):
        return np.full((p, p), np.nan), np.full(p, np.nan)
    r_aug = np.linalg.qr(np.column_stack([gsc, r]), mode="r")
    if r_aug.shape[0] < p + 1:  # fewer rows than columns: pad the factor with zero rows
        r_aug = np.vstack([r_aug, np.zeros((p + 1 - r_aug.shape[0], p + 1))])
    return r_aug[:p, :p], r_aug[:p, p]


def face_basis(rows: np.ndarray) -> np.ndarray | None:
    """(P, P - rank) orthonormal basis of the steps dg with rows @ dg = 0, or None where no row
    is given (rows all zero, a limit on parameters that are held, count as none).
    """
    rows = rows[np.any(rows != 0, axis=1)] if rows.size else rows
    if not rows.size:
        return None
    _, sv, vt = np.linalg.svd(rows)
    rank = int(np.sum(sv > 1e-10 * sv[0]))
    return vt[rank:].T


#: What the solver asks of its caller: ("linearize", x) is answered with a Linearization at x,
#: ("residuals", xs (B, size)) with the residuals (B, N) at each point.
Request = tuple[str, np.ndarray]


def levenberg_marquardt(prob: Problem, x0, max_iter: int, tol: float = 0.0, rel_tol: float = 0.0,
                        decrement: float | None = None) -> Generator[Request, object, Result]:
    """The solve as a generator (see the module docstring); returns its Result."""
    gi = np.flatnonzero(prob.free)
    x = _put_back(prob, np.asarray(x0, float))
    lin = yield ("linearize", x)
    cost = float(lin.r @ lin.r)
    if not math.isfinite(cost):
        return Result(x, cost, 0, False)
    n_res = lin.r.size
    lam, restarted, converged, iterations = LM_START, False, False, 0
    for iterations in range(1, max_iter + 1):  # noqa: B007 (the count is returned)
        lin, blocks, on_face = _normal_blocks(prob, lin, x, gi)
        if decrement is not None:
            left = _predicted_gain(blocks, on_face)
            if left <= decrement * cost / n_res:
                converged = True
                break
        accepted, tried = None, 0
        while accepted is None and tried < LM_TRIES:
            batch, damping = [], lam
            for _ in range(min(SPECULATE, LM_TRIES - tried)):
                batch.append(_trials(prob, x, blocks, damping, on_face, gi))
                damping *= LM_GROWTH
            flat = [xn for trials in batch for xn in trials]
            rows = (yield ("residuals", np.array(flat))) if flat else None
            at = 0
            for trials in batch:
                tried += 1
                if not trials:
                    lam *= LM_GROWTH
                    continue
                rs = np.asarray(rows[at:at + len(trials)], float)
                at += len(trials)
                with np.errstate(over="ignore", invalid="ignore"):
                    costs = np.where(np.all(np.isfinite(rs), axis=1), np.einsum("ij,ij->i", rs, rs), np.inf)
                best = int(np.argmin(costs))
                if costs[best] < cost:
                    accepted = (trials[best], float(costs[best]))
                    break
                lam *= LM_GROWTH
        improved = False
        if accepted is not None:
            x_new, cost_new = accepted
            improved = cost - cost_new > tol + rel_tol * cost / n_res
            x, cost, lam = x_new, cost_new, max(lam / LM_FALL, 1e-12)
            lin = yield ("linearize", x)
        if improved:
            restarted = False
            continue
        # no damping lowered the cost, or only by the tolerance: converged, unless the damping had
        # grown along a curved valley (it stands above the initial one); then once more from it
        if restarted or lam <= LM_START / LM_FALL:
            converged = True
            break
        lam, restarted = LM_START, True
    return Result(x, cost, iterations, converged)


def _normal_blocks(prob: Problem, lin: Linearization, x,
                   gi) -> tuple[Linearization, NormalBlocks, tuple | None]:
    """(lin with its free columns kept and non-finite entries zeroed, its normal blocks, and
    where x sits on a limit's face (face basis, the blocks of the columns projected on it), else
    None).
    """
    g = lin.g[:, gi] if lin.g.shape[1] == prob.n_global != gi.size else lin.g
    g = np.where(np.isfinite(g), g, 0.0)  # a column that breaks the model moves nothing
    js = None if lin.js is None else np.where(np.isfinite(lin.js), lin.js, 0.0)
    lin = dataclasses.replace(lin, g=g, js=js)
    blocks = NormalBlocks.of(lin, prob.segments, prob.locals_free)
    face = None if prob.face is None else face_basis(prob.face(x)[:, gi])
    # the step kept on a limit's face: the same least squares over the face's directions
    on_face = None if face is None else (face, NormalBlocks.of(dataclasses.replace(lin, g=g @ face),
                                                               prob.segments, prob.locals_free))
    return lin, blocks, on_face


def predicted_gain(prob: Problem, lin: Linearization, x) -> float:
    """The cost (|r|^2 units) the undamped Gauss-Newton step from x predicts to gain over the free
    parameters of prob (lin: the linearization at x); at a limit, the lesser of it and the same
    step's kept on the limit's face. The score statistic of a least-squares fit: exact where the
    model is linear over the step, an overstatement where it curves.
    """
    x = np.asarray(x, float)
    _, blocks, on_face = _normal_blocks(prob, lin, x, np.flatnonzero(prob.free))
    return _predicted_gain(blocks, on_face)


def _predicted_gain(blocks: NormalBlocks, on_face) -> float:
    """The cost the undamped Gauss-Newton step predicts to gain; at a limit, the lesser of it and
    the step's kept on the limit's face.
    """
    left = blocks.decrement()
    return left if on_face is None else min(left, on_face[1].decrement())


def _put_back(prob: Problem, x) -> np.ndarray:
    if prob.bounds is not None:
        x = np.clip(x, *prob.bounds)
    return x if prob.project is None else prob.project(x)


def _trials(prob: Problem, x, blocks: NormalBlocks, lam: float, on_face, gi) -> list[np.ndarray]:
    """The points one damping tries: x moved by the step, put back into the domain; where that
    moved it (a limit) and x sits on a face (on_face: its basis (P, F) and the blocks of the
    columns projected on it), also the step kept on the face. Points whose step breaks a trust
    radius, or that are not finite, are left out.
    """
    out = []
    steps = [blocks.step(lam)]
    for k, (dg, ds) in enumerate(steps):
        xn = x.copy()
        xn[gi] += dg
        if prob.segments and prob.locals_free and ds.size:
            xn[prob.n_global:] += ds.ravel()
        moved = np.abs(xn[:prob.n_global] - x[:prob.n_global])
        if prob.max_step is not None and np.any(moved > prob.max_step):
            continue
        clipped = xn if prob.bounds is None else np.clip(xn, *prob.bounds)
        put = clipped if prob.project is None else prob.project(clipped)
        if np.all(np.isfinite(put)):
            out.append(put)
        if k == 0 and on_face is not None and not np.array_equal(put, clipped):
            dz, ds_face = on_face[1].step(lam)
            steps.append((on_face[0] @ dz, ds_face))
    return out


def run(gen: Generator[Request, object, Result], linearize: Callable[[np.ndarray], Linearization],
        residuals: Callable[[np.ndarray], np.ndarray]) -> Result:
    """Drive one solve: linearize(x) -> Linearization, residuals(x) -> (N,) for one point."""
    try:
        kind, arg = next(gen)
        while True:
            if kind == "linearize":
                answer = linearize(arg)
            else:
                answer = np.array([residuals(x) for x in arg])
            kind, arg = gen.send(answer)
    except StopIteration as done:
        return done.value


__all__ = ["Linearization", "Problem", "Result", "NormalBlocks", "face_basis", "levenberg_marquardt",
           "predicted_gain", "run"]
