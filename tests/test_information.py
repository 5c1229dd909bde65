import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from inertia_gym.errors import ConfigError
from inertia_gym.information import (
    cost,
    inertia_from_theta,
    lambda_min,
    psi,
    runs_window_grams,
    soft_min,
    theta_from_inertia,
    window_grams,
    window_length,
    window_starts,
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


def _window_grams_by_definition(w, w_dot, starts, n_window, epsilon):
    """C[t] = sum_{k<t} Psi_k^T Psi_k accumulated in time order, G_bar(s) = C[s+N] - C[s] + eps I."""
    p = psi(w, w_dot)
    g = sum(p[:, r, :, None] * p[:, r, None, :] for r in range(3))
    prefix = np.concatenate([np.zeros((1, 6, 6)), np.cumsum(g, axis=0)])
    return prefix[starts + n_window] - prefix[starts] + epsilon * np.eye(6)


def test_window_grams_are_the_prefix_differences_exactly(rng):
    w, w_dot = rng.standard_normal((60, 3)), rng.standard_normal((60, 3))
    starts = np.array([0, 3, 4, 30, 53])
    grams = window_grams(w, w_dot, starts, 7, 1e-3)
    np.testing.assert_array_equal(grams, _window_grams_by_definition(w, w_dot, starts, 7, 1e-3))
    p = psi(w, w_dot)
    direct = sum(p[k].T @ p[k] for k in range(3, 10)) + 1e-3 * np.eye(6)
    assert np.allclose(grams[1], direct, rtol=1e-12)
    with pytest.raises(ConfigError, match="increasing"):
        window_grams(w, w_dot, starts[::-1], 7, 1e-3)
    with pytest.raises(ConfigError, match="fit"):
        window_grams(w, w_dot, starts, 8, 1e-3)


def test_runs_window_grams_equal_each_run_alone(rng):
    lengths, n_window = [40, 25, 33], [5, 7, 3]
    w, w_dot = rng.standard_normal((3, 40, 3)), rng.standard_normal((3, 40, 3))
    starts = [np.array([0, 1, 20, 35]), np.array([], dtype=int), np.array([2, 30])]
    offsets = np.r_[0, np.cumsum([len(s) for s in starts])]
    stacked = runs_window_grams(w, w_dot, np.concatenate(starts), offsets, n_window, 1e-2)
    for r in range(3):
        alone = window_grams(w[r, :lengths[r]], w_dot[r, :lengths[r]], starts[r], n_window[r], 1e-2)
        np.testing.assert_array_equal(stacked[offsets[r]:offsets[r + 1]], alone)


def test_lambda_min_is_min_eigenvalue_of_regularised_window(rng):
    w, w_dot = rng.standard_normal((40, 3)), rng.standard_normal((40, 3))
    p = psi(w, w_dot)
    starts = np.array([0, 3, 30])
    lam = lambda_min(window_grams(w, w_dot, starts, 7, 1e-3))
    for s, value in zip(starts, lam):
        g = sum(p[k].T @ p[k] for k in range(s, s + 7)) + 1e-3 * np.eye(6)
        assert value == pytest.approx(np.linalg.eigvalsh(g)[0], rel=1e-9, abs=1e-12)
    assert lambda_min(np.zeros((0, 6, 6))).shape == (0,)


def test_lambda_min_of_a_stack_split_over_threads_is_each_matrix_alone(rng, monkeypatch):
    import inertia_gym.information as information

    x = rng.standard_normal((information.SPLIT_EIGVALSH + 7, 20, 6))
    grams = np.einsum("wki,wkj->wij", x, x)
    alone = np.array([np.linalg.eigvalsh(g)[0] for g in grams])
    monkeypatch.setattr(information.nb, "get_num_threads", lambda: 2)
    np.testing.assert_array_equal(lambda_min(grams), alone)
    grams[3, 0, 0] = np.nan  # an error in the helper thread's half reaches the caller
    with pytest.raises(np.linalg.LinAlgError):
        lambda_min(grams)


def test_torque_free_windows_carry_no_scale_information(rng):
    """With w_dot from eq. (12) and tau = 0, theta_hat is in the Gram's null space."""
    j = np.array([[100.0, 6, -4], [6, 80, 3], [-4, 3, 70]])
    w = rng.standard_normal((30, 3)) * 5
    w_dot = np.array([np.linalg.solve(j, -np.cross(x, j @ x)) for x in w])
    lam = lambda_min(window_grams(w, w_dot, np.array([0]), 30, 1e-8))
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
