import dataclasses

import numpy as np
import pytest

from inertia_gym import sensors
from inertia_gym.dynamics import (
    NO_DISTURBANCE,
    Disturbance,
    _state_rate_into,
    euler_to_quat,
    quat_to_rotation,
)
from inertia_gym.errors import ConfigError
from inertia_gym.estimation import ekf
from inertia_gym.estimation.inertia_param import (
    dtheta_dphi,
    inertia_from_phi,
    nearest_realizable,
    phi_from_inertia,
    realizable_face,
    realizable_phi,
    theta_from_phi,
)
from inertia_gym.information import theta_from_inertia
from inertia_gym.simulation import initial_state, pack_filter_config, run_segment

J = np.array([[100.0, 6, -4], [6, 80, 3], [-4, 3, 70]])


def test_log_cholesky_round_trip_and_positive_definite(rng):
    assert np.allclose(inertia_from_phi(phi_from_inertia(J)), J)
    for phi in rng.normal(0, 3, (200, 6)):
        eig = np.linalg.eigvalsh(inertia_from_phi(phi))
        assert eig.min() > 0
    with pytest.raises(ConfigError):
        phi_from_inertia(np.diag([1.0, -1.0, 1.0]))


def test_scale_coordinate_is_pure_scale():
    phi = phi_from_inertia(J)
    shifted = phi.copy()
    shifted[0] += np.log(3.0)
    assert np.allclose(inertia_from_phi(shifted), 3.0 * J)
    assert np.allclose(dtheta_dphi(phi)[:, 0], theta_from_inertia(J))


def _slack(inertia) -> float:
    """(J_min + J_mid - J_max) / trace J: >= 0 for every body, 0 for a flat plate."""
    moments = np.linalg.eigvalsh(inertia)
    return float((moments[0] + moments[1] - moments[2]) / moments.sum())


def test_nearest_realizable_is_the_nearest_mass_distribution(rng):
    """Against its definition: J = trace(S) I - S with S >= 0 (a mass distribution's second
    moment), nearest in the principal moments with J's axes kept; a body's inertia is kept."""
    assert np.array_equal(nearest_realizable(J), J)
    # hand-worked: (1, 0.45, 0.05) moves along (-1, 1, 1) by 1/6 onto J_max = J_mid + J_min
    assert np.allclose(np.linalg.eigvalsh(nearest_realizable(np.diag([1.0, 0.45, 0.05]))),
                       [13 / 60, 37 / 60, 5 / 6])
    for _ in range(20):
        axes = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        moments = np.sort(rng.uniform(0.05, 1.0, 3))
        moments[2] = (moments[0] + moments[1]) * rng.uniform(1.01, 1.5)  # beyond the limit
        bad = axes @ np.diag(moments) @ axes.T
        near = nearest_realizable(bad)
        assert abs(_slack(near)) < 1e-12  # on the limit: a flat plate
        assert np.allclose(axes.T @ near @ axes, np.diag(np.diag(axes.T @ near @ axes)), atol=1e-12)
        # no mass distribution on these axes comes nearer: a grid over S >= 0
        grid = np.stack(np.meshgrid(*[np.linspace(0, 1.5, 61)] * 3), -1).reshape(-1, 3)
        candidates = grid.sum(1, keepdims=True) - grid  # J_i = S_j + S_k
        best = np.min(np.linalg.norm(candidates - moments, axis=1))
        found = np.linalg.norm(np.linalg.eigvalsh(near) - np.sort(moments))
        assert found <= best + 1e-12


