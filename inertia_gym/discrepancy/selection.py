"""The selection: which of the catalogue's effects explain a record, ranked and chosen by BIC.

Every testable effect is fitted alone (fit_all, ranked); the compound explanation comes from a
forward selection with a backward check (search), the best of up to three searches (select),
each effect claimed only where it gains its claim margin (claim_margin).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from inertia_gym.discrepancy.crossval import held_out_sums, predicts_words
from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.fitting import SIGNIFICANT_DELTA_BIC, _helpers, fanned, fit_model, predicted_bic
from inertia_gym.discrepancy.objective import Fit, Layout
from inertia_gym.discrepancy.plausibility import implausible
from inertia_gym.discrepancy.starts import SHORT_SEGMENTS, Probe
from inertia_gym.discrepancy.statistics import residual_correlated

TIE_BIC = 0.5  # BICs closer than this are a tie (the solver's own spread on equivalent models)
#: At most this many effects in a compound explanation; the best this many screens of each
#: forward step are refitted jointly.
MAX_EFFECTS, REFIT_SCREENED = 3, 3
#: Residual rms / noise (on some axis) over which a fit leaves the record unexplained.
UNEXPLAINED_RMS = 1.3


def candidates(d: Data) -> tuple[list[str], dict]:
    """Effects the data can test, and why the others are skipped."""
    names, skipped = [], {}
    for name, model in REGISTRY.items():
        reason = model.skip_reason(d)
        if reason is None:
            names.append(name)
        else:
            skipped[name] = reason
    return names, skipped


def fit_effect(name: str, d: Data, nominal: Fit) -> Fit:
    """One effect fitted jointly with the inertia from the nominal fit, in each of its forms;
    the form of lowest BIC. A form that nests the first (EffectModel.nested: viscous_damping's
    varying factor at 1 is its constant drag) extends it: it is fitted only where the first form
    improves the nominal's BIC by SIGNIFICANT_DELTA_BIC (a drag that changes in time, where a
    drag is seen at all), started from the first form's fit (and, on a record of few segments,
    where starts matter more, from its own starts as well).
    """
    model = REGISTRY[name]
    forms = model.forms(d)
    first = fit_model((name,), (forms[0],), d, nominal)
    fits = [first]
    span = first.layout.slices()[-1]
    for form in forms[1:]:
        inner = model.nested(form, d, first.x[span])
        if inner is None:
            fits.append(fit_model((name,), (form,), d, nominal))
        elif nominal.bic - first.bic > SIGNIFICANT_DELTA_BIC:
            extended = np.concatenate([first.x[:span.start], inner, first.x[span.stop:]])
            if d.segments < SHORT_SEGMENTS:
                fits.append(fit_model((name,), (form,), d, nominal, extra_starts=[extended]))
            else:
                fits.append(fit_model((name,), (form,), d, nominal, start=extended))
    return min(fits, key=lambda f: f.bic)


def fit_all(d: Data, nominal: Fit) -> tuple[list[Fit], dict]:
    """Every testable effect's fit (ranked by BIC, best first) and the skipped ones.

    actuator_scale is only a candidate with the trace pinned to a trusted nominal (skip_reason):
    J at the nominal trace, torque scaled by 1 + s. Exactly confounded effects (actuator_scale
    and inertia_offset: c J with c tau) tie to rounding; the tie goes to the earlier one in the
    catalogue (BICs within TIE_BIC), the report names both.
    """
    names, skipped = candidates(d)
    return ranked(fanned(fit_effect, d, [{"name": name, "nominal": nominal} for name in names])), skipped


def ranked(fits: list[Fit]) -> list[Fit]:
    """Single-effect fits best first; BICs within TIE_BIC (two solver runs of equivalent models
    differ below it) in the catalogue's order: each place goes to the earliest in the catalogue
    of the fits left within TIE_BIC of the best left, fits without a finite BIC last.
    """
    order = {name: i for i, name in enumerate(REGISTRY)}
    left = sorted(fits, key=lambda f: order[f.name])
    out = []
    while left:
        best = min((f.bic for f in left if np.isfinite(f.bic)), default=None)
        i = 0 if best is None else next(i for i, f in enumerate(left) if f.bic <= best + TIE_BIC)
        out.append(left.pop(i))
    return out


@dataclasses.dataclass(frozen=True)
class Explanation:
    """A compound explanation: the fits of the chain nominal -> +e1 -> +e1+e2 ..., the BIC each
    effect added along that chain, and what the selection tried and left out.

    chain: fits, chain[i] holds the first i+1 effects; added: (name, delta BIC) per effect along
    the chain as selected (diagnose then polishes chain[-1], the fit it reports, and keeps these:
    the last effect's gain is not credited with the polish's); dropped: {name: reason} of effects
    removed by the backward check or never added; refused: those left out as implausible.
    """

    chain: tuple[Fit, ...]
    added: tuple[tuple[str, float], ...]
    dropped: dict
    #: {name: (why it is implausible, the BIC it would have gained)}: effects that cleared the
    #: margin but are not physics the body or its sensor plausibly has (plausibility), left out
    refused: dict = dataclasses.field(default_factory=dict)
    #: {name: held-out residual sum with it over without it}: effects the selection added after
    #: the leader that did not predict the rows held out in turn (predictive), left out
    unpredictive: dict = dataclasses.field(default_factory=dict)
    #: the search left an effect that restarts_on_base out of a joint refit because the residual
    #: tested white, while its score test cleared the claim margin (_forward): the same search
    #: with such effects refitted may find a better explanation
    gated_out: bool = False

    @property
    def fit(self) -> Fit | None:
        """The compound fit (None when no effect is selected)."""
        return self.chain[-1] if self.chain else None


def _alone(single: Fit, form: str, d: Data, nominal: Fit) -> Fit:
    """The single-effect fit of single's effect in `form`: single itself where it has that form."""
    return single if single.forms == (form,) else fit_model((single.name,), (form,), d, nominal)


