import numpy as np
import pytest
from scipy.integrate import solve_ivp

from inertia_gym.dynamics import (
    DISTURBANCE_SIZE,
    Disturbance,
    euler_to_quat,
    pack_fields,
    propagate,
    propagate_batch,
    quat_mul,
    quat_to_rotation,
    rk4_lanes,
    rk4_step_into,
)
from inertia_gym.errors import ConfigError
from inertia_gym.model_dynamics import propagate_model_batch

J = np.array([[100.0, 6, -4], [6, 80, 3], [-4, 3, 70]])


def _reference(q0, w0, inertia, tau, t_end, dist_torque=None):
    """scipy DOP853 at tight tolerance, from the textbook equations."""
    inv = np.linalg.inv(inertia)

    def rhs(_, y):
        q, w = y[:4], y[4:]
        extra = np.zeros(3) if dist_torque is None else dist_torque(q, w)
        dq = 0.5 * quat_mul(q, np.r_[0.0, w])
        dw = inv @ (tau + extra - np.cross(w, inertia @ w))
        return np.r_[dq, dw]

    return solve_ivp(rhs, (0, t_end), np.r_[q0, w0], method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]


@pytest.mark.parametrize("method", ["rk4", "gauss"])
def test_torque_free_invariants_over_1000s_at_paper_rate(paper, method):
    q0 = euler_to_quat(paper.attitude0_euler_deg)
    w0 = np.array(paper.omega0)
    q, w = propagate(q0, w0, J, np.zeros((100_000, 3)), 0.01, method=method)
    energy = 0.5 * np.einsum("ni,ij,nj->n", w, J, w)
    # Angular momentum in the inertial frame: h_I = R(q) J w (constant vector, not just its norm).
    h_inertial = np.array([quat_to_rotation(qk) @ (J @ wk) for qk, wk in zip(q[::500], w[::500])])
    assert np.abs(energy / energy[0] - 1).max() < 1e-6
    assert np.abs(h_inertial - h_inertial[0]).max() / np.linalg.norm(h_inertial[0]) < 1e-6
    assert np.abs(np.linalg.norm(q, axis=1) - 1).max() < 1e-12


def test_matches_high_accuracy_reference_with_torque():
    q0 = euler_to_quat([10, -20, 30])
    w0 = np.array([0.5, 10.0, 0.45])
    tau = np.array([3.0, -1.0, 2.0])
    q, w = propagate(q0, w0, J, np.tile(tau, (300, 1)), 0.01)
    ref = _reference(q0, w0, J, tau, 3.0)
    assert np.allclose(w[-1], ref[4:], atol=1e-6)
    assert np.allclose(q[-1] * np.sign(q[-1][0] * ref[0]), ref[:4], atol=1e-6)


@pytest.mark.parametrize("method", ["rk4", "gauss"])
def test_order_four_convergence(method):
    q0, w0 = euler_to_quat([0, 0, 0]), np.array([1.0, 8.0, 2.0])
    ref = _reference(q0, w0, J, np.zeros(3), 2.0)
    errs = []
    for n in (50, 100, 200):
        _, w = propagate(q0, w0, J, np.zeros((n, 3)), 2.0 / n, method=method)
        errs.append(np.linalg.norm(w[-1] - ref[4:]))
    assert errs[0] / errs[1] > 12 and errs[1] / errs[2] > 12  # 2^4 = 16


def test_torque_changes_inertial_momentum_by_its_impulse():
    q0, w0 = euler_to_quat([5, 5, 5]), np.array([0.3, 2.0, -0.5])
    tau = np.array([1.0, -2.0, 0.5])
    n, dt = 200, 0.005
    q, w = propagate(q0, w0, J, np.tile(tau, (n, 1)), dt)
    h = np.array([quat_to_rotation(qk) @ (J @ wk) for qk, wk in zip(q, w)])
    impulse = sum(0.5 * dt * (quat_to_rotation(q[k]) + quat_to_rotation(q[k + 1])) @ tau
                  for k in range(n))
    assert np.allclose(h[-1] - h[0], impulse, atol=1e-4)


