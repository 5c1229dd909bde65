"""The rigid body augmented with the effect catalogue's states (a flexible mode, an inertia change
with the momentum J w kept across it, internal dissipation, a viscous damping that changes in time)
and a known internal momentum, integrated by compiled RK4 for diagnose's model:
:func:`propagate_model_batch` advances many trajectories on one grid of sample times and
sub-steps, one RK4 step per grid interval, in segments (multiple shooting) run in parallel, and is
both the truth simulator of the effect catalogue and the model that diagnose fits. Its step is
dynamics.py's rk4_augmented, the one RK4 step of the rigid body and its effect states.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from inertia_gym.dynamics import (
    _D_C0,
    _D_C1,
    _D_DELTA,
    _D_ETA0,
    _D_ETAD0,
    _D_K0,
    DISTURBANCE_SIZE,
    disturbance_entries,
    inv3,
    mat3_entries,
    modal_coupling,
    rk4_augmented,
    root,
)
from inertia_gym.task_threads import run_split


@nb.njit(cache=True, forceinline=True)
def _momentum_kept(y, j_now, j_new_inv):
    """The state y (9-tuple) with w <- J_new^-1 J_now w (the momentum J w is kept across an inertia
    change); j_now and j_new_inv row-major 9-tuples.
    """
    m0 = j_now[0] * y[4] + j_now[1] * y[5] + j_now[2] * y[6]
    m1 = j_now[3] * y[4] + j_now[4] * y[5] + j_now[5] * y[6]
    m2 = j_now[6] * y[4] + j_now[7] * y[5] + j_now[8] * y[6]
    ji = j_new_inv
    return (y[0], y[1], y[2], y[3], ji[0] * m0 + ji[1] * m1 + ji[2] * m2,
            ji[3] * m0 + ji[4] * m1 + ji[5] * m2, ji[6] * m0 + ji[7] * m1 + ji[8] * m2, y[7], y[8])


@nb.njit(cache=True, forceinline=True)
def _damping_scaled(d, f):
    """The disturbance tuple d with its viscous damping matrix (slots _D_C) times f."""
    return (d[0], d[1], d[2], d[3], d[4], d[5], d[6] * f, d[7] * f, d[8] * f, d[9] * f, d[10] * f,
            d[11] * f, d[12] * f, d[13] * f, d[14] * f, d[15], d[16], d[17], d[18], d[19], d[20],
            d[21], d[22], d[23], d[24], d[25], d[26], d[27], d[28], d[29], d[30], d[31], d[32],
            d[33], d[34], d[35], d[36], d[37], d[38], d[39], d[40], d[41], d[42])


# _damping_scaled spells out every slot, the damping matrix at 6..14.
assert (_D_C0, _D_C1, DISTURBANCE_SIZE) == (6, 15, 43), "update _damping_scaled to the new slots"


@nb.njit(cache=True)
def _model_segment(grid_t, sample_pos, a, b, i, last, y0, eta, etad, inertia, inertia_after, change_t,
                   tau, h, dist, damping, out):
    """One segment of a model trajectory: grid steps a .. b from (q, w) = y0 (7,) and the modal
    state (eta, etad); writes (q, w) at the samples from index i on (sample_pos[i] == a) into out
    and returns the modal state at b. last: the segment ends the record (its end is a sample).
    damping (m,): the factor of dist's viscous damping matrix over each grid interval.

    J is `inertia` before change_t and `inertia_after` from there on; a change inside a grid
    interval splits its step at change_t, so the trajectory is continuous and differentiable in
    change_t. What a segment computes depends on nothing of the segments before it but the
    modal state it starts from (the change is a time, J w kept across it).
    """
    n_samples = sample_pos.size
    changed = grid_t[a] >= change_t  # the segment starts after the change
    j_after, j_after_inv = mat3_entries(inertia_after), mat3_entries(inv3(inertia_after))
    j, j_inv = (j_after, j_after_inv) if changed else (mat3_entries(inertia), mat3_entries(inv3(inertia)))
    entries = disturbance_entries(dist)
    jd0, jd1, jd2, denom = modal_coupling(j_inv, entries)
    s = 1.0 / root(y0[0] ** 2 + y0[1] ** 2 + y0[2] ** 2 + y0[3] ** 2)
    y = (y0[0] * s, y0[1] * s, y0[2] * s, y0[3] * s, y0[4], y0[5], y0[6], eta, etad)
    for k in range(a, b + 1):
        while i < n_samples and sample_pos[i] == k and (k < b or last):
            for c in range(7):
                out[i, c] = y[c]
            i += 1
        if k == b:
            break
        t0, t1 = grid_t[k], grid_t[k + 1]
        dt = t1 - t0
        step_dist = entries if damping[k] == 1.0 else _damping_scaled(entries, damping[k])
        if not changed and t0 >= change_t:
            y = _momentum_kept(y, j, j_after_inv)
            j, j_inv = j_after, j_after_inv
            jd0, jd1, jd2, denom = modal_coupling(j_inv, entries)
            changed = True
        # h linear over the step: its rate is the step's slope, subtracted from the torque
        r0 = (h[k + 1, 0] - h[k, 0]) / dt
        r1 = (h[k + 1, 1] - h[k, 1]) / dt
        r2 = (h[k + 1, 2] - h[k, 2]) / dt
        tx, ty, tz = tau[k, 0] - r0, tau[k, 1] - r1, tau[k, 2] - r2
        if not changed and t1 > change_t:  # the change falls inside this step: split it
            f = change_t - t0
            hc0, hc1, hc2 = h[k, 0] + f * r0, h[k, 1] + f * r1, h[k, 2] + f * r2
            y = rk4_augmented(y, f, j, j_inv, jd0, jd1, jd2, denom, tx, ty, tz, h[k, 0], h[k, 1],
                               h[k, 2], hc0, hc1, hc2, step_dist)
            y = _momentum_kept(y, j, j_after_inv)
            j, j_inv = j_after, j_after_inv
            jd0, jd1, jd2, denom = modal_coupling(j_inv, entries)
            changed = True
            y = rk4_augmented(y, dt - f, j, j_inv, jd0, jd1, jd2, denom, tx, ty, tz, hc0, hc1, hc2,
                               h[k + 1, 0], h[k + 1, 1], h[k + 1, 2], step_dist)
        else:
            y = rk4_augmented(y, dt, j, j_inv, jd0, jd1, jd2, denom, tx, ty, tz, h[k, 0], h[k, 1],
                               h[k, 2], h[k + 1, 0], h[k + 1, 1], h[k + 1, 2], step_dist)
    return y[7], y[8]


@nb.njit(cache=True, nogil=True, error_model="numpy")
def _model_tasks(first, last, grid_t, sample_pos, seg_pos, seg_sample, y0, inertia, inertia_after,
                 change_t, tau, tau_index, h, h_index, dist, damping, damping_index, out):
    """Tasks first .. last - 1 of a batch, each a (trajectory, segment) pair: multiple shooting
    makes the segments of a trajectory independent, except that a flexible mode's state carries
    from one segment into the next; a trajectory with a mode runs its segments in order, in the
    task of its first. seg_sample (S,): index of each segment's first sample. The GIL is
    released: threads run disjoint task ranges of one batch side by side (propagate_model_batch). A model
    that blows up divides by zero: numpy's error model gives inf or nan, which its caller
    prices, where Python's would raise (the callees compiled here take this error model; one
    already compiled elsewhere for the same argument types keeps its own).
    """
    n_seg = seg_pos.size - 1
    for task in range(first, last):
        b, s = task // n_seg, task % n_seg
        coupled = np.any(dist[b, _D_DELTA:_D_DELTA + 3] != 0.0) or np.any(dist[b, _D_K0:_D_K0 + 6] != 0.0)
        if coupled and s > 0:
            continue  # the task of segment 0 runs them all
        rest = 0.0 * dist[b, _D_ETA0]  # a mode at rest, of the state's own type
        eta, etad = (dist[b, _D_ETA0], dist[b, _D_ETAD0]) if coupled else (rest, rest)
        for r in range(s, n_seg if coupled else s + 1):
            eta, etad = _model_segment(grid_t, sample_pos, seg_pos[r], seg_pos[r + 1], seg_sample[r],
                                       r == n_seg - 1, y0[b, r], eta, etad, inertia[b],
                                       inertia_after[b], change_t[b], tau[tau_index[b]],
                                       h[h_index[b]], dist[b], damping[damping_index[b]], out[b])


#: RK4 steps a thread must have on average before a batch is split over threads (numba's thread
#: count: what the caller allows, 1 while helper processes run): handing a range to another
#: thread costs tens of microseconds, the time of a few thousand steps.
STEPS_PER_THREAD = 5000


def propagate_model_batch(grid_t, sample_pos, seg_pos, y0, inertia, inertia_after, change_t, tau,
                          h, dist, tau_index=None, h_index=None, damping=None,
                          damping_index=None) -> np.ndarray:
    """Integrate B model trajectories on one time grid (RK4, one step per grid interval) and return
    (q, w) at the sample points: the truth simulator of the effect catalogue and the model that
    diagnose fits, one integrator for both.

    The body obeys J(t) w_dot + h_dot + delta eta_ddot + w x (J(t) w + h + delta eta_dot) = tau +
    the hook's torques (dynamics.state_rate: constant torque, stored momentum, damping, drag per
    axis, gravity gradient) - the dissipation torque, with the flexible mode's equation beside it
    (see Disturbance). J(t) is `inertia` before change_t and `inertia_after` from the first grid
    point at or after it, the momentum J w kept across the change.

    Parameters
    ----------
    grid_t : (m+1,) s, increasing: the sample times and any sub-steps between them.
    sample_pos : (n,) int, increasing grid indices of the samples to return.
    seg_pos : (S+1,) int, grid indices where segments start (multiple shooting: each restarts
        from its own y0; the modal state eta, eta_dot carries over, dist's flex_eta0 and
        flex_eta_dot0 at the first); the last
        entry is m. Every segment start must be a sample position.
    y0 : (B, S, 7) (q (4), w (3) rad/s) at each segment start.
    inertia, inertia_after : (B, 3, 3) kg·m².  change_t : (B,) s (inf: no change).
    tau : (V, m, 3) N·m applied torque, held over each grid interval; tau_index (B,) picks the
        variant of each trajectory (default all 0).
    h : (W, m+1, 3) kg·m²/s known internal momentum at the grid points, linear in between (its
        rate is each interval's slope); h_index (B,) as tau_index.
    dist : (B, DISTURBANCE_SIZE) packed Disturbance vectors.
    damping : (U, m) factor of each trajectory's viscous damping matrix over each grid interval
        (a drag coefficient that changes in time; default 1 throughout); damping_index (B,) as
        tau_index.

    Returns
    -------
    (B, n, 7): q (4) and w (3) rad/s at the samples; complex where y0, the inertias or dist are
    (the run is then complex throughout: a complex step's imaginary part carries the derivative
    of the same discrete steps, estimation/integrator.py).

    """
    batch = y0.shape[0]
    tau_index = np.zeros(batch, np.int64) if tau_index is None else np.asarray(tau_index, np.int64)
    h_index = np.zeros(batch, np.int64) if h_index is None else np.asarray(h_index, np.int64)
    damping = np.ones((1, np.asarray(grid_t).size - 1)) if damping is None else damping
    damping_index = (np.zeros(batch, np.int64) if damping_index is None
                     else np.asarray(damping_index, np.int64))
    # complex y0, inertias or dist make the run complex throughout (complex-step derivatives)
    kind = np.result_type(float, y0, inertia, inertia_after, dist)
    out = np.empty((batch, sample_pos.size, 7), dtype=kind)
    sample_pos, seg_pos = np.asarray(sample_pos, np.int64), np.asarray(seg_pos, np.int64)
    steps = batch * (np.asarray(grid_t).size - 1)
    run_split(_model_tasks, batch * (seg_pos.size - 1), min(nb.get_num_threads(), steps // STEPS_PER_THREAD),
              (np.ascontiguousarray(grid_t, dtype=float), sample_pos, seg_pos,
               np.searchsorted(sample_pos, seg_pos[:-1]), np.ascontiguousarray(y0, dtype=kind),
               np.ascontiguousarray(inertia, dtype=kind), np.ascontiguousarray(inertia_after, dtype=kind),
               np.ascontiguousarray(change_t, dtype=float), np.ascontiguousarray(tau, dtype=float),
               tau_index, np.ascontiguousarray(h, dtype=float), h_index,
               np.ascontiguousarray(dist, dtype=kind), np.ascontiguousarray(damping, dtype=float),
               damping_index, out))
    return out
