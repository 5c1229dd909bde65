"""The catalogue as a registry of classes, and the truth simulator (the model diagnose fits)
against an independent integration of each effect's stated equations."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicSpline

from inertia_gym.discrepancy.effects import (
    EFFECTS,
    REGISTRY,
    Body,
    Effect,
    EffectModel,
    inertia6,
    matrix6,
    random_params,
    rotvec_matrix,
)
from inertia_gym.discrepancy.synthetic import gyro_reading, simulate_truth
from inertia_gym.dynamics import Disturbance, propagate, quat_to_rotation

BODY = Body(np.diag([70.0, 80.0, 100.0]), 10.0, 50.0, 0.03, 60.0)
INERTIA = np.array([[100.0, 2.0, -3.0], [2.0, 80.0, 1.5], [-3.0, 1.5, 70.0]])
W0 = np.array([0.5, 3.0, -0.45])
DRAG = np.array([[0.5, 0.2, -0.1], [0.2, 1.5, 0.05], [-0.1, 0.05, 0.2]])  # a plate at an angle
Q0 = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])


def test_registry_is_the_catalogue():
    assert list(EFFECTS) == list(REGISTRY)
    assert "inertia_offset" in REGISTRY and len(REGISTRY) == 15
    for name, model in REGISTRY.items():
        assert model.name == name and EFFECTS[name] == model.params and model.family


def test_each_effect_is_one_class_in_one_module_named_for_it():
    """The catalogue's rule: an effect is one class in one file, inertia_gym/discrepancy/effects/<name>.py."""
    modules = [type(model).__module__ for model in REGISTRY.values()]
    for (name, model), module in zip(REGISTRY.items(), modules):
        assert module == f"inertia_gym.discrepancy.effects.{name}"
        assert Path(sys.modules[module].__file__).name == f"{name}.py"
        defined = [v for v in vars(sys.modules[module]).values()
                   if isinstance(v, type) and issubclass(v, EffectModel) and v.__module__ == module]
        assert defined == [type(model)]
    assert len(set(modules)) == len(modules)


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_draw_pack_unpack_round_trip(name):
    model = REGISTRY[name]
    params = model.draw(np.random.default_rng(3), BODY)
    # a draw gives every parameter but those with a default (a mode that moves no mass: K = 0)
    assert set(params) <= set(model.params) and set(model.params) - set(params) <= set(model.optional)
    p = model.pack(params)
    assert p.shape == (model.size,)
    back = model.unpack(p)
    for key in params:
        a, b = np.ravel(params[key]), np.ravel(back[key])
        if name == "flexible_mode" and key in ("coupling", "eta0", "eta_dot0"):  # delta's sign is
            a, b = np.abs(a), np.abs(b)  # not observable (delta delta^T, delta eta)
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(random_params(name, np.random.default_rng(3), BODY.inertia, 10.0,
                                                50.0, 0.03, 60.0)[model.params[0]],
                                  params[model.params[0]])


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_only_an_effect_that_sets_the_inertia_has_one(name):
    """The model's inertia is read from the effects flagged sets_inertia alone."""
    model = REGISTRY[name]
    params = model.draw(np.random.default_rng(3), BODY)
    assert (model.true_inertia(params) is not None) == model.sets_inertia


def test_a_loaded_mode_round_trips_its_inertia_rate_with_the_coupling_sign():
    """flexible_mode's loaded form: K (6) after the mode's seven; the model depends on delta eta
    and K eta, so K flips with delta when delta's sign is made canonical."""
    model = REGISTRY["flexible_mode"]
    params = {"omega_n": 3.0, "zeta": 0.02, "coupling": [-0.3, 0.1, 0.05], "eta0": 0.01, "eta_dot0": -0.02,
              "inertia_rate": [0.1, -0.2, 0.3, 0.05, 0.0, -0.1]}
    p = model.pack(params)
    assert p.shape == (model.form_size("loaded", None),)
    back = model.unpack(p)
    np.testing.assert_allclose(back["coupling"], -np.asarray(params["coupling"]))
    np.testing.assert_allclose(back["inertia_rate"], -np.asarray(params["inertia_rate"]))
    np.testing.assert_allclose(back["eta0"] * back["inertia_rate"],
                               params["eta0"] * np.asarray(params["inertia_rate"]))
    assert model.nested("loaded", None, p[:7]).tolist() == [*p[:7], 0, 0, 0, 0, 0, 0]


