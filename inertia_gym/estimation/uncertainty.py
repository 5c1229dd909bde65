"""Uncertainty of an estimate: the inertia with its covariance, and the noise models behind it.

Three noise models, each a covariance of the fitted parameters:

* white: the inverse Fisher information (J^T J)^-1 of the whitened Jacobian, widened by the
  residuals' rms over the noise level where that exceeds 1;
* correlated: the Bartlett (Newey-West) sandwich A^-1 B A^-1 over as many lags as the residuals
  stay correlated (coloured sensor noise: vibration);
* model error: residuals in excess of the noise, represented as a white disturbance torque on
  the body's momentum whose intensity is sized by that excess (model_error_covariance): the
  Fisher bound plus what the disturbance moves the parameters by.

InertiaEstimate carries an inertia (theta = Jxx, Jxy, Jxz, Jyy, Jyz, Jzz, kg·m²) with its
covariance and derives its intervals, principal moments, axes, shape and scale uncertainty.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import stats

from inertia_gym.errors import ConfigError
from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_from_phi, theta_from_phi
from inertia_gym.estimation.longrun import correlation_lags, long_run_covariance
from inertia_gym.estimation.output_error import Evaluation, Problem
from inertia_gym.estimation.solver import GRAM_CONDITION
from inertia_gym.information import inertia_from_theta

#: A scale whose relative standard deviation exceeds this is poorly determined (said in notes).
SCALE_SIGMA_IDENTIFIED = 0.05
#: The chi-square level of identify's tests (lack of fit, a gyro bias, two estimates' agreement):
#: one false alarm in a thousand records.
TEST_LEVEL = 0.999
#: The trace of theta: theta @ TRACE_WEIGHTS.
TRACE_WEIGHTS = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 1.0])


#: The intervals' widening by white residuals' rms over the noise level is said (NoiseModel.
#: describe) from this factor on: a widening the user is not told of is an interval they misread.
WIDENING_SAID = 1.05


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """How the residuals were treated: kind 'white' or 'coloured'; sigma (3,) rad/s gyro noise
    used for weighting and its source; hac_lags (0 for white); inflation = the factor by which
    the intervals widened over the white-noise Fisher bound (for white residuals their rms over
    the noise level where over 1, said by describe());
    disturbance_q N²·m²·s the intensity of the white disturbance torque that stands for the
    model error (0: none; see model_error_covariance).
    """

    kind: str
    sigma: np.ndarray
    source: str
    hac_lags: int
    inflation: float
    disturbance_q: float = 0.0

    def describe(self) -> str:
        """One sentence for reports."""
        sig = ", ".join(f"{s:.3g}" for s in self.sigma)
        if self.kind == "white":
            text = f"white gyro noise, sigma = ({sig}) rad/s ({self.source})"
            if self.inflation > WIDENING_SAID:  # the residual's rms over that level widens them
                text += (f"; the residual's rms is {self.inflation:.2f}x that level, which the "
                         "intervals are widened by (model error, or noise above that level)")
            return text
        text = (f"coloured residuals (autocorrelated over {self.hac_lags} samples): weighted with "
                f"sigma = ({sig}) rad/s ({self.source}), ")
        if self.disturbance_q > 0:
            text += ("covariance = the noise's Fisher bound plus the model error's, the model "
                     "error represented as a white disturbance torque of intensity "
                     f"{self.disturbance_q:.3g} N²·m²·s estimated from the residuals' excess")
        else:
            text += f"covariance by the Bartlett/Newey-West sandwich over {self.hac_lags} lags"
        return text + f"; intervals {self.inflation:.2f}x the white bound"


@dataclasses.dataclass(frozen=True)
class Principal:
    """An estimate's principal moments (3,) kg·m² ascending with their 95 % half-widths (3,),
    the axes (3, 3) as columns, and each axis' 95 % cone half-angle (3,) in degrees.
    """

    moments: np.ndarray
    half: np.ndarray
    axes: np.ndarray
    cone_deg: np.ndarray


@dataclasses.dataclass(frozen=True)
class InertiaEstimate:
    """An inertia with its uncertainty.

    theta (6,) kg·m² (xx, xy, xz, yy, yz, zz); theta_cov (6, 6); scale_identified: False means
    theta is normalised (trace = its trace) and theta_cov is that of the normalised inertia;
    ratio_ci (3, 2): the principal ratios' profile-likelihood intervals where a fit traced them
    (estimation.profile), which the reported intervals take in beside the delta method's.
    """

    theta: np.ndarray
    theta_cov: np.ndarray
    scale_identified: bool
    ratio_ci: np.ndarray | None = None

    @property
    def inertia(self) -> np.ndarray:
        """(3, 3) kg·m²."""
        return inertia_from_theta(self.theta)

    @property
    def sigma(self) -> np.ndarray:
        """(6,) standard deviations of theta."""
        return np.sqrt(np.clip(np.diag(self.theta_cov), 0.0, None))

    def ci95(self) -> np.ndarray:
        """(6, 2) 95 % intervals of theta."""
        return np.stack([self.theta - 1.96 * self.sigma, self.theta + 1.96 * self.sigma], axis=1)

    def principal(self) -> "Principal":
        """The principal moments, axes and their 95 % intervals (delta method)."""
        vals, vecs, grads = self._moment_gradients()
        half = 1.96 * np.sqrt(np.clip(np.einsum("ij,jk,ik->i", grads, self.theta_cov, grads), 0, None))
        cone = np.zeros(3)
        for i in range(3):
            var = 0.0
            for k in range(3):
                if k != i:
                    g = _eig_gradient(vecs[:, k], vecs[:, i]) / (vals[i] - vals[k])
                    var += float(g @ self.theta_cov @ g)
            cone[i] = math.degrees(min(math.pi / 2, 1.96 * math.sqrt(max(var, 0.0))))
        return Principal(vals, half, vecs, cone)

    def _moment_gradients(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Principal moments (3,) ascending, axes (3, 3) as columns, and each moment's gradient
        with respect to theta (3, 6).
        """
        vals, vecs = np.linalg.eigh(self.inertia)
        return vals, vecs, np.stack([_eig_gradient(vecs[:, i], vecs[:, i]) for i in range(3)])

    def moment_covariance(self) -> np.ndarray:
        """(3, 3) covariance of the principal moments, ascending as principal() gives them (delta
        method).
        """
        _, _, grads = self._moment_gradients()
        return grads @ self.theta_cov @ grads.T

    def scale_sigma(self) -> float:
        """The relative standard deviation of the trace: how well the scale is known."""
        trace = float(TRACE_WEIGHTS @ self.theta)
        return math.sqrt(max(float(TRACE_WEIGHTS @ self.theta_cov @ TRACE_WEIGHTS), 0.0)) / abs(trace)

    def principal_ratios(self) -> tuple[np.ndarray, np.ndarray]:
        """The principal moments over the largest (3,), descending (the first is 1), and their
        covariance (3, 3) (delta method; the first row and column zero): the inertia's shape,
        which gyro-only data fix without its scale.
        """
        ratios, g = principal_ratio_gradients(self.inertia)
        return ratios, g @ self.theta_cov @ g.T

    def summary(self) -> dict:
        """Its keys of identify.json: the inertia, its entries, covariance and intervals,
        principal moments, axes and ratios with theirs, whether its scale is identified and the
        relative standard deviation of its trace.
        """
        principal = self.principal()
        vals, half, axes, cone = principal.moments, principal.half, principal.axes, principal.cone_deg
        ratios, ratio_cov = self.principal_ratios()
        ratio_half = 1.96 * np.sqrt(np.clip(np.diag(ratio_cov), 0.0, None))
        ratio_ci = np.stack([ratios - ratio_half, ratios + ratio_half], axis=1)
        if self.ratio_ci is not None:
            ratio_ci = np.stack([np.minimum(ratio_ci[:, 0], self.ratio_ci[:, 0]),
                                 np.maximum(ratio_ci[:, 1], self.ratio_ci[:, 1])], axis=1)
        return {"inertia": self.inertia.tolist(), "theta": self.theta.tolist(),
                "theta_cov": self.theta_cov.tolist(), "ci95": self.ci95().tolist(),
                "principal_moments": vals.tolist(),
                "principal_moments_ci95": np.stack([vals - half, vals + half], axis=1).tolist(),
                "principal_moments_cov": self.moment_covariance().tolist(), "principal_axes": axes.T.tolist(),
                "principal_axes_ci95_deg": cone.tolist(), "principal_ratios": ratios.tolist(),
                "principal_ratios_ci95": ratio_ci.tolist(),
                "principal_ratios_cov": ratio_cov.tolist(), "scale_identified": bool(self.scale_identified),
                "scale_rel_sigma": float(self.scale_sigma()) if self.scale_identified else None}


