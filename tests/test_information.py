import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from inertia_gym.errors import ConfigError
from inertia_gym.information import (
    cost,
    gram_prefix,
    inertia_from_theta,
    psi,
    soft_min,
    theta_from_inertia,
    window_length,
    window_starts,
    windowed_lambda_min,
)

vec3 = arrays(np.float64, 3, elements=st.floats(-20, 20))
theta6 = arrays(np.float64, 6, elements=st.floats(-200, 200))


@settings(max_examples=200, deadline=None)
@given(w=vec3, w_dot=vec3, theta=theta6)
def test_psi_theta_equals_euler_torque(w, w_dot, theta):
    """Psi(w, w_dot) theta = J w_dot + w x (J w), eq. (6), for any symmetric J."""
    j = inertia_from_theta(theta)
    expected = j @ w_dot + np.cross(w, j @ w)
    assert np.allclose(psi(w, w_dot) @ theta, expected, rtol=1e-10, atol=1e-9)


def test_psi_fixes_the_two_printed_errata():
    w, w_dot = np.array([2.0, 3.0, 5.0]), np.zeros(3)
    p = psi(w, w_dot)
    assert p[0, 5] == pytest.approx(w[1] * w[2])  # printed w_y w_x
    assert p[2, 0] == pytest.approx(-w[0] * w[1])  # printed 0


def test_theta_inertia_round_trip(rng):
    a = rng.standard_normal((5, 3, 3))
    j = a + np.swapaxes(a, 1, 2)
    assert np.allclose(inertia_from_theta(theta_from_inertia(j)), j)


def test_gram_prefix_matches_direct_sum(rng):
    w, w_dot = rng.standard_normal((50, 3)), rng.standard_normal((50, 3))
    prefix = gram_prefix(w, w_dot)
    p = psi(w, w_dot)
    direct = np.einsum("kij,kil->kjl", p, p)
    assert np.allclose(prefix[17] - prefix[5], direct[5:17].sum(0))
    assert np.allclose(prefix[-1], direct.sum(0))


def test_windowed_lambda_min_is_min_eigenvalue_of_regularised_window(rng):
    w, w_dot = rng.standard_normal((40, 3)), rng.standard_normal((40, 3))
    prefix = gram_prefix(w, w_dot)
    p = psi(w, w_dot)
    starts = np.array([0, 3, 30])
    lam = windowed_lambda_min(prefix, starts, 7, 1e-3)
    for s, value in zip(starts, lam):
        g = sum(p[k].T @ p[k] for k in range(s, s + 7)) + 1e-3 * np.eye(6)
        assert value == pytest.approx(np.linalg.eigvalsh(g)[0], rel=1e-9, abs=1e-12)


def test_torque_free_windows_carry_no_scale_information(rng):
    """With w_dot from eq. (12) and tau = 0, theta_hat is in the Gram's null space."""
    j = np.array([[100.0, 6, -4], [6, 80, 3], [-4, 3, 70]])
    w = rng.standard_normal((30, 3)) * 5
    w_dot = np.array([np.linalg.solve(j, -np.cross(x, j @ x)) for x in w])
    lam = windowed_lambda_min(gram_prefix(w, w_dot), np.array([0]), 30, 1e-8)
    assert lam[0] == pytest.approx(1e-8, abs=1e-9)


def test_window_length_and_starts():
    assert window_length(0.01, 0.01) == 5
    assert window_length(0.99, 0.01) == 99
    assert window_length(1.0, 0.01) == 100
    assert list(window_starts(10, 5)) == [0, 1, 2, 3, 4, 5]
    # Only windows overlapping the burst [6, 8) are kept.
    assert list(window_starts(20, 5, np.array([[6, 8]]))) == [2, 3, 4, 5, 6, 7]


def test_soft_min_limits():
    v = np.array([0.3, 1.0, 2.0, 5.0])
    assert soft_min(v, 1e6) == pytest.approx(v.min(), abs=1e-5)
    assert soft_min(v, 1e-8) == pytest.approx(v.mean(), rel=1e-6)
    beta = 2.0
    assert soft_min(v, beta) == pytest.approx(-np.log(np.mean(np.exp(-beta * v))) / beta)
    # Stable for huge values where exp underflows.
    assert soft_min(np.array([1e5, 1e5 + 1]), 10.0) == pytest.approx(1e5 - np.log(np.mean(
        np.exp(-10 * np.array([0.0, 1.0])))) / 10)
    with pytest.raises(ConfigError):
        soft_min(np.array([]), 1.0)


def test_cost_is_negative_log():
    assert cost(1.0, 0.0) == pytest.approx(0.0)
    assert cost(np.e - 1e-8, 1e-8) == pytest.approx(-1.0)
