"""Batch maximum-likelihood (output-error) estimation of the inertia from a whole record.

Model (body frame, known torque tau and known internal momentum h):

    L = J w + h,    L_dot = tau - w x L,    w = J^-1 (L - h),    q_dot = 1/2 q (x) (0, w)

The total body momentum L is integrated instead of w, so a sampled h enters only algebraically
(linearly interpolated between rows) and is never differentiated. Measurements: gyro
z_w = w + b + noise (sigma_w rad/s per axis) and, where recorded, attitude z_q = q (x) exp(n)
(the sensor's sigma_q per quaternion component gives 2 sigma_q rad per axis of the rotation
vector 2 vec(q_hat^* (x) z_q)). The residuals are the measurements minus the model's output:
no differentiated gyro enters the cost.

Unknowns p = [phi (6), w0 (3), dq0 (3) if attitude, b (3) if bias] with phi the positive-definite
log-Cholesky parameters of estimation/inertia_param.py (J = e^s L L^T; s the pure scale), w0 the
rate at the first grid point, dq0 a body-frame rotation vector correcting the initial attitude.
Sensitivities come from the variational equations integrated beside the trajectory (RK4, one
compiled kernel):

    dS_L/dt = [L]x S_w - [w]x S_L,   S_w = J^-1 S_L - [J^-1 J_j w]_j (phi columns),
    dS_att/dt = -[w]x S_att + S_w     (body-frame attitude error, q_true = q (x) exp(d/2))

Long records: a single trajectory's phase is only locally linear in J (a 0.1 % inertia error
turns a 10 rad/s tumble by 1 rad in 1000 s), so the fit grows its horizon from a window the
start estimate can predict to the whole record, refitting at each step (progressive-horizon
shooting, an equivalent of multiple shooting: every stage starts inside its basin). Stages
before the last carry the start as a weak prior; the last is the pure likelihood.
"""

from __future__ import annotations

import dataclasses
import math

import numba as nb
import numpy as np

from inertia_gym.errors import ConfigError
from inertia_gym.estimation.inertia_param import (
    dtheta_dphi,
    inertia_from_phi,
    realizable_face,
    realizable_phi,
)

N_DYN = 12  # sensitivity columns integrated by the kernel: phi (6), w0 (3), dq0 (3)
#: Largest rotation per integration sub-step, rad (RK4's phase error ~ (w h)^5 / 120 per step).
MAX_ROTATION_PER_STEP = 0.1
#: Largest change of the inertia's log-Cholesky parameters in one Levenberg-Marquardt step.
MAX_PHI_STEP = 0.2
#: A horizon stage whose residual rms exceeds the previous stage's by this factor has slipped.
SLIP_FACTOR = 1.5
#: A horizon stage whose start misses the new data by this factor over the last good rms is
#: abandoned before iterating.
GIVE_UP_FACTOR = 10.0
#: Iterations more that the last good stage may take where it stopped at its iteration limit:
#: a crawl along a curved, ill-conditioned valley (a 1-s flip or a spin near the major axis, where
#: the nutation's frequency and shape fix nearly the same combination of the moments) stopped at
#: 40 iterations 2-3 % off in the moments' ratios, its intervals missing the truth on 10 of 10
#: noise seeds; continued, it converges, and they cover it.
CRAWL_MAX_ITER = 400
#: ... unless its residuals exceed this many times the noise: such a fit is no answer however long
#: it crawls (identify refuses it unconverged: UNEXPLAINED_MISFIT), and a caught throw's 4-kHz
#: record took 25 s more to be refused.
CRAWL_MAX_RMS = 30.0


# ------------------------------------------------------------------------------------------
# Compiled trajectory with sensitivities
# ------------------------------------------------------------------------------------------


