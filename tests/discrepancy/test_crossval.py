"""What an explanation adds after its leader must predict the record where it was not fitted
(discrepancy/crossval.py and selection.predictive): the folds against their definition, held-out
sums at the noise for the true model and far above it without the effect, and a tested profile
predicted without its values fitted to the rows held out (a real toss's case:
test_selection.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from inertia_gym.discrepancy.crossval import (
    FOLDS,
    _held_out_sum,
    _profile_from_rows_kept,
    folds,
    held_out_sums,
)
from inertia_gym.discrepancy.fit import fit_effect, fit_model, fit_nominal, prepare
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.scenario import Scenario


@pytest.fixture(scope="module")
def biased():
    """A 40-s record with a concealed gyro bias, its Data, rigid fit and the bias's fit."""
    rec, _ = simulate_recording(Scenario(tau_max=50.0), 40.0, "gyro_bias", seed=3)
    d = prepare(rec)
    nominal = fit_nominal(d)
    return d, nominal, fit_effect("gyro_bias", d, nominal)


def test_each_segment_is_cut_into_contiguous_equal_blocks_its_first_never_held_out(biased):
    d = biased[0]
    fold = folds(d)
    for s in range(d.segments):
        f = fold[d.row_seg == s]
        assert np.all(np.diff(f) >= 0)  # contiguous, in time order
        assert f[0] == -1  # the block the segment's initial state is fitted on
        if f.size > FOLDS:
            counts = np.bincount(f + 1, minlength=FOLDS + 1)
            assert counts.max() - counts.min() <= 1


def test_held_out_rows_are_predicted_at_the_noise_by_the_true_model_and_far_worse_without_it(biased):
    d, nominal, bias = biased
    with_bias, rigid = held_out_sums([bias, nominal], d, ["gyro_bias", None])
    n = 3 * int(np.sum(folds(d) >= 0))  # whitened residuals held out, each of unit variance at the truth
    assert 0.7 * n < with_bias < 1.3 * n
    assert rigid > 3.0 * with_bias


def test_a_profile_held_out_is_predicted_from_its_knots_outside_the_rows_held_out():
    """A varying momentum's knots inside the rows held out were fitted to those rows; the refit
    on the rest has nothing to move them, so they are drawn linearly through the knots outside
    first. The held-out sum then does not depend on the values the whole-record fit gave them:
    the rows held out never reach their own prediction."""
    rec, _ = simulate_recording(Scenario(tau_max=50.0), 40.0, "internal_momentum", seed=2)
    d = prepare(rec)
    nominal = fit_nominal(d)
    fit = fit_model(("internal_momentum",), ("varying",), d, nominal)
    fold, k = folds(d), 1
    held = fold == k
    params = fit.layout.models[0].unpack(fit.x[fit.layout.slices()[0]])
    knot_t, profile = np.asarray(params["profile_t"]), np.asarray(params["profile"])
    sample_held = np.zeros(d.t.size, bool)
    sample_held[d.row >= 0] = held[d.row[d.row >= 0]]
    inside = sample_held[np.clip(np.searchsorted(d.t, knot_t), 0, d.t.size - 1)]
    assert inside.any() and (~inside).sum() >= 2
    kept = fit.layout.models[0].unpack(_profile_from_rows_kept(fit, d, held, "internal_momentum")[
        fit.layout.slices()[0]])["profile"]
    np.testing.assert_array_equal(kept[~inside], profile[~inside])
    np.testing.assert_allclose(kept[inside], np.interp(knot_t[inside], knot_t[~inside], profile[~inside]))
    np.testing.assert_array_equal(_profile_from_rows_kept(fit, d, held, None), fit.x)
    x = np.array(fit.x)
    stop = fit.layout.slices()[0].stop
    x[stop - profile.size:stop][inside] += 10.0 * np.ptp(profile)  # another value fitted there
    moved = dataclasses.replace(fit, x=x)
    # the same start, so the same refit (with the knots kept, moving them changes the sum by 0.5 %)
    assert _held_out_sum(moved, d, fold, k, "internal_momentum") == pytest.approx(
        _held_out_sum(fit, d, fold, k, "internal_momentum"), rel=1e-6)