def principal_ratio_gradients(inertia) -> tuple[np.ndarray, np.ndarray]:
    """The principal moments of inertia (3, 3) over the largest (3,), descending (the first is
    1), and their gradients (3, 6) with respect to theta.
    """
    vals, vecs = np.linalg.eigh(inertia)
    vals, vecs = vals[::-1], vecs[:, ::-1]
    grads = np.stack([_eig_gradient(vecs[:, i], vecs[:, i]) for i in range(3)])
    return vals / vals[0], (grads * vals[0] - np.outer(vals, grads[0])) / vals[0] ** 2


def _eig_gradient(u, v) -> np.ndarray:
    """Gradient of u^T J v with respect to theta (6,), J symmetric."""
    return np.array([u[0] * v[0], u[0] * v[1] + u[1] * v[0], u[0] * v[2] + u[2] * v[0],
                     u[1] * v[1], u[1] * v[2] + u[2] * v[1], u[2] * v[2]])


def inertia_estimate(phi, cov_phi, scale_fixed: bool, trace_ref: float | None = None) -> InertiaEstimate:
    """The inertia parameters theta and their covariance from phi (6,) and cov_phi (6, 6) (delta method).

    scale_fixed: the data do not fix the scale; theta is normalised to trace_ref (its own trace
    if None) and the covariance is that of the normalised inertia.
    """
    theta = theta_from_phi(np.ascontiguousarray(phi))
    d = dtheta_dphi(np.ascontiguousarray(phi))
    cov = d @ cov_phi @ d.T
    if not scale_fixed:
        return InertiaEstimate(theta, 0.5 * (cov + cov.T), True)
    trace = float(TRACE_WEIGHTS @ theta)
    target = trace if trace_ref is None else float(trace_ref)
    norm = target / trace * (np.eye(6) - np.outer(theta, TRACE_WEIGHTS) / trace)
    cov_n = norm @ cov @ norm.T
    return InertiaEstimate(theta * target / trace, 0.5 * (cov_n + cov_n.T), False)