def test_realizable_phi_and_its_face_keep_a_fit_on_the_bodies_that_exist(rng):
    phi = phi_from_inertia(J)
    assert np.array_equal(realizable_phi(phi), phi) and realizable_face(phi).shape == (0, 6)
    beyond = phi_from_inertia(np.diag([1.0, 0.45, 0.05]))
    flat = realizable_phi(beyond)
    assert abs(_slack(inertia_from_phi(flat))) < 1e-12
    kept = realizable_phi(beyond, keep_scale=True)  # the scale coordinate held: the shape moves
    assert kept[0] == beyond[0] and abs(_slack(inertia_from_phi(kept))) < 1e-12
    np.testing.assert_allclose(inertia_from_phi(kept), inertia_from_phi(flat) * np.exp(beyond[0] - flat[0]))
    face = realizable_face(flat)
    assert face.shape == (1, 6)
    for _ in range(10):  # a step with face . step = 0 stays on the limit to second order
        step = rng.normal(size=6) * 1e-3
        along = step - face[0] * (face[0] @ step) / (face[0] @ face[0])
        assert abs(_slack(inertia_from_phi(flat + along))) < 1e-5
    across = 1e-3 * face[0] / np.linalg.norm(face[0])
    assert _slack(inertia_from_phi(flat + across)) > 1e-4  # into the bodies that exist


def test_dtheta_dphi_matches_finite_differences(rng):
    for phi in rng.normal(0, 1, (5, 6)):
        num = np.empty((6, 6))
        for j in range(6):
            e = np.zeros(6)
            e[j] = 1e-6
            num[:, j] = (theta_from_phi(phi + e) - theta_from_phi(phi - e)) / 2e-6
        assert np.allclose(dtheta_dphi(phi), num, rtol=1e-6, atol=1e-6)


def _predict(x, tau, n, dt=0.01):
    x = x.copy()
    phi_top = np.zeros((7, 13))
    phi_top[:, :7] = np.eye(7)
    inertia = inertia_from_phi(x[7:])
    for _ in range(n):
        ekf.ekf_predict_step(x, tau, dt, inertia, np.linalg.inv(inertia), phi_top,
                             NO_DISTURBANCE)
    return x, phi_top


def test_rate_rows_of_transition_match_finite_differences():
    """The accumulated analytic transition matches the numerical sensitivity of the mean."""
    x0 = np.r_[euler_to_quat([10, 20, 30]), 0.5, 10.0, 0.45, phi_from_inertia(J)]
    tau = np.array([3.0, -2.0, 4.0])
    _, phi_top = _predict(x0, tau, 15)
    analytic = phi_top[4:7].copy()
    analytic[:, 7:] = phi_top[4:7, 7:] @ dtheta_dphi(x0[7:])
    numeric = np.empty((3, 13))
    for j in range(13):
        e = np.zeros(13)
        e[j] = 1e-6
        numeric[:, j] = (_predict(x0 + e, tau, 15)[0][4:7] - _predict(x0 - e, tau, 15)[0][4:7]) / 2e-6
    # F = I + dt A per step is first order: a few percent over an interval of |w| dt = 1.5 rad.
    assert np.abs(analytic[:, 4:] - numeric[:, 4:]).max() < 0.06 * np.abs(numeric[:, 4:]).max()
    # The scale column is exactly -integral of J^-1 tau: zero without torque.
    _, phi_free = _predict(x0, np.zeros(3), 15)
    assert np.allclose(phi_free[4:7, 7:] @ dtheta_dphi(x0[7:])[:, 0], 0.0, atol=1e-9)


def _rate_of_theta(y, theta, tau):
    """(q_dot, w_dot) of eq. (1) with the inertia given by theta (6,), unnormalised q."""
    t = theta
    inertia = np.array([[t[0], t[1], t[2]], [t[1], t[3], t[4]], [t[2], t[4], t[5]]])
    out = np.empty(7)
    _state_rate_into(y, inertia, np.linalg.inv(inertia), tau, NO_DISTURBANCE, out)
    return out


