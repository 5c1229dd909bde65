"""Profile-likelihood intervals on the principal ratios of an output-error fit.

The delta method's interval r_hat +- 1.96 sigma assumes the likelihood is quadratic in the ratio
over the interval. Where the data fix the shape weakly (a near-symmetric body, a short toss) the
likelihood's valley curves and flattens, and the true 95 % set is wider than that: on a prolate
body the best fit can sit at a near-rod while the truth, a few noise variances up, lies many
delta-method sigmas away. The profile likelihood follows the valley: for each value r of a ratio
the rest (the other shape parameters, initial state, bias, drag) is refitted with the ratio held
at r, and the 95 % interval is where the refitted residual sum rises by less than
chi-square(1, 0.95) = 3.84 noise variances above the best fit's.

The level carries the fit's noise model: with residuals wider than the noise (rms over noise,
coloured residuals, model error, a coarse gyro lattice), the reported covariance exceeds the
Fisher bound by a factor kappa^2 along the ratio, and the level is 3.84 kappa^2, so where the
likelihood is quadratic the profile interval is the reported delta-method interval exactly.

The profile is traced outwards from the fit by continuation (each constrained fit starts where
the last ended, its step predicted from the root of the rise, which is linear in the ratio where
the likelihood is quadratic, and it starts where the quadratic likelihood puts the constrained
fit; each runs for up to output_error.FINAL_ITER iterations, as a valley crawl may need). A
local solver's constrained fit only bounds the profile from above, so its interval bounds the
true one from inside: the reported interval is the union of the profile's and the delta
method's. A constrained fit that ends below the fit itself shows the fit short of the
likelihood's maximum; the profile hands it back (RatioProfile.better).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from inertia_gym.estimation import output_error
from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_from_phi
from inertia_gym.estimation.output_error import Fit, Pin, Problem
from inertia_gym.estimation.uncertainty import (
    InertiaEstimate,
    inertia_estimate,
    jacobian_covariance,
    principal_ratio_gradients,
)

#: chi-square(1) at 0.95: the rise of the residual sum (noise variances) at a 95 % interval's edge.
LEVEL_95 = 3.841458820694124
#: Constrained fits per edge: the continuation's steps grow up to MAX_GROWTH-fold, so this reaches
#: an edge some 4^(n-1) delta-method widths out, far past any the delta method misplaces by less.
MAX_SOLVES, MAX_GROWTH = 8, 4.0
#: Each step aims this far past the edge its root predicts, so that where the likelihood is
#: quadratic one constrained fit crosses the edge and the root's line between the two points
#: (exact there) places it.
OVERSHOOT = 1.15
#: The pin's weight in units of 1 / (the ratio's Fisher sigma): the constrained fit then misses
#: its target by 1 / (1 + PIN_STIFFNESS^2) of the distance, 1e-4 (the achieved ratio is used).
PIN_STIFFNESS = 100.0


def principal_ratio(phi, k: int) -> tuple[float, np.ndarray]:
    """The k-th principal moment over the largest (descending order: k = 1 the middle, 2 the
    smallest) of the inertia phi (6,), and its gradient (6,) in phi.
    """
    phi = np.ascontiguousarray(phi, dtype=float)
    ratios, grads = principal_ratio_gradients(inertia_from_phi(phi))
    return float(ratios[k]), grads[k] @ dtheta_dphi(phi)


@dataclasses.dataclass(frozen=True)
class RatioProfile:
    """The principal ratios' 95 % profile intervals (3, 2), descending (the first is 1); better:
    a constrained fit met on the way whose residual sum lies below the fit's by more than
    BETTER_BY (its p (n,) and q_ref (4,)), or None: the fit is then the likelihood's maximum
    along every profile traced; cost: the fit's residual sum in the problem's weights.
    """

    intervals: np.ndarray
    better: tuple[np.ndarray, np.ndarray] | None
    cost: float


#: A constrained fit below the fit's residual sum by more than this (noise variances) shows the
#: fit short of the likelihood's maximum: the solver's own stopping gain (output_error.TOL) is
#: far smaller, so the fit stalled (on a narrow valley's wall, or in another basin), not in its
#: last crawl.
BETTER_BY = 0.5


@dataclasses.dataclass
class _Trace:
    """The lowest residual sum met while tracing (cost, p, q_ref)."""

    cost: float
    p: np.ndarray | None = None
    q: np.ndarray | None = None


def _edge(prob: Problem, start: tuple, k: int, side: int, sigma: float, level: float,
          best: _Trace, lean: np.ndarray) -> float:
    """The ratio k's profile interval edge on one side (+1 up, -1 down) from start (p, q_ref,
    cost): where the refitted residual sum first rises by `level` over the start's, or the
    furthest ratio reached below it. Every constrained fit below best.cost is kept in best.
    Each constrained fit starts from the last moved by lean (n,) per unit of the ratio: the
    change of every parameter with the ratio along the likelihood's quadratic valley, which
    is the constrained fit itself where the likelihood is quadratic.
    """
    p, q, cost0 = start
    r_prev, root_prev = principal_ratio(p[:6], k)[0], 0.0
    edge = r_prev
    step = OVERSHOOT * math.sqrt(level) * sigma
    weight = PIN_STIFFNESS / sigma
    for _ in range(MAX_SOLVES):
        if not 0.0 < r_prev + side * step / OVERSHOOT < 1.0:
            # the edge predicted lies past the bounds of a ratio to the largest moment, (0, 1):
            # the interval reaches the bound (where a ratio meets 1 two moments cross, and the
            # ratio's gradient jumps)
            return 1.0 if side > 0 else 0.0
        target = r_prev + side * step
        if not 0.0 < target < 1.0:
            target = r_prev + side * step / OVERSHOOT
        pin = Pin(lambda phi: principal_ratio(phi, k), target, weight)
        leaned = output_error.projected(prob, p + lean * (target - r_prev))
        stage = output_error.solve(prob, leaned, q, pin=pin, max_iter=output_error.FINAL_ITER)
        if not stage.evaluation.ok:
            break
        r = principal_ratio(stage.p[:6], k)[0]
        moved = side * (r - r_prev)
        if not moved > 0.0:  # held at a limit of the bodies that exist
            break
        cost = float(stage.evaluation.r @ stage.evaluation.r)
        if cost < best.cost:
            best.cost, best.p, best.q = cost, stage.p, stage.q_ref
        rise = cost - cost0
        root = math.sqrt(max(rise, 0.0))
        if rise >= level:  # the root of the rise, linear between the two points
            share = (math.sqrt(level) - root_prev) / max(root - root_prev, 1e-300)
            return r_prev + side * share * moved
        edge = r
        slope = (root - root_prev) / moved
        wanted = (OVERSHOOT * math.sqrt(level) - root) / slope if slope > 0 else MAX_GROWTH * moved
        step = float(np.clip(wanted, moved / MAX_GROWTH, MAX_GROWTH * moved))
        r_prev, root_prev, p, q = r, root, stage.p, stage.q_ref
    return edge


def ratio_profile(prob: Problem, fit: Fit, estimate: InertiaEstimate) -> RatioProfile:
    """The principal ratios' 95 % profile-likelihood intervals of a one-trajectory fit with its
    reported estimate (the delta method's for a ratio without curvature to trace; the estimate
    takes in the union of the two: InertiaEstimate.ratio_ci). The profile is traced in prob's
    weights, its level 3.84 times the reported variance of each ratio over its Fisher bound in
    those weights (so the two intervals agree where the likelihood is quadratic).
    """
    q = fit.q0 if fit.q0 is not None else np.array([1.0, 0.0, 0.0, 0.0])
    ev = output_error.evaluate(prob, fit.p, q, True)
    ratios, ratio_cov = estimate.principal_ratios()
    half = 1.96 * np.sqrt(np.clip(np.diag(ratio_cov), 0.0, None))
    out = np.stack([ratios - half, ratios + half], axis=1)
    if not ev.ok:
        return RatioProfile(out, None, math.inf)
    cov = jacobian_covariance(ev.jac, prob.free())
    fisher_cov = inertia_estimate(fit.p[:6], cov[:6, :6], prob.fix_scale).principal_ratios()[1]
    cost0 = float(ev.r @ ev.r)
    best = _Trace(cost0 - BETTER_BY)
    for k in (1, 2):
        sigma = math.sqrt(max(float(fisher_cov[k, k]), 0.0))
        if not 0.0 < sigma < 1.0:  # no curvature, or none worth tracing: the delta method's
            continue
        level = LEVEL_95 * max(float(ratio_cov[k, k]) / sigma ** 2, 1.0)
        grad = np.zeros(prob.n_params)
        grad[:6] = principal_ratio(fit.p[:6], k)[1]
        lean = cov @ grad / sigma ** 2  # E[p | ratio] per unit of the ratio (Gaussian conditioning)
        out[k] = [_edge(prob, (fit.p, q, cost0), k, side, sigma, level, best, lean) for side in (-1, 1)]
    return RatioProfile(out, None if best.p is None else (best.p, best.q), cost0)


__all__ = ["LEVEL_95", "BETTER_BY", "RatioProfile", "principal_ratio", "ratio_profile"]
