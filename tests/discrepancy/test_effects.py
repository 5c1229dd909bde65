"""The catalogue as a registry of classes, and the truth simulator built on dynamics.state_rate."""

from __future__ import annotations

import numpy as np
import pytest

from inertia_gym.discrepancy.effects import EFFECTS, REGISTRY, Body, Effect, random_params
from inertia_gym.discrepancy.synthetic import simulate_truth
from inertia_gym.scenario import Scenario

BODY = Body(np.diag([70.0, 80.0, 100.0]), 10.0, 50.0, 0.03, 60.0)


def test_registry_is_the_catalogue():
    assert list(EFFECTS) == list(REGISTRY)
    assert "inertia_offset" in REGISTRY and len(REGISTRY) == 14
    for name, model in REGISTRY.items():
        assert model.name == name and EFFECTS[name] == model.params


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_draw_pack_unpack_round_trip(name):
    model = REGISTRY[name]
    params = model.draw(np.random.default_rng(3), BODY)
    assert set(params) == set(model.params)
    p = model.pack(params)
    assert p.shape == (model.size,)
    back = model.unpack(p)
    for key in model.params:
        a, b = np.ravel(params[key]), np.ravel(back[key])
        if name == "flexible_mode" and key == "coupling":  # only delta delta^T is observable
            a, b = np.abs(a), np.abs(b)
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(random_params(name, np.random.default_rng(3), BODY.inertia, 10.0,
                                                50.0, 0.03, 60.0)[model.params[0]],
                                  params[model.params[0]])


def _run(effects, momentum=None, n=400, dt=0.005, torque=None):
    sc = Scenario()
    tau = np.zeros((n, 3)) if torque is None else torque
    return simulate_truth(np.array([1.0, 0.0, 0.0, 0.0]), np.asarray(sc.omega0),
                          sc.inertia_true_array, tau, dt, effects, momentum)


@pytest.mark.parametrize("name", ["constant_body_torque", "internal_momentum", "viscous_damping",
                                  "aero_drag", "gravity_gradient", "inertia_change",
                                  "actuator_scale"])
def test_hook_path_matches_augmented_rk4(name):
    """The compiled path (dynamics.propagate with the disturbance hook) and the augmented RK4
    (taken when a known momentum is given: here zero) integrate the same equations."""
    sc = Scenario()
    body = Body(sc.inertia_true_array, 10.0, 50.0, 0.03, 2.0)
    effect = Effect(name, REGISTRY[name].draw(np.random.default_rng(1), body))
    torque = np.tile([20.0, -10.0, 5.0], (400, 1))
    q1, w1 = _run(effect, torque=torque)
    q2, w2 = _run(effect, momentum=lambda t: (np.zeros(3), np.zeros(3)), torque=torque)
    _, w0 = _run(None, torque=torque)
    np.testing.assert_allclose(w1, w2, atol=1e-9)
    np.testing.assert_allclose(q1, q2, atol=1e-9)
    assert np.abs(w1 - w0).max() > 1e-3  # the effect acted


def _reference(inertia, w0, t_end, extra_torque, flex):
    """Independent integration (scipy, tight tolerances) of the mass-matrix form
    [[J, d], [d^T, 1]] [w_dot, eta_ddot] = [-w x (J w + d eta_dot) + torque, -2 z W eta_dot - W^2 eta].
    """
    from scipy.integrate import solve_ivp

    delta, om, ze = flex

    def rhs(_, y):
        w, eta, eta_d = y[:3], y[3], y[4]
        m = np.zeros((4, 4))
        m[:3, :3], m[:3, 3], m[3, :3], m[3, 3] = inertia, delta, delta, 1.0
        f = np.append(-np.cross(w, inertia @ w + delta * eta_d) + extra_torque(w),
                      -2 * ze * om * eta_d - om * om * eta)
        acc = np.linalg.solve(m, f)
        return np.concatenate([acc, [eta_d], acc[3:]])[[0, 1, 2, 4, 3]]

    sol = solve_ivp(rhs, (0.0, t_end), np.r_[w0, 0.0, 0.0], rtol=1e-11, atol=1e-12)
    return sol.y[:3, -1]


def test_flexible_mode_and_dissipation_truth_match_an_independent_integration():
    sc = Scenario()
    inertia, dt, n = sc.inertia_true_array, 0.002, 1000
    delta = np.array([2.0, -1.0, 1.5])
    flex = Effect("flexible_mode", {"omega_n": 6.0, "zeta": 0.02, "coupling": delta})
    _, w = _run(flex, n=n, dt=dt)
    ref = _reference(inertia, np.asarray(sc.omega0), n * dt, lambda w: np.zeros(3), (delta, 6.0, 0.02))
    np.testing.assert_allclose(w[-1], ref, atol=1e-6)
    _, w_rigid = _run(None, n=n, dt=dt)
    assert np.abs(w[-1] - w_rigid[-1]).max() > 1e-2  # the mode moved the rates

    diss = Effect("internal_dissipation", {"d": 5.0})

    def torque(w):
        u = inertia @ w / np.linalg.norm(inertia @ w)
        return -5.0 * (w - u * (u @ w))

    _, w = _run(diss, n=n, dt=dt)
    ref = _reference(inertia, np.asarray(sc.omega0), n * dt, torque, (np.zeros(3), 1.0, 0.0))
    np.testing.assert_allclose(w[-1], ref, atol=1e-6)
