"""The output-error fit (estimation/output_error.py): residuals and sensitivities against central
differences, the scale's sensitivity without forcing, a window of the problem, and the
progressive horizon on a long record."""

import dataclasses

import numpy as np
import pytest
from rigid_records import J_TRUE, Q0, W0, grid, model, noisy_problem, start

from inertia_gym.dynamics import quat_exp, quat_mul
from inertia_gym.estimation import ml, output_error
from inertia_gym.estimation.inertia_param import phi_from_inertia


@pytest.mark.parametrize("drag", [None, [0.02, 0.05, -0.01]])
def test_sensitivities_equal_central_differences(drag):
    t, tau, h = grid()
    meas = np.arange(0, t.size, 10)
    phi = phi_from_inertia(J_TRUE)
    p = np.r_[phi, W0, 0.0, 0.0, 0.0, [] if drag is None else drag, 0.01, -0.02, 0.03]
    z_w, z_q = model(t, tau, h, meas, phi, W0, Q0, drag=drag)
    prob = output_error.Problem(t, tau, h, np.ones(t.size, dtype=np.int64), meas, z_w + p[-3:], z_q,
                      np.full(3, 0.03), 0.02, fit_bias=True, fix_scale=False,
                      fit_drag=drag is not None)
    ev = output_error.evaluate(prob, p, Q0, True)
    assert np.abs(ev.r).max() < 1e-9
    numeric = np.zeros_like(ev.jac)
    step = 1e-6
    for j in range(p.size):
        dp = np.zeros(p.size)
        dp[j] = step
        qa, qb = quat_mul(Q0, quat_exp(dp[9:12])), quat_mul(Q0, quat_exp(-dp[9:12]))
        pa, pb = p + dp, p - dp
        pa[9:12] = pb[9:12] = 0.0
        ra, rb = output_error.evaluate(prob, pa, qa, False).r, output_error.evaluate(prob, pb, qb, False).r
        numeric[:, j] = (ra - rb) / (2 * step)
    rel = np.abs(numeric - ev.jac).max(axis=0) / np.abs(numeric).max(axis=0)
    assert rel.max() < 1e-3, rel


def test_scale_sensitivity_is_exactly_zero_without_torque_or_momentum():
    # Scaling J leaves a torque-free body's motion unchanged; a torque pulse moves it.
    t, tau, h = grid(torque=False, momentum=False)
    meas = np.arange(0, t.size, 10)
    z_w, z_q = model(t, tau, h, meas, phi_from_inertia(J_TRUE), W0, Q0)
    prob = output_error.Problem(t, tau, h, np.ones(t.size, dtype=np.int64), meas, z_w, z_q, np.full(3, 0.03),
                      0.02, fit_bias=False, fix_scale=True)
    ev = output_error.evaluate(prob, np.r_[phi_from_inertia(J_TRUE), W0, 0, 0, 0], Q0, True)
    assert np.abs(ev.jac[:, 0]).max() < 1e-9 * np.abs(ev.jac).max()
    with_torque = dataclasses.replace(prob, tau_grid=grid()[1], fix_scale=False)
    forced = output_error.evaluate(with_torque, np.r_[phi_from_inertia(J_TRUE), W0, 0, 0, 0], Q0, True)
    assert np.abs(forced.jac[:, 0]).max() > 1e-5 * np.abs(forced.jac).max()


def test_long_record_converges_from_a_start_outside_a_single_trajectory_basin():
    # 200 s at 10 rad/s: a 1 % inertia error turns the phase by ~20 rad; the progressive
    # horizon still reaches the likelihood's optimum.
    prob = noisy_problem(5, n=20000, every=15)
    p0, cov = start(prob, rel=0.01, seed=5)
    ref = ml.refine(prob, p0, prob.z_q[0], cov, None, "test")
    err = np.linalg.norm(ref.estimate.inertia - J_TRUE) / np.linalg.norm(J_TRUE)
    assert ref.fit.stages > 2
    assert err < 4 * ref.crlb
    assert np.sqrt(np.mean(ref.fit.evaluation.r ** 2)) < 1.1