def _added(nominal: Fit, chain, names) -> tuple[tuple[str, float], ...]:
    """(name, delta BIC) of each effect along chain (chain[i] holds names[:i + 1])."""
    bics = [nominal.bic] + [f.bic for f in chain]
    return tuple((n, float(bics[i] - bics[i + 1])) for i, n in enumerate(names))


def _chain(names, forms, d: Data, singles: dict) -> list[Fit]:
    """Fits of the prefixes of names, each added to the previous one (singles reused)."""
    out = [singles[names[0]]]
    for i in range(1, len(names)):
        out.append(fit_model(names[:i + 1], forms[:i + 1], d, out[-1]))
    return out


def select(d: Data, nominal: Fit, singles: list[Fit], max_effects: int = MAX_EFFECTS,
           first: Explanation | None = None) -> Explanation:
    """The compound explanation of lowest BIC of up to six searches (search): over the singles
    as fitted (each effect in its best form; `first`, where the caller has run that search), and,
    where that explanation holds an effect in a
    richer form than its simplest (internal_momentum or viscous_damping varying), over the
    singles with every effect in its simplest form and over the singles as fitted led by the
    runner-up; and each of these again, with score_gate, where it left out an effect that its
    score test favoured (Explanation.gated_out). A rich form can soak up a second effect and lead
    the greedy search astray (racquet round 1 segment 3: the free momentum profile alone, where
    the varying drag and a flexible mode fit better by 85 with every row counted); the final
    explanations' BICs then decide, each effect an explanation claims charged the significance
    margin, as the forward selection charges it: an explanation that names one more effect must
    fit better by SIGNIFICANT_DELTA_BIC to be preferred. Ties go to the earlier search. The explanation is
    listed led by the effect that explains most alone (_led_by_best_single): the first search's
    own lead, unless the backward check dropped it or another search found the explanation.
    """
    if first is None:
        first = search(d, nominal, singles, max_effects)
    if not first.chain:
        return first
    runs = [((singles, 0), first)]
    simplest = {n: REGISTRY[n].forms(d)[0] for n in REGISTRY}
    if any(f != simplest[n] for n, f in zip(first.fit.names, first.fit.forms)):
        plain = ranked(fanned(_alone, d, [{"single": f, "form": simplest[f.name], "nominal": nominal}
                                          for f in singles]))
        runs += [((pool, lead), search(d, nominal, pool, max_effects, lead=lead))
                 for pool, lead in ((plain, 0), (singles, 1))]
    # a search that left out an effect its score test favoured is run again with it refitted:
    # one more search whose explanation competes, never one that replaces another's
    runs += [(args, search(d, nominal, args[0], max_effects, lead=args[1], score_gate=True))
             for args, run in list(runs) if run.gated_out]
    best = first
    for _, other in runs[1:]:
        if other.chain and _claims_cost(other.fit, d) < _claims_cost(best.fit, d) - TIE_BIC:
            best = other
    return _led_by_best_single(best, d, nominal, singles)