def test_transition_step_is_identity_plus_dt_jacobian_and_accumulates(rng):
    """One step maps phi_top to (I + dt A) phi_top, A = d(q_dot, w_dot)/d(q, w, theta) of the
    model (here by central differences, all 7 rows and 13 columns), and steps compose."""
    dt = 0.01
    theta = theta_from_phi(phi_from_inertia(J))
    tau = np.array([3.0, -2.0, 4.0])
    steps = []
    for _ in range(2):
        q = rng.normal(size=4)
        y = np.r_[q / np.linalg.norm(q), rng.normal(0, 3, 3)]
        jac = np.empty((7, 13))
        for j in range(13):
            e = np.zeros(13)
            e[j] = 1e-6
            plus, minus = np.r_[y, theta] + e, np.r_[y, theta] - e
            jac[:, j] = (_rate_of_theta(plus[:7], plus[7:], tau)
                         - _rate_of_theta(minus[:7], minus[7:], tau)) / 2e-6
        big = np.eye(13)
        big[:7] += dt * jac
        steps.append((np.r_[y, phi_from_inertia(J)], big))
    phi_top = np.eye(7, 13)
    inertia = inertia_from_phi(phi_from_inertia(J))
    ekf.accumulate_transition(steps[0][0], inertia, np.linalg.inv(inertia), tau, dt, phi_top,
                              NO_DISTURBANCE)
    assert np.allclose(phi_top, steps[0][1][:7], rtol=0, atol=1e-9)
    ekf.accumulate_transition(steps[1][0], inertia, np.linalg.inv(inertia), tau, dt, phi_top,
                              NO_DISTURBANCE)
    assert np.allclose(phi_top, (steps[1][1] @ steps[0][1])[:7], rtol=0, atol=1e-9)


def test_vector_sensor_jacobian_matches_finite_differences(rng):
    q = euler_to_quat([40, -10, 70])
    v = np.array([0.2, 0.0, 0.45])
    out, jac = sensors.body_vector_and_jacobian(q, v)
    assert np.allclose(out, quat_to_rotation(q).T @ v)
    num = np.empty((3, 4))
    for j in range(4):
        e = np.zeros(4)
        e[j] = 1e-7
        num[:, j] = (sensors.body_vector_and_jacobian(q + e, v)[0]
                     - sensors.body_vector_and_jacobian(q - e, v)[0]) / 2e-7
    assert np.allclose(jac, num, atol=1e-6)


def test_update_keeps_covariance_symmetric_positive_definite(paper, rng):
    state = initial_state(paper, [rng])
    x, P = state.x[0].copy(), state.P[0].copy()
    cfg = pack_filter_config(paper)
    z = np.r_[x[4:7] + 0.05, x[0:4]]
    ekf.ekf_update(x, P, z, cfg)
    assert np.allclose(P, P.T)
    assert np.linalg.eigvalsh(P).min() > 0
    assert np.linalg.norm(x[0:4]) == pytest.approx(1.0)


def test_covariance_prediction_equals_its_definition(paper, rng):
    """P^- = Phi P Phi^T + Q_k with Phi = [[phi_top (theta columns times D)], [0, I6]] and
    Q_k = alpha_k blkdiag(Q_q I4, Q_w I3, Q_phi), Q_phi = D^-1 Q_theta D^-T with the scale-shape
    entries zero, alpha_k = 0.999 gamma^k + q_min (paper, simulation section)."""
    state = initial_state(paper, [rng])
    cfg = pack_filter_config(paper)
    a = rng.normal(size=(13, 13))
    spread = a @ a.T
    x, P = state.x[0].copy(), state.P[0] + 1e-2 * (spread + spread.T)  # exactly symmetric
    phi_top = np.eye(7, 13) + 0.1 * rng.normal(size=(7, 13))
    phi_top[4:7, 0:4] = 0.0  # the rate rows do not depend on the attitude
    n_updates = 7
    d = dtheta_dphi(x[7:13])
    big_phi = np.eye(13)
    big_phi[:7, :7] = phi_top[:, :7]
    big_phi[:7, 7:] = phi_top[:, 7:] @ d
    d_inv = np.linalg.inv(d)
    q_phi = paper.Q_theta * d_inv @ d_inv.T
    q_phi[0, 1:] = q_phi[1:, 0] = 0.0
    alpha = 0.999 * paper.alpha_gamma**n_updates + paper.alpha_qmin
    q_k = alpha * np.block([
        [np.diag([paper.Q_quat] * 4 + [paper.Q_omega] * 3), np.zeros((7, 6))],
        [np.zeros((6, 7)), q_phi],
    ])
    expected = big_phi @ P @ big_phi.T + q_k
    ekf.propagate_covariance(P, phi_top, x, n_updates, cfg, np.empty((14, 13)))
    assert np.allclose(P, expected, rtol=1e-10, atol=1e-12 * np.abs(expected).max())
    assert np.array_equal(P, P.T)


