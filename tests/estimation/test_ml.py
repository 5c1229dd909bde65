"""Maximum likelihood with its statistics (estimation/ml.py): efficiency and coverage over fixed
seeds, and the ratios without forcing."""

import numpy as np
import pytest
from rigid_records import J_TRUE, noisy_problem, start

from inertia_gym.estimation.ml import refine
from inertia_gym.information import theta_from_inertia


@pytest.mark.slow
def test_ml_is_efficient_and_its_intervals_cover_over_fixed_seeds():
    """20 seeds: the error is about the Cramér-Rao bound and 95 % intervals cover 85-99 %."""
    ratios, covered = [], []
    theta_true = theta_from_inertia(J_TRUE)
    for seed in range(20):
        prob = noisy_problem(seed)
        p0, cov = start(prob, seed=seed)
        ref = refine(prob, p0, prob.z_q[0], cov, None, "test")
        assert ref.fit.converged and ref.estimate.scale_identified
        err = np.linalg.norm(ref.estimate.inertia - J_TRUE) / np.linalg.norm(J_TRUE)
        ratios.append(err / ref.crlb)
        covered.extend(np.abs(ref.estimate.theta - theta_true) <= 1.96 * ref.estimate.sigma)
    assert np.median(ratios) < 1.5
    assert 0.85 <= np.mean(covered) <= 0.99


def test_ml_without_torque_identifies_ratios_and_says_the_scale_is_not():
    prob = noisy_problem(3, torque=False, momentum=False)
    p0, cov = start(prob)
    ref = refine(prob, p0, prob.z_q[0], cov, float(np.trace(J_TRUE)), "test")
    assert not ref.estimate.scale_identified
    est = ref.estimate.inertia
    assert np.trace(est) == pytest.approx(np.trace(J_TRUE))
    assert np.linalg.norm(est - J_TRUE) / np.linalg.norm(J_TRUE) < 5 * ref.crlb + 1e-3


