"""The ranking of single-effect fits (discrepancy/selection.py's ranked) against its definition:
best BIC first, fits within TIE_BIC of the best left in the catalogue's order, whatever the
BICs' position on the number line, and fits without a finite BIC last."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from inertia_gym.discrepancy.effects import REGISTRY
from inertia_gym.discrepancy.selection import TIE_BIC, ranked

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
