"""The shipped example scenarios, each validated: the filter identifies the inertia, scale
included, from the derived defaults alone (issue 12, must-show 1, with fewer seeds and margins).

The README's figures (16 seeds, 1000 s) come from `inertia-gym validate --scenario NAME --xi MID`.
"""

import warnings

import numpy as np
import pytest

from inertia_gym.scenario import Scenario, ScenarioWarning, shipped_scenarios
from inertia_gym.validation import validate

SEEDS = range(3)
DURATION = 1000.0


def mid_xi(sc: Scenario) -> np.ndarray:
    """The middle of the scenario's xi bounds (a, b, T_on)."""
    lo, hi = sc.xi_bounds
    return 0.5 * (lo + hi)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["paper", "cubesat-6u", "upper-stage"])
def test_example_scenario_identifies_its_inertia(name):
    assert name in shipped_scenarios()
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScenarioWarning)  # the examples are plausible
        sc = Scenario.load(name)
    summary = validate(sc, mid_xi(sc), DURATION, SEEDS).summary()
    assert summary["diverged"] == 0
    assert summary["scale_identified"] and all(summary["scale_identified_per_seed"])
    assert summary["median_rel_error"] < 0.01
    assert max(summary["rel_errors"]) < 0.02


@pytest.mark.slow
def test_cubesat_with_the_papers_absolute_constants_does_not_identify():
    """What the derived defaults fix: the paper's absolute Q_theta and P0_theta on a CubeSat."""
    sc = Scenario.load("cubesat-6u").replace(Q_theta=5e-2, P0_theta=15000.0)
    summary = validate(sc, mid_xi(sc), DURATION, SEEDS).summary()
    assert summary["median_rel_error"] is None or summary["median_rel_error"] > 0.05