@nb.njit(cache=True, nogil=True)
def _rate(y, h, tau, jm, jinv, jj, drag, nd, with_sens, with_att, dy, s_w):
    """Right-hand side of the augmented state y = [L (3), S_L (3 x nd), q (4), S_att (3 x nd)].

    h, tau (3,) at the stage time; jm, jinv (3, 3); jj (6, 3, 3) dJ/dphi_j; drag (3,) N·m·s²
    the body-axis aerodynamic damping c (torque -c_i |w| w_i); nd sensitivity columns (12, or
    15 with the drag's own three). Writes dy and the rate sensitivity s_w (3, nd); returns w.
    """
    lx, ly, lz = y[0], y[1], y[2]
    ax, ay, az = lx - h[0], ly - h[1], lz - h[2]
    wx = jinv[0, 0] * ax + jinv[0, 1] * ay + jinv[0, 2] * az
    wy = jinv[1, 0] * ax + jinv[1, 1] * ay + jinv[1, 2] * az
    wz = jinv[2, 0] * ax + jinv[2, 1] * ay + jinv[2, 2] * az
    wn = math.sqrt(wx * wx + wy * wy + wz * wz)
    dy[0] = tau[0] - (wy * lz - wz * ly) - drag[0] * wn * wx
    dy[1] = tau[1] - (wz * lx - wx * lz) - drag[1] * wn * wy
    dy[2] = tau[2] - (wx * ly - wy * lx) - drag[2] * wn * wz
    inv_wn = 1.0 / wn if wn > 0.0 else 0.0
    if with_sens:
        for p in range(nd):
            sx, sy, sz = y[3 + p], y[3 + nd + p], y[3 + 2 * nd + p]
            vx = jinv[0, 0] * sx + jinv[0, 1] * sy + jinv[0, 2] * sz
            vy = jinv[1, 0] * sx + jinv[1, 1] * sy + jinv[1, 2] * sz
            vz = jinv[2, 0] * sx + jinv[2, 1] * sy + jinv[2, 2] * sz
            if p < 6:  # - J^-1 (dJ/dphi_p) w
                ux = jj[p, 0, 0] * wx + jj[p, 0, 1] * wy + jj[p, 0, 2] * wz
                uy = jj[p, 1, 0] * wx + jj[p, 1, 1] * wy + jj[p, 1, 2] * wz
                uz = jj[p, 2, 0] * wx + jj[p, 2, 1] * wy + jj[p, 2, 2] * wz
                vx -= jinv[0, 0] * ux + jinv[0, 1] * uy + jinv[0, 2] * uz
                vy -= jinv[1, 0] * ux + jinv[1, 1] * uy + jinv[1, 2] * uz
                vz -= jinv[2, 0] * ux + jinv[2, 1] * uy + jinv[2, 2] * uz
            s_w[0, p], s_w[1, p], s_w[2, p] = vx, vy, vz
            # d/dp (-w x L) = L x S_w - w x S_L;  d/dp (-c_i |w| w_i) = -c_i (|w| v_i + w_i w.v/|w|)
            wv = (wx * vx + wy * vy + wz * vz) * inv_wn
            dy[3 + p] = (ly * vz - lz * vy) - (wy * sz - wz * sy) - drag[0] * (wn * vx + wx * wv)
            dy[3 + nd + p] = (lz * vx - lx * vz) - (wz * sx - wx * sz) - drag[1] * (wn * vy + wy * wv)
            dy[3 + 2 * nd + p] = ((lx * vy - ly * vx) - (wx * sy - wy * sx)
                                  - drag[2] * (wn * vz + wz * wv))
        if nd > N_DYN:  # the drag coefficients' own columns: d/dc_i of -c_i |w| w_i
            dy[3 + N_DYN] -= wn * wx
            dy[3 + nd + N_DYN + 1] -= wn * wy
            dy[3 + 2 * nd + N_DYN + 2] -= wn * wz
    if with_att:
        o = 3 + 3 * nd
        qw, qx, qy, qz = y[o], y[o + 1], y[o + 2], y[o + 3]
        dy[o] = 0.5 * (-qx * wx - qy * wy - qz * wz)
        dy[o + 1] = 0.5 * (qw * wx + qy * wz - qz * wy)
        dy[o + 2] = 0.5 * (qw * wy - qx * wz + qz * wx)
        dy[o + 3] = 0.5 * (qw * wz + qx * wy - qy * wx)
        if with_sens:
            a = o + 4
            for p in range(nd):
                ex, ey, ez = y[a + p], y[a + nd + p], y[a + 2 * nd + p]
                dy[a + p] = -(wy * ez - wz * ey) + s_w[0, p]
                dy[a + nd + p] = -(wz * ex - wx * ez) + s_w[1, p]
                dy[a + 2 * nd + p] = -(wx * ey - wy * ex) + s_w[2, p]
    return wx, wy, wz


