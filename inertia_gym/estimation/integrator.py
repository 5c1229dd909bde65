"""The one output-error integrator: the rigid body with its known inputs, and its sensitivities.

Model (body frame, known torque tau and known internal momentum h):

    L = J w + h,    L_dot = tau - w x L - c_i |w| w_i,    w = J^-1 (L - h),    q_dot = 1/2 q (x) (0, w)

The total body momentum L is integrated instead of w, so a sampled h enters only algebraically
(linearly interpolated between rows) and is never differentiated. The optional term -c_i |w| w_i
is a body-axis aerodynamic damping (c (3,) N·m·s²). Sensitivities with respect to the inertia's
log-Cholesky parameters phi (estimation/inertia_param.py), the initial rate w0, the initial
attitude's body-frame correction dq0 and the damping c come from the variational equations
integrated beside the trajectory (RK4, one compiled kernel):

    dS_L/dt = [L]x S_w - [w]x S_L,   S_w = J^-1 S_L - [J^-1 J_j w]_j (phi columns),
    dS_att/dt = -[w]x S_att + S_w     (body-frame attitude error, q_true = q (x) exp(d/2))
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_from_phi

#: Sensitivity columns the kernel integrates: phi (6), w0 (3), dq0 (3) (and the damping's 3).
N_DYN = 12
#: Largest rotation per integration sub-step, rad (RK4's phase error ~ (w h)^5 / 120 per step).
MAX_ROTATION_PER_STEP = 0.1


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


def substeps(t_grid, w_scale) -> np.ndarray:
    """(G,) RK4 sub-steps per grid interval so that |w| h <= MAX_ROTATION_PER_STEP.

    w_scale (G,) or scalar rad/s: the rate magnitude to plan for (e.g. |gyro| of the row).
    """
    dt = np.diff(t_grid, append=t_grid[-1])
    rot = np.abs(np.broadcast_to(w_scale, dt.shape)) * 1.5 * dt
    return np.maximum(1, np.ceil(rot / MAX_ROTATION_PER_STEP)).astype(np.int64)


@nb.njit(cache=True, nogil=True)
def trajectories(t_grid, tau_grid, h_grid, n_sub, meas_idx, seg, phi, w0s, q0s, with_sens, with_att,
                 out_w, out_sw, out_q, out_sa, drag=None):
    """trajectory() over each segment of a multiply shot record: segment s holds the
    measurements seg[s] .. seg[s+1] - 1 (seg (S+1,)) and starts at its first measurement's grid
    point from its own rate w0s[s] (3,) and attitude q0s[s] (4,); its sensitivities' w0 and dq0
    columns are to its own initial state. Writes the outputs of every measurement as trajectory()
    does (out_sw and out_sa only where with_sens and with_att ask for them). Returns False if a
    segment's state became non-finite.
    """
    ok = True
    for s in range(seg.shape[0] - 1):
        a, b = seg[s], seg[s + 1]
        g0, g1 = meas_idx[a], meas_idx[b - 1] + 1
        local = meas_idx[a:b] - g0
        sw = out_sw[a:b] if with_sens else out_sw
        q = out_q[a:b] if with_att else out_q
        sa = out_sa[a:b] if (with_sens and with_att) else out_sa
        ok = trajectory(t_grid[g0:g1], tau_grid[g0:g1], h_grid[g0:g1], n_sub[g0:g1], local, phi, w0s[s],
                        q0s[s], with_sens, with_att, out_w[a:b], sw, q, sa, drag) and ok
    return ok
