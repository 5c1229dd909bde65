"""What an effect gains from a coarsely read gyro's rounding alone: the floors its claims must
clear (rounding_floors), and the check of an explanation's effects against it (rounding_checked).
"""

from __future__ import annotations

import numpy as np

from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.fitting import SIGNIFICANT_DELTA_BIC, fanned, fit_nominal
from inertia_gym.discrepancy.lattice import ROUNDING_RUNS, _refit, _rounding_records, rounding_runs
from inertia_gym.discrepancy.objective import Fit, Layout
from inertia_gym.discrepancy.selection import (
    Explanation,
    _added,
    _alone,
    _led_by_best_single,
    _without,
    fit_effect,
)

#: The rounded records rounding_checked reads for each effect of an explanation: its
#: refits start from the data's fits and take a fraction of a single effect's search, so enough
#: draws that their most is the 95th percentile of what the rounding gives an effect there
ROUNDING_CHECK_DRAWS = 19
#: What an effect added on top of others gains from the rounding, over the most any effect gained
#: alone (the largest single floor), beyond which rounding_checked does not look: 1.44 on the one
#: clean record of the tests where the check decides (279 against 194, 600-s slow tumble seed 2)
ROUNDING_CHECK_REACH = 4.0


def rounding_floors(d: Data, nominal: Fit, names) -> dict:
    """Effect name -> the most its single fit improves the BIC (rows counted as independent) on
    records of d's rows that hold nothing but the rounding, for each effect of `names`: the
    nominal fit's own prediction with the noise beneath the step added (the level less the
    rounding's share, sqrt(sigma^2 - step^2 / 12)), rounded to the data's lattice and to
    ROUNDING_DRAWS - 1 lattices shifted by a random fraction of a step (seeded: the same record
    gets the same floors); 0 where no draw gains. {} where no axis runs ROUNDING_RUNS samples or
    more on one value (rounding that the motion or the noise scrambles from sample to sample is
    white, and the BICs already count it right).
    """
    names = list(names)
    if not names or not np.any(rounding_runs(d) >= ROUNDING_RUNS) or not np.isfinite(nominal.bic):
        return {}
    floors = dict.fromkeys(names, 0.0)
    for rounded in _rounding_records(d, nominal):
        base = fit_nominal(rounded)
        for fit in fanned(fit_effect, rounded, [{"name": name, "nominal": base} for name in names]):
            if np.isfinite(base.bic - fit.bic):
                floors[fit.name] = max(floors[fit.name], float(base.bic - fit.bic))
    return floors


def _moved_last(fit: Fit, i: int, d: Data) -> tuple[Layout, np.ndarray]:
    """The layout and x of `fit` with its i-th effect moved to the end (the others in order)."""
    order = [j for j in range(len(fit.names)) if j != i] + [i]
    layout = Layout.of([fit.names[j] for j in order], [fit.forms[j] for j in order], d, fit.layout.omega_max)
    parts = [fit.x[fit.layout.slices()[j]] for j in order]
    return layout, np.concatenate([fit.x[:6], *parts, fit.x[fit.layout.n_global:]])


def rounding_checked(d: Data, nominal: Fit, expl: Explanation,
                     singles: list[Fit]) -> tuple[Explanation, dict]:
    """The explanation expl, each effect of it checked against what it adds where it is
    absent, on a record whose gyro rounds its samples as a function of the rate (d.rounding_floor
    set): the explanation without the effect, fitted on the data, predicts records that hold it
    and the rounding alone (_rounding_records); the explanation refitted there with and without
    the effect (from the data's fits, the effect also from where it changes nothing) gives
    what the effect gains from the rounding on top of the others (of an explanation of one
    effect: on the rigid fit's records). The first effect whose removal costs the data at most
    SIGNIFICANT_DELTA_BIC plus that gain (most over ROUNDING_CHECK_DRAWS draws, recounted with
    the rows' independent share) is dropped, until none is. The single floors price each effect
    alone, over few draws; on top of another effect the rounding can give it more (a gyro scale
    on top of a rotor's momentum on a clean slow tumble read in steps of 20x its noise: 111 in
    BIC, where alone it gains 32 against a floor of 95), and over more draws the rounding gives
    more (that momentum alone: 21 against a floor of 11 from four draws). An effect whose
    removal costs more than ROUNDING_CHECK_REACH times the largest single floor (and the margin)
    is kept unchecked, and an effect's draws stop once one drops it: checked in full, the refits
    of a mode and a varying momentum, 19 draws each, take 68 s of a 111-s diagnosis where the
    largest floor is 4.3 and the effects gain 39333 and 52.

    Returns the explanation left and {name: gain} of each effect checked alone (on the rigid
    fit's records: what rounding_floors reads, over more draws; the caller raises the floors).
    """
    by_name = {f.name: f for f in singles}
    dropped = dict(expl.dropped)
    alone: dict = {}
    reach = SIGNIFICANT_DELTA_BIC + d.effective_share * ROUNDING_CHECK_REACH * max(d.rounding_floor.values(),
                                                                                  default=0.0)
    while expl.fit is not None:
        fit = expl.fit
        for i, name in enumerate(fit.names):
            j = 1 if i == 0 else 0
            rest = [] if len(fit.names) == 1 else _without(
                fit, i, _alone(by_name[fit.names[j]], fit.forms[j], d, nominal), d)
            others = rest[-1] if rest else nominal
            cost = others.bic - fit.bic
            if cost > reach:  # beyond anything the rounding gives: kept unchecked
                continue
            need = (cost - SIGNIFICANT_DELTA_BIC) / d.effective_share  # the gain that drops it
            layout, x = _moved_last(fit, i, d)
            neutral = x.copy()
            neutral[layout.slices()[-1]] = REGISTRY[name].neutral(fit.forms[i], d, others)
            gain = 0.0
            for rounded in _rounding_records(d, others, ROUNDING_CHECK_DRAWS):
                without = _refit(others.layout, others.x, rounded)
                with_it = min((_refit(layout, x0, rounded) for x0 in (x, neutral)), key=lambda f: f.bic)
                if np.isfinite(without.bic - with_it.bic):
                    gain = max(gain, float(without.bic - with_it.bic))
                if gain >= need:
                    break  # dropped whatever the other draws give
            if not rest:
                alone[name] = gain
            if gain >= need:
                dropped[name] = (f"{'removing it from the explanation' if rest else 'alone it'} improves "
                                 f"the BIC by only {cost:.1f}, where on records of the "
                                 f"{'rest of the explanation' if rest else 'rigid fit'} read through the "
                                 f"gyro's rounding alone it gains up to {d.effective_share * gain:.1f} "
                                 f"(rounding check)")
                names = [n for n in fit.names if n != name]
                expl = Explanation((), (), dropped, expl.refused) if not rest else _led_by_best_single(
                    Explanation(tuple(rest), _added(nominal, rest, names), dropped, expl.refused), d, nominal,
                    singles)
                break
        else:
            break
    return expl, alone
