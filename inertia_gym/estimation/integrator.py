"""The output-error model's trajectories and their sensitivities, on the project's one integrator.

Model (body frame, known torque tau held over each grid interval and known internal momentum h,
linear between grid points): J w_dot + h_dot + w x (J w + h) = tau - |w| diag(c) w, q_dot =
1/2 q (x) (0, w). The optional term is a body-axis aerodynamic damping (c (3,) N·m·s²).

The trajectories are model_dynamics.propagate_model_batch's (dynamics.rk4_augmented, the one
RK4 step, also diagnose's model), on the record's grid refined into its sub-steps. The
sensitivities with respect to the inertia's log-Cholesky parameters phi
(estimation/inertia_param.py), the initial rate w0, the initial attitude's body-frame correction
dq0 and the damping c are complex steps of that same integrator: column p runs the model with
parameter p moved by i*h, and Im(y)/h is dy/dp of the discrete steps to rounding, for any
h small enough that h^2 vanishes beside 1 (no difference is taken, so no step has to balance
truncation against cancellation; Squire and Trapp, SIAM Review 40, 1998). Every column runs in
one parallel batch, and each column's real part is the trajectory itself.
"""

from __future__ import annotations

import numpy as np

from inertia_gym.dynamics import _D_AERO, _D_AERO_ON, Disturbance, quat_mul
from inertia_gym.estimation.inertia_param import dtheta_dphi, inertia_from_phi
from inertia_gym.information import inertia_from_theta
from inertia_gym.model_dynamics import propagate_model_batch

#: Sensitivity columns: phi (6), w0 (3), dq0 (3) (and the damping's 3).
N_DYN = 12
#: Largest rotation per integration sub-step, rad (RK4's phase error ~ (w h)^5 / 120 per step).
MAX_ROTATION_PER_STEP = 0.1
#: The complex step: 1e-20 of a parameter's unit leaves h^2 ~ 1e-40 beside every real part,
#: and its imaginary parts stay far above the smallest double however small a sensitivity.
COMPLEX_STEP = 1e-20


def substeps(t_grid, w_scale) -> np.ndarray:
    """(G,) RK4 sub-steps per grid interval so that |w| h <= MAX_ROTATION_PER_STEP.

    w_scale (G,) or scalar rad/s: the rate magnitude to plan for (e.g. |gyro| of the row).
    """
    dt = np.diff(t_grid, append=t_grid[-1])
    rot = np.abs(np.broadcast_to(w_scale, dt.shape)) * 1.5 * dt
    return np.maximum(1, np.ceil(rot / MAX_ROTATION_PER_STEP)).astype(np.int64)


def _refined(t_grid, tau_grid, h_grid, n_sub, g_end):
    """(t (m+1,), tau (m, 3), h (m+1, 3), offset (g_end,)): the grid's first g_end points with
    n_sub[g] equal sub-steps in interval g, tau held and h linear over each; offset[g] is grid
    point g's index in the refined grid.
    """
    n = np.asarray(n_sub[:g_end - 1], np.int64)
    offset = np.r_[0, np.cumsum(n)]
    interval = np.repeat(np.arange(g_end - 1), n)
    frac = (np.arange(offset[-1]) - offset[interval]) / n[interval]
    t = np.asarray(t_grid, float)
    h = np.asarray(h_grid, float)
    t_f = np.r_[t[interval] + frac * (t[interval + 1] - t[interval]), t[g_end - 1]]
    h_f = np.concatenate([h[interval] + frac[:, None] * (h[interval + 1] - h[interval]), h[g_end - 1:g_end]])
    return t_f, np.asarray(tau_grid, float)[interval], h_f, offset