@nb.njit(cache=True, nogil=True)
def trajectory(t_grid, tau_grid, h_grid, n_sub, meas_idx, phi, w0, q0, with_sens, with_att,
               out_w, out_sw, out_q, out_sa, drag=None):
    """Integrate the model over the grid and write the outputs at the measurement points.

    t_grid (G,) s increasing; tau_grid (G, 3) N·m held over [t_k, t_k+1); h_grid (G, 3) kg·m²/s,
    linear between grid points; n_sub (G,) RK4 sub-steps per interval; meas_idx (M,) grid
    indices (non-decreasing) of the measurements; phi (6,), w0 (3,) rad/s and q0 (4,) at t_grid[0].
    drag (3,) N·m·s² or None: body-axis aerodynamic damping c (external torque -c_i |w| w_i);
    given, it is also a parameter and the sensitivities gain its three columns.
    Writes out_w (M, 3) rad/s, out_sw (M, 3, nd) d w / d [phi, w0, dq0, (c)], out_q (M, 4) and
    out_sa (M, 3, nd) d(attitude error)/dp (rad), nd = 12 (15 with drag). Returns False if the
    state became non-finite.
    """
    nd = N_DYN if drag is None else N_DYN + 3
    c_drag = np.zeros(3)
    if drag is not None:
        c_drag[:] = drag
    jm = inertia_from_phi(phi)
    jinv = np.linalg.inv(jm)
    d = dtheta_dphi(phi)
    jj = np.empty((6, 3, 3))
    for p in range(6):
        jj[p, 0, 0], jj[p, 0, 1], jj[p, 0, 2] = d[0, p], d[1, p], d[2, p]
        jj[p, 1, 0], jj[p, 1, 1], jj[p, 1, 2] = d[1, p], d[3, p], d[4, p]
        jj[p, 2, 0], jj[p, 2, 1], jj[p, 2, 2] = d[2, p], d[4, p], d[5, p]
    n_state = 3 + 3 * nd + 4 + 3 * nd
    y = np.zeros(n_state)
    for i in range(3):
        y[i] = h_grid[0, i] + jm[i, 0] * w0[0] + jm[i, 1] * w0[1] + jm[i, 2] * w0[2]
    for p in range(6):
        for i in range(3):
            y[3 + i * nd + p] = jj[p, i, 0] * w0[0] + jj[p, i, 1] * w0[1] + jj[p, i, 2] * w0[2]
    for c in range(3):
        for i in range(3):
            y[3 + i * nd + 6 + c] = jm[i, c]
    o = 3 + 3 * nd
    for i in range(4):
        y[o + i] = q0[i]
    for c in range(3):
        y[o + 4 + c * nd + 9 + c] = 1.0
    k1, k2, k3, k4, tmp = (np.empty(n_state), np.empty(n_state), np.empty(n_state),
                           np.empty(n_state), np.empty(n_state))
    s_w = np.zeros((3, nd))
    h_a, h_m, h_b = np.empty(3), np.empty(3), np.empty(3)
    tau = np.empty(3)
    m = 0
    n_meas = meas_idx.shape[0]
    g_count = t_grid.shape[0]
    for g in range(g_count):
        while m < n_meas and meas_idx[m] == g:
            for i in range(3):
                h_a[i] = h_grid[g, i]
            wx, wy, wz = _rate(y, h_a, tau_grid[g], jm, jinv, jj, c_drag, nd, with_sens, with_att,
                               k1, s_w)
            out_w[m, 0], out_w[m, 1], out_w[m, 2] = wx, wy, wz
            if with_sens:
                out_sw[m] = s_w
            if with_att:
                for i in range(4):
                    out_q[m, i] = y[o + i]
                if with_sens:
                    for i in range(3):
                        for p in range(nd):
                            out_sa[m, i, p] = y[o + 4 + i * nd + p]
            m += 1
        if g == g_count - 1 or m == n_meas:
            break
        ns = n_sub[g]
        hstep = (t_grid[g + 1] - t_grid[g]) / ns
        for i in range(3):
            tau[i] = tau_grid[g, i]
        for s in range(ns):
            fa, fb = s / ns, (s + 1) / ns
            fm = 0.5 * (fa + fb)
            for i in range(3):
                dh = h_grid[g + 1, i] - h_grid[g, i]
                h_a[i] = h_grid[g, i] + fa * dh
                h_m[i] = h_grid[g, i] + fm * dh
                h_b[i] = h_grid[g, i] + fb * dh
            _rate(y, h_a, tau, jm, jinv, jj, c_drag, nd, with_sens, with_att, k1, s_w)
            for i in range(n_state):
                tmp[i] = y[i] + 0.5 * hstep * k1[i]
            _rate(tmp, h_m, tau, jm, jinv, jj, c_drag, nd, with_sens, with_att, k2, s_w)
            for i in range(n_state):
                tmp[i] = y[i] + 0.5 * hstep * k2[i]
            _rate(tmp, h_m, tau, jm, jinv, jj, c_drag, nd, with_sens, with_att, k3, s_w)
            for i in range(n_state):
                tmp[i] = y[i] + hstep * k3[i]
            _rate(tmp, h_b, tau, jm, jinv, jj, c_drag, nd, with_sens, with_att, k4, s_w)
            for i in range(n_state):
                y[i] += hstep / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
            if with_att:
                nq = math.sqrt(y[o] ** 2 + y[o + 1] ** 2 + y[o + 2] ** 2 + y[o + 3] ** 2)
                for i in range(4):
                    y[o + i] /= nq
        if not (math.isfinite(y[0]) and math.isfinite(y[1]) and math.isfinite(y[2])):
            return False
    return True


