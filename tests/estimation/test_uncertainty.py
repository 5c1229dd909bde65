"""Uncertainty (estimation/uncertainty.py): the normalised covariance, the model error's
covariance where its transition cannot be inverted, the scale's standard deviation, and the
choice between an efficient and a robust estimate."""

import dataclasses

import numpy as np
import pytest
from rigid_records import J_TRUE, Q0, W0, noisy_problem
from scipy import stats

from inertia_gym.estimation import output_error
from inertia_gym.estimation.inertia_param import phi_from_inertia
from inertia_gym.estimation.longrun import correlation_lags
from inertia_gym.estimation.uncertainty import (
    Forecast,
    InertiaEstimate,
    choose,
    forecast_comparison,
    homogeneity,
    inertia_estimate,
    model_error_covariance,
    relative_frobenius_bound,
)
from inertia_gym.information import theta_from_inertia


def test_normalised_covariance_has_no_variance_along_the_trace():
    phi = phi_from_inertia(J_TRUE)
    cov = np.diag([0.0, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4])
    est = inertia_estimate(phi, cov, scale_fixed=True, trace_ref=3.0)
    w = np.array([1.0, 0, 0, 1, 0, 1])
    assert w @ est.theta == pytest.approx(3.0)
    assert abs(w @ est.theta_cov @ w) < 1e-12 * np.abs(est.theta_cov).max()


def test_model_error_error_bars_are_infinite_where_the_transition_cannot_be_inverted():
    """dL(s)/dL0 is read off the sensitivities to the initial rates; where they are grown past
    inversion (a real toss cut to hold its catch has entries of 1e8 and rank 1) the model error's
    intensity and covariance are infinite (refine then refuses the error bars) instead of numpy's
    LinAlgError escaping identify."""
    prob = noisy_problem(0, torque=False, momentum=False, n=400)
    p = np.r_[phi_from_inertia(J_TRUE), W0, 0, 0, 0]
    ev = output_error.evaluate(prob, p, Q0, True)
    q, cov = model_error_covariance(prob, p, ev)
    assert np.isfinite(q) and np.all(np.isfinite(cov))
    folded = ev.jac.copy()
    m = ev.e_w.shape[0]
    last = 3 * (m - 1)  # rows: block (gyro, attitude), measurement, axis
    folded[[last, last + 2], 6:9] = 0.0  # d w_x / d w0 = d w_z / d w0 = 0 at the last: rank 1
    q, cov = model_error_covariance(prob, p, dataclasses.replace(ev, jac=folded))
    assert q == np.inf and np.all(cov == np.inf)


def test_the_scales_sigma_is_the_delta_methods_of_the_trace():
    theta = theta_from_inertia(J_TRUE)
    cov = np.diag([4.0, 1.0, 1.0, 9.0, 1.0, 16.0])
    est = InertiaEstimate(theta, cov, True)
    assert est.scale_sigma() == pytest.approx(np.sqrt(4.0 + 9.0 + 16.0) / np.trace(J_TRUE))


def _estimate(theta, cov):
    return InertiaEstimate(np.asarray(theta, float), np.asarray(cov, float), True)


def test_the_forecast_comparison_is_diebold_mariano_with_the_bartlett_variance():
    """z = sum(d) / sqrt(sum over sequences of the Bartlett long-run variance of d), d the
    second predictor's loss less the first's, row by row; p = P(N(0, 1) > z)."""
    rng = np.random.default_rng(1)
    seqs = []
    for n in (300, 200):
        common = np.convolve(rng.normal(size=n + 9), np.ones(10) / 10, mode="valid")  # correlated
        seqs.append((1.0 + common ** 2, 1.2 + common ** 2 + 0.3 * rng.normal(size=n)))
    out = forecast_comparison(seqs)
    total, var = 0.0, 0.0
    for first, second in seqs:
        d = second - first
        total += d.sum()
        c = d - d.mean()
        lags = correlation_lags(c[:, None])
        var += c @ c + sum(2 * (1 - k / (lags + 1)) * (c[k:] @ c[:-k]) for k in range(1, lags + 1))
    assert out.statistic == pytest.approx(total / np.sqrt(var), rel=1e-9)
    assert out.p_value == pytest.approx(stats.norm.sf(total / np.sqrt(var)), rel=1e-9)
    assert out.costs == pytest.approx((sum(a.sum() for a, _ in seqs), sum(b.sum() for _, b in seqs)))
    assert out.first_better  # 0.2 a row better on 500 rows


def test_the_forecast_comparison_sees_no_difference_between_equal_predictors_over_fixed_seeds():
    """Two predictors whose losses differ only by noise: the one-sided test at 99.9 % calls the
    first better on no more than 1 of 200 seeds."""
    calls = 0
    for seed in range(200):
        rng = np.random.default_rng(seed)
        base = np.convolve(rng.normal(size=409), np.ones(10) / 10, mode="valid") ** 2
        calls += forecast_comparison([(base + rng.normal(size=400) ** 2,
                                       base + rng.normal(size=400) ** 2)]).first_better
    assert calls <= 1


