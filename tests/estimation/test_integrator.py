"""The output-error integrator (estimation/integrator.py): its trajectory against the rigid-body
integrator, the drag term's closed form, the invariant a changing internal momentum keeps, and
its sensitivities against an axisymmetric body's closed-form derivatives."""

import numpy as np
from rigid_records import J_TRUE, Q0, W0, grid, model

from inertia_gym.dynamics import propagate, quat_to_rotation
from inertia_gym.estimation.inertia_param import phi_from_inertia
from inertia_gym.estimation.integrator import trajectory


def test_trajectory_without_momentum_equals_the_rigid_body_integrator():
    t, tau, h = grid(momentum=False)
    q, w = propagate(Q0, W0, J_TRUE, tau[:-1], 0.01)
    meas = np.arange(0, t.size, 7)
    out_w, out_q = model(t, tau, h, meas, phi_from_inertia(J_TRUE), W0, Q0)
    np.testing.assert_allclose(out_w, w[meas], atol=1e-10)
    np.testing.assert_allclose(out_q, q[meas], atol=1e-10)


def test_drag_torque_is_the_quadratic_damping_it_claims():
    # d L / dt = -w x L - c (.) |w| w: with w along a principal axis the rate decays as
    # w(t) = w0 / (1 + c w0 t / J) (no gyroscopic coupling), the closed form of J w' = -c w^2.
    inertia = np.diag([2.0, 3.0, 4.0])
    t = np.arange(2001) * 0.001
    zero = np.zeros((t.size, 3))
    meas = np.array([0, 1000, 2000])
    out_w, _ = model(t, zero, zero, meas, phi_from_inertia(inertia), np.array([0.0, 5.0, 0.0]),
                      Q0, drag=[0.0, 0.3, 0.0])
    np.testing.assert_allclose(out_w[:, 1], 5.0 / (1 + 0.3 * 5.0 * t[meas] / 3.0), rtol=1e-9)
    assert np.abs(out_w[:, [0, 2]]).max() < 1e-12


def test_trajectory_with_changing_momentum_keeps_inertial_angular_momentum():
    # J w_dot + h_dot + w x (J w + h) = 0 keeps R(q) (J w + h) constant in the inertial frame.
    t, tau, h = grid(n=4000, torque=False)
    meas = np.arange(0, t.size, 10)
    out_w, out_q = model(t, tau, h, meas, phi_from_inertia(J_TRUE), W0, Q0, n_sub=2)
    total = np.array([quat_to_rotation(q) @ (J_TRUE @ w + hh) for q, w, hh in zip(out_q, out_w, h[meas])])
    assert np.ptp(total, axis=0).max() < 1e-6 * np.linalg.norm(total[0])
    # ... and the momentum really acted (the rate is not that of a free body)
    free_w, _ = model(t, tau, np.zeros_like(h), meas, phi_from_inertia(J_TRUE), W0, Q0, n_sub=2)
    assert np.abs(free_w - out_w).max() > 0.1




def test_sensitivities_are_the_derivatives_of_an_axisymmetric_bodys_closed_form():
    # J = diag(a, a, c), torque-free from w0 = (u, 0, v): w1 = u cos(l t), w2 = u sin(l t), w3 = v,
    # l = (c - a) v / a. phi = (log a, 0, 0, 0, 0, log sqrt(c / a)): dc/dphi_5 = 2 c, and the
    # scale phi_0 moves a and c together, which leaves l unchanged.
    a, c, u, v = 2.0, 3.0, 0.7, 1.3
    t = np.arange(4001) * 0.001
    zero = np.zeros((t.size, 3))
    meas = np.arange(0, t.size, 50)
    out_w, out_sw = np.zeros((meas.size, 3)), np.zeros((meas.size, 3, 12))
    phi = phi_from_inertia(np.diag([a, a, c]))
    assert trajectory(t, zero, zero, np.ones(t.size, dtype=np.int64), meas, phi, np.array([u, 0.0, v]), Q0,
                      True, False, out_w, out_sw, np.zeros((1, 4)), np.zeros((1, 3, 12)))
    tm, lam = t[meas], (c - a) * v / a
    np.testing.assert_allclose(out_w, np.c_[u * np.cos(lam * tm), u * np.sin(lam * tm), np.full(tm.size, v)],
                               atol=1e-9)
    dlam = {5: 2.0 * c * v / a, 8: (c - a) / a}  # dl/dphi_5 and dl/dw0_3
    for col, dl in dlam.items():
        np.testing.assert_allclose(out_sw[:, 0, col], -u * np.sin(lam * tm) * tm * dl, atol=1e-6)
        np.testing.assert_allclose(out_sw[:, 1, col], u * np.cos(lam * tm) * tm * dl, atol=1e-6)
    np.testing.assert_allclose(out_sw[:, :2, 6], np.c_[np.cos(lam * tm), np.sin(lam * tm)], atol=1e-6)
    assert np.abs(out_sw[:, :, 0]).max() < 1e-6
