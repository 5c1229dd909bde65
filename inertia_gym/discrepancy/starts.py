"""Where the solves start: the rigid model's starts, and what an effect's starts may ask.

A segment's initial rates start at its first gyro sample, a fitted inertia at the sidecar's
nominal and at the linear equation-error estimate. Probe gives an effect's starts() the costs,
the screens and the linear estimates (a flexible mode, an inertia change, an internal
momentum) built on the fit that the effect is added to.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.effects import FLEX_BAND, REGISTRY, flex_floor_hz, matrix6
from inertia_gym.discrepancy.effects.flexible_mode import MODE_ZETAS, pole_spread
from inertia_gym.discrepancy.objective import Fit, Layout, _penalty_rows, jacobian, objective, whitened
from inertia_gym.dynamics import skew
from inertia_gym.estimation import solver
from inertia_gym.estimation.equation_error import (
    equation_error_theta,
    modulating_windows,
    omega_matrix,
    valid_theta,
)
from inertia_gym.estimation.inertia_param import interior, nearest_realizable, phi_from_inertia
from inertia_gym.information import inertia_from_theta

#: Records of fewer segments than SHORT_SEGMENTS choose between starts cut into that many.
SHORT_SEGMENTS = 4
#: Axes searched (over a hemisphere, about 7 deg apart) for a momentum varying along one, and
#: how far apart (deg) the few kept as starts are.
MOMENTUM_AXES, MOMENTUM_AXES_APART = 200, 30.0
#: A varying momentum's knots follow its changes where the record has room for at least
#: KNOTS_FOLLOW times as many knots as the profile takes (Probe.momentum_knots): a first estimate
#: on that many times as many evenly spaced knots says where the momentum changes, and where it
#: changes beyond its noise (NOISE_CHANGES times the median change between neighbouring knots:
#: 3.4 standard deviations of a change that is noise alone), KNOTS_ON_CHANGE of the knots follow
#: that change.
KNOTS_FOLLOW, NOISE_CHANGES = 2, 5.0
#: The share of those knots that follow the change (the rest evenly spaced over the record): a
#: smooth spin-up's corners, where its curvature jumps, need knots a fraction of its length
#: apart (a wheel of 15 % of the body's momentum spinning up in 5 s of a 300-s record at 10 Hz:
#: with half, 3.6 s apart there, a second effect takes up the corners in 4 of 8 cases and the
#: worst axis reaches 1.59x the noise; with three quarters, 2.6 s apart, 2 of 8 and 1.18x).
KNOTS_ON_CHANGE = 0.75
#: A flexible mode's fit may move its frequency up to this factor above its fastest start; its
#: screen scans frequencies this factor apart.
MODE_REACH, MODE_GRID = 1.5, 1.15


def initial_rates(d: Data) -> np.ndarray:
    """(S * 3,) each segment's first gyro sample: the start of its initial rates."""
    return d.w[d.seg[:-1]].ravel()


def equation_error_phi(d: Data) -> np.ndarray:
    """The phi (6,) of the linear equation-error estimate of the inertia (the nearest body that
    exists, moved strictly inside: inertia_param.interior; its trace pinned to d.trace0 where the
    scale is not seen), from the kept samples.
    """
    kept = d.row >= 0  # clipped samples and trimmed impulses left out here too
    theta = equation_error_theta(d.t[kept], d.w[kept], d.tau[kept] if d.has_torque else None,
                                 None if d.h is None else d.h[kept], trace=d.trace0)
    return phi_from_inertia(interior(nearest_realizable(inertia_from_theta(theta))))


def _inertia_starts(d: Data) -> list[np.ndarray]:
    """Starting phi of a fitted inertia: the sidecar's nominal (first, where given), the linear
    equation-error estimate, and on a short record (one segment) the three elongated bodies too,
    since a short flip can leave several inertias locally consistent.
    """
    out = [] if d.inertia0 is None else [phi_from_inertia(d.inertia0)]
    out.append(equation_error_phi(d))
    if d.segments == 1:
        for diag in ([1.0, 1.0, 0.1], [1.0, 0.1, 1.0], [0.1, 1.0, 1.0], [1.0, 1.0, 1.0]):
            out.append(phi_from_inertia(np.diag(diag) * d.trace0 / sum(diag)))
    return out


def hemisphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over a hemisphere (a Fibonacci lattice): the axes
    a sign-free direction is searched over.
    """
    k = np.arange(count) + 0.5
    z = k / count
    r = np.sqrt(1 - z ** 2)
    phi = np.pi * (1 + 5 ** 0.5) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


#: Change times scanned for an inertia change's start, and the refinements around each scan
#: peak (each at a third of the last spacing).
CHANGE_SCAN = 20
REFINE_LEVELS = 3


@dataclasses.dataclass(frozen=True)
class Probe:
    """What an effect's starts() may ask while it is added to the fit `base`: costs of the joint
    model with the base's parameters and candidate vectors of the new effect, and screens built
    on the base's residual.
    """

    layout: Layout
    d: Data
    base: Fit

    def x(self, p, inertia=None) -> np.ndarray:
        """Joint x of the base's parameters with the new effect's vector p (and the inertia
        (3, 3) instead of the base's, where the model fits one).
        """
        b = self.base
        head = b.x[:b.layout.n_global].copy()
        if inertia is not None:
            head[:6] = phi_from_inertia(inertia)
        return np.concatenate([head, p, b.x[b.layout.n_global:]])

    def own_starts(self) -> list[np.ndarray]:
        """The new effect's own starts (EffectModel.starts) as joint vectors x, each segment's
        initial rates the base's or its first gyro sample's (with_segment_rates); kept in d.cache
        for the same base on the same rows (a second search asks them again).
        """
        key = ("starts", self.layout, *_rows_and_base(self.d, self.base))
        if key not in self.d.cache:
            model, form = self.layout.models[-1], self.layout.forms[-1]
            self.d.cache[key] = self.with_segment_rates([s if s.size == self.layout.size else self.x(s)
                                                         for s in model.starts(form, self.d, self)])
        return [x.copy() for x in self.d.cache[key]]

    def with_segment_rates(self, xs) -> list[np.ndarray]:
        """Each joint x with, segment by segment, its initial rates or the segment's first gyro
        sample (initial_rates), whichever leaves that segment's rows the smaller residual.

        The base's rates are fitted without the new effect and bend to stand in for it: on a
        300-s record of five segments whose only misfit is an internal momentum, the momentum's
        equation-error start (within 2 % of the truth) with the nominal fit's rates costs 9993 in
        BIC more than no momentum at all, and the fit stalls at a gain of 821 where the truth
        gains 93324; from the first samples' rates it reaches the truth.
        """
        d, n = self.d, self.layout.n_global
        measured = [np.concatenate([x[:n], initial_rates(d)]) for x in xs]
        z = whitened(np.stack([*xs, *measured]), self.layout, d)
        z = np.clip(np.nan_to_num(z, nan=1e6), -1e6, 1e6)  # a start that blew up costs a lot, finitely
        rows = np.einsum("brk,brk->br", z, z)
        cost = np.stack([np.bincount(d.row_seg, weights=r, minlength=d.segments) for r in rows])
        out = []
        for i, x in enumerate(xs):
            take = np.repeat(cost[len(xs) + i] < cost[i], 3)
            out.append(np.concatenate([x[:n], np.where(take, measured[i][n:], x[n:])]))
        return out

    @property
    def few_segments(self) -> bool:
        """The record has few segments (each long): the cost is rough, starts matter more."""
        return self.d.segments < SHORT_SEGMENTS

    def costs(self, xs) -> np.ndarray:
        """(len(xs),) least-squares cost of each joint x."""
        r = objective(np.stack(xs), self.layout, self.d)
        return np.einsum("ij,ij->i", r, r)

    def best_x(self, xs, keep: int = 1) -> list[np.ndarray]:
        """The `keep` joint x of lowest cost."""
        return [xs[i] for i in np.argsort(self.costs(xs))[:keep]]

    def best_of(self, ps, keep: int = 1) -> list[np.ndarray]:
        """The `keep` candidate vectors p of the new effect of lowest cost (everything else the base's)."""
        return [ps[i] for i in np.argsort(self.costs([self.x(p) for p in ps]))[:keep]]

    def mode_starts(self, keep: int = 3, zetas: tuple = MODE_ZETAS[:1]) -> list[np.ndarray]:
        """Starts of flexible_mode from a linear screen over the modal frequency and damping ratio.

        To first order the mode's effect on the predicted rates is linear in M = delta delta^T
        (a symmetric 3x3; what the body's motion excites) and in a = delta eta0, b = delta
        eta_dot0 / omega (what the mode's state at the start sets swinging): integrations with
        small couplings along e_i and e_i + e_j give M's six columns (polarization), three more
        with a modal displacement and three with a modal velocity (eta0 = eps, eta_dot0 = eps
        omega: as small as the coupling eps, which is sized to the body, so the probe stays
        linear on a body of any mass) a's and b's, and one least-squares solve the twelve that
        explain most at that frequency and damping ratio. Over a geometric grid of frequencies
        at each of `zetas` (MODE_GRID apart in the band for a light ratio; for an overdamped one
        MODE_REACH apart where both its poles lie in the band), then finer around the best, the
        first ratio's `keep` best frequencies and each other ratio's best (an overdamped mode's lag
        is a response of its own, which a start at a light ratio does not reach) give
        delta = sqrt(lambda) v from M's leading eigenpair (size within the room J leaves:
        J - delta delta^T stays positive) or, where M has none, along a and b's leading direction
        at a fifth of that room; eta0, eta_dot0 follow from a and b along delta.
        A loaded mode (flexible_mode's "loaded" form) starts with its inertia rate K at zero.
        """
        d, base = self.d, self.base
        lam_min = float(np.linalg.eigvalsh(base.inertia)[0])
        if not lam_min > 0 or d.n_rows < 16:
            return []
        lo, hi = 2 * np.pi * flex_floor_hz(d), 2 * np.pi * FLEX_BAND[1] / d.dt
        eps = np.sqrt(1e-4 * lam_min)
        directions = [np.eye(3)[i] for i in range(3)] + [np.eye(3)[i] + np.eye(3)[j]
                                                         for i, j in ((0, 1), (0, 2), (1, 2))]
        part = self.layout.slices()[-1]
        rest = np.zeros(part.stop - part.start - 7)  # a loaded mode's K: of second order in the couplings
        r0 = objective(self.x(np.zeros(7 + rest.size))[None], self.layout, self.d)[0]

        def screen(omega, zeta):
            layout = dataclasses.replace(self.layout, omega_max=omega)
            xs = [self.x(np.r_[omega, zeta, eps * v, 0.0, 0.0, rest]) for v in directions]
            xs += [self.x(np.r_[omega, zeta, eps * e, eps, 0.0, rest]) for e in np.eye(3)]
            xs += [self.x(np.r_[omega, zeta, eps * e, 0.0, eps * omega, rest]) for e in np.eye(3)]
            resp = objective(np.stack(xs), layout, d) - r0
            excite = resp[:6] / eps ** 2
            cols = np.stack([excite[0], excite[1], excite[2], excite[3] - excite[0] - excite[1],
                             excite[4] - excite[0] - excite[2], excite[5] - excite[1] - excite[2]]
                            + [(resp[6 + i] - eps ** 2 * excite[i % 3]) / eps ** 2 for i in range(6)], 1)
            m = np.linalg.lstsq(cols, -r0, rcond=None)[0]
            gain = float(r0 @ r0 - np.sum((r0 + cols @ m) ** 2))
            return gain, omega, m, zeta

        def grid(zeta):
            # both poles of the mode (omega_n r and omega_n / r) lie in the band for omega_n in
            # [lo r, hi / r]. Damped past resonance it has no peak to miss between grid points: it
            # is screened MODE_REACH apart, the factor a fit moves a start by.
            r = pole_spread(zeta)
            a, b = lo * r, max(hi / r, lo * r)
            step = MODE_GRID if zeta < 1.0 else MODE_REACH
            return np.geomspace(a, b, max(2, int(np.log(b / a) / np.log(step)) + 1))

        scan = [screen(om, z) for z in zetas for om in grid(z)]
        best = sorted(scan, key=lambda g: -g[0])[:keep]
        for _, om, _, z in list(best):
            scan += [screen(om * f, z) for f in MODE_GRID ** np.linspace(-1, 1, 5)[[1, 3]]]
        out = []
        room = 0.7 * np.sqrt(lam_min)
        taken = {z: 0 for z in zetas}  # the first ratio's `keep` best frequencies, each other's best
        for gain, om, m, zeta in sorted(scan, key=lambda g: -g[0]):
            if (gain <= 0 or taken[zeta] == (keep if zeta == zetas[0] else 1)
                    or any(abs(om - x[0]) < 0.02 * om and x[1] == zeta for x in out)):
                continue
            vals, vecs = np.linalg.eigh(matrix6(m[:6]))
            state = np.stack([m[6:9], m[9:12]], 1)  # (3, 2): a, b
            if vals[-1] > 0:
                delta = min(np.sqrt(vals[-1]), room) * vecs[:, -1]
            elif np.any(state):
                delta = 0.2 * room * np.linalg.svd(state)[0][:, 0]
            else:
                continue
            a, b = state.T @ delta / (delta @ delta)
            out.append(np.r_[om, zeta, delta, a, b * om, rest])
            taken[zeta] += 1
        return out

    def change_starts(self, keep: int = 2) -> list[np.ndarray]:
        """Starts of inertia_change (joint x): over CHANGE_SCAN change times, one Gauss-Newton step from
        no change in delta_J, the segments' rates held or moved with it (everything else held;
        the rates after a change absorb part of it: moving them finds a large change's time,
        holding them a precise one); for each, the `keep` times whose steps explain most among
        the scan's local maxima, each refined REFINE_LEVELS times around itself.
        """
        d, layout = self.d, self.layout
        times = d.t_row[np.linspace(2, d.n_rows - 3, min(CHANGE_SCAN, d.n_rows - 4)).astype(int)]
        x0 = self.x(np.zeros(7))
        delta = np.arange(layout.n_global)[layout.slices()[-1]][1:]
        n_res = d.n_rows * 3
        seg_of = np.full(n_res + _penalty_rows(x0, layout, d, n_res).size, -1)
        seg_of[:n_res] = np.repeat(d.row_seg, 3)
        free = np.zeros(x0.size, bool)
        free[delta] = True
        # (change time, rates moved) -> (gain, x): the two scans share their times, so one
        # linearisation serves both and only its two steps are kept (a long record's Jacobians,
        # kept for every time scanned, would take 1.5 GB at 60 000 rows)
        steps = {}

        def gauss_newton(tc, rates):
            if (tc, rates) not in steps:
                x = x0.copy()
                x[delta[0] - 1] = tc
                r, g, js = jacobian(x, free, layout, d)
                g, js = np.where(np.isfinite(g), g, 0.0), np.where(np.isfinite(js), js, 0.0)
                for moved in (True, False):
                    lin = solver.Linearization(r, g, js, seg_of)
                    dg, ds = solver.NormalBlocks.of(lin, layout.segments, moved).step(1e-9)
                    ds = ds if ds.size else np.zeros((layout.segments, 3))
                    pred = r + g @ dg
                    pred[:n_res] += np.einsum("ij,ij->i", js[:n_res], ds[seg_of[:n_res]])
                    xn = x.copy()
                    xn[delta] += dg
                    xn[layout.n_global:] += ds.ravel()
                    steps[(tc, moved)] = float(r @ r - pred @ pred), xn
            return steps[(tc, rates)]

        starts = []
        for rates in (True, False):
            scan = [gauss_newton(tc, rates) for tc in times]
            gain = np.array([g for g, _ in scan])
            padded = np.r_[-np.inf, gain, -np.inf]
            peaks = np.flatnonzero((gain >= padded[:-2]) & (gain >= padded[2:]))
            for i in peaks[np.argsort(-gain[peaks])][:keep]:
                best, span = scan[i], (times[-1] - times[0]) / max(times.size - 1, 1)
                for _ in range(REFINE_LEVELS):  # ever finer, around the best time so far
                    grid = np.clip(best[1][delta[0] - 1] + span * np.array([-2, -1, 1, 2]) / 3,
                                   times[0], times[-1])
                    best = max([best] + [gauss_newton(t, rates) for t in grid], key=lambda gs: gs[0])
                    span /= 3
                starts.append(best[1])
        return starts

    def momentum_estimate(self, tk, axes=None, with_inertia: bool = True, keep: int = 1,
                          unknowns: int | None = None,
                          from_start: bool = True) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Linear estimates (tk, H, J): at the knot times tk (K,) s (one: a constant momentum),
        an unknown internal momentum H (K, 3) kg·m²/s piecewise linear through them (with several
        knots, zero at the first where not from_start: the momentum's change from the record's
        start), and the
        inertia (3, 3) estimated with it (the base's where the nominal is held, or with_inertia is
        False). The modulating windows span a third of a turn at most, and at least 8 samples,
        and are short enough for four times as many equations as `unknowns` (default: those of
        the free three-axis form, 3K + 6).

        The integral equation error of d/dt (J w + h_known + h) + w x (J w + h_known + h) = tau
        over modulating windows is linear in theta and H (no derivative of the gyro is taken);
        an unseen scale is pinned to the trace the model uses. With `axes` (A, 3) unit vectors,
        h = axis m(t) along each in turn (linear in theta and m): the `keep` axes (at least
        MOMENTUM_AXES_APART deg apart) that explain most are returned, best first. A momentum
        changing along one fixed axis is not confused with an inertia error J w(t), which a free
        three-axis h(t) could partly absorb. Without from_start the momentum at the start is left
        to the inertia (and to the nonlinear fit that starts here): while the rates stay near
        their mean w_m, a constant momentum h0 and an inertia error dJ with dJ w_m = h0 act alike,
        and solved together the two take large values of opposite sign whose remainder distorts
        the change; where the rates sweep widely, h0 is seen apart from the inertia and
        from_start estimates it.
        """
        d, base = self.d, self.base
        tk = np.asarray(tk, float)
        knots = tk.size
        unknowns = 3 * knots + 6 if unknowns is None else unknowns
        span = min(2.0 / (d.omega_ref * d.dt), 3 * d.t.size // (4 * unknowns))  # 3 equations a window
        edges, phi, dphi = modulating_windows(d.t, int(max(span, 8)))
        quad = np.gradient(d.t)
        w = d.w
        known = np.zeros_like(w) if d.h is None else d.h
        fit_j = d.inertia0 is None and with_inertia
        mom = known if fit_j else w @ base.inertia.T + known
        first = 0 if from_start else 1  # the first knot's column: the momentum at the start
        basis = (np.stack([np.interp(d.t, tk, e) for e in np.eye(knots)[first:]], 1) if knots > 1
                 else np.ones((d.t.size, 1)))
        free_knots = basis.shape[1]
        op = quad[:, None, None] * (-dphi[:, None, None] * np.eye(3) + phi[:, None, None] * skew(w))
        # (win, 3, free_knots, 3)
        a_h = np.add.reduceat(np.einsum("nij,nk->nikj", op, basis), edges[:-1], axis=0)
        a_j = np.add.reduceat(op @ omega_matrix(w), edges[:-1], axis=0).reshape(-1, 6) if fit_j else None
        g = -dphi[:, None] * mom + phi[:, None] * (np.cross(w, mom) - d.tau)
        rhs = -np.add.reduceat(quad[:, None] * g, edges[:-1], axis=0).ravel()

        def solve_for(a):
            """Least squares of a (..., rows, cols) theta-and-momentum against rhs, the pinned
            trace as a heavily weighted row; returns solutions (..., cols) and costs (...).
            """
            rows = a
            target = np.broadcast_to(rhs, a.shape[:-1])
            if fit_j and d.scale_fixed:  # the trace the model pins
                weight = 1e3 * (np.linalg.norm(a, axis=(-2, -1)) + 1e-300) / np.sqrt(a.shape[-1])
                pin = np.r_[1, 0, 0, 1, 0, 1, np.zeros(a.shape[-1] - 6)]
                rows = np.concatenate([a, weight[..., None, None] * pin], axis=-2)
                target = np.concatenate([target, weight[..., None] * d.trace0], axis=-1)
            col = np.linalg.norm(rows, axis=-2) + 1e-300
            scaled = rows / col[..., None, :]
            gram = np.swapaxes(scaled, -1, -2) @ scaled
            gram = gram + 1e-12 * np.einsum("...ii->...", gram)[..., None, None] * np.eye(gram.shape[-1])
            sol = np.linalg.solve(gram, (np.swapaxes(scaled, -1, -2) @ target[..., None]))[..., 0] / col
            return sol, np.sum((np.einsum("...ij,...j->...i", a, sol) - rhs) ** 2, axis=-1)

        def with_j(a):
            return np.concatenate([np.broadcast_to(a_j, a.shape[:-1] + (6,)), a], axis=-1) if fit_j else a

        def result(sol, u=None):
            tail = sol[6 if fit_j else 0:]
            hk = tail.reshape(free_knots, 3) if u is None else np.outer(tail, u)
            if free_knots < knots:
                hk = np.vstack([np.zeros((1, 3)), hk])
            trace = d.trace0 if d.scale_fixed else None
            inertia = interior(inertia_from_theta(valid_theta(sol[:6], trace))) if fit_j else base.inertia
            return tk, hk, inertia

        if axes is None:
            return [result(solve_for(with_j(a_h.reshape(-1, 3 * free_knots)))[0])]
        along = np.einsum("wikj,aj->awik", a_h, axes).reshape(len(axes), -1, free_knots)
        sols, costs = solve_for(with_j(along))
        out, kept = [], []
        for i in np.argsort(costs):
            u = axes[i]
            if all(abs(u @ v) < np.cos(np.radians(MOMENTUM_AXES_APART)) for v in kept):
                kept.append(u)
                out.append(result(sols[i], u))
            if len(out) == keep:
                break
        return out

    def inertia_estimate(self) -> np.ndarray:
        """The phi (6,) of the record's equation-error inertia (equation_error_phi), kept in d.cache."""
        key = ("inertia_estimate", (self.d.row >= 0).tobytes())
        if key not in self.d.cache:
            self.d.cache[key] = equation_error_phi(self.d)
        return self.d.cache[key]

    def momentum_knots(self, knots: int) -> np.ndarray:
        """Knot times (knots,) s of a varying momentum's profile: evenly spaced, unless the
        record has room for KNOTS_FOLLOW times as many (EffectModel.knot_room) and the momentum
        changes somewhere beyond its noise; then a quarter of them are evenly spaced in time and
        three quarters (KNOTS_ON_CHANGE) follow that change, so that a rotor spinning up for ten
        seconds of a ten-minute record is followed through its spin-up (evenly spaced, twenty
        knots half a minute apart draw it as a slow ramp, and a gyro drift and a flexible mode
        take up the rest). Where it changes: a
        first estimate on KNOTS_FOLLOW times as many evenly spaced knots (momentum_estimate along
        the axis that explains most, in windows of a third of a turn where the record has room
        for four times as many equations as that estimate's unknowns: shorter windows leave the
        spin-up of a wheel of 5 % of the body's momentum at 4-8 times the median change, longer
        at 23-31): the intervals where it changes by more than NOISE_CHANGES times the median
        change, and those beside them, are where the change's knots go, evenly spread over them.
        A smooth spin-up starts and ends below the noise of that estimate, and its corners are
        where a spline needs knots: placed in proportion to the change, they gather where the
        spin-up is steepest, begin after the start of a thrown device's 0.3-s spin-up, and a
        flexible mode takes up the corner the spline cannot draw (2 of 3 seeds). Neighbouring
        knots stay at least ROWS_PER_KNOT residual rows apart. Cached in d.cache
        (depends on the data and the base).
        """
        d = self.d
        even = np.linspace(d.t[0], d.t[-1], knots)
        model = REGISTRY["internal_momentum"]
        fine = KNOTS_FOLLOW * knots
        if model.knot_room(d) < fine:
            return even
        key = ("knots", knots, *_rows_and_base(d, self.base))
        if key not in d.cache:
            tf = np.linspace(d.t[0], d.t[-1], fine)
            # windows sized for the unknowns of one axis's profile (fine + 6), not three axes'
            (_, hk, _), = self.momentum_estimate(tf, hemisphere(MOMENTUM_AXES), unknowns=fine + 6)
            change = np.linalg.norm(np.diff(hk, axis=0), axis=1)
            beyond = change > NOISE_CHANGES * np.median(change)
            if not beyond.any():
                d.cache[key] = even
            else:  # the cumulative share of time and of the time it changes (KNOTS_ON_CHANGE);
                # the intervals beside those that change too, where a smooth spin-up starts and ends
                changing = np.convolve(beyond, [1, 1, 1], mode="same") > 0
                share = ((1 - KNOTS_ON_CHANGE) * (tf - tf[0]) / (tf[-1] - tf[0])
                         + KNOTS_ON_CHANGE * np.r_[0.0, np.cumsum(changing)] / changing.sum())
                placed = np.interp(np.linspace(0.0, 1.0, knots), share, tf)
                gap = model.ROWS_PER_KNOT * d.block * d.dt
                for i in range(1, knots):  # at least `gap` apart, from the start, then from the end
                    placed[i] = max(placed[i], placed[i - 1] + gap)
                placed[-1] = d.t[-1]
                for i in range(knots - 2, -1, -1):
                    placed[i] = min(placed[i], placed[i + 1] - gap)
                placed[0] = d.t[0]
                d.cache[key] = placed
        return d.cache[key]

    def momentum_starts(self, knots: int) -> list[np.ndarray]:
        """Starts of internal_momentum (with the inertia estimated beside it, and with the base's):
        constant (knots 0), or varying along the three axes, of those searched, that explain most
        (momentum_estimate), its momentum at the start estimated and left to the inertia (which
        of the two the record separates depends on how widely its rates sweep: the fits decide);
        ranked by cost, with no momentum at all among them.
        """
        model = REGISTRY["internal_momentum"]
        starts = []
        knot_t = self.momentum_knots(knots) if knots else None
        for with_inertia in (True, False):  # the inertia estimated beside it, or the base's
            if not knots:
                (_, hk, inertia), = self.momentum_estimate(self.d.t[:1], with_inertia=with_inertia)
                starts.append(self.x(hk[0], inertia))
                continue
            for tk, hk, inertia in (est for from_start in (True, False) for est in self.momentum_estimate(
                    knot_t, hemisphere(MOMENTUM_AXES), with_inertia, keep=3, from_start=from_start)):
                change = hk - hk[0]
                axis = np.linalg.svd(change, full_matrices=False)[2][0]
                starts.append(self.x(model.pack({"h": hk[0], "axis": axis, "profile_t": tk,
                                                 "profile": change @ axis}), inertia))
        if knots:
            starts.append(self.x(model.pack({"h": np.zeros(3), "axis": axis, "profile_t": tk,
                                             "profile": np.zeros(knots)})))
        else:
            starts.append(self.x(np.zeros(3)))
        return self.best_x(starts, keep=len(starts))  # ranked: an estimate can be worse than none


def _rows_and_base(d: Data, base: "Fit") -> tuple:
    """What a cached fit or start (in d.cache) depends on beyond its own arguments: the rows'
    segments (resegmented data share the cache) and the fit it is added to.
    """
    return d.seg.tobytes(), base.layout, base.x.tobytes()