def _led_by_best_single(expl: Explanation, d: Data, nominal: Fit, singles: list[Fit]) -> Explanation:
    """The explanation expl with the effect that explains most alone first (of its effects, the
    one ranked first among the single-effect fits, each in its best form: the ranking the report's
    `effects` lists and the first search starts from), the others in the order the search added
    them, as a search led by the best single effect lists them; the chain's prefixes refitted in
    expl's forms to give what each adds, its compound fit kept. expl itself where it is so led.

    Ranked in their best forms, not in expl's: racquet round 1 segment 0's explanation (an
    inertia change, then a constant drag) would be listed led by the inertia change, whose single fit
    beats the constant drag's, while the report's best single effect is the drag, which in its
    varying form alone explains almost three times as much (354 against 128 in BIC).
    """
    final = expl.fit
    by_name = {f.name: f for f in singles}
    rank = {f.name: i for i, f in enumerate(ranked(singles))}
    lead = min(final.names, key=rank.__getitem__)
    if lead == expl.added[0][0]:  # listed so already (its compound fit may hold them in another order)
        return expl
    alone = {n: _alone(by_name[n], form, d, nominal) for n, form in zip(final.names, final.forms)}
    order = [final.names.index(lead)] + [i for i, n in enumerate(final.names) if n != lead]
    names, forms = [final.names[i] for i in order], [final.forms[i] for i in order]
    chain = [*_chain(names[:-1], forms[:-1], d, alone), final]
    return Explanation(tuple(chain), _added(nominal, chain, names), expl.dropped, expl.refused)


def predictive(expl: Explanation, d: Data, nominal: Fit, singles: list[Fit]) -> Explanation:
    """The explanation expl without the effects it adds after its leader that do not predict where
    they were not fitted (crossval: the explanation without each, against it whole, refitted on
    the rows kept and scored on those held out in turn); expl itself where every one predicts.

    A term that only follows the leader's leftover misfit in the rows it is fitted to lowers the
    BIC there and fits the held-out rows worse: it pads the explanation with physics the body
    need not have. The effects left out are written into dropped with the held-out ratio.
    """
    final = expl.fit
    if final is None or len(final.names) < 2:
        return expl
    by_name = {f.name: f for f in singles}
    listing = [name for name, _ in expl.added]  # the leader first (the compound fit's own order may differ)
    tested = listing[1:]
    rest = []  # the explanation without each added effect
    for name in tested:
        drop = final.names.index(name)
        j = 1 if drop == 0 else 0  # the first effect left, in the compound fit's order
        rest.append(_without(final, drop, _alone(by_name[final.names[j]], final.forms[j], d, nominal), d)[-1])
    sums = held_out_sums([final] * len(tested) + rest, d, tested + [None] * len(tested))
    ratio = {n: sums[i] / sums[len(tested) + i] if sums[len(tested) + i] > 0 else np.inf
             for i, n in enumerate(tested)}
    left = {n: float(r) for n, r in ratio.items() if not r < 1.0}
    if not left:
        return expl
    names = [n for n in listing if n not in left]
    forms = [final.forms[final.names.index(n)] for n in names]
    if names == listing[:len(names)]:
        chain = list(expl.chain[:len(names)])
    else:
        chain = _chain(names, forms, d, {names[0]: _alone(by_name[names[0]], forms[0], d, nominal)})
    dropped = {**expl.dropped, **{n: predicts_words(r) for n, r in left.items()}}
    return Explanation(tuple(chain), _added(nominal, chain, names), dropped, expl.refused, left)