def test_varying_internal_momentum_round_trip():
    model = REGISTRY["internal_momentum"]
    params = {"h": [0.1, -0.2, 0.3], "axis": [0.0, 0.6, 0.8], "profile_t": [0.0, 1.0, 2.0],
              "profile": [0.0, 2.0, 1.5]}
    back = model.unpack(model.pack(params))
    for key, value in params.items():
        np.testing.assert_allclose(back[key], value, atol=1e-12)
    # three knots: the not-a-knot cubic spline is the parabola through them, 3.25 t - 1.25 t^2;
    # beyond the knots it is held at its end values
    h = model.momentum(back, np.array([-1.0, 0.5, 1.5, 3.0]))
    np.testing.assert_allclose(h, np.outer([0.0, 1.3125, 2.0625, 1.5], [0.0, 0.6, 0.8]), atol=1e-12)


def test_varying_internal_momentum_is_the_cubic_spline_through_its_knots():
    # not-a-knot: a cubic through the knots is reproduced exactly, anywhere between them
    cubic = np.polynomial.Polynomial([0.0, 2.0, -3.0, 0.7])
    knots_t = np.array([0.0, 0.3, 1.1, 1.6, 2.4, 3.0])
    params = {"h": np.zeros(3), "axis": np.array([0.6, 0.0, 0.8]), "profile_t": knots_t,
              "profile": cubic(knots_t)}
    t = np.linspace(0.0, 3.0, 301)
    h = REGISTRY["internal_momentum"].momentum(params, t)
    np.testing.assert_allclose(h, np.outer(cubic(t), params["axis"]), atol=1e-12)


# --- an independent reference: scipy's adaptive integrator on the stated equations -----------

def _reference(t_end, torque_at, momentum_at=lambda t: (np.zeros(3), np.zeros(3)), extra=None,
               inertia=INERTIA, flex=None, breaks=(), w0=W0, timed=None):
    """w(t_end) and q(t_end) of J w_dot + h_dot + d eta_ddot + w x (J w + h + d eta_dot) = tau + extra,
    eta_ddot + 2 z W eta_dot + W^2 eta = -d . w_dot, q_dot = q (x) (0, w) / 2, integrated by
    solve_ivp piece by piece between `breaks` (where the torque or h_dot jumps). flex: (d, W, z)
    with the mode at rest at the start, or (d, W, z, eta0, eta_dot0). timed(t, w): a torque that
    also depends on time, added to extra.
    """
    delta, om, ze, eta0, eta_dot0 = (*flex, 0.0, 0.0)[:5] if flex is not None else (np.zeros(3), 0.0, 0.0,
                                                                                    0.0, 0.0)

    def rhs(t, y):
        q, w, eta, eta_d = y[:4], y[4:7], y[7], y[8]
        h, h_dot = momentum_at(t)
        tau = torque_at(t) - h_dot + (extra(q, w, h) if extra else 0.0) + (timed(t, w) if timed else 0.0)
        m = np.zeros((4, 4))
        m[:3, :3], m[:3, 3], m[3, :3], m[3, 3] = inertia, delta, delta, 1.0
        f = np.append(tau - np.cross(w, inertia @ w + h + delta * eta_d),
                      -2 * ze * om * eta_d - om * om * eta)
        acc = np.linalg.solve(m, f)
        qw, qx, qy, qz = q
        q_dot = 0.5 * np.array([-qx * w[0] - qy * w[1] - qz * w[2], qw * w[0] + qy * w[2] - qz * w[1],
                                qw * w[1] - qx * w[2] + qz * w[0], qw * w[2] + qx * w[1] - qy * w[0]])
        return np.concatenate([q_dot, acc[:3], [eta_d, acc[3]]])

    y = np.r_[Q0, w0, eta0, eta_dot0]
    edges = [0.0, *[b for b in breaks if 0 < b < t_end], t_end]
    for a, b in zip(edges[:-1], edges[1:]):
        y = solve_ivp(rhs, (a, b), y, rtol=1e-11, atol=1e-12, method="DOP853").y[:, -1]
    return y[4:7], y[:4] / np.linalg.norm(y[:4])