# ------------------------------------------------------------------------------------------
# Problem definition and residuals
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Problem:
    """One record prepared for the output-error fit.

    t_grid (G,) s; tau_grid (G, 3) N·m held from each grid point on; h_grid (G, 3) kg·m²/s;
    n_sub (G,) integration sub-steps per interval; meas_idx (M,) grid index of each measurement;
    z_w (M, 3) rad/s gyro; z_q (M, 4) unit quaternions or None; sigma_w (3,) rad/s;
    sigma_att rad (per axis of the attitude error); fit_bias: estimate a constant gyro bias;
    fix_scale: the scale s is not a free parameter (no torque and h zero); fit_drag:
    estimate a body-axis aerodynamic damping c (3,) N·m·s² (external torque -c_i |w| w_i).
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

    def free(self) -> np.ndarray:
        """Bool mask (n_params,) of the parameters the fit moves."""
        mask = np.ones(self.n_params, dtype=bool)
        mask[0] = not self.fix_scale
        return mask

    def window(self, n_meas: int) -> "Problem":
        """The same problem restricted to its first n_meas measurements."""
        g_end = int(self.meas_idx[n_meas - 1]) + 1
        return dataclasses.replace(
            self, t_grid=self.t_grid[:g_end], tau_grid=self.tau_grid[:g_end],
            h_grid=self.h_grid[:g_end], n_sub=self.n_sub[:g_end], meas_idx=self.meas_idx[:n_meas],
            z_w=self.z_w[:n_meas], z_q=None if self.z_q is None else self.z_q[:n_meas])


def substeps(t_grid, w_scale) -> np.ndarray:
    """(G,) RK4 sub-steps per grid interval so that |w| h <= MAX_ROTATION_PER_STEP.

    w_scale (G,) or scalar rad/s: the rate magnitude to plan for (e.g. |gyro| of the row).
    """
    dt = np.diff(t_grid, append=t_grid[-1])
    rot = np.abs(np.broadcast_to(w_scale, dt.shape)) * 1.5 * dt
    return np.maximum(1, np.ceil(rot / MAX_ROTATION_PER_STEP)).astype(np.int64)


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """Model output at p: weighted residuals r (R,), their Jacobian dr/dp (R, n_params) or None,
    gyro residual e_w (M, 3) rad/s and attitude residual e_att (M, 3) rad (or None).
    """

    r: np.ndarray
    jac: np.ndarray | None
    e_w: np.ndarray
    e_att: np.ndarray | None
    ok: bool


def quat_mul(p, q) -> np.ndarray:
    """Hamilton product of (..., 4) scalar-first quaternions."""
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw],
                    axis=-1)


def quat_exp(v) -> np.ndarray:
    """Unit quaternion exp(v/2) of a rotation vector v (3,) rad."""
    v = np.asarray(v, dtype=float)
    a = np.linalg.norm(v)
    if a < 1e-12:
        return np.r_[1.0, 0.5 * v] / np.sqrt(1 + 0.25 * a * a)
    return np.r_[np.cos(a / 2), np.sin(a / 2) * v / a]


def attitude_error(q_model, z_q) -> np.ndarray:
    """(M, 3) rad: 2 vec(q_model^* (x) z_q), sign-aligned (the measured minus the model)."""
    conj = q_model * np.array([1.0, -1.0, -1.0, -1.0])
    dq = quat_mul(conj, z_q)
    dq *= np.where(dq[:, :1] < 0, -1.0, 1.0)
    return 2.0 * dq[:, 1:]


def evaluate(prob: Problem, p, q_ref, with_jac: bool) -> Evaluation:
    """Weighted residuals (and Jacobian) of the problem at p; q_ref (4,) the attitude that dq0
    perturbs (q0 = q_ref (x) exp(dq0/2)).
    """
    m = prob.meas_idx.size
    nd = N_DYN + (3 if prob.fit_drag else 0)
    out_w = np.zeros((m, 3))
    out_sw = np.zeros((m, 3, nd)) if with_jac else np.zeros((1, 3, nd))
    out_q = np.zeros((m, 4)) if prob.with_att else np.zeros((1, 4))
    out_sa = np.zeros((m, 3, nd)) if (with_jac and prob.with_att) else np.zeros((1, 3, nd))
    q0 = quat_mul(q_ref, quat_exp(p[9:12])) if prob.with_att else np.array([1.0, 0, 0, 0])
    drag = np.ascontiguousarray(p[prob.drag_slice]) if prob.fit_drag else None
    ok = trajectory(prob.t_grid, prob.tau_grid, prob.h_grid, prob.n_sub, prob.meas_idx,
                    np.ascontiguousarray(p[:6]), np.ascontiguousarray(p[6:9]), q0, with_jac,
                    prob.with_att, out_w, out_sw, out_q, out_sa, drag)
    bias = p[-3:] if prob.fit_bias else np.zeros(3)
    e_w = prob.z_w - out_w - bias
    parts = [(e_w / prob.sigma_w).ravel()]
    e_att = None
    if prob.with_att:
        e_att = attitude_error(out_q, prob.z_q)
        parts.append((e_att / prob.sigma_att).ravel())
    r = np.concatenate(parts)
    ok = ok and bool(np.all(np.isfinite(r)))
    jac = None
    if with_jac and ok:
        n_p = prob.n_params
        jw = np.zeros((m, 3, n_p))
        jw[:, :, :9] = out_sw[:, :, :9]
        jw[:, :, prob.drag_slice] = out_sw[:, :, N_DYN:]
        if prob.fit_bias:
            jw[:, :, -3:] = np.eye(3)
        blocks = [(jw / prob.sigma_w[None, :, None]).reshape(-1, n_p)]
        if prob.with_att:
            ja = np.zeros((m, 3, n_p))
            ja[:, :, :N_DYN] = out_sa[:, :, :N_DYN]
            ja[:, :, prob.drag_slice] = out_sa[:, :, N_DYN:]
            blocks.append((ja / prob.sigma_att).reshape(-1, n_p))
        # r = z - model: dr/dp = -d model/dp
        jac = -np.concatenate(blocks, axis=0)
    return Evaluation(r, jac, e_w, e_att, ok)


# ------------------------------------------------------------------------------------------
# Levenberg-Marquardt with a progressive horizon
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class MLFit:
    """Result of the output-error fit.

    p (n,) the estimate [phi, w0, (dq0 = 0), (b)] with q0 (4,) its initial attitude (or None);
    cost = 0.5 |r|^2; evaluation at p (of the first n_used measurements; its Jacobian gives the
    Fisher information J^T J under white noise at sigma); n_stages horizons fitted; converged: the last
    stage met its tolerance; n_used: measurements the estimate rests on (M unless the
    horizon could not grow over the whole record).
    """

    p: np.ndarray
    q0: np.ndarray | None
    evaluation: Evaluation
    cost: float
    n_iter: int
    n_stages: int
    converged: bool
    n_used: int


def _levenberg_marquardt(prob: Problem, p, q_ref, prior_mean=None, prior_info=None,
                         max_iter: int = 40, tol: float = 1e-3, give_up_rms: float = math.inf):
    """Minimise 0.5|r|^2 (+ 0.5 (p - mean)^T info (p - mean)) over the free parameters.

    Converged when the last step's predicted or actual decrease of |r|^2 is below tol
    (chi-square units: 1e-3 is a step of about 0.03 standard deviations). give_up_rms: if the
    start's residual rms (per residual) exceeds it, return at once unconverged (a horizon stage
    whose start already lost the trajectory).

    Returns (p, q_ref, evaluation with Jacobian, cost, iterations, converged).
    """
    free = prob.free()
    p = np.array(p, dtype=float)
    q_ref = np.array(q_ref, dtype=float)

    def total_cost(ev, p_):
        c = 0.5 * float(ev.r @ ev.r)
        if prior_info is not None:
            dp = (p_ - prior_mean)[free]
            c += 0.5 * float(dp @ prior_info[np.ix_(free, free)] @ dp)
        return c

    ev = evaluate(prob, p, q_ref, True)
    if not ev.ok:
        raise ConfigError("the model's trajectory is not finite at the start estimate")
    cost = total_cost(ev, p)
    if math.sqrt(np.mean(ev.r ** 2)) > give_up_rms:
        return p, q_ref, ev, cost, 0, False
    # Damped at first, then quickly Gauss-Newton: Marquardt's damping along diag(A) crawls along
    # the strongly correlated inertia-phase directions, so it falls tenfold per accepted step.
    # A step may change the inertia's log-parameters by at most MAX_PHI_STEP (a trust region:
    # on a short, poorly conditioned window an undamped step can leap to another basin).
    lam = 1e-3
    converged = False
    iterations = 0
    prior_root = None
    if prior_info is not None:  # rows R_p with R_p^T R_p = the prior information (free block)
        vals, vecs = np.linalg.eigh(prior_info[np.ix_(free, free)])
        keep = vals > 1e-12 * max(vals.max(), 1e-300)
        prior_root = (vecs[:, keep] * np.sqrt(vals[keep])).T
    for iterations in range(1, max_iter + 1):  # noqa: B007 (the count is returned)
        # Gauss-Newton steps from the QR factor of the column-scaled Jacobian, never from J^T J:
        # over a long tumble the sensitivities grow by many orders and J^T J would square a
        # condition number of 1e8 into 1e16.
        jf = ev.jac[:, free]
        col = np.maximum(np.linalg.norm(jf, axis=0), 1e-300)
        r_fac, qtr = _qr_rhs(jf / col, -ev.r)
        blocks, rhs = [r_fac], [qtr]
        if prior_root is not None:
            blocks.append(prior_root / col)
            rhs.append(-prior_root @ (p - prior_mean)[free])
        g = np.concatenate(blocks).T @ np.concatenate(rhs)  # -gradient, in scaled coordinates
        # at the limit of the bodies that exist (a flat plate's inertia) steps are taken along
        # it (inertia_param.realizable_face, in scaled coordinates), not creeping by projections
        along = _face_steps(realizable_face(p[:6]), free, col)
        improved = False
        for _ in range(20):
            damped = np.concatenate(blocks + [math.sqrt(lam) * np.eye(col.size)])
            stacked = np.concatenate(rhs + [np.zeros(col.size)])
            steps = [np.linalg.lstsq(damped, stacked, rcond=None)[0]]
            if along is not None:
                steps.append(along @ np.linalg.lstsq(damped @ along, stacked, rcond=None)[0])
            trials = [(scaled, t) for scaled in steps
                      if (t := _trial(prob, p, q_ref, free, scaled / col)) is not None]
            if not trials:  # every step leaps too far in the inertia: damp more
                lam = max(lam * 10.0, 1e-6)
                continue
            costs = [total_cost(ev_new, p_new) if ev_new.ok else np.inf for _, (p_new, _, ev_new) in trials]
            best = int(np.argmin(costs))
            if costs[best] <= cost:
                scaled, (p, q_ref, _) = trials[best]
                predicted = float(scaled @ g)  # ~ twice the predicted decrease
                drop = cost - costs[best]
                cost = costs[best]
                lam = max(lam / 10.0, 1e-15)
                improved = True
                break
            lam = max(lam * 10.0, 1e-6)
        if not improved:
            converged = True  # no step lowers the cost: a (local) minimum to working precision
            ev = evaluate(prob, p, q_ref, True)
            break
        ev = evaluate(prob, p, q_ref, True)
        if predicted <= tol or drop <= 0.5 * tol:  # nothing left to gain, or none gained
            converged = True
            break
    return p, q_ref, ev, cost, iterations, converged


def _trial(prob: Problem, p, q_ref, free, step):
    """(p, q_ref, evaluation) after the step (of the free parameters), the inertia projected
    onto the bodies that exist with its scale coordinate kept (a flat body's fit, pulled by
    what the model leaves out, otherwise ends where no body is); None where the step changes
    the inertia's log-parameters by more than MAX_PHI_STEP (a trust region: on a short, poorly
    conditioned window an undamped step can leap to another basin).
    """
    p_new = p.copy()
    p_new[free] += step
    p_new[:6] = realizable_phi(p_new[:6], keep_scale=True)
    if np.abs(p_new[:6] - p[:6]).max() > MAX_PHI_STEP:
        return None
    q_new = q_ref
    if prob.with_att:
        q_new = quat_mul(q_ref, quat_exp(p_new[9:12]))
        q_new /= np.linalg.norm(q_new)
        p_new[9:12] = 0.0
    return p_new, q_new, evaluate(prob, p_new, q_new, False)


def _face_steps(face, free, col) -> np.ndarray | None:
    """Orthonormal basis (F, F - 1) of the scaled steps of the free parameters that keep the
    face row (1, 6) over phi at zero, or None off the face (face (0, 6)) or where phi is held.
    """
    if not face.size:
        return None
    row = np.zeros(free.size)
    row[:6] = face[0]
    row = row[free] / col
    if not np.any(row):
        return None
    _, _, vt = np.linalg.svd(row[None])
    return vt[1:].T


def _qr_rhs(a, b):
    """R (n, n) of the thin QR of a (R, n) and Q^T b (n,), from the triangular factor of [a | b]
    alone (Q is never formed).
    """
    n = a.shape[1]
    r_aug = np.linalg.qr(np.column_stack([a, b]), mode="r")
    return r_aug[:n, :n], r_aug[:n, n]


def jacobian_covariance(jac, free) -> np.ndarray:
    """(J^T J)^-1 over the free columns of the weighted Jacobian jac (R, n), zeros elsewhere,
    from the SVD of the column-scaled J (its condition number, not its square, limits the
    precision). Raises ConfigError when the record does not determine every free parameter.
    """
    jf = jac[:, free]
    col = np.maximum(np.linalg.norm(jf, axis=0), 1e-300)
    _, sv, vt = np.linalg.svd(jf / col, full_matrices=False)
    if sv[-1] <= 1e-13 * sv[0]:
        raise ConfigError("the record does not determine every parameter (Jacobian condition "
                          f"number {sv[0] / max(sv[-1], 1e-300):.2g})")
    inner = (vt.T / sv ** 2) @ vt
    out = np.zeros((jac.shape[1], jac.shape[1]))
    out[np.ix_(free, free)] = inner / np.outer(col, col)
    return 0.5 * (out + out.T)


def fit(prob: Problem, p_start, q_start=None, start_info=None, first_horizon: int | None = None,
        max_iter: int = 40) -> MLFit:
    """Maximum-likelihood fit of the problem from p_start (q_start: initial attitude guess).

    start_info (n, n): information (inverse covariance) of the start, used as a prior on the
    stages before the last; first_horizon: measurements in the first stage (default: all).
    The horizon doubles until it covers the record; the last stage has no prior. A stage that
    does not converge, or whose residual rms jumps by more than SLIP_FACTOR over the previous
    stage's (the trajectory slipped out of the fit's basin: near a separatrix the sensitivities
    grow exponentially), is retried with a quarter more instead of twice the last horizon; if
    that fails too, the fit keeps the last good horizon (refitted without the prior) and says
    so in ``n_used`` < M. The last good stage, where it stopped at the iteration limit within
    CRAWL_MAX_RMS times the noise, carries on for up to CRAWL_MAX_ITER more iterations
    (``converged`` says whether it then converged).
    """
    m_total = prob.meas_idx.size
    n = m_total if first_horizon is None else int(np.clip(first_horizon, 1, m_total))
    p = np.array(p_start, dtype=float)
    q_ref = np.array([1.0, 0.0, 0.0, 0.0]) if q_start is None else np.asarray(q_start, dtype=float)
    prior_mean = p.copy()
    total_iter, stages = 0, 0
    good = None  # (n, p, q_ref, evaluation, cost, converged, had_prior, rms)
    retried = False
    while True:
        last = n == m_total
        info = None if (last or start_info is None) else start_info
        # A start that already misses the new data by far (GIVE_UP_FACTOR times the last good
        # rms) has lost the trajectory: back off at once instead of iterating.
        give_up = math.inf if good is None else GIVE_UP_FACTOR * good[7]
        out = _levenberg_marquardt(prob.window(n), p, q_ref, prior_mean if info is not None else None,
                                   info, max_iter=max_iter, give_up_rms=give_up)
        total_iter += out[4]
        stages += 1
        rms = float(np.sqrt(np.mean(out[2].r ** 2)))
        # A stage stopped by the iteration limit with residuals as small as the last good
        # stage's is kept (a slow crawl along an ill-conditioned valley, reported through
        # `converged`); one whose residuals jumped has lost the trajectory.
        ok = good is None or rms <= SLIP_FACTOR * good[7]
        if ok or good is None:
            p, q_ref = out[0], out[1]
            good = (n, p, q_ref, out[2], out[3], out[5], info is not None, rms)
            retried = False
            if last:
                break
            n = min(2 * n, m_total)
        elif not retried:
            retried = True
            n = min(max(good[0] + 1, int(1.25 * good[0])), m_total)
        else:
            break
    n_used, p, q_ref, ev, cost, converged, had_prior, rms = good
    crawl = not converged and rms <= CRAWL_MAX_RMS  # stopped at the limit, and worth carrying on
    if had_prior or crawl:  # refit without the start's prior (pure likelihood), or carry on
        p, q_ref, ev, cost, it, converged = _levenberg_marquardt(
            prob.window(n_used), p, q_ref, max_iter=CRAWL_MAX_ITER if crawl else max_iter)
        total_iter += it
    return MLFit(p, q_ref if prob.with_att else None, ev, cost, total_iter, stages, converged,
                 n_used)


#: ||J||_F^2 = theta^T W theta for theta in eq. (8) order (off-diagonals count twice).
FROBENIUS_WEIGHTS = np.array([1.0, 2.0, 2.0, 1.0, 2.0, 1.0])


def relative_frobenius_bound(theta, cov_theta) -> float:
    """sqrt(E ||J_hat - J||_F^2) / ||J||_F for an estimate with covariance cov_theta (6, 6)."""
    theta = np.asarray(theta, dtype=float)
    expected = float(np.sum(FROBENIUS_WEIGHTS * np.diag(cov_theta)))
    return math.sqrt(max(expected, 0.0)) / math.sqrt(float(np.sum(FROBENIUS_WEIGHTS * theta ** 2)))


__all__ = ["Problem", "MLFit", "fit", "evaluate", "trajectory", "jacobian_covariance",
           "relative_frobenius_bound", "substeps"]
