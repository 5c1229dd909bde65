"""The library filter object: same numbers as the filter inside the simulator's closed loop,
textbook quantities exposed, the known internal momentum in its model."""

import numpy as np
import pytest

from inertia_gym.dynamics import euler_to_quat
from inertia_gym.errors import ConfigError
from inertia_gym.estimation import ukf
from inertia_gym.estimation.config import FilterConfig
from inertia_gym.estimation.filters import InertiaFilter
from inertia_gym.estimation.inertia_param import inertia_from_phi, phi_from_inertia
from inertia_gym.estimation.integrator import trajectory
from inertia_gym.simulation import initial_state
from inertia_gym.validation import validate


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ["ekf", "ukf"])
def test_filter_over_validate_readings_reproduces_validate(paper, estimator):
    """Replaying the readings and torques of a validate run through InertiaFilter gives the same
    estimate after every update as the filter inside the compiled closed loop. The run crosses
    a segment boundary (a ~95-s coast, then a burst segment): the closed loop must carry the
    update count and the prediction in progress across it."""
    sc = paper.replace(estimator=estimator)
    res = validate(sc, (0.4, 4.0, 1.0), 150.0, [3])
    start = initial_state(sc, [np.random.default_rng([3, 0])])
    filt = InertiaFilter(FilterConfig.from_scenario(sc), start.x[0], start.P[0])
    steps = np.rint(res.t_meas[0] / sc.dt).astype(int)
    readings = res.measurements[0][:, 7:14]
    m = 0
    for k in range(int(steps.max())):
        filt.predict(sc.dt, res.tau[0, k])
        if m < steps.size and steps[m] == k + 1:
            filt.update(readings[m])
            np.testing.assert_allclose(filt.theta, res.theta_hat[0, m], rtol=1e-10, atol=0)
            m += 1
    assert m == steps.size > 500
    assert np.any(res.tau[0] != 0.0)  # the second segment's burst acted
    np.testing.assert_allclose(filt.inertia, res.inertia_hat[0], rtol=1e-10)


def test_update_exposes_innovation_its_covariance_and_nis(paper):
    cfg = FilterConfig.from_scenario(paper)
    x0 = np.r_[euler_to_quat([0, 0, 0]), 0.5, 10.0, 0.45, phi_from_inertia(np.diag([85.0, 135.0, 210.0]))]
    p0 = np.diag(np.r_[np.full(7, 1e-2), np.full(6, 0.1)])
    filt = InertiaFilter(cfg, x0, p0)
    filt.predict(0.1, np.zeros(3))
    z = np.r_[filt.x[4:7] + 0.01, filt.x[:4]]
    nis = filt.update(z)
    assert filt.y.shape == (7,) and filt.S.shape == (7, 7)
    np.testing.assert_allclose(filt.y[:3], 0.01, atol=1e-12)
    assert nis == pytest.approx(filt.y @ np.linalg.solve(filt.S, filt.y))
    assert not np.allclose(filt.P, filt.P_prior)
    with pytest.raises(ConfigError, match="finite"):
        filt.update(np.full(7, np.nan))


def test_prediction_with_known_internal_momentum_follows_the_momentum_model():
    """With P tiny and no update, predict(dt, tau, h, h_dot) integrates J w_dot + h_dot +
    w x (J w + h) = tau: it matches the output-error model (estimation/integrator.py)."""
    inertia = np.diag([5.2e-4, 2.2e-4, 5.2e-4])
    w0 = np.array([15.0, -6.0, -10.0])
    dt, n = 2.5e-4, 2000
    t = np.arange(n + 1) * dt
    h = np.zeros((n + 1, 3))
    h[:, 2] = -2e-3 * np.sin(np.pi * t / t[-1]) ** 2
    out_w = np.zeros((1, 3))
    trajectory(t, np.zeros((n + 1, 3)), h, np.ones(n + 1, dtype=np.int64), np.array([n]),
               phi_from_inertia(inertia), w0, np.array([1.0, 0, 0, 0]), False, False, out_w,
               np.zeros((1, 3, 12)), np.zeros((1, 4)), np.zeros((1, 3, 12)))
    cfg = FilterConfig(dt=dt, gyro_sigma=0.01, use_quat=False)
    filt = InertiaFilter(cfg, np.r_[1.0, 0, 0, 0, w0, phi_from_inertia(inertia)], 1e-12 * np.eye(13))
    for k in range(n):
        h_mid = 0.5 * (h[k] + h[k + 1])
        filt.predict(dt, None, h_mid, (h[k + 1] - h[k]) / dt)
    np.testing.assert_allclose(filt.x[4:7], out_w[0], atol=2e-3)
    free = InertiaFilter(cfg, np.r_[1.0, 0, 0, 0, w0, phi_from_inertia(inertia)], 1e-12 * np.eye(13))
    free.predict(n * dt)
    assert np.abs(free.x[4:7] - out_w[0]).max() > 0.1  # the momentum matters


def test_bad_start_is_refused():
    cfg = FilterConfig(dt=0.01, gyro_sigma=0.01, use_quat=False)
    with pytest.raises(ConfigError, match="shape"):
        InertiaFilter(cfg, np.zeros(12), np.eye(13))
    with pytest.raises(ConfigError, match="quat_sigma"):
        FilterConfig(dt=0.01, gyro_sigma=0.01, use_quat=True, quat_sigma=0.0)


def test_the_unscented_sigma_points_keep_a_held_state_and_refuse_an_indefinite_covariance():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((13, 13))
    p = a @ a.T + 0.1 * np.eye(13)
    p[7, :] = p[:, 7] = 0.0  # the scale held: its row and column zero
    low, ok = ukf.covariance_root(p)
    assert ok
    np.testing.assert_allclose(low @ low.T, p, atol=1e-12)
    assert np.all(low[:, 7] == 0.0) and np.all(np.triu(low, 1) == 0.0)
    x = np.r_[1.0, 0, 0, 0, 0.1, 0.2, 0.3, np.zeros(6)]
    sigma = np.empty((ukf.N_SIGMA, 13))
    inertia, inertia_inv = np.empty((ukf.N_SIGMA, 3, 3)), np.empty((ukf.N_SIGMA, 3, 3))
    assert ukf.draw_sigma_points(x, p, sigma, inertia, inertia_inv)
    assert np.all(sigma[:, 7] == x[7])  # every point keeps the held value
    np.testing.assert_allclose(sigma.mean(axis=0), x, atol=1e-12)
    indefinite = p.copy()
    indefinite[3, 3] = -1.0
    assert not ukf.covariance_root(indefinite)[1]
    assert not ukf.draw_sigma_points(x, indefinite, sigma, inertia, inertia_inv)
    assert ukf.covariance_root(np.zeros((13, 13)))[1]


def test_each_sigma_points_inertia_and_its_inverse_come_from_its_own_phi():
    rng = np.random.default_rng(3)
    n = ukf.N_SIGMA
    sigma = rng.normal(0.0, 1.0, (n, 13))
    for k in range(n):  # phi of physical bodies near a satellite's
        sigma[k, 7:13] = phi_from_inertia(np.diag([0.06, 0.075, 0.04]) * (1 + 0.1 * rng.random(3)))
    inertia, inverse = np.empty((n, 3, 3)), np.empty((n, 3, 3))
    ukf.sigma_inertias(sigma, inertia, inverse)
    for k in range(n):
        np.testing.assert_allclose(inertia[k], inertia_from_phi(sigma[k, 7:13]), rtol=1e-12)
        np.testing.assert_allclose(inertia[k] @ inverse[k], np.eye(3), atol=1e-12)