#: ||J||_F^2 = theta^T W theta for theta in eq. (8) order (off-diagonals count twice).
FROBENIUS_WEIGHTS = np.array([1.0, 2.0, 2.0, 1.0, 2.0, 1.0])


def relative_frobenius_bound(theta, cov_theta) -> float:
    """sqrt(E ||J_hat - J||_F^2) / ||J||_F for an estimate with covariance cov_theta (6, 6)."""
    theta = np.asarray(theta, dtype=float)
    expected = float(np.sum(FROBENIUS_WEIGHTS * np.diag(cov_theta)))
    return math.sqrt(max(expected, 0.0)) / math.sqrt(float(np.sum(FROBENIUS_WEIGHTS * theta ** 2)))




def jacobian_covariance(jac, free) -> np.ndarray:
    """(J^T J)^-1 over the free columns of the weighted Jacobian jac (R, n), zeros elsewhere,
    from the eigen-decomposition of the column-scaled J's Gram matrix where it is well
    conditioned (solver.GRAM_CONDITION), else from the SVD of the column-scaled J (its condition
    number, not its square, then limits the precision). Raises ConfigError when the record does
    not determine every free parameter.
    """
    jf = jac[:, free]
    col = np.maximum(np.linalg.norm(jf, axis=0), 1e-300)
    scaled = jf / col
    vals, vecs = np.linalg.eigh(scaled.T @ scaled)
    if vals[0] > vals[-1] / GRAM_CONDITION:  # the squared condition number keeps six digits
        sv, vt = np.sqrt(vals), vecs.T
    else:
        _, sv, vt = np.linalg.svd(scaled, full_matrices=False)
    if sv[-1] <= 1e-13 * sv[0]:
        raise ConfigError("the record does not determine every parameter (Jacobian condition "
                          f"number {sv[0] / max(sv[-1], 1e-300):.2g})")
    inner = (vt.T / sv ** 2) @ vt
    out = np.zeros((jac.shape[1], jac.shape[1]))
    out[np.ix_(free, free)] = inner / np.outer(col, col)
    return 0.5 * (out + out.T)