N, DT = 400, 0.005
T_END = N * DT
TORQUE = np.array([20.0, -10.0, 5.0])


def _truth(effects, torque=None, momentum=None):
    tau = np.tile(TORQUE, (N, 1)) if torque is None else torque
    q, w = simulate_truth(Q0, W0, INERTIA, tau, DT, effects, momentum)
    return w[-1], q[-1]


def _check(effects, ref_w, ref_q=None, torque=None, momentum=None, tol=2e-6):
    w, q = _truth(effects, torque, momentum)
    w_rigid, _ = _truth(())
    np.testing.assert_allclose(w, ref_w, atol=tol)
    if ref_q is not None:
        np.testing.assert_allclose(q, ref_q, atol=tol)
    assert np.abs(w - w_rigid).max() > 100 * tol  # the effect acted


def test_rigid_body_with_torque_matches_reference_and_the_closed_loop_integrator():
    w_ref, q_ref = _reference(T_END, lambda t: TORQUE)
    w, q = _truth(())
    np.testing.assert_allclose(w, w_ref, atol=2e-6)
    np.testing.assert_allclose(q, q_ref, atol=2e-6)
    qp, wp = propagate(Q0, W0, INERTIA, np.tile(TORQUE, (N, 1)), DT)  # the closed loop's RK4
    np.testing.assert_allclose(w, wp[-1], atol=1e-12)
    np.testing.assert_allclose(q, qp[-1], atol=1e-12)


def test_body_torques_match_their_stated_equations():
    nadir = np.array([0.3, -0.2, -0.9]) / np.linalg.norm([0.3, -0.2, -0.9])
    cases = {
        "constant_body_torque": ({"torque": [3.0, -2.0, 1.0]}, lambda q, w, h: np.array([3.0, -2.0, 1.0])),
        "internal_momentum": ({"h": [20.0, 5.0, -10.0]},
                              lambda q, w, h: -np.cross(w, [20.0, 5.0, -10.0])),
        "viscous_damping": ({"c": [2.0, 1.0, 3.0]}, lambda q, w, h: -np.array([2.0, 1.0, 3.0]) * w),
        "aero_drag": ({"c": DRAG}, lambda q, w, h: -np.linalg.norm(w) * DRAG @ w),
        "internal_dissipation": ({"d": 4.0}, None),
        "gravity_gradient": ({"orbit_rate": 0.3, "nadir_inertial": nadir}, None),
    }

    def dissipation(q, w, h):
        u = INERTIA @ w + h
        u = u / np.linalg.norm(u)
        return -4.0 * (w - u * (u @ w))

    def gradient(q, w, h):
        r = quat_to_rotation(q).T @ nadir
        return 3 * 0.3 ** 2 * np.cross(r, INERTIA @ r)

    cases["internal_dissipation"] = (cases["internal_dissipation"][0], dissipation)
    cases["gravity_gradient"] = (cases["gravity_gradient"][0], gradient)
    for name, (params, torque) in cases.items():
        w_ref, q_ref = _reference(T_END, lambda t: TORQUE, extra=torque)
        _check(Effect(name, params), w_ref, q_ref)