def trajectories(t_grid, tau_grid, h_grid, n_sub, meas_idx, seg, phi, w0s, q0s, with_sens, with_att,
                 out_w, out_sw, out_q, out_sa, drag=None, first_grid=None) -> bool:
    """Integrate each segment of a multiply shot record and write the outputs at its measurements.

    t_grid (G,) s increasing; tau_grid (G, 3) N·m held over [t_k, t_k+1); h_grid (G, 3) kg·m²/s,
    linear between grid points; n_sub (G,) RK4 sub-steps per interval; meas_idx (M,) grid indices
    (non-decreasing) of the measurements; segment s holds the measurements seg[s] .. seg[s+1] - 1
    (seg (S+1,)) and starts at its first measurement's grid point from its own rate w0s[s] (3,)
    rad/s and attitude q0s[s] (4,); phi (6,) the inertia. drag (3,) N·m·s² or None: the body-axis
    damping c, given, also a parameter whose three columns the sensitivities gain.

    Writes out_w (M, 3) rad/s, out_q (M, 4) where with_att, and where with_sens out_sw (M, 3, nd)
    d w / d [phi, w0, dq0, (c)] and (with_att) out_sa (M, 3, nd) d(attitude error)/dp (rad, the
    body-frame rotation q_true = q (x) exp(d/2)), nd = 12 (15 with drag); a segment's w0 and dq0
    columns are to its own initial state. first_grid: the grid index the first segment starts
    from (default its first measurement's). Returns False if a state became non-finite.
    """
    meas_idx = np.asarray(meas_idx, np.int64)
    seg = np.asarray(seg, np.int64)
    starts = seg[1:-1]
    if np.any(meas_idx[starts] == meas_idx[starts - 1]):
        raise ValueError("a shooting cut between two measurements at one grid point")
    t_f, tau_f, h_f, offset = _refined(t_grid, tau_grid, h_grid, n_sub, int(meas_idx[-1]) + 1)
    sample_pos = offset[meas_idx]
    seg_pos = np.r_[offset[meas_idx[seg[:-1]]], offset[-1]]
    if first_grid is not None:
        seg_pos[0] = offset[first_grid]
    c = np.zeros(3) if drag is None else np.asarray(drag, float)
    nd = N_DYN if drag is None else N_DYN + 3
    jm = inertia_from_phi(np.asarray(phi, float))
    w0s = np.asarray(w0s, float)
    q0s = np.asarray(q0s, float)
    n_seg = seg.size - 1
    cols = [p for p in range(nd) if with_sens and (with_att or not 9 <= p < 12)]
    packed = Disturbance(aero_drag=tuple(c)).pack()
    step = COMPLEX_STEP
    # row k moves column cols[k] by i h (one real row where no sensitivity is asked for); every
    # row's real part is the trajectory
    batch = max(len(cols), 1)
    kind = complex if cols else float
    inertia = np.repeat(jm[None].astype(kind), batch, axis=0)
    y0 = np.empty((batch, n_seg, 7), kind)
    y0[:, :, :4], y0[:, :, 4:] = q0s, w0s
    dist = np.repeat(packed[None].astype(kind), batch, axis=0)
    d_phi = dtheta_dphi(np.asarray(phi, float))
    for k, p in enumerate(cols):
        if p < 6:
            inertia[k] += 1j * step * inertia_from_theta(d_phi[:, p])
        elif p < 9:
            y0[k, :, p - 2] += 1j * step
        elif p < 12:  # q0 (x) exp(i h e / 2) = q0 + i h/2 q0 (x) (0, e), to first order
            y0[k, :, :4] += 0.5j * step * quat_mul(q0s, np.r_[0.0, np.eye(3)[p - 9]])
        else:  # the drag's diagonal entry c_i, the drag switched on (it may be fitted from zero)
            dist[k, _D_AERO_ON] = 1.0
            dist[k, _D_AERO.start + 4 * (p - 12)] += 1j * step
    out = propagate_model_batch(t_f, sample_pos, seg_pos, y0, inertia, inertia, np.full(batch, np.inf),
                                tau_f[None], h_f[None], dist)
    real = out[0].real
    out_w[:] = real[:, 4:]
    if with_att:
        out_q[:] = real[:, :4]
    if cols:
        conj = real[:, :4] * np.array([1.0, -1.0, -1.0, -1.0])
        out_sw[:] = 0.0
        if with_att:
            out_sa[:] = 0.0
        for k, p in enumerate(cols):
            out_sw[:, :, p] = out[k, :, 4:].imag / step
            if with_att:  # q_true = q (x) exp(d/2): d = 2 vec(q^* (x) dq)
                out_sa[:, :, p] = 2.0 * quat_mul(conj, out[k, :, :4].imag)[:, 1:] / step
    return bool(np.all(np.isfinite(real)))


def trajectory(t_grid, tau_grid, h_grid, n_sub, meas_idx, phi, w0, q0, with_sens, with_att,
               out_w, out_sw, out_q, out_sa, drag=None) -> bool:
    """trajectories() of one segment: the record from w0 (3,) rad/s and q0 (4,) at t_grid[0]."""
    return trajectories(t_grid, tau_grid, h_grid, n_sub, meas_idx, np.array([0, np.asarray(meas_idx).size]),
                        phi, np.asarray(w0, float)[None], np.asarray(q0, float)[None], with_sens, with_att,
                        out_w, out_sw, out_q, out_sa, drag, first_grid=0)