def sandwich_covariance(jac, r, n_meas: int, lags: int) -> np.ndarray:
    """A^-1 B A^-1 with A = J^T J and B the Bartlett long-run covariance of the per-measurement
    scores g_k = J_k^T r_k over `lags` lags. jac (R, n), r (R,) with R = c * n_meas rows laid
    out channel block by channel block (as output_error.evaluate stacks gyro then attitude).
    """
    n_par = jac.shape[1]
    blocks = jac.shape[0] // (3 * n_meas)
    j = jac.reshape(blocks, n_meas, 3, n_par)
    rr = r.reshape(blocks, n_meas, 3)
    b = long_run_covariance(np.einsum("bmcn,bmc->mn", j, rr), lags)
    a_inv = jacobian_covariance(jac, np.ones(n_par, dtype=bool))
    cov = a_inv @ b @ a_inv
    return 0.5 * (cov + cov.T)


def model_error_covariance(prob: "Problem", p, ev: "Evaluation") -> tuple[float, np.ndarray]:
    """The parameters' covariance (n, n) caused by an unmodelled disturbance torque, and its
    intensity q (N²·m²·s) estimated from the residuals.

    Model error is represented as a white torque d(t) on the total momentum L (the filter's
    process noise), E d(s) d(s')^T = q I delta(s - s'). It perturbs the outputs by
    dy(t) = sum_{s<=t} (dy(t)/dx(s)) d(s) ds with x = L (and the attitude where measured);
    the transition dy(t)/dx(s) = M(t) Phi(s, 0)^-1 comes from the sensitivities to the
    initial rate and attitude already in ev.jac (Phi(t, 0) = [[J G J^-1, 0], [G_a J^-1, G_q]],
    G = dw/dw0, G_a, G_q the attitude's to w0 and dq0). The fit absorbs part of dy into the
    parameters: dp = A^-1 sum_s C_s d(s) ds with A = J^T J and C_s = sum_{t>=s} J_t^T M(t)
    Phi(s, 0)^-1[:, :3], so cov = q A^-1 (sum_s C_s C_s^T ds) A^-1. q follows from the residuals'
    excess over the white noise at prob.sigma: E |r|^2 = (R - n) + q tr((I - P) K) with K the
    disturbance's output covariance per unit q and P the fit's hat matrix (method of moments;
    q = 0 when the residuals show no excess). ev: the evaluation (with Jacobian) at p (n,).
    Both are infinite where dL(s)/dL0 cannot be inverted: the model's error bars then say nothing.
    """
    m = ev.e_w.shape[0]
    n = prob.n_params
    free = prob.free()
    jm = inertia_from_phi(np.ascontiguousarray(p[:6]))
    jinv = np.linalg.inv(jm)
    blocks = 2 if prob.with_att else 1
    jb = ev.jac.reshape(blocks, m, 3, n)
    n_state = 6 if prob.with_att else 3
    # M(t): weighted outputs per unit change of the initial state (L0 (3), attitude (3)).
    out_state = np.zeros((m, 3 * blocks, n_state))
    out_state[:, :3, :3] = jb[0][:, :, 6:9] @ jinv
    g = -jb[0][:, :, 6:9] * np.asarray(prob.sigma_w)[..., None]  # dw/dw0 (m, 3, 3)
    try:
        phi_ll_inv = np.linalg.inv(jm @ g @ jinv)  # (dL(s)/dL0)^-1
    except np.linalg.LinAlgError:  # sensitivities grown past inversion (a catch left in the
        return np.inf, np.full((n, n), np.inf)  # record): no error bars
    back = np.zeros((m, n_state, 3))  # Phi(s, 0)^-1[:, :3]
    back[:, :3] = phi_ll_inv
    if prob.with_att:
        out_state[:, 3:, :3] = jb[1][:, :, 6:9] @ jinv
        out_state[:, :3, 3:] = jb[0][:, :, 9:12]
        out_state[:, 3:, 3:] = jb[1][:, :, 9:12]
        g_att_w = -jb[1][:, :, 6:9] * prob.sigma_att
        g_att_q = -jb[1][:, :, 9:12] * prob.sigma_att
        back[:, 3:] = -np.linalg.solve(g_att_q, g_att_w @ jinv @ phi_ll_inv)
    ds = np.gradient(prob.t_grid[prob.meas_idx]) if m > 1 else np.ones(1)
    rows = jb.transpose(1, 0, 2, 3).reshape(m, 3 * blocks, n)[:, :, free]
    later = np.cumsum(np.einsum("mrn,mrs->mns", rows, out_state)[::-1], axis=0)[::-1]
    c = np.einsum("mns,msk->mnk", later, back)
    b = np.einsum("mnk,mlk,m->nl", c, c, ds)
    a_inv = jacobian_covariance(ev.jac, free)[np.ix_(free, free)]
    walk = np.cumsum(np.einsum("msk,mtk,m->mst", back, back, ds), axis=0)
    trace_k = float(np.einsum("mrs,mst,mrt->", out_state, walk, out_state))
    trace_pk = float(np.trace(a_inv @ b))
    excess = float(ev.r @ ev.r) - (ev.r.size - int(free.sum()))
    cov = np.zeros((n, n))
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # refine checks
        q = max(0.0, excess / max(trace_k - trace_pk, 1e-300))
        cov[np.ix_(free, free)] = q * (a_inv @ b @ a_inv)
        return q, 0.5 * (cov + cov.T)


