"""Profile-likelihood intervals on the principal ratios (estimation.profile)."""

import numpy as np
import pytest
from records import toss_record
from rigid_records import noisy_problem, start

from inertia_gym.estimation import ml, output_error, profile
from inertia_gym.estimation.inertia_param import phi_from_inertia
from inertia_gym.identification import _estimates, identify
from inertia_gym.prepare import prepared

PROLATE = np.array([0.3, 1.0, 1.02]) * 3e-4
NEAR_SPHERICAL = np.array([1.0, 1.01, 1.02]) * 3e-4


def _true_ratios(inertia) -> np.ndarray:
    vals = np.sort(np.linalg.eigvalsh(inertia))[::-1]
    return vals / vals[0]


def test_a_principal_ratio_and_its_gradient_match_their_definition():
    rng = np.random.default_rng(0)
    for _ in range(5):
        a = rng.normal(size=(3, 3))
        inertia = a @ a.T + np.eye(3)
        phi = phi_from_inertia(inertia)
        for k in (1, 2):
            value, grad = profile.principal_ratio(phi, k)
            assert value == pytest.approx(_true_ratios(inertia)[k], rel=1e-12)
            step = 1e-6
            numeric = [(profile.principal_ratio(phi + step * e, k)[0]
                        - profile.principal_ratio(phi - step * e, k)[0]) / (2 * step) for e in np.eye(6)]
            np.testing.assert_allclose(grad, numeric, rtol=1e-5, atol=1e-9)


def _fitted(moments, rate, seed):
    rec, inertia = toss_record(moments, rate, 1e-3, seed)
    both = _estimates(prepared(rec), None, False, None, profiled=False)
    return both.prob, both.oe, inertia


def test_a_pinned_solve_holds_the_ratio_at_its_target_and_fits_the_rest():
    """Three sigma from the fit, a sharp likelihood's pinned fit rises by about 3^2 = 9 noise
    variances; its pin's row is not a measurement's."""
    prob, oe, _ = _fitted(np.array([1.0, 1.3, 1.8]) * 3e-4, 15.0, 0)
    r0 = profile.principal_ratio(oe.fit.p[:6], 2)[0]
    sigma = np.sqrt(oe.estimate.principal_ratios()[1][2, 2])
    target = r0 + 3 * sigma
    pin = output_error.Pin(lambda phi: profile.principal_ratio(phi, 2), target, profile.PIN_STIFFNESS / sigma)
    stage = output_error.solve(prob, oe.fit.p, np.array([1.0, 0, 0, 0]), pin=pin,
                               max_iter=output_error.FINAL_ITER)
    assert profile.principal_ratio(stage.p[:6], 2)[0] == pytest.approx(target, abs=0.01 * 3 * sigma)
    assert stage.evaluation.r.size == oe.fit.evaluation.r.size
    assert 6.0 < float(stage.evaluation.r @ stage.evaluation.r) - oe.fit.cost < 12.0


def test_where_the_likelihood_is_quadratic_the_profile_interval_is_the_delta_methods():
    # a well-spun body of distinct moments: a sharp, nearly quadratic likelihood
    prob, oe, _ = _fitted(np.array([1.0, 1.3, 1.8]) * 3e-4, 15.0, 1)
    traced = profile.ratio_profile(prob, oe.fit, oe.estimate)
    ratios, cov = oe.estimate.principal_ratios()
    half = 1.96 * np.sqrt(np.diag(cov))
    assert traced.better is None
    for k in (1, 2):
        lo, hi = traced.intervals[k]
        assert hi - lo == pytest.approx(2 * half[k], rel=0.1)
        assert (lo + hi) / 2 == pytest.approx(ratios[k], abs=0.1 * half[k])


def test_with_attitude_and_a_bias_the_profile_follows_the_reference_attitude():
    """A record with attitude, torque and a fitted gyro bias: each pinned fit carries its own
    attitude correction, and the sharp likelihood's profile interval is the delta method's."""
    prob = noisy_problem(3, n=1500)
    p0, cov = start(prob)
    ref = ml.refine(prob, p0, prob.z_q[0], cov, None, "test")
    traced = profile.ratio_profile(prob, ref.fit, ref.estimate)
    ratios, ratio_cov = ref.estimate.principal_ratios()
    half = 1.96 * np.sqrt(np.diag(ratio_cov))
    assert traced.better is None
    for k in (1, 2):
        assert np.diff(traced.intervals[k])[0] == pytest.approx(2 * half[k], rel=0.1)


def test_a_fit_short_of_the_maximum_is_found_by_its_profile_and_identify_continues_it():
    # a prolate body spun slowly: the fit stops on a near-rod, the profile of the smallest ratio
    # runs down a valley to inertias that fit better by several noise variances
    prob, oe, _ = _fitted(PROLATE, 5.0, 8)
    traced = profile.ratio_profile(prob, oe.fit, oe.estimate)
    assert traced.better is not None
    better = output_error.evaluate(prob, *traced.better, False)
    assert float(better.r @ better.r) < oe.fit.cost - 2 * profile.BETTER_BY
    rec, _ = toss_record(PROLATE, 5.0, 1e-3, 8)
    continued = _estimates(prepared(rec), None, False, None).oe
    assert continued.fit.cost < oe.fit.cost - 2 * profile.BETTER_BY


@pytest.mark.slow
def test_intervals_on_weakly_informed_near_spherical_tosses_cover_their_truth():
    """Ten seeds of a near-spherical body spun at 15 rad/s, whose likelihood is far from
    quadratic: the reported 95 % intervals of both ratios cover the truth on at least 17 of 20
    (measured 19; the delta method's alone, 17)."""
    covered = 0
    for seed in range(10):
        rec, inertia = toss_record(NEAR_SPHERICAL, 15.0, 1e-3, seed)
        ci = np.array(identify(rec).summary()["principal_ratios_ci95"])
        truth = _true_ratios(inertia)
        covered += int(np.sum((ci[1:, 0] <= truth[1:]) & (truth[1:] <= ci[1:, 1])))
    assert covered >= 18