def test_disturbance_hook_matches_reference():
    dist = Disturbance(constant_torque=(0.1, 0.0, -0.2), internal_momentum=(0.0, 1.0, 0.0),
                       damping=np.diag([0.5, 0.2, 0.1]).tolist(), aero_drag=0.05,
                       orbit_rate=0.2, nadir_inertial=(0.0, 0.0, -1.0))

    def torque(q, w):
        r_b = quat_to_rotation(q).T @ np.array([0.0, 0.0, -1.0])
        return (np.array([0.1, 0, -0.2]) - np.cross(w, [0.0, 1.0, 0.0]) - np.diag([0.5, 0.2, 0.1]) @ w
                - 0.05 * np.linalg.norm(w) * w + 3 * 0.2**2 * np.cross(r_b, J @ r_b))

    q0, w0 = euler_to_quat([20, 10, -30]), np.array([1.0, 3.0, -2.0])
    q, w = propagate(q0, w0, J, np.zeros((200, 3)), 0.01, dist)
    ref = _reference(q0, w0, J, np.zeros(3), 2.0, torque)
    assert np.allclose(w[-1], ref[4:], atol=1e-6)


def test_an_internal_dissipation_matches_its_torque_and_keeps_the_momentum():
    """The rigid-body RK4 applies the dissipation torque -d (w - u (u . w)), u along J w: the
    trajectory is the reference's, |J w| stays and the energy falls."""
    d = 50.0

    def torque(q, w):
        u = J @ w / np.linalg.norm(J @ w)
        return -d * (w - u * (u @ w))

    q0, w0 = euler_to_quat([20, 10, -30]), np.array([1.0, 3.0, -2.0])
    q, w = propagate(q0, w0, J, np.zeros((300, 3)), 0.01, Disturbance(dissipation=d))
    np.testing.assert_allclose(w[-1], _reference(q0, w0, J, np.zeros(3), 3.0, torque)[4:], atol=1e-6)
    momentum = np.linalg.norm(w @ J, axis=1)
    energy = np.einsum("ni,ij,nj->n", w, J, w)
    assert np.ptp(momentum) < 1e-6 * momentum[0]
    assert energy[-1] < 0.98 * energy[0] and np.all(np.diff(energy) <= 0.0)


@pytest.mark.parametrize("method, dist, words", [
    ("rk4", Disturbance(flex_omega=3.0, flex_coupling=(0.1, 0.0, 0.0)), "flexible mode"),
    ("gauss", Disturbance(dissipation=1.0), "dissipation")])
def test_the_rigid_body_steps_refuse_what_they_cannot_integrate(method, dist, words):
    with pytest.raises(ConfigError, match=words):
        propagate(euler_to_quat([0, 0, 0]), np.ones(3), J, np.zeros((5, 3)), 0.01, dist, method)


def test_batch_equals_single_runs(rng):
    q0 = np.array([euler_to_quat(a) for a in rng.uniform(-90, 90, (3, 3))])
    w0 = rng.standard_normal((3, 3))
    tau = rng.standard_normal((3, 50, 3))
    qb, wb = propagate_batch(q0, w0, J, tau, 0.01)
    for b in range(3):
        q, w = propagate(q0[b], w0[b], J, tau[b], 0.01)
        assert np.array_equal(w, wb[b]) and np.array_equal(q, qb[b])


def test_euler_to_quat_matches_rotation_composition():
    roll, pitch, yaw = np.radians([30.0, -20.0, 75.0])
    rx = np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]])
    ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]])
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    assert np.allclose(quat_to_rotation(euler_to_quat([30, -20, 75])), rz @ ry @ rx)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(torque=np.zeros((5, 2))), "torque"),
        (dict(dt=0.0), "dt"),
        (dict(dt=-0.01), "dt"),
        (dict(w0=np.array([np.nan, 0, 0])), "omega0"),
        (dict(torque=np.full((5, 3), np.inf)), "torque"),
    ],
)
def test_bad_inputs_raise_config_error(kwargs, field):
    args = dict(q0=np.array([1.0, 0, 0, 0]), w0=np.zeros(3), torque=np.zeros((5, 3)), dt=0.01)
    args.update(kwargs)
    with pytest.raises(ConfigError, match=field):
        propagate(args["q0"], args["w0"], J, args["torque"], args["dt"])


@pytest.mark.filterwarnings("error::RuntimeWarning")  # bad input: one ConfigError, no warning
def test_disturbance_validation():
    with pytest.raises(ConfigError, match="damping"):
        Disturbance(damping=(1.0, 2.0)).pack()
    with pytest.raises(ConfigError, match="nadir"):
        Disturbance(nadir_inertial=(0.0, 0.0, 0.0)).pack()
    for field, value in [("flex_coupling", (0.0, np.nan, 0.0)), ("orbit_rate", np.inf),
                         ("nadir_inertial", (0.0, np.inf, 1.0)), ("dissipation", np.nan)]:
        with pytest.raises(ConfigError, match=f"{field} must be finite"):
            Disturbance(**{field: value}).pack()
    with pytest.raises(ConfigError, match="unknown disturbance term 'drag'"):
        pack_fields({"drag": 1.0})
    # the terms not given take the dataclass's defaults
    fields = {"aero_drag": (1.0, 2.0, 3.0), "flex_coupling": (0.1, 0.2, 0.3)}
    np.testing.assert_array_equal(pack_fields(fields), Disturbance(**fields).pack())
    np.testing.assert_array_equal(pack_fields({}), Disturbance().pack())


