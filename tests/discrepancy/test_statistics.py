"""The fit statistics of diagnose (discrepancy/statistics.py): the whiteness test of a fit's
residual, against its definition and beside the effective share of independent rows."""

import dataclasses

import numpy as np

from inertia_gym.discrepancy import fit as F
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