def with_gyro_scale(est: InertiaEstimate, reference: InertiaEstimate, scale_sigma) -> tuple:
    """Gyro only, scale identified: a common scale error s of the gyro moves the inertia by about
    -s in every entry and fits as well. With the sidecar's gyro_scale_sigma (relative, 1 sigma)
    its variance s^2 theta theta^T joins the covariance. Returns (estimate, note).
    """
    if scale_sigma is None:
        return est, ("the intervals assume the gyro's scale factor is exact: without attitude a common "
                     "scale error s of the gyro moves every moment by about -s and fits as well; give its "
                     "relative 1-sigma uncertainty as gyro_scale_sigma in the sidecar to include it")
    cov = est.theta_cov + float(scale_sigma) ** 2 * np.outer(est.theta, est.theta)
    return dataclasses.replace(est, theta_cov=cov), (
        f"the intervals include the gyro's scale-factor uncertainty ({100 * float(scale_sigma):.3g} %, 1 "
        "sigma, sidecar gyro_scale_sigma), common to every moment")


@dataclasses.dataclass(frozen=True)
class Agreement:
    """Estimates of one inertia against each other (homogeneity): statistic (chi-square), dof,
    p_value.
    """

    statistic: float
    dof: int
    p_value: float

    @property
    def disagree(self) -> bool:
        """The difference is beyond both intervals at TEST_LEVEL."""
        return self.p_value < 1.0 - TEST_LEVEL


@dataclasses.dataclass(frozen=True)
class Forecast:
    """Two estimates' predictions of data neither was fitted to: costs (their summed losses:
    the first's, the second's), statistic (the Diebold-Mariano z of the second's loss less the
    first's: positive where the first predicts better) and p_value (one-sided, that the first
    predicts no better).
    """

    costs: tuple[float, float]
    statistic: float
    p_value: float

    @property
    def first_better(self) -> bool:
        """The first predicts significantly better, at TEST_LEVEL."""
        return self.p_value < 1.0 - TEST_LEVEL