def test_gauss_keeps_invariants_to_round_off_at_fast_spin():
    w0 = np.array([3.0, 30.0, 2.0])  # |w| dt = 0.3: RK4 drifts, Gauss-Legendre does not
    w = propagate(euler_to_quat([0, 0, 0]), w0, J, np.zeros((20_000, 3)), 0.01, method="gauss")[1]
    energy = 0.5 * np.einsum("ni,ij,nj->n", w, J, w)
    assert np.abs(energy / energy[0] - 1).max() < 1e-11


def test_unknown_integrator_is_rejected():
    with pytest.raises(ConfigError, match="method"):
        propagate(np.array([1.0, 0, 0, 0]), np.zeros(3), J, np.zeros((2, 3)), 0.01, method="euler")


def test_rk4_lanes_step_each_lane_as_rk4_step_into_and_leave_the_masked_ones(rng):
    """Lane l of rk4_lanes is bit for bit the one-run step; lanes with on[l] = 0 do not move."""
    lanes = 8
    inertias = [J * (1 + 0.1 * k) for k in range(lanes)]
    dist = Disturbance(constant_torque=(0.1, 0, -0.2), internal_momentum=(0.5, 0, 1),
                       aero_drag=0.01, orbit_rate=0.001).pack()
    q = rng.normal(size=(lanes, 4))
    y = np.c_[q / np.linalg.norm(q, axis=1, keepdims=True), rng.normal(0, 5, (lanes, 3))]
    tau = rng.normal(size=(lanes, 3))
    on = (np.arange(lanes) % 3 != 1).astype(float)
    y_lanes = np.ascontiguousarray(y.T)
    rk4_lanes(y_lanes, np.array([m.ravel() for m in inertias]).T.copy(),
              np.array([np.linalg.inv(m).ravel() for m in inertias]).T.copy(),
              np.ascontiguousarray(tau.T), tuple(dist), 0.01, on)
    for lane in range(lanes):
        expected = y[lane].copy()
        if on[lane]:
            rk4_step_into(y[lane], 0.01, inertias[lane], np.linalg.inv(inertias[lane]), tau[lane],
                          dist, expected)
        assert np.array_equal(y_lanes[:, lane], expected)


def _segment_alone(grid_t, sample_pos, seg_pos, y0, inertia, after, change_t, tau, h, dist, s):
    """Segment s of a multiple-shooting record integrated as a record of its own."""
    a, b = seg_pos[s], seg_pos[s + 1]
    samples = sample_pos[(sample_pos >= a) & (sample_pos <= b)]
    return propagate_model_batch(grid_t[a:b + 1], samples - a, np.array([0, b - a]), y0[:, s:s + 1],
                                 inertia, after, change_t, tau[:, a:b], h[:, a:b + 1], dist)


def test_model_segments_are_independent_but_a_flexible_mode_carries_over(rng):
    """Multiple shooting: without a flexible mode each segment (computed as its own parallel
    task) is exactly that segment integrated alone, an inertia change before its start included;
    with a mode, its state runs on from the segment before (alone, a segment starts at rest).
    """
    substeps = rng.integers(1, 4, 299)
    sample_pos = np.r_[0, np.cumsum(substeps)]
    grid_t = np.interp(np.arange(sample_pos[-1] + 1), sample_pos, np.linspace(0.0, 6.0, 300))
    seg_pos = np.r_[sample_pos[[0, 80, 190]], sample_pos[-1]]
    y0 = np.zeros((2, 3, 7))
    y0[..., 0] = 1.0
    y0[..., 4:] = rng.normal(0.0, 1.0, (2, 3, 3))
    inertia = np.tile(np.diag([3.0, 2.0, 1.5]), (2, 1, 1))
    after = inertia + 0.2 * np.eye(3)
    change_t = np.full(2, 0.5 * (grid_t[seg_pos[1]] + grid_t[seg_pos[2]]))  # inside segment 1
    tau = rng.normal(0.0, 0.1, (2, sample_pos[-1], 3))
    h = rng.normal(0.0, 0.1, (2, sample_pos[-1] + 1, 3))
    dist = np.zeros((2, DISTURBANCE_SIZE))
    dist[1] = Disturbance(flex_omega=6.0, flex_zeta=0.05, flex_coupling=(0.3, 0.1, 0.0)).pack()
    args = (grid_t, sample_pos, seg_pos, y0, inertia, after, change_t, tau, h, dist)
    whole = propagate_model_batch(*args)
    first = np.searchsorted(sample_pos, seg_pos)
    for s in range(3):
        alone = _segment_alone(*args, s)
        rows = slice(first[s], first[s + 1] if s < 2 else None)
        assert np.array_equal(whole[0, rows], alone[0, :(None if s == 2 else -1)])
        if s == 0:
            assert np.array_equal(whole[1, rows], alone[1, :-1])
        else:  # the mode excited in the segments before moves this one's rates
            assert np.abs(whole[1, rows, 4:] - alone[1, :(None if s == 2 else -1), 4:]).max() > 1e-6


