"""Mission limits of the closed loop: an impulse budget per episode and a body-rate limit.

The loop spends sum_i |tau_i| dt per torqued step, stops the actuator when the budget is spent
(the overdrawing step scaled to spend it exactly), and inhibits the rest of a burst once the
filter's rate estimate reaches the rate limit. Without limits it runs exactly as before.
"""

import numpy as np
import pytest

from inertia_gym.episode import run_episode
from inertia_gym.errors import ConfigError
from inertia_gym.scenario import Scenario, ScenarioWarning
from inertia_gym.simulation import initial_state, run_segment
from inertia_gym.validation import validate

XI = (0.4, 4.0, 1.0)
N_STEPS = 900
# Two bursts of 1 s (100 steps at the paper's dt) in a 9-s segment.
BURSTS = [[[50, 150], [400, 500]]] * 3


def _segment(sc, xi=XI, **kwargs):
    rngs = [np.random.default_rng(s) for s in range(3)]
    state = initial_state(sc, rngs)
    return run_segment(sc, state, N_STEPS, BURSTS, xi, [0.0, 1.0, 0.0], rngs, **kwargs)


def _spent(sc, trace):
    """Definition: the 1-norm impulse of the logged torque, sum over steps of |tau|_1 dt."""
    return np.abs(trace.tau).sum(axis=(1, 2)) * sc.dt


def test_without_limits_the_impulse_is_the_logged_torque_and_nothing_is_cut(paper):
    _, trace = _segment(paper)
    assert np.allclose(trace.impulse, _spent(paper, trace), rtol=1e-12)
    assert trace.impulse.min() > 0
    assert np.allclose(trace.demand, trace.impulse, rtol=1e-12)
    assert not trace.budget_spent.any() and not trace.rate_cuts.any()


def test_limits_that_never_bind_change_nothing(paper):
    end, trace = _segment(paper)
    loose = paper.replace(impulse_budget=1e6, rate_limit=1e6)
    end_l, trace_l = _segment(loose)
    assert np.array_equal(end.x, end_l.x) and np.array_equal(trace.tau, trace_l.tau)
    assert np.array_equal(trace.impulse, trace_l.impulse)


def test_the_budget_is_spent_exactly_then_the_actuator_stops(paper):
    _, free = _segment(paper)
    budget = 0.4 * float(free.impulse.min())  # runs out during the first burst
    sc = paper.replace(impulse_budget=budget)
    _, trace = _segment(sc)
    assert np.allclose(trace.impulse, budget, rtol=1e-12)
    assert np.allclose(_spent(sc, trace), budget, rtol=1e-9)
    assert trace.budget_spent.all()
    # What the law asked for is about what it spends without the budget (the second burst's
    # rate estimate differs a little once the first was cut).
    assert np.allclose(trace.demand, free.impulse, rtol=1e-2)
    # Nothing fires after the step that spent the budget: the second burst is silent.
    assert not np.any(trace.tau[:, 400:500])
    assert np.all(np.any(trace.tau[:, 50:60], axis=(1, 2)))


def test_an_impulse_already_spent_counts_against_the_budget(paper):
    sc = paper.replace(impulse_budget=10.0)
    _, trace = _segment(sc, impulse_spent=[10.0, 4.0, 0.0])
    assert not np.any(trace.tau[0])
    assert np.allclose(_spent(sc, trace)[1:], [6.0, 10.0], rtol=1e-9)
    assert np.allclose(trace.impulse, 10.0, rtol=1e-12)


def test_the_rate_monitor_inhibits_bursts_at_the_limit_of_the_estimated_rate(paper):
    # Bursts along the spin axis that add about 0.5 rad/s each, far above the filter's noise.
    strong = paper.replace(tau_max=50.0)
    spin_up = (0.0, 40.0, 1.0)
    _, free = _segment(strong, spin_up)
    start = float(np.linalg.norm(paper.omega0))
    assert free.rate_peak.min() > start + 0.8
    limit = start + 0.6
    sc = strong.replace(rate_limit=limit)
    _, trace = _segment(sc, spin_up)
    torqued = np.any(trace.tau != 0.0, axis=2)
    rate_hat = np.linalg.norm(trace.w_hat, axis=2)
    assert torqued.any() and np.all(rate_hat[torqued] < limit)
    assert np.all(trace.rate_cuts >= 1)
    assert np.all(trace.impulse < free.impulse)
    assert np.all(trace.rate_peak < free.rate_peak)
    assert np.all(trace.rate_peak >= start)