@pytest.mark.parametrize("vector_sensors", [False, True])
def test_update_equals_textbook_joseph_form(paper, rng, vector_sensors):
    """With the NIS gate and the step limit off, the update is the textbook EKF update:
    K = P H^T S^-1, x += K (z - h(x)), P = (I - K H) P (I - K H)^T + K R K^T (dense H)."""
    sc = paper.replace(use_vector_sensors=vector_sensors, nis_gate=0.0, inertia_step_limit=0.0)
    state = initial_state(sc, [rng])
    cfg = pack_filter_config(sc)
    a = rng.normal(size=(13, 13))
    x, P = state.x[0].copy(), state.P[0] + 1e-3 * a @ a.T  # dense covariance: all H entries count
    h, big_h = sensors.measurement_model(x, cfg)
    z = h + 0.02 * rng.normal(size=h.shape)
    r = np.diag(sensors.measurement_noise(cfg))
    gain = P @ big_h.T @ np.linalg.inv(big_h @ P @ big_h.T + r)
    i_kh = np.eye(13) - gain @ big_h
    x_ref = x + gain @ (z - h)
    x_ref[:4] /= np.linalg.norm(x_ref[:4])
    p_ref = i_kh @ P @ i_kh.T + gain @ r @ gain.T
    ekf.ekf_update(x, P, z, cfg)
    assert np.allclose(x, x_ref, rtol=1e-10, atol=1e-12)
    assert np.allclose(P, p_ref, rtol=1e-8, atol=1e-10 * np.abs(p_ref).max())


def test_inertia_step_limit_bounds_the_change_of_j(rng):
    """After limiting, ||J(phi + K_phi nu) - J(phi)||_F <= limit ||J(phi)||_F, only the inertia
    rows of the gain are scaled (all by one factor), and a small step is left untouched."""
    x = np.r_[1.0, 0, 0, 0, 0, 0, 0, phi_from_inertia(J)]
    innov = rng.normal(size=7)
    for size, limit in ((0.3, 0.05), (2.0, 0.05), (1e-4, 0.05), (0.3, 0.5)):
        gain = size * rng.normal(size=(13, 7))
        limited_t = gain.T.copy()  # the kernel takes K^T
        ekf.limit_inertia_step(x, limited_t, innov, limit)
        limited = limited_t.T
        step = limited[7:] @ innov
        change = np.linalg.norm(inertia_from_phi(x[7:] + step) - J)
        assert change <= limit * np.linalg.norm(J) * (1 + 1e-12)
        assert np.array_equal(limited[:7], gain[:7])
        factor = limited[7:] / gain[7:]
        assert np.allclose(factor, factor[0, 0]) and 0 < factor[0, 0] <= 1
        unlimited = np.linalg.norm(inertia_from_phi(x[7:] + gain[7:] @ innov) - J)
        if unlimited <= limit * np.linalg.norm(J):
            assert factor[0, 0] == 1.0


