"""Terms nested in the rigid model (estimation/nested.py): the lack-of-fit test by its definition,
and a gyro bias or drag kept by the likelihood-ratio test where it explains the first fit's misfit."""

import dataclasses

import numpy as np
import pytest

from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.estimation import ml, output_error
from inertia_gym.estimation.equation_error import equation_error
from inertia_gym.estimation.nested import lack_of_fit
from inertia_gym.estimation.uncertainty import TEST_LEVEL, InertiaEstimate
from inertia_gym.identification import output_error_fit
from inertia_gym.prepare import prepared
from inertia_gym.scenario import Scenario


def test_the_lack_of_fit_test_holds_a_segmented_fit_to_the_noise_like_a_single_one():
    """lack_of_fit by its definition: the whitened residuals' sum of squares against a
    chi-square whose degrees of freedom leave out the fitted parameters and each further
    segment's initial state. A fit in 1 or 5 segments whose residuals are the noise passes on
    about 95 % of seeds (at least 16 of 20 asked); residuals 10 % above the noise fail on all
    (z about 14 on 9000 rows)."""
    level = np.array([0.01, 0.02, 0.03])
    prob = dataclasses.make_dataclass("Prob", ["n_params", "with_att"])(15, True)
    noise = dataclasses.make_dataclass("Noise", ["hac_lags"])(0)

    def p_value(e_w, segments):
        evaluation = dataclasses.make_dataclass("Evaluation", ["e_w"])(e_w)
        fit = dataclasses.make_dataclass("Fit", ["segments", "evaluation"])(segments, evaluation)
        refinement = dataclasses.make_dataclass("Refinement", ["fit", "noise"])(fit, noise)
        return lack_of_fit(refinement, level, prob)

    for segments in (1, 5):
        draws = [np.random.default_rng(seed).normal(size=(3000, 3)) * level for seed in range(20)]
        assert sum(p_value(e, segments) >= 1 - TEST_LEVEL for e in draws) >= 16
        assert all(p_value(1.1 * e, segments) < 1e-6 for e in draws)


@pytest.mark.parametrize("seed", [3, pytest.param(5, marks=pytest.mark.science)])
def test_a_bias_that_explains_the_first_fits_misfit_is_kept_and_no_other_basin_is_searched(monkeypatch, seed):
    """Gyro only, torque bursts, a bias of (0.02, -0.01, 0.015) rad/s under 0.03 rad/s noise: the
    fit from the equation error's inertia fails the lack-of-fit test; the bias added to it passes,
    is kept (within 4 of its sigmas of the truth) and said, and that one fit is all that runs (no
    start of another basin: the misfit is explained)."""
    rec, _ = simulate_recording(Scenario(), 100.0, effect_name="gyro_bias",
                                overrides={"bias": [0.02, -0.01, 0.015]}, seed=seed, sample_dt=0.1)
    prep = prepared(dataclasses.replace(rec, q=None))
    ee = equation_error(prep.rec.t - prep.rec.t[0], prep.rec.w, prep.rec.tau, prep.rec.h, 1.0, prep.usable,
                        sigma=prep.level)
    reference = InertiaEstimate(ee.theta, ee.theta_cov, ee.scale_seen)
    prob = output_error.problem_from(prep, prep.sigma, False, False)
    starts = []
    real = ml.fit_from_prior
    monkeypatch.setattr(ml, "fit_from_prior", lambda *a, **k: starts.append(a[1]) or real(*a, **k))
    found = output_error_fit(prep, prob, reference, False, None, nested=True)
    assert len(starts) == 1
    assert found.prob.fit_bias and "constant gyro bias" in found.note
    bias, sigma = found.refinement.fit.p[-3:], np.sqrt(np.diag(found.refinement.cov))[-3:]
    assert np.all(np.abs(bias - [0.02, -0.01, 0.015]) < 4 * sigma)
    assert lack_of_fit(found.refinement, prep.level, found.prob) >= 1 - TEST_LEVEL