def test_an_axis_whose_pulse_is_below_the_minimum_impulse_bit_does_not_fire(paper):
    # Bursts along a tilted direction: a large pulse on y, small ones on x and z.
    v = np.array([0.1, 1.0, 0.2]) / np.linalg.norm([0.1, 1.0, 0.2])
    rngs = [np.random.default_rng(0)]
    free_sc = paper
    _, free = run_segment(free_sc, initial_state(free_sc, rngs), N_STEPS, BURSTS[:1], (0.0, 4.0, 1.0),
                          v, rngs)
    pulses = np.abs(free.tau[0, 50]) * 100 * paper.dt  # per axis over the 1-s burst
    bit = 0.5 * (pulses[1] + max(pulses[0], pulses[2]))
    sc = paper.replace(min_impulse_bit=bit)
    rngs = [np.random.default_rng(0)]
    _, trace = run_segment(sc, initial_state(sc, rngs), N_STEPS, BURSTS[:1], (0.0, 4.0, 1.0), v, rngs)
    fired = np.abs(trace.tau[0, 50:150]) > 0
    assert fired[:, 1].all() and not fired[:, [0, 2]].any()
    assert trace.demand[0] == pytest.approx(trace.impulse[0], rel=1e-12)
    assert trace.impulse[0] < free.impulse[0]


def test_an_episode_reports_what_it_used_of_each_limit(paper):
    sc = paper.replace(impulse_budget=5.0)
    rngs = [np.random.default_rng(s) for s in range(2)]
    _, results = run_episode(sc, initial_state(sc, rngs), sc.xi_bounds[1], rngs, cost="posterior")
    for res in results:
        assert res.impulse == pytest.approx(5.0, rel=1e-12)
        assert res.budget_spent and res.rate_cuts == 0
        assert res.rate_peak >= np.linalg.norm(sc.omega0)


def test_validation_renews_the_budget_every_episode_of_bursts(paper):
    sc = paper.replace(impulse_budget=2.0, bursts_per_episode=2, validation_coast=(5.0, 5.0))
    res = validate(sc, XI, 40.0, [0, 1])
    # 40 s of 6-s burst-and-coast segments after a 5-s coast: 6 bursts, 3 episodes of 2.
    assert np.allclose(res.impulse, 3 * 2.0, rtol=1e-9)
    assert res.summary()["impulse_used"] == pytest.approx([6.0, 6.0], rel=1e-9)


@pytest.mark.parametrize("field", ["impulse_budget", "rate_limit", "min_impulse_bit"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), "ten"])
def test_limits_must_be_positive_numbers(field, value):
    with pytest.raises(ConfigError, match=field):
        Scenario(**{field: value})


def test_a_limit_that_leaves_no_room_to_excite_is_warned_about():
    with pytest.warns(ScenarioWarning, match="rate_limit"):
        Scenario(rate_limit=5.0)
    with pytest.warns(ScenarioWarning, match="impulse_budget"):
        Scenario(impulse_budget=1e-3)
    with pytest.warns(ScenarioWarning, match="min_impulse_bit"):
        Scenario(min_impulse_bit=6.0)


def test_a_scenario_serialises_its_limits_only_where_set(paper):
    assert not set(paper.to_dict()) & {"impulse_budget", "rate_limit"}
    limited = paper.replace(impulse_budget=13.0)
    assert limited.to_dict()["impulse_budget"] == 13.0 and "rate_limit" not in limited.to_dict()
    assert Scenario.from_mapping(limited.to_dict()) == limited
