"""Uncertainty (estimation/uncertainty.py): the normalised covariance, the model error's
covariance where its transition cannot be inverted, the scale's standard deviation, and the
choice between an efficient and a robust estimate."""

import dataclasses

import numpy as np
import pytest
from rigid_records import J_TRUE, Q0, W0, noisy_problem

from inertia_gym.estimation import output_error
from inertia_gym.estimation.inertia_param import phi_from_inertia
from inertia_gym.estimation.uncertainty import (
    InertiaEstimate,
    choose,
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
    inversion (a real toss cut to hold its catch had entries of 1e8 and rank 1) the model error's
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


@pytest.mark.parametrize("fits, narrower, expect_efficient", [
    (True, True, True),      # the data accept the model and it is the more precise
    (False, True, False),    # the data reject the efficient estimate's model
    (True, False, False),    # no more precise than the robust one
])
def test_choose_keeps_the_efficient_estimate_only_where_its_model_fits_and_it_is_more_precise(
        fits, narrower, expect_efficient):
    theta = np.array([1.0, 0.0, 0.0, 0.8, 0.0, 0.5])
    efficient = _estimate(theta, (1e-6 if narrower else 9e-6) * np.eye(6))
    robust = _estimate(theta + 1e-3, 4e-6 * np.eye(6))
    choice = choose(efficient, robust, fits)
    assert choice.efficient is expect_efficient
    assert choice.model_fits is fits
    assert choice.expected[0] == pytest.approx(relative_frobenius_bound(efficient.theta, efficient.theta_cov))