def test_quaternion_sign_flip_is_the_same_measurement(paper, rng):
    state = initial_state(paper, [rng])
    cfg = pack_filter_config(paper)
    z = np.r_[state.x[0, 4:7] + 0.01, state.x[0, 0:4]]
    results = []
    for sign in (1.0, -1.0):
        x, P = state.x[0].copy(), state.P[0].copy()
        zz = z.copy()
        zz[3:] *= sign
        ekf.ekf_update(x, P, zz, cfg)
        results.append(x)
    assert np.allclose(results[0], results[1])


def test_zero_torque_never_moves_the_scale(paper):
    rngs = [np.random.default_rng(s) for s in range(2)]
    state = initial_state(paper, rngs)
    s0 = state.x[:, 7].copy()
    state, _ = run_segment(paper, state, 3000, np.zeros((2, 0, 2)), np.zeros(3), np.eye(3)[0],
                           rngs, record_steps=False)
    assert np.allclose(state.x[:, 7], s0)
    assert not state.diverged.any()


def test_divergence_is_reported_not_raised(paper):
    rngs = [np.random.default_rng(0)]
    state = initial_state(paper, rngs)
    bad_p = state.P.copy()
    bad_p[0, 5, 5] = np.nan
    state = dataclasses.replace(state, P=bad_p)
    new, trace = run_segment(paper, state, 100, np.zeros((1, 0, 2)), np.zeros(3), np.eye(3)[0],
                             rngs, record_steps=False)
    assert new.diverged[0]
    assert np.all(np.isfinite(new.y_true))


def test_vector_sensors_run_and_converge_ratios(paper):
    sc = paper.replace(use_vector_sensors=True)
    rngs = [np.random.default_rng(3)]
    state = initial_state(sc, rngs)
    state, trace = run_segment(sc, state, 20000, np.zeros((1, 0, 2)), np.zeros(3), np.eye(3)[0],
                               rngs, record_steps=False)
    j_hat = state.inertia_hat()[0]
    err = np.linalg.norm(j_hat / np.trace(j_hat) - J / np.trace(J)) / np.linalg.norm(J / np.trace(J))
    assert not state.diverged[0]
    assert err < 0.02


def test_ekf_predict_lanes_step_each_lane_as_ekf_predict_step(rng):
    """Lane l of ekf_predict_lanes (mean and transition) is bit for bit the one-run step;
    lanes with on[l] = 0 do not move."""
    lanes = 8
    xs, phis, taus, inertias = [], [], [], []
    for _ in range(lanes):
        q = rng.normal(size=4)
        inertia = J * rng.uniform(0.5, 2.0)
        xs.append(np.r_[q / np.linalg.norm(q), rng.normal(0, 5, 3), phi_from_inertia(inertia)])
        phis.append(np.eye(7, 13) + 0.01 * rng.normal(size=(7, 13)))
        taus.append(rng.normal(size=3))
        inertias.append(inertia)
    on = (np.arange(lanes) % 3 != 1).astype(float)
    dist = Disturbance(constant_torque=(0.1, -0.2, 0.3), internal_momentum=(0.5, 0.0, 1.0)).pack()
    x_lanes = np.array(xs).T.copy()
    phi_lanes = np.array([p.ravel() for p in phis]).T.copy()
    ekf.ekf_predict_lanes(x_lanes, np.array([m.ravel() for m in inertias]).T.copy(),
                          np.array([np.linalg.inv(m).ravel() for m in inertias]).T.copy(),
                          np.array(taus).T.copy(), tuple(dist), 0.01, phi_lanes,
                          np.empty((ekf.N_COEF, lanes)), on)
    for lane in range(lanes):
        x, phi = xs[lane].copy(), phis[lane].copy()
        if on[lane]:
            ekf.ekf_predict_step(x, taus[lane], 0.01, inertias[lane], np.linalg.inv(inertias[lane]),
                                 phi, dist)
        assert np.array_equal(x_lanes[:, lane], x)
        assert np.array_equal(phi_lanes[:, lane], phi.ravel())
