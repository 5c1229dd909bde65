"""The fit statistics of diagnose (discrepancy/statistics.py): the whiteness test of a fit's
residual, against its definition and beside the effective share of independent rows; the
covariance's widening by the misfit and that share."""

import dataclasses

import numpy as np

from inertia_gym.discrepancy import fit as F
from inertia_gym.discrepancy import statistics
from inertia_gym.discrepancy.statistics import effective_share, residual_correlated
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.scenario import Scenario


def test_an_oscillating_residual_is_correlated_where_its_integrated_correlation_reads_it_white():
    """Whitened residual rows of pure noise read as uncorrelated on at least 18 of 20 seeds (the
    autocorrelation test counts 3-sigma excursions); the same noise plus an oscillation of twice
    its size, 8.5 rows a period, reads as correlated on all 20, although its autocorrelation
    alternates in sign and its effective share of independent rows stays near 1 (a
    structure-free reading a selection must not take as white)."""
    rec, _ = simulate_recording(Scenario(), 30.0, seed=1, sample_dt=0.1)
    d = F.prepare(rec)
    fit = F.fit_nominal(d)
    swing = 2.0 * np.sin(2 * np.pi * np.arange(d.n_rows) / 8.5)[:, None] * np.array([1.0, -0.6, 0.3])
    white, oscillating, shares = 0, 0, []
    for seed in range(20):
        noise = np.random.default_rng(seed).normal(size=fit.z.shape)
        white += not residual_correlated(d, dataclasses.replace(fit, z=noise))
        swung = dataclasses.replace(fit, z=noise + swing)
        oscillating += residual_correlated(d, swung)
        shares.append(effective_share(d, swung))
    assert white >= 18 and oscillating == 20, (white, oscillating)
    assert min(shares) > 0.8, min(shares)


def test_the_covariance_is_widened_by_the_misfit_over_the_rows_effective_share(monkeypatch):
    """covariance against its definition: the inverse information times max(1, mean square of the
    whitened residual) over the share of independent rows, so rows correlated over 4 of them
    (a share of 0.25) give 4 times the covariance of white rows, and a misfit of twice the noise
    another factor 4 (the coverage this buys over seeds: test_fit.py's science study)."""
    rec, _ = simulate_recording(Scenario(), 30.0, seed=1, sample_dt=0.1)
    d = F.prepare(rec)
    fit = F.fit_effect("gyro_bias", d, F.fit_nominal(d))
    white = dataclasses.replace(fit, z=np.zeros_like(fit.z))
    monkeypatch.setattr(statistics, "effective_share", lambda d, fit: 1.0)
    base, idx = statistics.covariance(white, d)
    assert np.all(np.isfinite(base)) and np.all(np.diag(base) > 0) and idx.size > 0
    monkeypatch.setattr(statistics, "effective_share", lambda d, fit: 0.25)
    np.testing.assert_allclose(statistics.covariance(white, d)[0], 4.0 * base, rtol=1e-9, atol=0.0)
    misfit = dataclasses.replace(fit, z=np.full_like(fit.z, 2.0))
    np.testing.assert_allclose(statistics.covariance(misfit, d)[0], 16.0 * base, rtol=1e-9, atol=0.0)