def test_actuator_effects_transform_the_applied_torque():
    rot = rotvec_matrix([0.2, -0.1, 0.3])
    w_ref, _ = _reference(T_END, lambda t: 1.3 * TORQUE)
    _check(Effect("actuator_scale", {"scale": 0.3}), w_ref)
    w_ref, _ = _reference(T_END, lambda t: rot @ TORQUE)
    _check(Effect("actuator_misalignment", {"rotvec": [0.2, -0.1, 0.3]}), w_ref)
    # a burst from 0.5 s on, arriving 0.3127 s late (not a multiple of the step: the increment
    # of the running integral splits the step it falls in)
    on = int(0.5 / DT)
    burst = np.zeros((N, 3))
    burst[on:] = TORQUE
    w_ref, _ = _reference(T_END, lambda t: TORQUE * (t >= 0.8127), breaks=[0.8127])
    w, _ = _truth(Effect("actuator_delay", {"delay": 0.3127}), torque=burst)
    np.testing.assert_allclose(w, w_ref, atol=0.02)  # the split step is averaged: O(dt) at one step
    w_late, _ = _truth(Effect("actuator_delay", {"delay": 0.35}), torque=burst)
    assert np.abs(w_late - w).max() > 10 * np.abs(w - w_ref).max()


def test_flexible_mode_matches_the_mass_matrix_form():
    delta = np.array([2.0, -1.0, 1.5])
    w_ref, q_ref = _reference(T_END, lambda t: TORQUE, flex=(delta, 6.0, 0.02))
    _check(Effect("flexible_mode", {"omega_n": 6.0, "zeta": 0.02, "coupling": delta}), w_ref, q_ref)


def test_flexible_mode_swinging_at_the_start_matches_the_mass_matrix_form():
    """A panel already swinging where the recording starts (eta0, eta_dot0): the same equations
    from that state, and not the mode started at rest."""
    delta = np.array([2.0, -1.0, 1.5])
    params = {"omega_n": 6.0, "zeta": 0.02, "coupling": delta, "eta0": 0.4, "eta_dot0": -1.5}
    w_ref, q_ref = _reference(T_END, lambda t: TORQUE, flex=(delta, 6.0, 0.02, 0.4, -1.5))
    _check(Effect("flexible_mode", params), w_ref, q_ref)
    w_rest, _ = _truth(Effect("flexible_mode", {**params, "eta0": 0.0, "eta_dot0": 0.0}))
    assert np.abs(w_rest - w_ref).max() > 1e-3


def test_inertia_change_keeps_the_momentum():
    delta = np.diag([5.0, -3.0, -2.0])
    t_change = 0.8123  # inside a step: the step is split there
    w_mid, q_mid = _reference(t_change, lambda t: TORQUE)
    after = INERTIA + delta
    w_switch = np.linalg.solve(after, INERTIA @ w_mid)

    def rest():
        from scipy.integrate import solve_ivp as ivp

        def rhs(t, y):
            w = y[4:]
            q = y[:4]
            qw, qx, qy, qz = q
            q_dot = 0.5 * np.array([-qx * w[0] - qy * w[1] - qz * w[2], qw * w[0] + qy * w[2] - qz * w[1],
                                    qw * w[1] - qx * w[2] + qz * w[0], qw * w[2] + qx * w[1] - qy * w[0]])
            return np.r_[q_dot, np.linalg.solve(after, TORQUE - np.cross(w, after @ w))]

        return ivp(rhs, (t_change, T_END), np.r_[q_mid, w_switch], rtol=1e-11, atol=1e-12).y[4:, -1]

    _check(Effect("inertia_change", {"t_change": t_change, "delta_inertia": delta}), rest())


