"""The selection (discrepancy/selection.py): the ranking of single-effect fits against its
definition (best BIC first, fits within TIE_BIC of the best left in the catalogue's order,
whatever the BICs' position on the number line, and fits without a finite BIC last), an
explanation listed led by its best single effect, whose effect added after the leader is the one
cross-validated, and a real racquet toss: select's searches, and a momentum that follows the
toss's leftover misfit in-sample but does not predict it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from inertia_gym.discrepancy import report as report_module
from inertia_gym.discrepancy import selection
from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.fit import MAX_EFFECTS
from inertia_gym.discrepancy.report import _fits as fits_of
from inertia_gym.discrepancy.report import diagnose
from inertia_gym.discrepancy.selection import (
    TIE_BIC,
    Explanation,
    _added,
    _alone,
    _chain,
    _claims_cost,
    _led_by_best_single,
    predictive,
    ranked,
    search,
    select,
)
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.prepare import prepared
from inertia_gym.scenario import Scenario

CATALOGUE = list(REGISTRY)


def _fits(*pairs):
    """Stand-ins with what ranked reads of a Fit: the effect's name and the fit's BIC."""
    return [SimpleNamespace(name=name, bic=bic) for name, bic in pairs]


@pytest.mark.parametrize("base", [100.0, 100.2, 100.26, 100.49, -3.1, 1e4 + 0.25])
def test_a_tie_goes_to_the_earlier_effect_wherever_the_bics_lie(base):
    """Two BICs 0.4 TIE_BIC apart are a tie at every offset: the earlier effect of the catalogue
    leads, whichever fits better."""
    early, late = CATALOGUE[1], CATALOGUE[5]
    for bic_early, bic_late in ((base + 0.4 * TIE_BIC, base), (base, base + 0.4 * TIE_BIC)):
        names = [f.name for f in ranked(_fits((late, bic_late), (early, bic_early)))]
        assert names == [early, late]


@pytest.mark.parametrize("base", [100.0, 100.2, 100.26, -3.1])
def test_bics_further_apart_than_the_tie_keep_their_order(base):
    early, late = CATALOGUE[1], CATALOGUE[5]
    names = [f.name for f in ranked(_fits((early, base + 1.5 * TIE_BIC), (late, base)))]
    assert names == [late, early]


def test_every_place_is_the_earliest_effect_within_the_tie_of_the_best_left():
    """Random BICs, many of them within a tie of one another: each place holds the effect
    earliest in the catalogue among those left within TIE_BIC of the lowest BIC left."""
    rng = np.random.default_rng(0)
    order = {name: i for i, name in enumerate(CATALOGUE)}
    for _ in range(200):
        names = list(rng.permutation(CATALOGUE))
        bics = rng.uniform(0.0, 3 * TIE_BIC, len(names))
        out = ranked(_fits(*zip(names, bics)))
        assert sorted(f.name for f in out) == sorted(names)
        for i, f in enumerate(out):
            best = min(g.bic for g in out[i:])
            tied = [g for g in out[i:] if g.bic <= best + TIE_BIC]
            assert f.name == min(tied, key=lambda g: order[g.name]).name


def test_fits_without_a_finite_bic_come_last_in_the_catalogues_order():
    a, b, c, e = CATALOGUE[0], CATALOGUE[2], CATALOGUE[3], CATALOGUE[7]
    out = ranked(_fits((c, np.nan), (e, 5.0), (b, np.inf), (a, np.nan)))
    assert [f.name for f in out] == [e, a, b, c]


@pytest.fixture(scope="module")
def listed_backwards():
    """A 40-s record with a gyro bias and a constant torque concealed: its fits as diagnose makes
    them (report._fits) and their compound explanation built the other way round, led by the
    effect the selection lists second (as another search, or a backward check that dropped the
    first search's lead, can leave it)."""
    rec, _ = simulate_recording(Scenario(tau_max=50.0), 40.0, ["gyro_bias", "constant_body_torque"],
                                seed=1000)
    meta = {k: v for k, v in rec.meta.items() if k not in ("effect", "effects")}
    found = fits_of(prepared(type(rec)(rec.t, rec.w, rec.q, rec.tau, meta, rec.name)))
    d, nominal, singles, chosen = found.data, found.nominal, found.singles, found.chosen
    names, forms = chosen.fit.names[::-1], chosen.fit.forms[::-1]
    by_name = {f.name: f for f in singles}
    chain = _chain(names, forms, d, {names[0]: _alone(by_name[names[0]], forms[0], d, nominal)})
    return found, Explanation(tuple(chain), _added(nominal, chain, names), {})


def test_an_explanation_in_any_order_is_listed_led_by_its_best_single_effect(listed_backwards):
    """The explanation listed the other way round is listed again led by its effect ranked first
    among the single fits: the compound fit kept, the prefix refitted, and the ΔBICs along the
    new chain adding up to the whole gain."""
    found, backwards = listed_backwards
    d, nominal, singles, chosen = found.data, found.nominal, found.singles, found.chosen
    assert sorted(chosen.fit.names) == ["constant_body_torque", "gyro_bias"]
    assert chosen.fit.names[0] == singles[0].name  # the selection's own listing
    led = _led_by_best_single(backwards, d, nominal, singles)
    assert [name for name, _ in led.added] == list(chosen.fit.names)
    assert led.fit is backwards.fit  # the compound fit kept, only its listing changed
    assert sum(gain for _, gain in led.added) == pytest.approx(nominal.bic - backwards.fit.bic)
    assert _led_by_best_single(led, d, nominal, singles) is led


def test_the_effect_cross_validated_is_the_one_added_after_the_listed_leader(listed_backwards,
                                                                            monkeypatch):
    """An explanation whose compound fit holds its effects in another order than it lists them:
    the cross-validation tests the effect listed second, never the leader, and keeps the
    listing."""
    found, backwards = listed_backwards
    d, nominal, singles = found.data, found.nominal, found.singles
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

@pytest.fixture(scope="module")
def real_toss(racquet_toss):
    """Racquet round 2 segment 3 diagnosed once: its report and the fits behind it, as
    report._fits returns them."""
    kept, real = [], report_module._fits
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(report_module, "_fits", lambda prep: kept.append(real(prep)) or kept[-1])
        report = diagnose(racquet_toss("round2", 3)).report
    return report, kept[0]


def test_select_keeps_the_best_of_its_searches_on_a_racquet_toss(real_toss):
    """Racquet round 2 segment 3, whose explanations of nearly equal BIC (varying drag and
    momentum; flat-plate drag and a mode) are reached by different searches: select keeps an
    explanation at least as good as the search led by the best single effect and the one led by
    the runner-up, each named effect charged its margin, and lists it led by the best single
    effect wherever it holds that effect."""
    found = real_toss[1]
    d, nominal, singles = found.data, found.nominal, found.singles
    chosen = select(d, nominal, singles)
    first = search(d, nominal, singles, MAX_EFFECTS)
    runner_up = search(d, nominal, singles, MAX_EFFECTS, lead=1)
    assert first.fit.names[0] == singles[0].name
    cost = _claims_cost(chosen.fit, d)
    assert cost <= min(_claims_cost(first.fit, d), _claims_cost(runner_up.fit, d)) + TIE_BIC
    assert cost < _claims_cost(nominal, d) - 500.0  # the air's share of the misfit is explained
    if singles[0].name in chosen.fit.names:
        assert [name for name, _ in chosen.added][0] == singles[0].name


def test_a_momentum_that_follows_a_real_toss_s_leftover_misfit_is_left_out(real_toss):
    """Racquet round 2 segment 3: the search led by the varying drag adds a varying momentum (it
    gains in BIC on the rows it is fitted to); it fits the stretches held out in turn many times
    worse than the drag alone, so predictive leaves it out and says why, and no explanation of
    the toss names a rotor."""
    report, found = real_toss
    d, nominal, singles = found.data, found.nominal, found.singles
    first = search(d, nominal, singles, MAX_EFFECTS)
    assert first.fit.names[0] in ("viscous_damping", "aero_drag")  # the air leads
    assert "internal_momentum" in first.fit.names  # what the BIC alone adds
    kept = predictive(first, d, nominal, singles)
    assert "internal_momentum" not in kept.fit.names
    assert kept.unpredictive["internal_momentum"] > 3.0
    assert "does not predict" in kept.dropped["internal_momentum"]
    assert "internal_momentum" not in found.chosen.fit.names
    assert found.chosen.fit.names[0] in ("viscous_damping", "aero_drag")
    assert "internal_momentum" not in [e["name"] for e in report["explanation"]]
