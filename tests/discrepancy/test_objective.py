"""The least-squares vector diagnose's fits minimise (discrepancy/objective.py), against its
definition: each row's mean of (predicted - measured) over its samples, over the row's noise;
samples left out of every row unread; a model that blew up priced finitely."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from inertia_gym.discrepancy.data import prepare
from inertia_gym.discrepancy.objective import Layout, objective, predict, whitened
from inertia_gym.discrepancy.starts import initial_rates
from inertia_gym.discrepancy.synthetic import simulate_recording
from inertia_gym.estimation.inertia_param import phi_from_inertia
from inertia_gym.scenario import Scenario


@pytest.fixture(scope="module")
def blocked():
    """A 4-s record sampled at 1 kHz, slow enough that its rows are means of several samples,
    and two points of the rigid model: the true inertia and one 3 % off on an axis."""
    sc = Scenario(dt=1e-3, tau_max=50.0)
    rec, _ = simulate_recording(sc, 4.0, None, seed=2)
    d = prepare(rec)
    layout = Layout.of((), (), d)
    j = sc.inertia_true_array
    xs = np.stack([np.r_[phi_from_inertia(j @ np.diag(s)), initial_rates(d)]
                   for s in ([1, 1, 1], [1.03, 1, 1])])
    return d, layout, xs


def _by_definition(xs, layout, d):
    diff = predict(xs, layout, d) - d.w
    rows = np.zeros((len(xs), d.n_rows, 3))
    for r in range(d.n_rows):
        rows[:, r] = diff[:, d.row == r].mean(axis=1) / (d.sigma * d.row_scale[r])
    return rows


def test_rows_are_the_means_of_their_samples_over_their_noise(blocked):
    d, layout, xs = blocked
    assert d.block > 1
    np.testing.assert_allclose(whitened(xs, layout, d), _by_definition(xs, layout, d), rtol=1e-12,
                               atol=1e-12)


def test_samples_outside_every_row_are_not_read(blocked):
    d, layout, xs = blocked
    row = d.row.copy()
    row[row == 3] = -1  # one row's samples left out: the rows after it keep their numbers
    row[row > 3] -= 1
    fewer = dataclasses.replace(d, row=row, row_seg=np.delete(d.row_seg, 3),
                                row_scale=np.delete(d.row_scale, 3), cache={})
    w = fewer.w.copy()
    w[row < 0] = np.nan  # unread, or the rows would be NaN
    fewer = dataclasses.replace(fewer, w=w)
    np.testing.assert_allclose(whitened(xs, layout, fewer), _by_definition(xs, layout, fewer),
                               rtol=1e-12, atol=1e-12)


def test_a_noise_level_changed_on_shared_data_is_the_one_read(blocked):
    """Data replaced with another noise level share the model's cache: the rows follow the new
    level, not the first one read."""
    d, layout, xs = blocked
    first = whitened(xs, layout, d)
    doubled = dataclasses.replace(d, sigma=2 * d.sigma)
    assert doubled.cache is d.cache
    np.testing.assert_allclose(whitened(xs, layout, doubled), first / 2, rtol=1e-12)
    np.testing.assert_allclose(whitened(xs, layout, d), first, rtol=1e-12)


def test_a_model_that_blew_up_costs_the_clip_on_every_row(blocked):
    d, layout, xs = blocked
    broken = xs.copy()
    broken[1, layout.n_global:] = np.nan  # no rates to start from: the model cannot be integrated
    z = objective(broken, layout, d)
    assert np.all(np.isfinite(z))
    np.testing.assert_array_equal(np.abs(z[1]), 1e6)
    np.testing.assert_allclose(z[0], whitened(xs[:1], layout, d).ravel(), rtol=1e-12)


@pytest.mark.parametrize("names, parts", [
    (("constant_body_torque", "gyro_bias"), ([1e-3, -2e-3, 5e-4], [2e-3, 1e-3, -1e-3])),
    # array-valued terms (a momentum on the grid, an inertia change) shared between points
    (("internal_momentum", "inertia_change"), ([0.5, -0.3, 1.0], [2.0, 0.8, 0.1, -0.2, 0.5, 0.05, 0.3])),
])
def test_a_batch_predicts_each_point_as_it_would_alone(blocked, names, parts):
    """Points that share one effect's parameters and differ in another's (a Jacobian's columns)
    share the terms of the effect they agree on: each point's prediction is the one it has
    alone, bit for bit."""
    d, layout, xs = blocked
    two = Layout.of(names, ("", ""), d)
    assert two.sizes == tuple(len(p) for p in parts)
    first, second = two.slices()
    base = np.r_[xs[1, :6], parts[0], parts[1], xs[1, 6:]]
    batch = np.repeat(base[None], 5, axis=0)
    batch[1, first.start] *= 1.5  # the first effect moved, the second shared
    batch[2, second.stop - 1] *= -1.0  # the second moved, the first shared
    batch[3, 0] *= 1.01  # the fitted inertia moved (unread: the record's nominal is the base)
    batch[4, first] = 0.0  # the first effect off
    together = predict(batch, two, d)
    for i, x in enumerate(batch):
        np.testing.assert_array_equal(together[i], predict(x[None], two, d)[0])
    assert d.inertia0 is not None
    np.testing.assert_array_equal(together[3], together[0])
    for i in (1, 2, 4):
        assert not np.array_equal(together[i], together[0])