def test_window_restricts_the_problem_to_its_first_measurements():
    prob = noisy_problem(0, n=500)
    sub = prob.window(10)
    assert sub.meas_idx.size == 10 and sub.t_grid.size == prob.meas_idx[9] + 1
    assert dataclasses.replace(sub, fit_bias=False).n_params == 12




def test_profile_cost_is_the_residual_sum_minimised_over_the_initial_state_at_a_fixed_inertia():
    """profile_cost(J): min over the initial rate and attitude of |r|^2 with J held. At the truth
    on a noise-free record it is zero from a start off the true initial state; an inertia 2 % off
    costs more than the noise's 3M; the inertia is never moved."""
    t, tau, h = grid()
    meas = np.arange(0, t.size, 10)
    phi = phi_from_inertia(J_TRUE)
    z_w, z_q = model(t, tau, h, meas, phi, W0, Q0)
    prob = output_error.Problem(t, tau, h, np.ones(t.size, dtype=np.int64), meas, z_w + [0.01, -0.01, 0.005],
                                z_q, np.full(3, 0.03), 0.02, fit_bias=False, fix_scale=False)
    assert output_error.profile_cost(dataclasses.replace(prob, z_w=z_w), phi, Q0) < 1e-12
    held = output_error.profile_cost(prob, phi, Q0)
    ev = output_error.evaluate(prob, np.r_[phi, W0, 0, 0, 0], Q0, False)
    assert held <= float(ev.r @ ev.r) + 1e-9  # the minimum over w0 is at most the cost at the truth's w0
    assert output_error.profile_cost(prob, phi_from_inertia(J_TRUE * [1.02, 1.0, 1.0]), Q0) > 3 * meas.size
    fixed = dataclasses.replace(prob, fixed_inertia=True)
    assert not fixed.free()[:6].any() and fixed.free()[6:].all()


def test_a_cut_no_trajectory_crosses_is_kept_while_the_crossable_ones_are_joined():
    """A kick the torque log does not hold, at a cut: the trajectory before it cannot follow the
    rows after it, so that cut stays; of the others, no two adjacent ones are dropped."""
    t, tau, h = grid(n=3000)
    meas, jump = np.arange(0, t.size, 5), 300
    phi = phi_from_inertia(J_TRUE)
    w_a, q_a = model(t, tau, h, meas, phi, W0, Q0)
    g = meas[jump]
    w_b, q_b = model(t[g:], tau[g:], h[g:], meas[jump:] - g, phi, w_a[jump] + [0.5, -0.4, 0.3], q_a[jump])
    w_true, q_true = np.r_[w_a[:jump], w_b], np.r_[q_a[:jump], q_b]
    rng = np.random.default_rng(0)
    prob = output_error.Problem(t, tau, h, np.ones(t.size, dtype=np.int64), meas,
                                w_true + 0.03 * rng.standard_normal(w_true.shape), q_true,
                                np.full(3, 0.03), 0.02, fit_bias=True, fix_scale=False)
    seg = np.arange(0, meas.size + 1, 100)
    x = np.r_[phi, np.zeros(3), np.concatenate([np.r_[w_true[a], np.zeros(3)] for a in seg[:-1]])]
    shooting = output_error.Shooting(prob, seg)
    held, _ = shooting.evaluate(x, q_true[seg[:-1]], False)
    stage = output_error._Stage(phi, q_true[0], held, 0, True, x, q_true[seg[:-1]])
    kept = output_error._kept_after_joining(prob, seg, stage)
    np.testing.assert_array_equal(kept, [0, 2, 3, 5])  # cuts at 100 and 400 dropped, 300 kept


def test_a_fitted_drag_never_feeds_the_rotation():
    """Air only takes energy out of a rotation: on records without air, where the noise alone
    would give a free drag coefficient either sign, every fitted c_i stays at or above zero."""
    signs = []
    for seed in range(4):
        prob = dataclasses.replace(noisy_problem(seed, n=1500), fit_drag=True, z_q=None, fit_bias=False)
        p0, _ = start(prob)
        fit = output_error.fit(prob, p0)
        c = fit.p[prob.drag_slice]
        assert np.all(c >= 0.0), c
        signs.append(c)
    assert np.any(np.concatenate(signs) == 0.0)  # the limit binds where the noise pulls below it