@pytest.mark.parametrize("fits, narrower, better, expect_efficient", [
    (True, True, None, True),       # the model fits and the efficient estimate is the more precise
    (True, False, None, False),     # no more precise than the robust one
    (True, True, False, True),      # the model fits: the covariances decide, not the forecast
    (False, False, True, True),     # rejected: the efficient one predicts significantly better
    (False, True, False, False),    # rejected, and it does not
    (False, True, None, True),      # rejected, no forecast: the covariances decide
])
def test_choose_by_precision_where_the_model_fits_and_by_forecast_where_it_does_not(
        fits, narrower, better, expect_efficient):
    theta = np.array([1.0, 0.0, 0.0, 0.8, 0.0, 0.5])
    efficient = _estimate(theta, (1e-6 if narrower else 9e-6) * np.eye(6))
    robust = _estimate(theta + 1e-3, 4e-6 * np.eye(6))
    forecast = None if better is None else Forecast((1.0, 2.0), 5.0 if better else 0.5,
                                                    float(stats.norm.sf(5.0 if better else 0.5)))
    choice = choose(efficient, robust, fits, forecast)
    assert choice.efficient is expect_efficient
    assert choice.model_fits is fits
    assert choice.forecast == forecast
    assert choice.expected[0] == pytest.approx(relative_frobenius_bound(efficient.theta, efficient.theta_cov))
    assert choice.expected[1] == pytest.approx(relative_frobenius_bound(robust.theta, robust.theta_cov))


@pytest.mark.parametrize("costs, z, expect_efficient", [
    ((1.0, 2.0), 0.5, True),    # they disagree: the better predictor, significant or not
    ((2.0, 1.0), -0.5, False),
])
def test_where_the_model_is_rejected_and_the_estimates_disagree_the_better_predictor_is_reported(
        costs, z, expect_efficient):
    theta = np.array([1.0, 0.0, 0.0, 0.8, 0.0, 0.5])
    efficient = _estimate(theta, 1e-6 * np.eye(6))
    robust = _estimate(theta + 0.05, 4e-6 * np.eye(6))  # far beyond both intervals
    choice = choose(efficient, robust, False, Forecast(costs, z, float(stats.norm.sf(z))))
    assert choice.efficient is expect_efficient


def test_homogeneity_is_the_weighted_scatter_and_for_two_the_difference_over_the_summed_covariance():
    """chi-square = sum_i (v_i - m)^T V_i^-1 (v_i - m), m the precision-weighted mean, on
    k (n - 1) degrees of freedom; for two estimates d^T (V_a + V_b)^-1 d; at a fixed trace
    (covariances without the trace's direction) one degree of freedom fewer per estimate."""
    rng = np.random.default_rng(3)
    vals, covs = [], []
    for _ in range(4):
        a = rng.normal(size=(6, 6))
        covs.append(a @ a.T + 0.1 * np.eye(6))
        vals.append(rng.normal(size=6))
    infos = [np.linalg.inv(c) for c in covs]
    mean = np.linalg.solve(sum(infos), sum(i @ v for i, v in zip(infos, vals)))
    expected = sum((v - mean) @ i @ (v - mean) for i, v in zip(infos, vals))
    test = homogeneity(vals, covs)
    assert test.statistic == pytest.approx(expected, rel=1e-8) and test.dof == 18
    assert test.p_value == pytest.approx(stats.chi2.sf(expected, 18), rel=1e-8)
    d = vals[0] - vals[1]
    two = homogeneity(vals[:2], covs[:2]).statistic
    assert two == pytest.approx(d @ np.linalg.solve(covs[0] + covs[1], d))
    keep = np.linalg.svd(np.array([[1.0, 0, 0, 1.0, 0, 1.0]]))[2][1:].T  # directions at a fixed trace
    fixed = [keep @ keep.T @ c @ keep @ keep.T for c in covs[:2]]
    assert homogeneity(vals[:2], fixed).dof == 5


def test_the_reported_ratio_intervals_take_in_a_profiles_and_never_narrow_the_delta_methods():
    est = inertia_estimate(phi_from_inertia(J_TRUE), np.diag([0.0, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4]), True)
    delta = np.array(est.summary()["principal_ratios_ci95"])
    traced = delta.copy()
    traced[1] = [delta[1, 0] - 0.05, delta[1, 1] - 0.001]  # wider below, narrower above
    traced[2] = [delta[2, 0] + 0.001, delta[2, 1] + 0.02]
    shown = np.array(dataclasses.replace(est, ratio_ci=traced).summary()["principal_ratios_ci95"])
    np.testing.assert_allclose(shown[1], [delta[1, 0] - 0.05, delta[1, 1]])
    np.testing.assert_allclose(shown[2], [delta[2, 0], delta[2, 1] + 0.02])
    np.testing.assert_allclose(shown[0], delta[0])
