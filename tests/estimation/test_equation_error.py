"""The equation error (estimation/equation_error.py): exact on noiseless forced motion, ratios at a
trace without forcing, unusable samples left out, valid inertias, and intervals that cover."""

import numpy as np
import pytest
from rigid_records import J_TRUE, Q0, W0, grid, model

from inertia_gym.estimation.equation_error import equation_error, equation_error_theta, valid_theta
from inertia_gym.estimation.inertia_param import phi_from_inertia
from inertia_gym.information import inertia_from_theta, theta_from_inertia


def test_equation_error_recovers_the_inertia_from_noiseless_forced_motion():
    t, tau, h = grid(n=3000)
    meas = np.arange(t.size)
    z_w, _ = model(t, tau, h, meas, phi_from_inertia(J_TRUE), W0, Q0, n_sub=4)
    theta = equation_error_theta(t, z_w, tau, h)
    np.testing.assert_allclose(theta, theta_from_inertia(J_TRUE), rtol=0, atol=2e-3 * np.trace(J_TRUE))


def test_equation_error_without_forcing_gives_ratios_at_the_requested_trace():
    t, tau, h = grid(n=3000, torque=False, momentum=False)
    z_w, _ = model(t, tau, h, np.arange(t.size), phi_from_inertia(J_TRUE), W0, Q0, n_sub=4)
    theta = equation_error_theta(t, z_w, trace=1.0)
    assert theta[0] + theta[3] + theta[5] == pytest.approx(1.0)
    np.testing.assert_allclose(theta, theta_from_inertia(J_TRUE) / np.trace(J_TRUE), atol=2e-3)

def test_equation_error_leaves_out_the_windows_that_hold_unusable_samples():
    """Samples flattened at a clip level (as a saturated gyro gives) and marked unusable: the
    windows holding them are left out and the estimate is within 0.3 % of the truth; using them
    costs 2.4x (21 % of the rows clipped) and 20x (42 %, where only the shortest windows stay
    clean)."""
    t, tau, h = grid(n=3000, torque=False, momentum=False)
    z_w, _ = model(t, tau, h, np.arange(t.size), phi_from_inertia(J_TRUE), W0, Q0, n_sub=4)
    trace = float(np.trace(J_TRUE))
    truth = theta_from_inertia(J_TRUE)
    for level in (8.0, 5.0):  # x clipped (its peaks are 9.7 rad/s)
        clipped = z_w.copy()
        clipped[:, 0] = np.clip(z_w[:, 0], -level, level)
        usable = np.abs(z_w[:, 0]) < level
        assert 0.05 < 1 - usable.mean() < 0.8
        left_out = equation_error_theta(t, clipped, tau, h, trace=trace, usable=usable)
        used = equation_error_theta(t, clipped, tau, h, trace=trace)
        assert np.linalg.norm(left_out - truth) < 0.003 * np.linalg.norm(truth)
        assert np.linalg.norm(used - truth) > 2 * np.linalg.norm(left_out - truth)  # 2.4x, 20x


@pytest.mark.parametrize("theta", [[1, 0, 0, 1, 0, -1], [1, 0, 0, 1, 0, 5], [0, 0, 0, 0, 0, 0.0]])
def test_valid_theta_is_positive_definite_and_meets_the_triangle_inequality(theta):
    moments = np.linalg.eigvalsh(inertia_from_theta(valid_theta(np.array(theta, float) + 1e-9)))
    assert moments.min() > 0
    assert moments.max() <= moments.sum() - moments.max() + 1e-12


def test_valid_theta_is_the_inertia_itself_where_a_body_has_it_and_else_the_nearest_one():
    """Inside the realizable set (moments 3, 2, 1.5) theta comes back as it is; beyond the flat
    plate's limit (1, 0.45, 0.05: the largest over the sum of the others) it is the least-squares
    projection with the axes kept, nearest_realizable's (5/6, 37/60, 13/60)."""
    axes = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))[0]

    def theta_of(moments):
        j = (axes * moments) @ axes.T
        return np.array([j[0, 0], j[0, 1], j[0, 2], j[1, 1], j[1, 2], j[2, 2]])

    inside = theta_of([3.0, 2.0, 1.5])
    np.testing.assert_allclose(valid_theta(inside), inside, rtol=0, atol=1e-12)
    beyond = valid_theta(theta_of([1.0, 0.45, 0.05]))
    np.testing.assert_allclose(beyond, theta_of([5 / 6, 37 / 60, 13 / 60]), rtol=0, atol=1e-12)




@pytest.mark.parametrize("forced, sigma", [(True, 0.001), (True, 0.003), (False, 0.01), (False, 0.03)])
def test_the_equation_errors_intervals_cover_over_fixed_seeds(forced, sigma):
    """20 noisy records, with a known torque and momentum (whose signal in the windows is weak:
    the noise's share of A^T A is corrected, else the inertia shrinks 38 % at sigma 0.01) and
    without: the sandwich of the windows' scores gives intervals that hold the truth at about
    their level."""
    truth = theta_from_inertia(J_TRUE)
    t, tau, h = grid(n=3000, torque=forced, momentum=forced)
    w, _ = model(t, tau, h, np.arange(t.size), phi_from_inertia(J_TRUE), W0, Q0, n_sub=4)
    z = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        ee = equation_error(t, w + sigma * rng.normal(size=w.shape), tau, h, trace=float(np.trace(J_TRUE)))
        assert ee.scale_seen == forced
        sd = np.sqrt(np.diag(ee.theta_cov))
        keep = sd > 0
        z.extend(((ee.theta - truth)[keep] / sd[keep]).tolist())
    z = np.array(z)
    assert 0.85 <= np.mean(np.abs(z) <= 1.96) <= 1.0
    assert 0.5 < np.sqrt(np.mean(z ** 2)) < 1.3
