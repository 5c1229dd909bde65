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
@pytest.mark.parametrize("name, xi", [
    # The paper's body at the paper's validated xi (README: 0.298 % median over 16 seeds); at
    # mid-range xi its bursts move the rate by less than a gyro sigma and 1000 s give ~2 %.
    ("paper", (0.4, 4.0, 1.0)),
    ("cubesat-6u", None),  # None: mid-range xi
    ("upper-stage", None),
])
def test_example_scenario_identifies_its_inertia(name, xi):
    assert name in shipped_scenarios()
    with warnings.catch_warnings():
        warnings.simplefilter("error", ScenarioWarning)  # the examples are plausible
        sc = Scenario.load(name)
    summary = validate(sc, mid_xi(sc) if xi is None else xi, DURATION, SEEDS).summary()
    assert summary["diverged"] == 0
    assert summary["scale_identified"] and all(summary["scale_identified_per_seed"])
    assert summary["median_rel_error"] < 0.01
    assert max(summary["rel_errors"]) < 0.02


@pytest.mark.slow
def test_cubesat_with_the_papers_absolute_constants_does_not_identify():
    """What the derived defaults fix: the paper's absolute Q_theta and P0_theta on a CubeSat."""
    sc = Scenario.load("cubesat-6u").replace(Q_theta=5e-2, P0_theta=15000.0)
    summary = validate(sc, mid_xi(sc), DURATION, SEEDS).summary()
    # Measured over these 3 seeds: median 8.8 %, one run diverged, scale not identified.
    assert not summary["scale_identified"]
    assert summary["median_rel_error"] is None or summary["median_rel_error"] > 0.03


def test_a_body_scaled_with_its_torque_is_estimated_identically(paper):
    """J and tau_max times s leave the motion unchanged; with the derived defaults the filter,
    in its log-scale/shape coordinates, then sees the same problem: the same relative errors to
    round-off (with the paper's absolute Q_theta and P0_theta it would not)."""
    s = 1e-3
    small = paper.replace(inertia_true=np.array(paper.inertia_true) * s,
                          inertia_guess=np.array(paper.inertia_guess) * s, tau_max=paper.tau_max * s)
    xi = np.array([0.4, 4.0, 1.0])
    ref = validate(paper, xi, 150.0, [0], record_torque=False)
    got = validate(small, xi * [s, s, 1.0], 150.0, [0], record_torque=False)
    assert ref.rel_errors[0] > 1e-3  # the guess moved: a real comparison, not 0 == 0
    np.testing.assert_allclose(got.rel_errors, ref.rel_errors, rtol=1e-6)
    np.testing.assert_allclose(got.theta_sigma / s, ref.theta_sigma, rtol=1e-6, equal_nan=True)
    assert bool(got.scale_identified[0]) == bool(ref.scale_identified[0])


@pytest.mark.parametrize("name, unlimited", [("paper-budget", "paper"),
                                             ("cubesat-6u-budget", "cubesat-6u")])
def test_a_budgeted_scenario_is_its_body_with_a_budget_the_corner_overdraws_threefold(name, unlimited):
    from inertia_gym.optimization import evaluate_episodes

    with warnings.catch_warnings():
        warnings.simplefilter("error", ScenarioWarning)
        sc = Scenario.load(name)
    free = Scenario.load(unlimited)
    assert sc == free.replace(impulse_budget=sc.impulse_budget)
    corner = evaluate_episodes(free, sc.xi_bounds[1], [0, 1, 2], "posterior")
    assert 2.5 < corner.impulses.mean() / sc.impulse_budget < 3.5
    limited = evaluate_episodes(sc, sc.xi_bounds[1], [0, 1, 2], "posterior")
    assert np.allclose(limited.impulses, sc.impulse_budget, rtol=1e-12)
    assert not limited.within.any()