def test_known_and_varying_internal_momentum():
    """A rotor's momentum h(t) enters as h and h_dot: given as the known momentum (the
    recording's h columns, linear between rows) as its stated equation says, and as
    internal_momentum's varying form (the cubic spline through its knots) as that spline read
    at the simulator's steps; both within the steps' error of the smooth spline itself."""
    axis, offset = np.array([0.0, 0.6, 0.8]), np.array([1.0, 0.0, -2.0])
    knots_t, knots = np.array([0.0, 0.7, 1.4, 2.0]), np.array([0.0, 30.0, 30.0, 5.0])
    grid_t = np.arange(N + 1) * DT
    spline = CubicSpline(knots_t, knots)
    h_grid = spline(grid_t)[:, None] * axis + offset

    def known_at(t):  # the rows' values, linear between them
        i = min(int(t // DT), N - 1)
        slope = (h_grid[i + 1] - h_grid[i]) / DT
        return h_grid[i] + (t - grid_t[i]) * slope, slope

    w_ref, q_ref = _reference(T_END, lambda t: TORQUE, known_at, breaks=grid_t)
    w, q = _truth((), momentum=h_grid)
    _check((), w_ref, q_ref, momentum=h_grid)
    effect = Effect("internal_momentum", {"h": offset, "axis": axis, "profile_t": knots_t, "profile": knots})
    w_varying, q_varying = _truth(effect)
    np.testing.assert_allclose(w_varying, w, atol=1e-10)
    np.testing.assert_allclose(q_varying, q, atol=1e-10)
    w_smooth, q_smooth = _reference(T_END, lambda t: TORQUE, lambda t: (spline(t) * axis + offset,
                                                                        spline(t, 1) * axis))
    np.testing.assert_allclose(w_varying, w_smooth, atol=2e-5)
    np.testing.assert_allclose(q_varying, q_smooth, atol=2e-5)


def test_sensor_effects_change_only_the_reading():
    w = np.array([[1.0, -2.0, 0.5], [0.3, 0.1, -0.2]])
    t = np.array([0.0, 0.1])
    np.testing.assert_allclose(gyro_reading(t, w, Effect("gyro_bias", {"bias": [0.1, 0.2, -0.3]})),
                               w + [0.1, 0.2, -0.3])
    np.testing.assert_allclose(gyro_reading(t, w, Effect("gyro_scale", {"scale": [0.01, -0.02, 0.03]})),
                               w * [1.01, 0.98, 1.03])


@pytest.mark.parametrize("drag", [0.4, (0.5, 1.5, 0.2), DRAG])
def test_drag_matrix_in_the_closed_loop_hook(drag):
    """dynamics.state_rate's drag hook (isotropic, per axis, a full matrix), as the closed loop
    integrates it."""
    q, w = propagate(Q0, W0, INERTIA, np.tile(TORQUE, (N, 1)), DT, Disturbance(aero_drag=drag))
    c = np.asarray(drag) * np.eye(3) if np.ndim(drag) == 0 else np.diag(drag) if np.ndim(drag) == 1 else drag
    w_ref, _ = _reference(T_END, lambda t: TORQUE, extra=lambda q, w, h: -np.linalg.norm(w) * c @ w)
    np.testing.assert_allclose(w[-1], w_ref, atol=2e-6)


@pytest.mark.parametrize("rank", [1, 2])
def test_drag_face_is_the_tangent_of_its_rank(rank):
    """face() at a C of rank r < 3: rows A with A dp = 0 exactly where n_i^T dC n_j = 0 over C's
    null directions, (3 - r)(4 - r)/2 independent rows; a step along it keeps C positive
    semi-definite to second order (its lowest eigenvalue falls as eps^2, not eps); none at C = 0
    or at a full-rank C."""
    model = REGISTRY["viscous_damping"]
    rot = rotvec_matrix(np.array([0.4, 0.1, -0.6]))
    values = np.array([2.0, 1.0, 0.0])[:rank].tolist() + [0.0] * (3 - rank)
    c = rot @ np.diag(values) @ rot.T
    a = model.face(model.pack({"c": c}))
    k = 3 - rank
    assert a.shape == (k * (k + 1) // 2, 6) and np.linalg.matrix_rank(a) == a.shape[0]
    null = rot[:, rank:]
    rng = np.random.default_rng(rank)
    basis = np.linalg.svd(a)[2][a.shape[0]:]
    for _ in range(5):
        dp = basis.T @ rng.normal(size=basis.shape[0])
        dc = model.unpack(dp)["c"]
        np.testing.assert_allclose(null.T @ dc @ null, 0.0, atol=1e-12)
        drops = [-np.linalg.eigvalsh(c + eps * dc)[0] for eps in (1e-2, 1e-3)]
        assert drops[1] <= 0.02 * max(drops[0], 1e-15) + 1e-15  # eps^2: a tenth of eps -> a hundredth
    assert model.face(np.zeros(6)).shape == (0, 6)
    assert model.face(model.pack({"c": np.diag([1.0, 2.0, 3.0])})).shape == (0, 6)


@pytest.mark.parametrize("name", ["viscous_damping", "aero_drag"])
def test_drag_that_feeds_energy_in_is_projected_out(name):
    """feasible() is the nearest positive semi-definite C (Frobenius): C's eigenvectors kept,
    its negative eigenvalues set to zero; a dissipative C is left as it is."""
    model = REGISTRY[name]
    c_ok = np.array([[2.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(model.unpack(model.feasible(model.pack({"c": c_ok}), np.eye(3)))["c"],
                               c_ok, atol=1e-15)
    rot = rotvec_matrix(np.array([0.3, -0.7, 0.2]))
    c_bad = rot @ np.diag([2.0, -1.0, 0.5]) @ rot.T
    projected = model.unpack(model.feasible(model.pack({"c": c_bad}), np.eye(3)))["c"]
    np.testing.assert_allclose(projected, rot @ np.diag([2.0, 0.0, 0.5]) @ rot.T, atol=1e-12)


def test_the_inertia_after_a_change_is_always_a_bodys():
    """feasible() leaves a change whose J + delta_J a body can have as it is, bit for bit, and
    projects one that no body can have (here indefinite, as unprojected fits on the rotor throws
    leave it) onto the nearest that one can: positive definite, each principal moment at most the
    sum of the other two, and a fixed point of the projection; the change time is kept."""
    model = REGISTRY["inertia_change"]
    inertia = np.array([[0.45, 0.02, 0.0], [0.02, 0.35, 0.01], [0.0, 0.01, 0.2]])  # kg·m²
    small = np.r_[0.3, 0.02, 0.01, 0.0, -0.03, 0.0, 0.01]
    np.testing.assert_array_equal(model.feasible(small, inertia), small)
    wild = np.r_[0.28, -1.665, 1.578, -0.341, -0.35, 2.445, 2.02]
    assert np.linalg.eigvalsh(inertia + matrix6(wild[1:]))[0] < 0
    fixed = model.feasible(wild, inertia)
    assert fixed[0] == wild[0]
    moments = np.linalg.eigvalsh(inertia + matrix6(fixed[1:]))
    assert moments[0] > 0 and moments[2] <= moments[0] + moments[1] + 1e-12
    np.testing.assert_allclose(model.feasible(fixed, inertia), fixed, rtol=0, atol=1e-12)
    # a change that leaves no body near (J + delta_J negative definite) is no change
    gone = np.r_[0.28, inertia6(-3 * inertia)]
    np.testing.assert_array_equal(model.feasible(gone, inertia), np.r_[0.28, np.zeros(6)])


def test_a_flexible_mode_heavier_than_the_body_allows_is_scaled_back():
    """feasible() keeps the modal mass fraction delta^T J^-1 delta of a flexible mode below
    MODE_MASS_LIMIT (at 1 the body and mode's joint mass matrix [[J, delta], [delta^T, 1]] is
    singular): a light mode is left as it is, a heavy one keeps its direction, its frequency and
    damping, and lands on the limit, where the joint mass matrix is positive definite."""
    from inertia_gym.discrepancy.effects import MODE_MASS_LIMIT

    model = REGISTRY["flexible_mode"]
    inertia = np.array([[0.1, 0.01, 0.0], [0.01, 0.12, 0.0], [0.0, 0.0, 0.05]])  # kg·m²
    light = model.pack({"omega_n": 3.0, "zeta": 0.02, "coupling": np.array([0.05, 0.02, 0.03])})
    np.testing.assert_array_equal(model.feasible(light, inertia), light)
    heavy = model.pack({"omega_n": 3.0, "zeta": 0.02, "coupling": np.array([0.3, -0.1, 0.2])})
    fixed = model.feasible(heavy, inertia)
    c = fixed[2:5]
    assert c @ np.linalg.solve(inertia, c) == pytest.approx(MODE_MASS_LIMIT, rel=1e-12)
    np.testing.assert_allclose(c / np.linalg.norm(c), heavy[2:5] / np.linalg.norm(heavy[2:5]), rtol=1e-12)
    np.testing.assert_array_equal(fixed[:2], heavy[:2])
    joint = np.block([[inertia, c[:, None]], [c[None, :], np.ones((1, 1))]])
    assert np.linalg.eigvalsh(joint)[0] > 0


def test_the_modal_screen_reaches_down_to_what_a_long_record_of_a_slow_body_shows():
    """The lowest screened mode: two cycles in the record, no lower than 0.05 Hz or the
    rotation, whichever is lower: 0.05 Hz on the harness's 40 s, lower on a long record of a
    slow body, higher on a short one (a 1-s toss: 2 Hz, not a twentieth of a cycle)."""
    from types import SimpleNamespace

    from inertia_gym.discrepancy.effects import flex_floor_hz

    def floor(duration, rate):
        return flex_floor_hz(SimpleNamespace(duration=duration, omega_ref=rate))

    assert floor(40.0, 10.0) == 0.05  # the harness
    assert floor(1.0, 20.0) == 2.0 and floor(0.5, 30.0) == 4.0  # a racquet toss, a rotor throw
    assert floor(1200.0, 0.02) == pytest.approx(0.02 / (2 * np.pi))  # a slow stage: its rotation
    assert floor(1200.0, 1e-3) == pytest.approx(2.0 / 1200.0)  # nearly still: two cycles in 20 min
    assert floor(60.0, 0.3) == pytest.approx(0.3 / (2 * np.pi))


def test_a_modes_damping_ratio_reaches_past_critical_until_its_poles_span_the_band():
    """flexible_mode's damping ratio is bounded by zeta_max: an overdamped mode's two poles
    omega_n (zeta -+ sqrt(zeta^2 - 1)) are as far apart as the band of modal frequencies the fit
    may take (mode_band) at zeta_max, and never less than critical damping."""
    from types import SimpleNamespace

    from inertia_gym.discrepancy.effects import flex_floor_hz
    from inertia_gym.discrepancy.effects.flexible_mode import mode_band, zeta_max

    records = [(40.0, 10.0, 0.1), (1.0, 20.0, 0.01), (0.5, 30.0, 2.5e-4), (1200.0, 0.02, 0.5)]
    for duration, rate, dt in records:
        d = SimpleNamespace(duration=duration, omega_ref=rate, dt=dt)
        lo, hi = mode_band(d)
        zeta = zeta_max(d)
        assert lo == pytest.approx(np.pi * flex_floor_hz(d)) and hi == pytest.approx(0.5 * np.pi / dt)
        slow, fast = zeta - np.sqrt(zeta ** 2 - 1.0), zeta + np.sqrt(zeta ** 2 - 1.0)
        assert hi / lo - 2.5 < fast / slow <= hi / lo  # 4 zeta^2 - 2 + O(1 / zeta^2) at zeta_max
        lb, ub = REGISTRY["flexible_mode"].bounds("", d)
        assert (lb[1], ub[1]) == (0.0, zeta) and (lb[0], ub[0]) == (lo, hi)
    tiny = SimpleNamespace(duration=1.0, omega_ref=20.0, dt=0.2)  # a band narrower than 4:1
    assert zeta_max(tiny) == 1.0


def test_the_pole_spread_is_where_the_modes_characteristic_roots_lie():
    """pole_spread(zeta) = r: the roots of s^2 + 2 zeta omega_n s + omega_n^2 are -omega_n r and
    -omega_n / r past critical damping, and both have magnitude omega_n (r = 1) below it."""
    from inertia_gym.discrepancy.effects.flexible_mode import pole_spread

    omega = 2.5
    for zeta in (0.03, 0.7, 1.0, 1.5, 3.0, 11.0):
        roots = np.roots([1.0, 2 * zeta * omega, omega ** 2])
        r = pole_spread(zeta)
        if zeta > 1.0:
            assert sorted(-roots.real) == pytest.approx([omega / r, omega * r], rel=1e-9)
        else:
            assert r == 1.0 and np.abs(roots) == pytest.approx([omega, omega], rel=1e-6)


def test_varying_viscous_damping_matches_its_stated_equation():
    """-s(t) C w, s piecewise linear through its knots: the truth simulator (the model diagnose
    fits; s held over each step at the step's mean) against the reference with s(t) exact."""
    knots_t, knots = np.array([0.0, 0.8, 2.0]), np.array([1.0, 3.0, 0.5])
    effect = Effect("viscous_damping", {"c": DRAG, "profile_t": knots_t, "profile": knots})
    w_ref, q_ref = _reference(T_END, lambda t: TORQUE, breaks=knots_t,
                              timed=lambda t, w: -np.interp(t, knots_t, knots) * DRAG @ w)
    _check(effect, w_ref, q_ref)
    w_flat, _ = _truth(Effect("viscous_damping", {"c": DRAG}))
    assert np.abs(_truth(effect)[0] - w_flat).max() > 1e-2  # the factor acted


def test_varying_viscous_damping_round_trip_and_its_fitted_layout():
    model = REGISTRY["viscous_damping"]
    params = {"c": DRAG, "profile_t": [0.0, 1.0, 2.0, 3.0], "profile": [1.0, 2.0, 0.5, 0.0]}
    back = model.unpack(model.pack(params))
    for key, value in params.items():
        np.testing.assert_allclose(back[key], value, atol=1e-12)
    np.testing.assert_allclose(model.damping_factor(back, np.array([0.5, 2.5])), [1.5, 0.25])
    assert model.damping_factor(model.unpack(model.pack({"c": DRAG})), np.zeros(2)) is None

    class Rows:  # what the form's layout reads of the prepared record
        def __init__(self, n_rows):
            self.n_rows, self.t, self.j_ref = n_rows, np.linspace(0.0, 2.0, 5), 1.0

    assert model.forms(Rows(47)) == ("",)  # fewer than 4 knots' worth of rows: constant only
    d = Rows(100)
    k = model.knots(d)
    assert model.forms(d) == ("", "varying") and k == 8
    lo, hi = model.bounds("varying", d)
    held = model.held("varying", d)
    assert model.form_size("varying", d) == lo.size == held.size == 6 + 2 * k
    assert np.all(lo[6 + k:] == 0.0) and np.all(np.isinf(lo[:6]))  # the factor is never negative
    assert held[6:6 + k + 1].all() and not held[:6].any() and not held[6 + k + 1:].any()
    p = np.r_[model.pack({"c": -DRAG})[:6], model.neutral("varying", d, None)[6:]]
    assert np.all(np.linalg.eigvalsh(model.unpack(model.feasible(p, None))["c"]) >= -1e-12)
    np.testing.assert_array_equal(model.feasible(p, None)[6:], p[6:])  # the profile untouched


def test_the_flights_cross_product_is_numpys():
    """aero_drag's flight torque takes n x (K u) row by row: the same numbers as np.cross."""
    from inertia_gym.discrepancy.effects.aero_drag import _cross
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=3), rng.normal(size=(50, 3)) * 10.0 ** rng.uniform(-8, 8, (50, 1))
    np.testing.assert_array_equal(_cross(a, b), np.cross(a, b))