def predictive_selection(expl: Explanation, d: Data, nominal: Fit, singles: list[Fit]) -> Explanation:
    """The explanation expl with what it adds after its leader judged on held-out rows
    (predictive); where that leaves effects out, the selection runs again without them (select
    over the other singles) and its additions are judged in turn, until none is left out. As the
    backward check's forward steps resume without the effects it drops: an effect that follows the
    leader's leftover misfit only where it was fitted can stand in the way of one that explains it
    (a slosh damped past resonance: a free momentum profile, dropped, hid the damped mode).
    """
    chosen = predictive(expl, d, nominal, singles)
    left = dict(chosen.unpredictive)
    dropped = dict(chosen.dropped)
    while chosen.unpredictive:
        pool = [f for f in singles if f.name not in left]
        chosen = predictive(select(d, nominal, pool), d, nominal, pool)
        left |= chosen.unpredictive
        dropped |= chosen.dropped
    return dataclasses.replace(chosen, dropped=dropped, unpredictive=left)


def _claims_cost(fit: Fit, d: Data) -> float:
    """A compound fit's BIC plus the margin each effect it names must clear (claim_margin)."""
    return fit.bic + sum(claim_margin(d, name) for name in fit.names)


def claim_margin(d: Data, name: str) -> float:
    """The BIC an effect must gain to be claimed on d: SIGNIFICANT_DELTA_BIC, plus what its fit
    gains from the rounding of a coarsely read gyro alone (d.rounding_floor, recounted with the
    rows' independent share as every BIC is).
    """
    return SIGNIFICANT_DELTA_BIC + d.effective_share * d.rounding_floor.get(name, 0.0)


def margin_words(d: Data, name: str) -> str:
    """claim_margin in words: "10", or "10 + 335 (what the rounding alone gives it)"."""
    floor = claim_margin(d, name) - SIGNIFICANT_DELTA_BIC
    return (f"{SIGNIFICANT_DELTA_BIC:g}" if floor <= 0 else
            f"{SIGNIFICANT_DELTA_BIC:g} + {floor:.1f} (what the gyro's rounding alone gives it)")


def _screened(single: Fit, current: Fit, structured: bool, d: Data) -> Fit:
    """The effect of `single` (its single-effect fit) screened on top of the fit `current`
    (search's screen): in the form of its single-effect fit, from that fit's parameters or
    from where it changes nothing, whichever fits better, and, for an effect in a form it
    restarts_on_base in, where the residual left is `structured` (not white), from each of its own
    starts on top of current; the best screen.
    """
    name, form = single.name, single.forms[0]
    layout = Layout.of((*current.names, name), (*current.forms, form), d,
                       max(current.layout.omega_max, single.layout.omega_max))
    probe = Probe(layout, d, current)
    model = REGISTRY[name]
    starts = probe.best_x([probe.x(single.x[single.layout.slices()[0]]),
                           probe.x(model.neutral(form, d, current))])
    if form in model.restarts_on_base and structured:  # its own starts, on top of the current fit
        starts += probe.own_starts()
    screened = [fit_model(layout.names, layout.forms, d, current, joint=False, start=start,
                          omega_max=layout.omega_max) for start in starts]
    return min(screened, key=lambda f: f.bic if np.isfinite(f.bic) else np.inf)


def _without(fit: Fit, drop: int, first: Fit, d: Data) -> list[Fit]:
    """The chain of the compound fit's effects without its drop-th, each added to the previous
    (first: the single-effect fit of the first effect left, in its form in fit).
    """
    keep = [i for i in range(len(fit.names)) if i != drop]
    return _chain(tuple(fit.names[i] for i in keep), tuple(fit.forms[i] for i in keep), d,
                  {first.name: first})


