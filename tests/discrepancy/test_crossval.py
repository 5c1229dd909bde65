"""What an explanation adds after its leader must predict the record where it was not fitted
(discrepancy/crossval.py and selection.predictive): the folds against their definition, held-out
sums at the noise for the true model and far above it without the effect, a tested profile
predicted without its values fitted to the rows held out, and a real toss whose leftover misfit a
rotor's momentum follows in-sample but does not predict."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from inertia_gym.discrepancy import selection
from inertia_gym.discrepancy.crossval import (
    FOLDS,
    _held_out_sum,
    _profile_from_rows_kept,
    folds,
    held_out_sums,
)
from inertia_gym.discrepancy.fit import fit_effect, fit_model, fit_nominal, prepare
from inertia_gym.discrepancy.report import _fits, diagnose
from inertia_gym.discrepancy.selection import (
    Explanation,
    _added,
    _alone,
    _chain,
    _led_by_best_single,
    predictive,
    select,
)
from inertia_gym.discrepancy.summary import _beyond_words
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.prepare import prepared
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
    assert _held_out_sum(moved, d, fold, k, "internal_momentum") == _held_out_sum(
        fit, d, fold, k, "internal_momentum")


def test_a_momentum_that_follows_a_real_toss_s_leftover_misfit_is_left_out(racquet_toss, kept_fits):
    """Racquet round 2 segment 3: the selection adds a varying momentum to the varying drag (it
    gains in BIC on the rows it is fitted to); it fits the stretches held out in turn worse than
    the drag alone, so the explanation leaves it out, says why, and is selected again without it.
    One diagnosis: the fits are kept as _fits returns them (the selection repeated on its rows
    reads their cache)."""
    report = diagnose(racquet_toss("round2", 3)).report
    found, = kept_fits
    selected = select(found.data, found.nominal, found.singles)
    assert "internal_momentum" in selected.fit.names  # what the BIC alone chose
    assert "internal_momentum" not in found.chosen.fit.names
    assert found.chosen.fit.names[0] in ("viscous_damping", "aero_drag")  # the air leads
    assert "does not predict" in found.chosen.dropped["internal_momentum"]
    assert "internal_momentum" not in [e["name"] for e in report["explanation"]]
    assert "does not predict" in report["left_out"]["internal_momentum"]
    left = {e["name"]: e for e in report["unpredictive"]}
    assert left["internal_momentum"]["held_out_ratio"] > 1.0
    assert report["beyond_catalogue"]  # the misfit it followed is structure the catalogue lacks
    words = "\n".join(_beyond_words(report))
    assert "`internal_momentum`" in words and "held out in turn" in words


def test_the_effect_tested_is_the_one_added_after_the_listed_leader(monkeypatch):
    """An explanation whose compound fit holds its effects in another order than it lists them
    (led by the best single effect: _led_by_best_single keeps the fit, changes the listing): the
    cross-validation tests the effect listed second, never the leader, and keeps the listing."""
    rec, _ = simulate_recording(Scenario(tau_max=50.0), 40.0, ["gyro_bias", "constant_body_torque"],
                                seed=1000)
    found = _fits(prepared(rec))
    d, nominal, singles = found.data, found.nominal, found.singles
    listed = select(d, nominal, singles)
    names, forms = listed.fit.names[::-1], listed.fit.forms[::-1]
    by_name = {f.name: f for f in singles}
    chain = _chain(names, forms, d, {names[0]: _alone(by_name[names[0]], forms[0], d, nominal)})
    backwards = Explanation(tuple(chain), _added(nominal, chain, names), {})
    led = _led_by_best_single(backwards, d, nominal, singles)
    lead, second = (name for name, _ in led.added)
    assert led.fit.names == (second, lead)  # the fit's own order is the other one
    asked = []
    real = selection.held_out_sums

    def spy(fits, data, tested):
        asked.append(list(tested))
        return real(fits, data, tested)

    monkeypatch.setattr(selection, "held_out_sums", spy)
    kept = predictive(led, d, nominal, singles)
    assert asked == [[second, None]]
    assert [name for name, _ in kept.added] == [lead, second]  # both predict: nothing left out
    assert kept.unpredictive == {}
