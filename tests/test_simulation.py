"""Closed-loop simulation plumbing: the measurement schedule."""

import numpy as np
import pytest

from inertia_gym.scenario import Scenario
from inertia_gym.simulation import _measurement_schedule


def _schedule_one_at_a_time(sc, rng, first, n_steps):
    """Definition: take a measurement at `first`, then draw one interval U[lo, hi] per
    measurement taken, while the measurement lies within the segment."""
    times, nxt = [], first
    while nxt <= n_steps:
        times.append(nxt)
        nxt += max(1, int(round(rng.uniform(*sc.meas_interval) / sc.dt)))
    return times, nxt - n_steps


@pytest.mark.parametrize("interval", [(0.1, 0.2), (0.01, 0.025), (0.3, 0.3), (5.0, 9.0)])
@pytest.mark.parametrize("first,n_steps", [(1, 1), (7, 5), (1, 3000), (25, 4321)])
def test_schedule_equals_drawing_intervals_one_at_a_time(interval, first, n_steps):
    sc = Scenario(meas_interval=interval)
    for seed in range(3):
        rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
        times, to_next = _measurement_schedule(sc, rng_a, first, n_steps)
        ref_times, ref_to_next = _schedule_one_at_a_time(sc, rng_b, first, n_steps)
        assert times.tolist() == ref_times
        assert to_next == ref_to_next
        # The generator is left where the one-at-a-time draws leave it.
        assert rng_a.standard_normal() == rng_b.standard_normal()