def search(d: Data, nominal: Fit, singles: list[Fit], max_effects: int = MAX_EFFECTS,
           lead: int = 0, score_gate: bool = False) -> Explanation:
    """Forward selection over the catalogue, then a backward check.

    Step 1 takes the best single-effect fit (the lead-th best with lead > 0) if it beats the
    nominal by its claim_margin (SIGNIFICANT_DELTA_BIC, more on a coarsely rounded record).
    Each further step fits every remaining candidate's own parameters on top of the current
    fit (everything else held: a screen, started from the candidate's single-effect fit or
    from its neutral parameters, whichever fits better, and for an effect in a form it
    restarts_on_base in also, where the current fit's residual is not white (residual_correlated),
    from each of its own starts found on top of the current fit, the best screen kept),
    refits the REFIT_SCREENED best (and any that restarts_on_base) jointly with the inertia and
    the effects already chosen,
    and keeps the best if that improves the BIC by the same margin; at most max_effects. Every
    testable effect is screened at every step, also those that explain nothing alone: a large
    effect can hide a second one. The backward check then refits without each chosen effect and
    drops any whose removal costs less than the margin, until none does. Where it dropped one,
    the forward steps resume from what is left (an effect once dropped is not screened again),
    then the backward check again, until it drops none: a rich effect taken early can be made
    redundant by those added after it, and the explanation without it may lack an effect that it
    stands in for (Basilisk's slosh with a hidden torque: led by the varying momentum, the
    search adds the inertia offset and a mode, then drops the momentum, short of the torque).
    """
    by_name = {f.name: f for f in singles}
    ranked = [f for f in singles if np.isfinite(f.bic) and nominal.bic - f.bic > claim_margin(d, f.name)]
    dropped = {f.name: f"alone it improves the BIC by {nominal.bic - f.bic:.1f} "
                       f"<= {margin_words(d, f.name)}" if np.isfinite(f.bic) else "no valid fit"
               for f in singles if f not in ranked}
    if len(ranked) <= lead:
        return Explanation((), (), dropped)
    current = ranked[lead]
    why = implausible(current.name, current.params, d, SIGNIFICANT_DELTA_BIC)
    if why:
        refused = {current.name: (why, float(nominal.bic - current.bic))}
        return Explanation((), (), {**dropped, **_refused_words(refused)}, refused)
    chain = [current]
    pool = [f.name for f in singles if np.isfinite(f.bic)]
    removed = []  # the effects the backward checks dropped
    gated_out = False
    while True:
        current, chain, refused, left_out = _forward(d, current, chain, by_name,
                                                     [n for n in pool if n not in removed], max_effects,
                                                     score_gate)
        gated_out |= left_out
        current, chain, now_removed = _backward(d, nominal, current, chain, by_name, dropped)
        if not now_removed:
            break
        removed += now_removed
    chosen = current.names
    for name in pool:
        if name not in chosen and not dropped.get(name, "").startswith("removing"):
            dropped[name] = (f"alone it improves the BIC by {nominal.bic - by_name[name].bic:.1f}, "
                             f"and it adds <= {margin_words(d, name)} once "
                             f"{', '.join(chosen)} {'is' if len(chosen) == 1 else 'are'} in")
    refused = {n: r for n, r in refused.items() if n not in chosen}
    return Explanation(tuple(chain), _added(nominal, chain, chosen), {**dropped, **_refused_words(refused)},
                       refused, gated_out=gated_out)


def _refused_words(refused: dict) -> dict:
    """The dropped reasons of the effects left out as implausible ({name: (why, gain)})."""
    return {n: f"it would improve the BIC by {gain:.1f}, but {why}" for n, (why, gain) in refused.items()}