def test_a_batch_split_over_threads_is_the_batch_run_in_one(rng, monkeypatch):
    """propagate_model_batch hands equal task ranges to threads: the trajectories, a flexible
    mode's (whose segments run in its first segment's task) and a complex step's included, are
    the one-thread run's bit for bit."""
    import numba

    import inertia_gym.model_dynamics as model_dynamics

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one thread on this machine: no batch to split")
    n, batch = 400, 7
    grid_t = np.linspace(0.0, 4.0, n)
    sample_pos = np.arange(0, n, 3)
    sample_pos[-1] = n - 1
    seg_pos = np.r_[sample_pos[[0, 40, 90]], n - 1]
    y0 = np.zeros((batch, 3, 7))
    y0[..., 0] = 1.0
    y0[..., 4:] = rng.normal(0.0, 1.0, (batch, 3, 3))
    inertia = np.tile(np.diag([3.0, 2.0, 1.5]), (batch, 1, 1))
    dist = np.zeros((batch, DISTURBANCE_SIZE))
    # a mode on trajectory 3 (tasks 9-11): its segments run in task 9, the split falls at task 10
    dist[3] = Disturbance(flex_omega=6.0, flex_zeta=0.05, flex_coupling=(0.3, 0.1, 0.0)).pack()
    dist[5] = Disturbance(constant_torque=(0.1, 0.0, -0.2)).pack()
    ranges = []
    compiled = model_dynamics._model_tasks

    def recorded(first, last, *rest):
        ranges.append((first, last))
        compiled(first, last, *rest)

    monkeypatch.setattr(model_dynamics, "_model_tasks", recorded)
    tau = rng.normal(0.0, 0.1, (1, n - 1, 3))
    h = rng.normal(0.0, 0.1, (1, n, 3))
    for kind in (float, complex):
        args = (grid_t, sample_pos, seg_pos, y0.astype(kind), inertia.astype(kind),
                inertia.astype(kind), np.full(batch, np.inf), tau, h, dist.astype(kind))
        before = numba.get_num_threads()
        try:
            numba.set_num_threads(1)
            alone = propagate_model_batch(*args)
            numba.set_num_threads(2)
            monkeypatch.setattr(model_dynamics, "STEPS_PER_THREAD", 1)
            ranges.clear()
            split = propagate_model_batch(*args)
        finally:
            numba.set_num_threads(before)
        assert sorted(ranges) == [(0, 10), (10, 21)]
        assert np.array_equal(split, alone)
        assert np.all(np.isfinite(split))


def test_a_model_that_blows_up_gives_non_finite_rates_not_an_error():
    """A trajectory the integrator cannot carry (here a zero quaternion, which it divides by its
    norm) comes back non-finite, for its caller to price; the others in the batch are unaffected."""
    n = 50
    grid_t = np.linspace(0.0, 1.0, n)
    y0 = np.zeros((2, 1, 7))
    y0[1, 0, 0] = 1.0
    y0[:, 0, 4:] = (0.3, 1.0, -0.2)
    inertia = np.tile(np.diag([3.0, 2.0, 1.5]), (2, 1, 1))
    out = propagate_model_batch(grid_t, np.arange(n), np.array([0, n - 1]), y0, inertia, inertia,
                                np.full(2, np.inf), np.zeros((1, n - 1, 3)), np.zeros((1, n, 3)),
                                np.tile(Disturbance().pack(), (2, 1)))
    assert not np.all(np.isfinite(out[0]))
    assert np.all(np.isfinite(out[1]))


def test_skew_is_the_cross_product_matrix(rng):
    """skew(v) @ u = v x u for single vectors and stacks of them."""
    from inertia_gym.dynamics import skew

    v, u = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", skew(v), u), np.cross(v, u), atol=1e-14)
    np.testing.assert_allclose(skew(v[0]) @ u[0], np.cross(v[0], u[0]), atol=1e-14)
    np.testing.assert_allclose(skew(v[0]), -skew(v[0]).T, atol=0)