def forecast_comparison(losses: list[tuple[np.ndarray, np.ndarray]]) -> Forecast:
    """The Diebold-Mariano comparison of two predictors over held-out sequences: losses, per
    sequence, each predictor's loss per row ((M,), (M,)). The rows' loss differences are
    correlated in time (a model error spans many rows), so the sum's variance is the Bartlett
    long-run variance over the lags they stay correlated (longrun), sequence by sequence.
    """
    costs, total, var = np.zeros(2), 0.0, 0.0
    for first, second in losses:
        first, second = np.asarray(first, float), np.asarray(second, float)
        costs += [first.sum(), second.sum()]
        d = (second - first)[:, None]
        total += float(d.sum())
        centred = d - d.mean()
        var += float(long_run_covariance(centred, correlation_lags(centred))[0, 0])
    if not (np.isfinite(total) and np.isfinite(var)):
        z = np.inf if total > 0 else -np.inf
    else:
        z = total / math.sqrt(max(var, 1e-300))
    return Forecast((float(costs[0]), float(costs[1])), float(z), float(stats.norm.sf(z)))


@dataclasses.dataclass(frozen=True)
class Choice:
    """Which of two estimates of one inertia to report: efficient (report the efficient one),
    model_fits (the data accept the efficient estimate's model: the lack-of-fit test), expected
    (the relative Frobenius errors their covariances expect: the efficient one's, the robust
    one's), forecast (their comparison on held-out data, the efficient one first, or None).
    """

    efficient: bool
    model_fits: bool
    expected: tuple[float, float]
    forecast: Forecast | None = None


def choose(efficient: InertiaEstimate, robust: InertiaEstimate, model_fits: bool,
           forecast: Forecast | None = None) -> Choice:
    """Which estimate to report. Where the data accept the efficient estimate's model
    (model_fits: the lack-of-fit test), the one whose covariance expects the smaller error: the
    maximum-likelihood fit of a model that holds is efficient, and a model error the residuals
    hide colours them, which widens the fit's covariance by the model error's share. Where the
    data reject the model, neither covariance is more than an approximation, and held-out data
    decide (forecast, the efficient one first). Where the two agree within their intervals
    (agreement), the robust one, whose error from a model error stays in the windows it acts
    in, is kept unless the efficient one predicts significantly better; where they disagree
    beyond them, one carries a model error its intervals do not count, and the better predictor
    is reported. Without a forecast the covariances decide.
    """
    expected = (relative_frobenius_bound(efficient.theta, efficient.theta_cov),
                relative_frobenius_bound(robust.theta, robust.theta_cov))
    if model_fits or forecast is None:
        keep = expected[0] < expected[1]
    elif agreement(efficient, robust).disagree:
        keep = forecast.costs[0] < forecast.costs[1]
    else:
        keep = forecast.first_better
    return Choice(bool(keep), bool(model_fits), expected, forecast)


def homogeneity(values, covs) -> Agreement:
    """The test that several estimates values [(k,)] with covariances covs [(k, k)] are of one
    vector: the chi-square of their deviations from their precision-weighted mean, on r (n - 1)
    degrees of freedom (r the covariances' rank: k, or k - 1 at a fixed trace, whose direction a
    normalised covariance leaves out). For two estimates it is their difference over the sum of
    their covariances. p is 1 without degrees of freedom.
    """
    x = [np.asarray(v, float) for v in values]
    cs = [0.5 * (np.asarray(c, float) + np.asarray(c, float).T) for c in covs]
    infos = [np.linalg.pinv(c, rcond=1e-12, hermitian=True) for c in cs]
    mean = np.linalg.pinv(sum(infos), rcond=1e-12, hermitian=True) @ sum(i @ v for i, v in zip(infos, x))
    stat = float(sum((v - mean) @ i @ (v - mean) for i, v in zip(infos, x)))
    vals = np.linalg.eigvalsh(cs[0])
    dof = int(np.sum(vals > 1e-12 * max(float(vals.max()), 1e-300))) * (len(x) - 1)
    return Agreement(stat, dof, float(stats.chi2.sf(stat, dof)) if dof else 1.0)


def agreement(a: InertiaEstimate, b: InertiaEstimate) -> Agreement:
    """Agreement of two estimates of one inertia (homogeneity; see Agreement); at a fixed trace
    the trace's direction is left out.
    """
    return homogeneity([a.theta, b.theta], [a.theta_cov, b.theta_cov])