def _forward(d: Data, current: Fit, chain: list[Fit], by_name: dict, pool: list[str],
             max_effects: int, score_gate: bool = False) -> tuple[Fit, list[Fit], dict, bool]:
    """The forward steps of `search` from the fit current (chain: its prefixes): each adds the effect of
    pool that improves the BIC most, by more than the margin; at most max_effects in all. Where
    that effect is not physics the body or its sensor plausibly has (plausibility), the steps
    stop: what is left is best fitted by something the catalogue does not plausibly hold, and a
    lesser effect that fits part of it would pad the explanation. Where the residual tests
    white, an effect that restarts_on_base is refitted jointly only with score_gate, and then
    where its score test (fitting.predicted_bic: the joint model's Gauss-Newton gain from its
    screen) clears the claim margin: a whiteness test has little power against a small, smooth
    misfit that such an effect takes up only together with the others. Returns the last fit, its
    chain, the effect refused so ({name: (why, gain)}, or {}) and whether, without score_gate,
    such an effect was left out (the search with it may differ).
    """
    gated_out = False
    while len(current.names) < max_effects:
        structured = residual_correlated(d, current)  # the residual left is not white
        trials = fanned(_screened, d, [{"single": by_name[n], "current": current, "structured": structured}
                                       for n in pool if n not in current.names])
        trials = [t for t in trials if np.isfinite(t.bic)]
        if not trials:
            break
        # a screen holds everything else and stops early: the leading few are refitted jointly,
        # and, where structure is left, every effect that restarts_on_base (a mode: its screen,
        # with the rates held that it trades with, says little of what it explains jointly);
        # where the residual tests white, only those whose score test clears the margin, and
        # only with score_gate (without it, that one would is recorded: gated_out)
        leading = sorted(trials, key=lambda t: t.bic)
        restarting = [t for t in leading[REFIT_SCREENED:]
                      if t.forms[-1] in REGISTRY[t.names[-1]].restarts_on_base]
        if not structured:
            favoured = [t for t in restarting
                        if current.bic - predicted_bic(t, d) > claim_margin(d, t.names[-1])]
            gated_out |= bool(favoured) and not score_gate
            restarting = favoured if score_gate else []
        leading = leading[:REFIT_SCREENED] + restarting
        refits = fanned(fit_model, d, [{"names": t.names, "forms": t.forms, "base": current, "start": t.x,
                                        "omega_max": t.layout.omega_max} for t in leading])
        best = min(refits, key=lambda f: f.bic)
        if not current.bic - best.bic > claim_margin(d, best.name):
            break
        # every effect of the new fit, not only the one added: two effects that trade (a bias and
        # a scale) can move an earlier one beyond what the body or its sensor plausibly has
        for name in best.names:
            why = implausible(name, best.effect_params[name], d, SIGNIFICANT_DELTA_BIC)
            if why:
                why = why if name == best.name else f"with it, `{name}` is fitted so that {why}"
                return current, chain, {best.name: (why, float(current.bic - best.bic))}, gated_out
        current = best
        chain = [*chain, best]
    return current, chain, {}, gated_out


def _backward(d: Data, nominal: Fit, current: Fit, chain: list[Fit], by_name: dict,
              dropped: dict) -> tuple[Fit, list[Fit], list[str]]:
    """The backward check of `search` on the fit current (chain: its prefixes): the explanation without
    each of its effects, the first whose removal costs at most the margin dropped (its reason
    written into dropped), until none is. Returns the fit left, its chain, and the names dropped.
    """
    removed = []
    changed = len(current.names) > 1
    while changed and len(current.names) > 1:
        changed = False
        # the explanation without each of its effects, in order, the first whose removal costs
        # less than the margin dropped; independent fits: as many at a time as there are
        # processes to run them (this one and the helpers ready), so that, run one after the
        # other, none is fitted that the order would skip
        removals = list(range(len(current.names)))
        while removals and not changed:
            width = 1 + _helpers()
            batch, removals = removals[:width], removals[width:]
            firsts = []  # the single fit of the first effect left without the i-th, in its form
            for i in batch:
                j = 1 if i == 0 else 0
                by_name[current.names[j]] = _alone(by_name[current.names[j]], current.forms[j], d, nominal)
                firsts.append(by_name[current.names[j]])
            without = fanned(_without, d, [{"fit": current, "drop": i, "first": first}
                                           for i, first in zip(batch, firsts)])
            for i, rest_chain in zip(batch, without):
                name = current.names[i]
                if rest_chain[-1].bic - current.bic <= claim_margin(d, name):
                    dropped[name] = (f"removing it from the explanation costs only "
                                     f"{rest_chain[-1].bic - current.bic:.1f} in BIC (backward check)")
                    current, chain, changed = rest_chain[-1], rest_chain, True
                    removed.append(name)
                    break
    return current, chain, removed