def _lagrangian_mode(inertia, delta, k, omega, zeta):
    """The rates of (w, eta, eta_dot) of a body with one mode, from its Lagrangian
    T = w^T J(eta) w / 2 + w^T delta eta_dot + eta_dot^2 / 2, V = omega^2 eta^2 / 2, J(eta) = J + K
    eta: [[J(eta), delta], [delta^T, 1]] (w_dot, eta_ddot) = (-K eta_dot w - w x (J(eta) w + delta
    eta_dot), w^T K w / 2 - 2 zeta omega eta_dot - omega^2 eta), solved as a 4x4 system.
    """
    def rhs(_, y):
        w, eta, etad = y[:3], y[3], y[4]
        j = inertia + k * eta
        mass = np.block([[j, delta[:, None]], [delta[None, :], np.ones((1, 1))]])
        force = np.r_[-k @ w * etad - np.cross(w, j @ w + delta * etad),
                      0.5 * w @ k @ w - 2 * zeta * omega * etad - omega ** 2 * eta]
        acc = np.linalg.solve(mass, force)
        return np.r_[acc[:3], etad, acc[3]]
    return rhs


def _model_run(inertia, delta, k, omega, zeta, w0, eta0, t):
    """propagate_model_batch's rates and its packed mode at the samples t (uniform), no torque."""
    k6 = k[np.triu_indices(3)]
    dist = Disturbance(flex_omega=omega, flex_zeta=zeta, flex_coupling=tuple(delta), flex_eta0=eta0,
                       flex_inertia_rate=tuple(k6)).pack()[None]
    y0 = np.zeros((1, 1, 7))
    y0[0, 0, 0], y0[0, 0, 4:] = 1.0, w0
    n = t.size
    out = propagate_model_batch(t, np.arange(n), np.array([0, n - 1]), y0, inertia[None], inertia[None],
                                np.array([np.inf]), np.zeros((1, n - 1, 3)), np.zeros((1, n, 3)), dist)
    return out[0, :, 4:]


@pytest.mark.parametrize("zeta", [0.0, 0.05])
def test_a_mode_that_moves_mass_follows_its_lagrangian(zeta, rng):
    """A mode whose motion changes the inertia (J + K eta) and which the rotation loads
    centrifugally (w^T K w / 2): the compiled model's rates match the Lagrangian's equations
    solved by scipy, and the angular momentum's size is kept (no external torque)."""
    inertia = np.array([[3.0, 0.1, -0.05], [0.1, 2.0, 0.08], [-0.05, 0.08, 1.5]])
    delta = np.array([0.3, -0.2, 0.1])
    k = rng.normal(0.0, 0.4, (3, 3))
    k = 0.5 * (k + k.T)
    w0, omega = np.array([0.4, 1.5, -0.9]), 4.0
    t = np.linspace(0.0, 10.0, 5001)
    w = _model_run(inertia, delta, k, omega, zeta, w0, 0.02, t)
    ref = solve_ivp(_lagrangian_mode(inertia, delta, k, omega, zeta), (0, t[-1]), np.r_[w0, 0.02, 0.0],
                    t_eval=t, method="DOP853", rtol=1e-11, atol=1e-12).y
    np.testing.assert_allclose(w, ref[:3].T, atol=1e-6 * np.abs(w0).max())
    momentum = np.linalg.norm([(inertia + k * e) @ x + delta * ed for x, e, ed in zip(w, ref[3], ref[4])],
                              axis=1)
    assert np.ptp(momentum) < 1e-6 * momentum[0]
    # the centrifugal load is what the mode's inertia rate adds: without it the rates differ
    plain = _model_run(inertia, delta, np.zeros((3, 3)), omega, zeta, w0, 0.02, t)
    assert np.abs(plain - w).max() > 1e-2 * np.abs(w0).max()


def test_the_inverse_of_a_singular_inertia_is_non_finite_not_an_error():
    """inv3 and inv3_entries of a singular matrix (a rod: one moment zero) return inf or nan
    entries, which their callers price or check, from Python and from a compiled caller."""
    from inertia_gym.dynamics import inv3, inv3_entries, mat3_entries

    rod = np.diag([0.0, 2.0, 2.0])
    assert not np.all(np.isfinite(inv3(rod)))
    assert not np.all(np.isfinite(inv3_entries(mat3_entries(rod))))
    np.testing.assert_allclose(inv3(np.diag([1.0, 2.0, 4.0])), np.diag([1.0, 0.5, 0.25]), rtol=1e-15)
